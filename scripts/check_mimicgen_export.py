"""Step 1 of scripts/check_mimicgen_signals.py, in digail's venv: export the robomimic fixture's known phases
(reach=0, carry=1) as check_format_exports.py does, and write digail's own segment table (csv export of the same
codes) beside it, into $MG_CHECK_OUT (default /tmp/mg_check)."""
import os
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
# run as a script, so its own folder (scripts/) is already where imports look
from format_fixture_episodes import episodes  # noqa: E402

from digail.data.annotations import export_segmentation  # noqa: E402
from digail.data.importers import read_demonstrations  # noqa: E402

NAMES = ["reach", "carry"]
OUT = Path(os.environ.get("MG_CHECK_OUT", "/tmp/mg_check"))
phases = [e["phase"] for e in episodes()]
im = read_demonstrations(ROOT / "tests/data/formats/robomimic_robosuite.hdf5")
codes = [p[:len(t)] for p, t in zip(phases, im.trajs, strict=True)]
for fmt, name in (("robomimic", "annotated-robomimic.hdf5"), ("csv", "segments.csv")):
    out = export_segmentation(fmt, OUT / name, im.episode_keys, codes, NAMES, source=im.source, force=True)
    print(fmt, "->", out)
