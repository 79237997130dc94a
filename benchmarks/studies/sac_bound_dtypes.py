"""How fast could one SAC update be if it were only its matrix products, in float32 and in bfloat16?

    python benchmarks/studies/sac_bound_dtypes.py [--env Hopper-v5] [--sizes 64 256 64:256] [--sb3 FILE]

The products are `benchmarks/sac_speed.py`'s `update_matmuls` (both critics and targets forward, the critics'
weight and input gradients, the policy's gradient back through the critics, the actor forward twice and
backward), timed on one thread by its `matmul_bound`, once with float32 and once with bfloat16 operands.
With `--sb3` (default benchmarks/results/speed/sac_speed.json) each bound is also divided by that file's SB3 steps
per CPU second at the same size: the most any SAC update of these nets could gain over SB3 here. Writes
benchmarks/studies/results/sac_bound_dtypes.json.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import sys
from pathlib import Path
from types import ModuleType

import torch

os.environ.setdefault("MUJOCO_GL", "egl")


def _sac_speed() -> ModuleType:
    """benchmarks/sac_speed.py, loaded from its file (this study lives one folder below it)."""
    spec = importlib.util.spec_from_file_location("sac_speed", Path(__file__).resolve().parents[1] / "sac_speed.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


_speed = _sac_speed()
matmul_bound, update_matmuls = _speed.matmul_bound, _speed.update_matmuls


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--env", default="Hopper-v5")
    parser.add_argument("--sizes", nargs="+", default=["64", "256", "64:256"])
    parser.add_argument("--sb3", type=Path, default=Path("benchmarks/results/speed/sac_speed.json"))
    parser.add_argument("--out", type=Path, default=Path("benchmarks/studies/results/sac_bound_dtypes.json"))
    args = parser.parse_args()
    torch.set_num_threads(1)
    sb3 = json.loads(args.sb3.read_text()) if args.sb3.is_file() else {}
    result: dict[str, object] = {"env": args.env, "torch": torch.__version__, "torch_threads": 1,
                                 "cpu_capability": torch.backends.cpu.get_cpu_capability(),
                                 "loadavg_start": os.getloadavg()[0], "sb3_from": str(args.sb3)}
    for h in args.sizes:
        shapes = update_matmuls(args.env, h)
        for name, dtype in (("float32", torch.float32), ("bfloat16", torch.bfloat16)):
            rate = matmul_bound(shapes, dtype=dtype)
            result[f"bound_{name}_cpu_sps_{h}"] = rate
            ref = sb3.get(f"sb3_cpu_sps_{h}")
            if ref:
                result[f"bound_{name}_over_sb3_{h}"] = rate / ref
        print({k: round(v, 2) for k, v in result.items() if k.endswith(f"_{h}") and isinstance(v, float)},
              flush=True)
    result["loadavg_end"] = os.getloadavg()[0]
    args.out.write_text(json.dumps(result, indent=2) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
