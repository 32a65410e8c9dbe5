"""Write example machine logs and their import mapping: the "bring your own machine" demo.

The machine is a 3-joint hydraulic arm (boom, arm, bucket; no swing) simulated in numpy by
``tests/helpers/arm3_plant.py`` (independent of the package's MuJoCo plant).  The logs look
like a real controller's: CSV at 100 Hz with timing jitter, time in ms, angles in degrees,
two one-way valve duties per joint in %, no velocity channel.  One log has a 3 s logger
pause (it is split into two episodes) and one is too short for the model window (it is
dropped, with the reason in the import report).

    python examples/arm3_make_logs.py --out arm3_demo
    exsur import arm3_demo/logs --mapping arm3_demo/arm3.toml --out arm3_demo/dataset
"""

from __future__ import annotations

import argparse
import importlib.util
import sys
from pathlib import Path
from types import ModuleType

PLANT = Path(__file__).resolve().parents[1] / "tests" / "helpers" / "arm3_plant.py"


def load_plant() -> ModuleType:
    """Import ``tests/helpers/arm3_plant.py`` by path (the tests are not installed)."""
    spec = importlib.util.spec_from_file_location("arm3_plant", PLANT)
    if spec is None or spec.loader is None:
        raise SystemExit(
            f"cannot find the test plant at {PLANT}; run from a clone of the repository"
        )
    mod = importlib.util.module_from_spec(spec)
    sys.modules["arm3_plant"] = mod
    spec.loader.exec_module(mod)
    return mod


def main(argv: list[str] | None = None) -> int:
    """Write OUT/logs/run01.csv ... and OUT/arm3.toml."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--out", type=Path, default=Path("arm3_demo"), help="folder to write (default arm3_demo)"
    )
    ap.add_argument("--n-logs", type=int, default=16, help="number of logs")
    ap.add_argument("--duration", type=float, default=120.0, help="length of each log [s]")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    plant = load_plant()
    logs = args.out / "logs"
    for i in range(args.n_logs):
        cols = plant.simulate(duration_s=args.duration, seed=args.seed + i)
        if i == 1:  # the logger paused for 3 s: rows between 20 s and 23 s are missing
            t = cols["t_ms"] * 1e-3
            keep = (t < 20.0) | (t >= 23.0)
            cols = {k: v[keep] for k, v in cols.items()}
        path = plant.write_csv(logs / f"run{i + 1:02d}.csv", cols)
        print(f"wrote {path} ({len(cols['t_ms'])} rows)")
    short = plant.simulate(duration_s=1.5, seed=args.seed + 99)  # 1.5 s: shorter than the window
    print(f"wrote {plant.write_csv(logs / 'run99_short.csv', short)} ({len(short['t_ms'])} rows)")
    mapping = args.out / "arm3.toml"
    mapping.write_text(plant.MAPPING_TOML)
    print(f"wrote {mapping}")
    print(f"next: exsur import {logs} --mapping {mapping} --out {args.out / 'dataset'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
