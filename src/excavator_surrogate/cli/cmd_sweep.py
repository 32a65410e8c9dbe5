"""``exsur sweep DATASET --out DIR --trials N``: Optuna hyper-parameter sweep with pruning."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from .common import add_out
from .knobs import add_set_option, overrides


def register(subparsers: Any) -> None:
    """Add the ``sweep`` subcommand."""
    p = subparsers.add_parser(
        "sweep",
        help="Optuna sweep over window, hidden size, layers, H, lambda_bias, lr and mode",
        description="Train N trials sampled from the [sweep] search space, prune bad ones on the "
        "per-epoch validation free-run error, and write DIR/sweep.md, DIR/sweep.png, "
        "DIR/sweep.json and DIR/best.pt (the best trial's checkpoint).  Workers on other "
        "machines join the same study with the same --storage URL and --study name.",
    )
    p.add_argument("dataset", type=Path, help="dataset folder (train and val splits)")
    add_out(p, "output folder", replaced=False)
    p.add_argument("--trials", type=int, required=True, help="trials this worker runs")
    p.add_argument(
        "--storage",
        default=None,
        help="Optuna storage URL (default sqlite:///OUT/study.db; postgresql://user:pw@host/db "
        "lets many machines share the study)",
    )
    p.add_argument(
        "--study",
        default="exsur",
        help="study name to create or join (default exsur); --out holds one study: another "
        "study needs another --out",
    )
    p.add_argument(
        "--timeout", type=float, default=None, help="stop starting new trials after S seconds"
    )
    p.add_argument(
        "--preset", default=None, help="preset name or .toml path ([train] base, [sweep] space)"
    )
    p.add_argument("--epochs", type=int, default=None, help="maximum epochs per trial")
    p.add_argument(
        "--trial-seconds",
        type=float,
        default=None,
        dest="max_train_seconds",
        help="wall-time budget per trial [s]",
    )
    p.add_argument("--device", default=None, help="torch device of the trials (cpu, cuda, auto)")
    p.add_argument("--seed", type=int, default=None, help="sampler seed (single-worker sweeps)")
    add_set_option(p, ("train", "sweep"))
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Handler: returns 0 and prints the table of the best trials."""
    from ..config import merge_tables
    from ..data.dataset import read_manifest
    from ..errors import ConfigError
    from ..outdir import check_out_dir
    from ..scale.sweep import SweepConfig, run_sweep
    from ..stages import load_preset
    from ..training import TrainConfig

    if args.device is not None:  # a device this computer lacks: one line before any trial
        from ..devices import resolve_device

        resolve_device(args.device)
    check_out_dir(
        args.out, overwrite=args.overwrite, inputs=[args.dataset], lock=True, kind="sweep"
    )
    read_manifest(args.dataset)  # a missing dataset is an error before --out is created
    named = {
        "train": {"device": args.device},
        "sweep": {
            "epochs": args.epochs,
            "max_train_seconds": args.max_train_seconds,
            "seed": args.seed,
        },
    }
    over = overrides(args, ("train", "sweep"), named)
    preset = merge_tables(load_preset(args.preset) if args.preset else {}, over)
    base = TrainConfig.mode_bases(preset)  # one base per mode: trials may switch mode
    scfg = SweepConfig.from_preset(preset)
    res = run_sweep(
        args.dataset,
        out=args.out,
        trials=args.trials,
        storage=args.storage,
        study_name=args.study,
        timeout=args.timeout,
        sweep=scfg,
        base=base,
        overwrite=args.overwrite,
    )
    if res.table is not None:
        print(res.table.read_text(encoding="utf-8"))
    if res.best_checkpoint is not None:
        print(res.best_checkpoint)
    if res.n_complete == 0:
        raise ConfigError(
            f"{args.out}: no trial of the study completed ({res.n_fail} failed, {res.n_pruned} "
            "pruned; each failure's reason is in the log above): fix the data "
            "or the [sweep] / [train] settings and run it again"
        )
    return 0
