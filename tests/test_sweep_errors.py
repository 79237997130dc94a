"""`digail sweep` refuses bad input before Ray starts: one sentence, exit status 2, nothing written; a sweep whose
trials failed exits non-zero and says how many; a local sweep's Ray listens on 127.0.0.1 only and leaves no process
or session folder behind, even when its driver is SIGKILLed."""

from __future__ import annotations

import glob
import os
import socket
import subprocess
import sys
import tempfile
import textwrap
import time
from pathlib import Path

import pytest

from digail.cli import main

CW = "digail/CircleWorld-v0"

SPECS = {
    "unknown_env.toml": 'envs = ["digail/NoSuchEnv-v0"]\n',
    "seed_a.toml": f'envs = ["{CW}"]\nseeds = ["a"]\n',
    "search_key.toml": f'envs = ["{CW}"]\nset = {{ "train.bonus_weight" = "0.01..0.1" }}\n[search]\nbudget = 3\n',
    "retries.toml": f'envs = ["{CW}"]\nretries = -1\n',
    "episodes.toml": f'envs = ["{CW}"]\nepisodes = 0\n',
    "no_demos.toml": f'envs = ["{CW}"]\ndemos = "nope/nothing-v0"\n',
    "other_demos.toml": f'envs = ["{CW}"]\ndemos = "digail/fourrooms/expert-v0"\n',
    "bad_set.toml": f'envs = ["{CW}"]\nmethods = ["vae"]\nset = {{ "train.no_such_field" = 1 }}\n',
    "set_out.toml": f'envs = ["{CW}"]\nmethods = ["vae"]\n[set]\n"pretrain.out" = "/tmp"\n',
    "grid_set_out.toml": f'[[grid]]\nenvs = ["{CW}"]\nset = {{ "train.out" = "../../x" }}\n',
    "tuple_flag.toml": f'envs = ["{CW}"]\nset = {{ "train.hidden" = [[64, "--out", "/tmp"]] }}\n',
}


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


# argv (OUT / SPEC / FILE replaced) -> a fragment of the one sentence
CASES: list[tuple[str, str]] = [
    ("--spec SPEC/unknown_env.toml --out OUT", "unknown environment id 'digail/NoSuchEnv-v0'"),
    ("--spec SPEC/no_demos.toml --out OUT", "its demonstrations 'nope/nothing-v0' cannot be read"),
    ("--spec SPEC/other_demos.toml --out OUT", "were recorded in digail/FourRooms-v0"),
    (f"--envs {CW} --set train.no_such_field=1 --out OUT", "'train.no_such_field' is not a setting a sweep may"),
    (f"--envs {CW} --methods vae --set train.no_such_field=1 --out OUT", "'train.no_such_field' is not a setting"),
    (f"--envs {CW} --methods vae --set vae.no_such_field=1 --out OUT", "'vae.no_such_field' is not a setting"),
    (f"--envs {CW} --methods gail --set evaluate.no_such=1 --out OUT", "'evaluate.no_such' is not a setting"),
    ("--spec SPEC/bad_set.toml --out OUT", "'train.no_such_field' is not a setting a sweep may"),
    # an override sets hyper-parameters only: never a stage's output, input or control flag
    (f"--envs {CW} --methods vae --set pretrain.out=PLACES/victim --out OUT", "'pretrain.out' is not a setting"),
    (f"--envs {CW} --set train.out=../../x --out OUT", "'train.out' is not a setting"),
    (f"--envs {CW} --set pretrain.force=true --out OUT", "'pretrain.force' is not a setting"),
    (f"--envs {CW} --set pretrain.demos=x --out OUT", "'pretrain.demos' is not a setting"),
    (f"--envs {CW} --set segment.demos=x --out OUT", "'segment.demos' is not a setting"),
    (f"--envs {CW} --set pretrain.device=cpu --out OUT", "'pretrain.device' is not a setting"),
    (f"--envs {CW} --set pretrain.resume=x --out OUT", "'pretrain.resume' is not a setting"),
    (f"--envs {CW} --set demos.path=x --out OUT", "'demos.path' is not a setting"),
    (f"--envs {CW} --set train.method=gail --out OUT", "'train.method' is not a setting"),
    (f"--envs {CW} --set train.ppo=1 --out OUT", "'train.ppo' is not a setting"),
    (f"--envs {CW} --set train.bonus_weight=--force --out OUT", "may not start with '-'"),
    ("--spec SPEC/set_out.toml --out OUT", "'pretrain.out' is not a setting"),
    ("--spec SPEC/grid_set_out.toml --out OUT", "'train.out' is not a setting"),
    ("--spec SPEC/tuple_flag.toml --out OUT", "may not start with '-'"),
    (f"--envs {CW} --set train.bonus_weight=abc --out OUT", "train.bonus_weight=abc"),
    (f"--envs {CW} --set train.bonus_weight=0.1.. --out OUT", "range '0.1..' is malformed"),
    (f"--envs {CW} --set train.bonus_weight=..0.1x --out OUT", "train.bonus_weight=..0.1x"),
    ("--spec SPEC/seed_a.toml --out OUT", "seed 'a' is not a seed"),
    ("--spec SPEC/search_key.toml --out OUT", "[search] has unknown key(s) budget"),
    ("--spec SPEC/retries.toml --out OUT", "retries must be a whole number of at least 0"),
    (f"--envs {CW} --retries -1 --out OUT", "retries must be a whole number of at least 0"),
    ("--spec SPEC/episodes.toml --out OUT", "episodes must be a whole number of at least 1"),
    (f"--envs {CW} --episodes 0 --out OUT", "--episodes must be at least 1"),
    (f"--envs {CW} --seeds --out OUT", "--seeds was given no value"),
    (f"--envs {CW} --methods --out OUT", "--methods was given no value"),
    (f"--envs {CW} --cpus-per-trial 4 --num-cpus 2 --out OUT", "needs 4 CPU but the largest node"),
    (f"--envs {CW} --cpus-per-trial 0 --out OUT", "cpus per trial must be more than 0"),
    (f"--envs {CW} --gpus-per-trial 1 --out OUT", "--gpus-per-trial 1 but"),
    (f"--envs {CW} --address 127.0.0.1:PORT --out OUT", "no Ray cluster answers at 127.0.0.1:"),
    (f"--envs {CW} --address auto --out OUT", "no Ray cluster at --address auto"),
    (f"--envs {CW} --address nowhere --out OUT", "is not a Ray address"),
    (f"--envs {CW} --set train.bonus_weight=0.01..0.1 --search optuna --address 127.0.0.1:PORT --out OUT",
     "a search on a Ray cluster runs its trials in the sweep folder itself"),
    (f"--envs {CW} --out FILE", "is a file, not a folder"),
    (f"--envs {CW} --out FILE/sub", "is a file, not a folder"),
    ("--summarize BROKEN", "sweep.json is not valid JSON"),
    (f"--envs {CW} --methods vae --out TRUNCATED", "vae_s0.json is not valid JSON"),
]


