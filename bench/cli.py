"""Benchmark the command line's start-up: ``exsur --help`` against importing torch.

Building the parser registers every subcommand, so an import on that path is paid by every
``--help``; torch took 2-4 s of a 4.7-s ``exsur --help`` on a slow computer before the parser
stopped importing it.  This times, in alternation (medians of ``--repeats`` fresh
interpreters each, side by side in one run):

- ``python -c pass``: the interpreter alone;
- ``exsur --help`` and ``exsur run --help`` (``python -m excavator_surrogate``);
- ``python -c "import torch"``: what a command that trains or runs a model pays first.

The last line printed is one JSON object with a ``goals`` object of booleans: each help
within half of torch's import (``--help`` must not wait for torch), and no help imports
torch, SciPy or MuJoCo::

    python bench/cli.py
    python bench/cli.py --repeats 9
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import time

GOAL_OVER_TORCH = 0.5
"""Each help's median within this share of ``import torch``'s."""
HEAVY = ("torch", "scipy", "mujoco")
"""Modules no help may import."""

COMMANDS = {
    "python": [sys.executable, "-c", "pass"],
    "help": [sys.executable, "-m", "excavator_surrogate", "--help"],
    "run_help": [sys.executable, "-m", "excavator_surrogate", "run", "--help"],
    "import_torch": [sys.executable, "-c", "import torch"],
}
"""What is timed, each in a fresh interpreter."""

PROBE = (
    "import contextlib, io, sys\n"
    "from excavator_surrogate.cli import main\n"
    "for argv in (['--help'], ['run', '--help']):\n"
    "    with contextlib.redirect_stdout(io.StringIO()), contextlib.suppress(SystemExit):\n"
    "        main(argv)\n"
    f"print(','.join(m for m in {HEAVY!r} if m in sys.modules))\n"
)
"""A fresh interpreter that prints the heavy modules the two helps imported."""


def wall(argv: list[str]) -> float:
    """Wall time of one run of ``argv`` [s]; it must succeed."""
    t0 = time.perf_counter()
    subprocess.run(argv, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return time.perf_counter() - t0


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark; print a summary and one JSON line."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=5, help="runs of each command (median)")
    args = ap.parse_args(argv)
    times: dict[str, list[float]] = {k: [] for k in COMMANDS}
    for k in COMMANDS:  # once each first: the page cache warm for every one alike
        wall(COMMANDS[k])
    for _ in range(max(1, args.repeats)):
        for k, cmd in COMMANDS.items():  # in alternation: a slow minute hits every one
            times[k].append(wall(cmd))
    med = {k: statistics.median(v) for k, v in times.items()}
    probe = subprocess.run(
        [sys.executable, "-c", PROBE], check=True, capture_output=True, text=True
    ).stdout.strip()
    heavy = [m for m in probe.split(",") if m]
    torch_s = med["import_torch"]
    for k, s in med.items():
        print(f"{k:>13}: {s:6.2f} s (median of {len(times[k])})")
    print(f"modules the helps imported of {', '.join(HEAVY)}: {', '.join(heavy) or 'none'}")
    over = {k: med[k] / torch_s for k in ("help", "run_help")}
    print(
        json.dumps(
            {
                "bench": "cli",
                "repeats": args.repeats,
                "seconds": {k: round(s, 3) for k, s in med.items()},
                "help_over_import_torch": round(over["help"], 3),
                "run_help_over_import_torch": round(over["run_help"], 3),
                "heavy_imported": heavy,
                "goals": {
                    f"help_le_{GOAL_OVER_TORCH:g}x_import_torch": over["help"] <= GOAL_OVER_TORCH,
                    f"run_help_le_{GOAL_OVER_TORCH:g}x_import_torch": over["run_help"]
                    <= GOAL_OVER_TORCH,
                    "helps_import_no_torch_scipy_mujoco": not heavy,
                },
            }
        )
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
