"""``exsur train DATASET --out DIR``: train an LSTM/GRU surrogate, keep the best free-run checkpoint.

Data-parallel (DDP) when launched by torchrun (``WORLD_SIZE`` > 1) or with ``--ddp``::

    torchrun --standalone --nproc_per_node=2 -m excavator_surrogate.cli train DATA --out DIR
"""

from __future__ import annotations

import argparse
import shutil
from pathlib import Path
from typing import TYPE_CHECKING, Any

from .common import add_cpus_option, add_overwrite
from .knobs import add_set_option, configs, overrides, positive_seconds

if TYPE_CHECKING:
    from ..data.dataset import Dataset
    from ..training.config import TrainConfig


def register(subparsers: Any) -> None:
    """Add the ``train`` subcommand."""
    p = subparsers.add_parser(
        "train",
        help="train a surrogate on a dataset (best checkpoint by validation free-run)",
        description="Train a surrogate on DATASET's train split, select it by closed-loop error on the "
        "val split, and write OUT/best.pt, OUT/last.pt, OUT/log.csv, OUT/config.toml, OUT/tb/ and "
        "OUT/learning_curve.png (training loss and validation error per epoch).  With --dry-run: "
        "print what it would train (the recipe's reasons or the preset, the trainings, epochs and "
        "caps and their time on the reference machine, the [train] table) and write nothing.",
    )
    p.add_argument("dataset", type=Path, help="dataset folder (manifest.json + episodes/)")
    p.add_argument("--out", type=Path, default=None, help="output folder (required to train)")
    p.add_argument(
        "--dry-run",
        action="store_true",
        help="print the recipe (or the preset's config), the trainings, epochs and caps it "
        "plans and their time on the reference machine; train and write nothing",
    )
    p.add_argument(
        "--preset",
        default=None,
        help="preset name or .toml path ([train] table); default: a recipe chosen from the "
        "dataset's sizes, rate and episode lengths (docs/real.md)",
    )
    p.add_argument("--mode", choices=("windowed", "stateful"), default=None, help="training mode")
    p.add_argument("--cell", choices=("lstm", "gru"), default=None, help="recurrent cell")
    p.add_argument("--epochs", type=int, default=None, help="maximum epochs")
    p.add_argument(
        "--max-seconds",
        type=positive_seconds("--max-seconds"),
        default=None,
        dest="max_train_seconds",
        help="wall-time budget for training [s], > 0 (default: the preset's; none: no budget)",
    )
    p.add_argument("--seed", type=int, default=None, help="random seed")
    p.add_argument(
        "--members",
        type=int,
        default=None,
        help="seed ensemble: train this many members (seeds SEED, SEED+1, ...) in parallel "
        "processes and merge them into OUT/best.pt (members in OUT/member_<i>/)",
    )
    p.add_argument(
        "--resume",
        type=Path,
        default=None,
        help="continue from a checkpoint (last.pt; into another --out, the best.pt beside it "
        "is carried over)",
    )
    p.add_argument("--device", default=None, help="torch device (cpu, cuda, cuda:N, auto)")
    p.add_argument(
        "--ddp",
        action="store_true",
        help="data-parallel training; requires a torchrun launch (automatic when torchrun "
        "sets WORLD_SIZE > 1); batch sizes are per process",
    )
    add_cpus_option(p)
    add_overwrite(p, replaced=False)
    add_set_option(p, ("train",))
    p.set_defaults(func=checked_run)


def checked_run(args: argparse.Namespace) -> int:
    """Check ``--out`` and ``--resume`` against the dataset before :func:`run` writes anything."""
    from ..data.dataset import load_dataset
    from ..errors import ConfigError
    from ..outdir import check_out_dir
    from ..surrogate.checkpoint import check_compatible, load_checkpoint

    if args.dry_run:
        return run(args)
    if args.out is None:
        raise ConfigError("--out DIR is required (or --dry-run to only print the plan)")
    out = Path(args.out)
    existed = out.is_dir()
    new = not existed or not any(out.iterdir())  # all that ends up in it is this command's
    check_out_dir(out, overwrite=args.overwrite, inputs=[args.dataset], lock=True, kind="model")
    try:
        if args.resume is not None:
            resumed = load_checkpoint(args.resume)
            spec = load_dataset(args.dataset, splits=()).spec  # the manifest only
            check_compatible(resumed.spec, spec, ckpt=args.resume, data_name=args.dataset)
        return run(args)
    except BaseException:
        if new and not any(out.rglob("*.pt")):  # a checkpoint stays: --resume continues it
            shutil.rmtree(out, ignore_errors=True)  # what this command wrote, nothing else
            if existed:  # the user's empty folder stays, empty
                out.mkdir(exist_ok=True)
        raise


