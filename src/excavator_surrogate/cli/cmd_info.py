"""``exsur info PATH``: what a trained checkpoint or a dataset is, without running anything."""

from __future__ import annotations

import argparse
from pathlib import Path


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``info`` subcommand."""
    p = subparsers.add_parser(
        "info",
        help="describe a checkpoint (machine, network, training, validation), an ONNX export "
        "(its graph's inputs and outputs, units, the checkpoint's card) or a dataset (splits, "
        "what each covers)",
        description="Describe a trained checkpoint (best.pt) without running it: the machine "
        "it models (joints, units, limits, command ranges, inputs), its network, how its "
        "training ended against the plan, on which computer, and its free-run scores on "
        "validation. Or describe an ONNX export (model.onnx from 'exsur export'): the name, "
        "type and shape of every graph input and output, the units and sample period, how it "
        "steps, and the card of the checkpoint it was exported from. Or describe a dataset "
        "folder (the one holding manifest.json): its "
        "splits, and per joint how far each split moves it and commands it. Notes flag what "
        "to know first (a training the wall-time cap cut short, a joint that validated "
        "poorly; validation that drives a joint over too little of the training's commands, "
        "a test that leaves the training's positions).",
    )
    p.add_argument(
        "path",
        metavar="PATH",
        help="a checkpoint file (.pt, e.g. runs/quick/model/best.pt), an ONNX export (.onnx) or "
        "a dataset folder (e.g. runs/quick/data)",
    )
    p.add_argument(
        "--json", action="store_true", help="print the description as one JSON object instead"
    )
    p.set_defaults(func=run, shows=True)  # -q does not mute what it was asked to show


def run(args: argparse.Namespace) -> int:
    """Handler of ``exsur info``: prints the card, returns 0."""
    import json

    from ..data.dataset import MANIFEST

    path = Path(args.path)
    if not path.exists():
        from ..errors import ConfigError

        raise ConfigError(
            f"{path}: not found; give a checkpoint file (.pt), an ONNX export (.onnx) or a "
            "dataset folder"
        )
    if path.is_dir() and (path / MANIFEST).is_file():
        from ..evaluate.card import public
        from ..evaluate.data_card import dataset_card, dataset_card_markdown

        card = dataset_card(path)
        text = dataset_card_markdown
    elif path.is_dir():
        from ..errors import ConfigError
        from ..surrogate.checkpoint import checkpoint_in

        raise ConfigError(
            f"{path}: a folder without {MANIFEST} is not a dataset; give a checkpoint file, "
            f"e.g. {checkpoint_in(path)}, or a dataset folder"
        )
    elif path.suffix.lower() == ".onnx":
        from ..env.onnx_card import onnx_card, onnx_card_json, onnx_card_markdown

        card = onnx_card(path)
        if args.json:
            print(json.dumps(onnx_card_json(card), indent=2, allow_nan=False))
        else:
            print(onnx_card_markdown(card), end="")
        return 0
    else:
        from ..evaluate.card import card_markdown, model_card, public

        card = model_card(path)
        text = card_markdown
    if args.json:
        print(json.dumps(public(card), indent=2, allow_nan=False))
    else:
        print(text(card), end="")
    return 0
