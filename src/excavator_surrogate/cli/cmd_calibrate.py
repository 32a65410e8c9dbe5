"""``exsur calibrate CKPT DATASET``: store the training coverage and the ensemble's bands."""

from __future__ import annotations

import argparse
import os
from pathlib import Path

TRAIN_RUNS = 32
"""Default of ``--train-runs`` (:data:`excavator_surrogate.surrogate.bands.TRAIN_RUNS`)."""
PRIOR_RUNS = 6
"""What the training runs weigh, in validation runs, as the help says
(:data:`excavator_surrogate.surrogate.bands.PRIOR_RUNS`)."""


def register(sub: argparse._SubParsersAction) -> None:
    """Add the ``calibrate`` subcommand."""
    p = sub.add_parser(
        "calibrate",
        help="calibrate an ensemble's uncertainty bands and record the training data's coverage",
        description="Add to CKPT (rewritten in place, atomically) what 'exsur train' adds at the "
        "end of training: the record of what DATASET's training split covered (command, angle "
        "and speed ranges, angle/command occupancy: the out-of-distribution flag) and, for a "
        "merged seed ensemble, the 50 % and 90 % band scales fitted on free runs (per joint, "
        "the level-quantile of |error| / spread over the validation runs and up to "
        f"--train-runs training runs together, the validation runs weighing n_val / (n_val + "
        f"{PRIOR_RUNS}); "
        "the angle's per horizon bin). Use it after 'exsur merge', or to re-calibrate on other "
        "data of the same machine.",
    )
    p.add_argument("ckpt", type=Path, help="checkpoint (best.pt), rewritten in place")
    p.add_argument("dataset", type=Path, help="dataset folder (its train and val splits)")
    p.add_argument(
        "--design",
        choices=("shared", "independent"),
        default="shared",
        help="members' velocity deviations integrated along the merged run (shared, default) "
        "or each member integrating its own angle (independent)",
    )
    p.add_argument(
        "--max-steps",
        type=int,
        default=0,
        help="truncate the free-run episodes to this many samples (0: whole episodes)",
    )
    p.add_argument(
        "--train-runs",
        type=int,
        default=TRAIN_RUNS,
        help=f"training episodes free-run for the band scales, evenly spread over the split "
        f"(default {TRAIN_RUNS}; 0: the validation runs alone, or every training run when "
        "DATASET has no validation split)",
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Calibrate and print one summary line."""
    from ..data.dataset import load_dataset
    from ..errors import ConfigError, DataError
    from ..outlock import lock_out
    from ..surrogate.bands import calibrate_checkpoint
    from ..surrogate.checkpoint import check_compatible, load_checkpoint

    if args.max_steps < 0:
        raise ConfigError(f"--max-steps must be >= 0, got {args.max_steps}")
    if args.train_runs < 0:
        raise ConfigError(f"--train-runs must be >= 0, got {args.train_runs}")
    path = args.ckpt.resolve()  # a link's target is calibrated; the link stays a link
    if path.is_file() and not os.access(path, os.W_OK):
        raise ConfigError(
            f"{args.ckpt}: not writable (calibrate rewrites the checkpoint in place); copy it "
            "or fix its permissions"
        )
    lock_out(path.parent, "folder")  # one writer: not while 'exsur train' writes it
    sur = load_checkpoint(args.ckpt)
    ds = load_dataset(args.dataset)
    check_compatible(sur.spec, ds.spec, ckpt=args.ckpt, data_name=args.dataset)
    if not ds.train:
        raise DataError(args.dataset, "has no training episodes", fix="give the training dataset")
    # no validation split: the bands come from training runs alone (rule "train", in-sample),
    # all of them with --train-runs 0 (there are no validation runs to use alone)
    train_runs = args.train_runs if ds.val or args.train_runs else len(ds.train)
    cal, cov = calibrate_checkpoint(
        path,
        ds.val,
        ds.train,
        design=args.design,
        max_steps=args.max_steps or None,
        train_runs=train_runs,
        calibrated_on={
            "dataset": str(args.dataset.resolve()),
            "design": args.design,
            "max_steps": args.max_steps,
            "train_runs": args.train_runs,
        },
    )
    what = f"coverage of {cov.n_sample} training samples"
    if cal is None:
        print(f"{args.ckpt}: {what} (single network: no uncertainty bands)")
    else:
        k = ", ".join(f"{v:.3g}" for v in cal.theta[-1])
        src = f"{cal.n_run} validation and {cal.n_train_run} training runs"
        if not ds.val:
            src = f"{cal.n_train_run} training runs (no val split: in-sample)"
        print(
            f"{args.ckpt}: {what}; bands calibrated on {cal.n_step} steps of {src} "
            f"({args.design}, {cal.rule}; angle 90 % band = {k} x spread per joint)"
        )
    return 0