@pytest.fixture(scope="module")
def places(tmp_path_factory):
    root = tmp_path_factory.mktemp("sweep_errors")
    (root / "spec").mkdir()
    for name, text in SPECS.items():
        (root / "spec" / name).write_text(text)
    (root / "file").write_text("not a folder\n")
    (root / "victim").mkdir()
    (root / "victim" / "thesis.tex").write_text("a user's file\n")
    (root / "broken").mkdir()
    (root / "broken" / "sweep.json").write_text('{"name": "x", "jo')
    (root / "truncated" / "trials").mkdir(parents=True)
    (root / "truncated" / ".digail").write_text("\n")  # a sweep folder, as every sweep marks its own
    (root / "truncated" / "trials" / "digail-CircleWorld-v0__vae_s0.json").write_text('{"stat')
    return root


def _tree(path: Path) -> dict[str, bytes]:
    return {str(p.relative_to(path)): p.read_bytes() for p in sorted(path.rglob("*")) if p.is_file()}


@pytest.mark.parametrize(("argv", "fragment"), CASES, ids=[c[0] for c in CASES])
def test_bad_sweep_input_is_one_sentence_exit_2_nothing_written_no_ray(argv, fragment, places, tmp_path, capsys,
                                                                      monkeypatch):
    ray = pytest.importorskip("ray")
    import ray._private.services as services

    monkeypatch.delenv("RAY_ADDRESS", raising=False)
    # `--address auto` would join any Ray running on this machine (another job's): none is running, as far as it knows
    nothing = lambda: []  # noqa: E731
    nothing.cache_clear = lambda: None  # type: ignore[attr-defined]
    monkeypatch.setattr(services, "find_gcs_addresses", nothing)
    monkeypatch.setattr(services, "find_bootstrap_address", lambda temp_dir: None)
    out = tmp_path / "out"
    words = (argv.replace("SPEC", str(places / "spec")).replace("OUT", str(out)).replace("FILE", str(places / "file"))
             .replace("BROKEN", str(places / "broken")).replace("TRUNCATED", str(places / "truncated"))
             .replace("PORT", str(_free_port())).replace("PLACES", str(places))).split()
    before = {p: _tree(places / p) for p in ("broken", "truncated", "victim")}
    ray_dirs = set(glob.glob(os.path.join(tempfile.gettempdir(), "digail-ray-*")))
    code = main(["sweep", *words])
    err = capsys.readouterr().err
    assert code == 2, err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("digail sweep: error: "), err
    assert fragment in lines[0], lines[0]
    assert "Traceback" not in err
    assert not out.exists(), "a refused sweep wrote its folder"
    assert before == {p: _tree(places / p) for p in ("broken", "truncated", "victim")}
    assert not ray.is_initialized(), "Ray was started for a sweep that could not run"
    assert set(glob.glob(os.path.join(tempfile.gettempdir(), "digail-ray-*"))) == ray_dirs


