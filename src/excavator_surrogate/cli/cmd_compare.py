"""``exsur compare CKPT --commands SRC``: replay commands through the MuJoCo and surrogate envs."""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

from .common import add_out


def register(sub: argparse._SubParsersAction) -> None:
    """Add the ``compare`` subcommand."""
    p = sub.add_parser(
        "compare",
        help="equivalence check: same commands through ExcavatorMujoco-v0 and ExcavatorSurrogate-v0",
        description="Drive ExcavatorMujoco-v0 (reference) and ExcavatorSurrogate-v0 with the same "
        "command sequence from the same at-rest pose and report the CBE metrics (RMSE, MAE, R² per "
        "joint for ω and θ). Writes metrics.json, table.md, compare.png and trajectories.npz.",
    )
    p.add_argument("ckpt", type=Path, help="surrogate checkpoint .pt")
    p.add_argument(
        "--commands",
        required=True,
        help="a CSV with u_<joint> columns, an episode .parquet, or a named excitation "
        "KIND[:seed=N,seconds=S|n_step=N] (steps, multisine, chirp, prbs, work_cycle), e.g. steps:seed=1",
    )
    add_out(p, "output folder (default: CKPT's folder/compare)", replaced=False, required=False)
    p.add_argument(
        "--theta0",
        default=None,
        help="start pose, comma-separated angles in rad (default: the file's first theta, else mid-range)",
    )
    p.add_argument(
        "--plant",
        choices=["ideal", "hydraulic"],
        default=None,
        help="MuJoCo plant (default: the one the checkpoint was trained on; another is refused)",
    )
    p.add_argument("--device", default="cpu", help="surrogate device (cpu, cuda, auto)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Run the comparison and print the table."""
    import numpy as np

    from ..env.compare import compare
    from ..errors import ConfigError
    from ..outdir import check_out_dir

    theta0 = None
    if args.theta0:
        try:
            theta0 = np.array([float(x) for x in args.theta0.split(",")])
        except ValueError as e:
            raise ConfigError(
                f"--theta0 must be comma-separated numbers in rad, got '{args.theta0}'"
            ) from e
    out = check_out_dir(
        args.out or args.ckpt.parent / "compare",
        overwrite=args.overwrite,
        lock=True,
        kind="compare",
    )
    res = compare(
        args.ckpt, args.commands, theta0=theta0, out=out, plant=args.plant, device=args.device
    )
    print((out / "table.md").read_text(encoding="utf-8"), end="")
    log = logging.getLogger(__name__)
    log.info(f"wrote {out}/metrics.json, table.md, compare.png, trajectories.npz")
    if res.metrics["run"]["diverged_at"] is not None:
        log.warning(f"the surrogate diverged (NaN) at sample {res.metrics['run']['diverged_at']}")
    return 0