def run(args: argparse.Namespace) -> int:
    """Handler: returns 0 and prints the best checkpoint path."""
    from ..data.dataset import load_dataset
    from ..evaluate.pace import pace_markdown, training_pace
    from ..io_utils import log
    from ..scale.ddp import distributed_env, env_world_size, init_distributed, shutdown
    from ..stages import load_preset
    from ..surrogate.checkpoint import read_checkpoint
    from ..training import train
    from ..training.auto import auto_config, recipe_table
    from ..training.estimate import describe_work, estimate_work
    from ..training.records import check_parallel_replay

    named = dict(
        mode=args.mode,
        cell=args.cell,
        epochs=args.epochs,
        max_train_seconds=args.max_train_seconds,
        seed=args.seed,
        device=args.device,
        members=args.members,
    )
    dataset = load_dataset(args.dataset, splits=("train", "val"))
    why: list[str] = []
    if args.preset:
        cfg = configs(args, ("train",), {"train": named})["train"]
        # a data-parallel run's record: the same global batch, or another model
        check_parallel_replay(
            load_preset(args.preset), cfg, world_size=env_world_size(), where=args.preset
        )
    else:
        over = overrides(args, ("train",), {"train": named}).get("train", {})
        cfg, why = auto_config(dataset, overrides=over)
    if args.dry_run:  # printed, not logged
        print(dry_run(cfg, dataset, why=why, source=args.preset), end="")
        return 0
    for line in why:
        log(f"recipe: {line}")
    for line in describe_work(estimate_work(cfg, dataset)):
        log(f"planned work: {line}")
    dist = None
    if args.ddp or distributed_env():
        dist = init_distributed(device=cfg.device, require=args.ddp)
    try:
        notes = None if args.preset else {"recipe": recipe_table(why)}  # why the recipe chose so
        best = train(
            cfg,
            dataset,
            out=args.out,
            overwrite=args.overwrite,
            resume=args.resume,
            dist=dist,
            notes=notes,
        )
    finally:
        shutdown(dist)
    if dist is not None and not dist.is_main:
        return 0
    _learning_curves(Path(args.out))
    m = read_checkpoint(best).get("metrics", {})
    ens = m.get("ensemble")
    which = f"{ens['n_member']}-member ensemble" if ens else f"epoch {m.get('epoch')}"
    log(f"best checkpoint: {best} ({which}, val_error {m.get('val_error', float('nan')):.4g})")
    pace = pace_markdown(training_pace(Path(args.out)), m.get("training")).strip()
    if pace:  # how fast this computer trained it, against the reference and the cap
        log(pace)
    print(best)
    return 0


def dry_run(cfg: TrainConfig, dataset: Dataset, *, why: list[str], source: str | None) -> str:
    """What ``exsur train --dry-run`` prints: the data's sizes, the recipe's reasons (or the
    preset), the planned work (:mod:`~excavator_surrogate.training.estimate`) and the
    ``[train]`` table that ``config.toml`` would record."""
    from ..config import dumps_toml, to_dict
    from ..run_plan import sizes_text
    from ..training.estimate import describe_work, estimate_work
    from ..training.speed_probe import timed_estimate

    lengths = {s: [e.n_step for e in dataset.episodes.get(s, [])] for s in ("train", "val")}
    lines = [f"data: {sizes_text(lengths, dataset.spec.rate_hz)}"]
    if source:
        lines.append(f"preset: {source}")
    else:
        lines.append("recipe (docs/real.md):")
        lines += [f"  - {w}" for w in why]
    lines.append("planned work (the reference machine's time; nothing is trained):")
    est = timed_estimate(estimate_work(cfg, dataset), cfg, n_joint=dataset.spec.n_joint)
    lines += [f"  - {w}" for w in describe_work(est)]
    return "\n".join(lines) + "\n\n" + dumps_toml({"train": to_dict(cfg)})


def _learning_curves(out: Path) -> None:
    """Draw ``out/learning_curve.png`` from the epoch logs.  The checkpoints are already
    final, so a figure that cannot be drawn is a warning, not a failed training."""
    import logging

    from ..errors import ExsurError
    from ..io_utils import LOGGER_NAME, log
    from ..plotting.training import plot_learning_curves

    try:
        png = plot_learning_curves(out, out=out / "learning_curve.png")
    except (ExsurError, OSError, ValueError) as e:
        logging.getLogger(LOGGER_NAME).warning(f"learning curves not drawn: {e}")
    else:
        log(f"learning curves: {png}")
