"""Export a segmentation of the format fixtures with digail and load the copies with robomimic's and LeRobot's own
loaders, recording what those loaders return (tests/data/formats/*.check.json).

Runs in digail's environment and calls the fixture scripts in the libraries' own (see
scripts/make_format_fixtures_robomimic.py and ..._lerobot.py for how those are made):

    python scripts/check_format_exports.py --robomimic-python venv-robomimic/bin/python \\
        --lerobot-python venv-lerobot/bin/python

The segmentation exported is the fixtures' own phases (reach, then carry) as codes 0 and 1, so the record says
what each loader reads for a known answer; tests/test_formats.py checks that digail's export of the same codes
still writes exactly what the loaders read then.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
FIXTURES = ROOT / "tests" / "data" / "formats"
# run as a script, so its own folder (scripts/) is already where imports look
from format_fixture_episodes import episodes  # noqa: E402

NAMES = ["reach", "carry"]


def main() -> None:
    from digail.data.annotations import export_segmentation
    from digail.data.importers import read_demonstrations

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robomimic-python", type=Path, required=True)
    parser.add_argument("--lerobot-python", type=Path, required=True)
    args = parser.parse_args()
    phases = [e["phase"] for e in episodes()]
    with tempfile.TemporaryDirectory() as tmp:
        for fmt, source, python, script, extra in (
            ("robomimic", FIXTURES / "robomimic_robosuite.hdf5", args.robomimic_python,
             "make_format_fixtures_robomimic.py", ["--signals", *NAMES]),
            ("lerobot", FIXTURES / "lerobot", args.lerobot_python, "make_format_fixtures_lerobot.py", []),
        ):
            im = read_demonstrations(source)
            codes = [p[:len(t)] for p, t in zip(phases, im.trajs, strict=True)]
            out = export_segmentation(fmt, Path(tmp) / f"annotated-{fmt}", im.episode_keys, codes, NAMES,
                                      source=im.source)
            run = subprocess.run([str(python), str(ROOT / "scripts" / script), "--check", str(out), *extra],
                                 capture_output=True, text=True, check=True)
            record = json.loads(run.stdout.strip().splitlines()[-1])
            (FIXTURES / f"{fmt}.check.json").write_text(json.dumps(record, indent=1) + "\n")
            print(f"{fmt}: {script} --check loaded the export; recorded in {FIXTURES / f'{fmt}.check.json'}")


if __name__ == "__main__":
    main()