def test_dashboard_without_its_packages_is_refused(monkeypatch, tmp_path, capsys):
    pytest.importorskip("ray")
    import ray._private.utils as ray_utils

    monkeypatch.setattr(ray_utils, "get_dashboard_dependency_error", lambda: ImportError("No module named 'aiohttp'"))
    code = main(["sweep", "--envs", CW, "--dashboard", "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert code == 2 and "--dashboard needs Ray's dashboard packages" in err and not (tmp_path / "out").exists()


def test_failed_trials_exit_non_zero_and_say_how_many(monkeypatch, tmp_path, capsys):
    import digail.sweep as sweep_pkg

    out = tmp_path / "sweep"

    def fake_run_sweep(spec, folder, **kwargs):
        Path(folder).mkdir()
        (Path(folder) / "results.md").write_text("# Sweep\n")
        return {"sweep": str(folder), "trials": 3, "done": 1, "table": {},
                "failed": [{"job": "digail-CircleWorld-v0/digail_s0", "error": "x"},
                           {"job": "digail-CircleWorld-v0/digail_s1", "error": "y"}]}

    monkeypatch.setattr(sweep_pkg, "run_sweep", fake_run_sweep)
    code = main(["sweep", "--envs", CW, "--seeds", "0", "1", "2", "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 1, err
    assert "2 of 3 trials failed" in err


# ------------------------------------------------------------------------------ a local Ray: loopback, no leftovers
def _listening(pids: set[int]) -> list[tuple[str, int, int]]:
    """(address, port, pid) of the TCP sockets the processes `pids` listen on, read from /proc."""
    inodes: dict[str, int] = {}
    for pid in pids:
        with_fd = Path(f"/proc/{pid}/fd")
        try:
            for fd in with_fd.iterdir():
                target = os.readlink(fd)
                if target.startswith("socket:["):
                    inodes[target[8:-1]] = pid
        except OSError:
            continue
    out = []
    for table, size in (("/proc/net/tcp", 4), ("/proc/net/tcp6", 16)):
        for row in Path(table).read_text().splitlines()[1:]:
            cols = row.split()
            local, state, inode = cols[1], cols[3], cols[9]
            if state != "0A" or inode not in inodes:  # 0A: LISTEN
                continue
            hex_ip, hex_port = local.split(":")
            raw = bytes.fromhex(hex_ip)
            raw = b"".join(raw[i:i + 4][::-1] for i in range(0, size, 4))  # the kernel writes 32-bit words
            family = socket.AF_INET if size == 4 else socket.AF_INET6
            out.append((socket.inet_ntop(family, raw), int(hex_port, 16), inodes[inode]))
    return out


def _session_pids(folder: str) -> set[int]:
    marker = f"DIGAIL_RAY_SESSION={folder}".encode()
    pids = set()
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                if marker in (entry / "environ").read_bytes().split(b"\0"):
                    pids.add(int(entry.name))
            except OSError:
                continue
    return pids


DRIVER = textwrap.dedent("""
    import os, sys, time
    from digail.sweep import start_ray
    session = start_ray(num_cpus=1)
    import ray
    ray.get(ray.remote(lambda: os.getpid()).remote())  # a worker process too
    print(session.folder, flush=True)
    time.sleep(600)
""")


@pytest.mark.skipif(not Path("/proc/net/tcp").exists(), reason="reads Linux's /proc")
def test_local_ray_listens_on_loopback_only_and_nothing_outlives_a_killed_driver(tmp_path):
    pytest.importorskip("ray")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    env.pop("RAY_ADDRESS", None)
    driver = subprocess.Popen([sys.executable, "-c", DRIVER], stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                              env=env, text=True)
    try:
        folder = driver.stdout.readline().strip()
        assert folder and Path(folder).is_dir(), "the driver did not start Ray"
        pids = _session_pids(folder)
        names = {pid: Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")[0].decode() for pid in pids}
        assert any("raylet" in n for n in names.values()) and any("gcs_server" in n for n in names.values())
        sockets = _listening(pids)
        assert len({pid for _, _, pid in sockets}) >= 3, sockets  # GCS, raylet, worker at least
        outside = [(ip, port, names.get(pid)) for ip, port, pid in sockets if ip not in ("127.0.0.1",
                                                                                         "::ffff:127.0.0.1")]
        assert not outside, f"Ray listens beyond the loopback interface: {outside}"
        assert not [s for s in sockets if s[1] in (8265, 10001)], "a dashboard or Ray Client port is open"
    finally:
        driver.kill()
        driver.wait()
    deadline = time.time() + 30
    while time.time() < deadline and (_session_pids(folder) or Path(folder).exists()):
        time.sleep(0.5)
    left = {pid: Path(f"/proc/{pid}/cmdline").read_bytes()[:80] for pid in _session_pids(folder)}
    assert not left, f"processes of the killed driver's Ray are still running: {left}"
    assert not Path(folder).exists(), "the Ray session folder was left behind"
