"""``exsur evaluate CKPT DATASET --out DIR``: closed-loop (CBE) metrics, table and figure."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from .common import add_out
from .knobs import add_set_option, configs


def _compare(text: str) -> tuple[str, Path]:
    label, sep, path = text.partition("=")
    if not sep:
        return Path(text).parent.name or "other", Path(text)
    return label, Path(path)


def register(subparsers: Any) -> None:
    """Add the ``evaluate`` subcommand."""
    p = subparsers.add_parser(
        "evaluate",
        help="free-run a checkpoint on test episodes; write metrics.json, table.md, cbe.png",
        description="Roll the surrogate out in closed loop on a dataset split (warm-up of W recorded "
        "samples, then recorded commands only) and score omega and theta per joint (RMSE, MAE, R²).",
    )
    p.add_argument("checkpoint", type=Path, help="surrogate checkpoint (best.pt)")
    p.add_argument("dataset", type=Path, help="dataset folder")
    add_out(p, "output folder", replaced=False)
    p.add_argument("--preset", default=None, help="preset name or .toml path ([evaluate] table)")
    p.add_argument("--split", default=None, help="split to evaluate (default test)")
    p.add_argument(
        "--reference",
        choices=("measured", "true"),
        default=None,
        help="compare with measured theta or ground-truth theta_true",
    )
    p.add_argument(
        "--compare",
        type=_compare,
        action="append",
        default=[],
        metavar="LABEL=CKPT",
        help="another checkpoint to put in the table (repeatable), e.g. GRU=runs/gru/best.pt",
    )
    p.add_argument("--no-arx", action="store_true", help="do not fit the ARX baseline")
    p.add_argument(
        "--no-structured",
        action="store_true",
        help="do not fit the structured baseline (dead zone, gain, delay, end stops per joint)",
    )
    p.add_argument(
        "--no-paper", action="store_true", help="do not show the paper's Table II values"
    )
    p.add_argument("--max-steps", type=int, default=None, help="truncate test episodes")
    p.add_argument("--device", default="cpu", help="torch device (cpu, cuda, cuda:N, auto)")
    add_set_option(p, ("evaluate",))
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Handler: returns 0 and prints the table."""
    import dataclasses

    from ..data.dataset import load_dataset
    from ..evaluate.cbe import evaluate_checkpoint
    from ..io_utils import log
    from ..outdir import check_out_dir

    named = dict(
        split=args.split,
        reference=args.reference,
        arx=False if args.no_arx else None,
        structured=False if args.no_structured else None,
        paper=False if args.no_paper else None,
        max_steps=args.max_steps,
    )
    check_out_dir(
        args.out, overwrite=args.overwrite, inputs=[args.dataset], lock=True, kind="evaluation"
    )
    cfg = configs(args, ("evaluate",), {"evaluate": named})["evaluate"]
    splits = (cfg.split, "train", "val") if cfg.arx or cfg.structured else (cfg.split,)
    dataset = load_dataset(args.dataset, splits=tuple(dict.fromkeys(splits)))
    # every [evaluate] field is an argument of evaluate_checkpoint, as exsur run passes them:
    # a field added to the config reaches the evaluation without a line here
    evaluate_checkpoint(
        args.checkpoint,
        dataset,
        out=args.out,
        overwrite=args.overwrite,
        compare=dict(args.compare),
        device=args.device,
        **dataclasses.asdict(cfg),
    )
    print((Path(args.out) / "table.md").read_text(encoding="utf-8"))
    log(
        f"wrote {args.out}/metrics.json, table.md, cbe.png"
        + (", horizon.png" if cfg.horizons and cfg.figure else "")
    )
    return 0
