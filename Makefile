# Every target sets up its own virtual environment, so a fresh clone needs only Python 3.11 and make.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
# torch first and pinned: a CPU build of exactly this version is what pip finds locally; a looser spec
# in a fresh venv can pull a multi-GB CUDA build.
TORCH := torch==2.13.0
PINS := "gymnasium[mujoco,classic-control]==1.4.0" "mujoco==3.11.0" "stable-baselines3==2.9.2" "gymnasium-robotics==1.4.2"
# Meta-World pins mujoco 3.3.0 but runs on the pin above: installed without its dependencies (all of which the
# pins bring: gymnasium, mujoco, numpy, scipy, imageio), after them, so it cannot move them
METAWORLD := metaworld==3.1.1

.PHONY: demo test test-kernels test-slow test-all bench lint docs venv clean presets-doc hashes table1 table2 readme-tables segmentation-table

$(BIN)/activate:
	$(PY) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip

$(VENV)/.installed: $(BIN)/activate pyproject.toml
	$(BIN)/pip install -q $(TORCH)
	$(BIN)/pip install -q $(PINS) -e ".[dev,sweep]"
	$(BIN)/pip install -q --no-deps $(METAWORLD)
	touch $@

venv: $(VENV)/.installed

demo: venv
	MUJOCO_GL=egl $(BIN)/digail run

# the default run leaves out the long checks (marked slow: learning checks, the Ray fault test); CI runs both
test: venv
	MUJOCO_GL=egl $(BIN)/python -m pytest -q -m "not slow" --durations=10

# every test module comparing floats of fitted models or closed-loop rollouts again under torch's portable and AVX2
# kernels (the default run uses the machine's best, e.g. AVX-512): a test whose outcome hangs on the last bits of a
# float fails here on any machine (tests/test_repo_rules.py checks that the list is complete)
KERNEL_TESTS := tests/test_ablations.py tests/test_committed_runs.py tests/test_composition.py \
	tests/test_disc_view.py tests/test_episodes.py tests/test_fast_path.py tests/test_fetch.py tests/test_gail.py \
	tests/test_learners.py tests/test_ppo.py tests/test_registry.py tests/test_returns.py tests/test_rewards.py \
	tests/test_room_visits.py tests/test_sac.py tests/test_segmentation.py tests/test_segmentation_benchmark.py \
	tests/test_vae.py tests/test_vector.py
# Each capability compiles into its own fresh inductor cache: torch's cache key leaves the capability out, and a
# graph compiled by an earlier run and loaded under ATEN_CPU_CAPABILITY=avx2 gave NaN weights.
test-kernels: venv
	for cap in default $$(grep -q avx2 /proc/cpuinfo 2>/dev/null && echo avx2); do \
		echo "ATEN_CPU_CAPABILITY=$$cap"; \
		cache=$$(mktemp -d) && \
		TORCHINDUCTOR_CACHE_DIR=$$cache ATEN_CPU_CAPABILITY=$$cap MUJOCO_GL=egl $(BIN)/python -m pytest -q \
			-m "not slow" -p no:cacheprovider $(KERNEL_TESTS); status=$$?; rm -rf $$cache; \
		[ $$status -eq 0 ] || exit 1; \
	done

test-slow: venv
	MUJOCO_GL=egl $(BIN)/python -m pytest -q -m slow --durations=10

test-all: venv
	MUJOCO_GL=egl $(BIN)/python -m pytest -q

# measures into runs/bench/ (untracked); publishing a measurement is a deliberate copy into benchmarks/results/
bench: venv
	mkdir -p runs/bench
	MUJOCO_GL=egl $(BIN)/python benchmarks/throughput.py --out runs/bench/throughput.json
	MUJOCO_GL=egl $(BIN)/python benchmarks/throughput.py --env digail/FetchPickAndPlace-v4 --rounds 3 \
		--out runs/bench/throughput_fetch.json

# behaviour fingerprint (sha256 of weights and metrics of short fixed-seed runs): equal before and after a refactor
hashes: venv
	MUJOCO_GL=egl $(BIN)/python benchmarks/hashes.py --out runs/hashes

# Generators of the published tables: each rewrites its file under benchmarks/results/ (and its README table) from
# the runs or sweeps its docstring names; run one on purpose, then commit what changed.
SWEEPS ?= runs/sweeps
table1: venv
	$(BIN)/python benchmarks/table1.py $(if $(wildcard $(SWEEPS)/table1/results.json),sweep $(SWEEPS)/table1,readme)

table2: venv
	$(BIN)/python benchmarks/table2.py $(SWEEPS)/table2

readme-tables: venv
	$(BIN)/python benchmarks/readme_tables.py $(SWEEPS)/results-fourrooms $(SWEEPS)/results-circleworld

segmentation-table: venv
	MUJOCO_GL=egl $(BIN)/python benchmarks/segmentation.py

# docs/presets.md from src/digail/presets/*.toml (tests/test_presets.py checks it is up to date)
presets-doc: venv
	$(BIN)/python scripts/presets_doc.py

lint: venv
	$(BIN)/ruff check src tests benchmarks
	$(BIN)/mypy src
	$(BIN)/lint-imports

# the documentation site into site/; --strict turns a broken link, anchor or API reference into an error
docs: venv
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs build --strict

clean:
	rm -rf $(VENV) build site *.egg-info
