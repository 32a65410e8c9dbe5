"""``exsur info CKPT``: what a trained checkpoint is, without running it."""

from __future__ import annotations

import argparse


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``info`` subcommand."""
    p = subparsers.add_parser(
        "info",
        help="describe a checkpoint: its machine, network, training and validation scores",
        description="Describe a trained checkpoint (best.pt) without running it: the machine "
        "it models (joints, units, limits, command ranges, inputs), its network, how its "
        "training ended against the plan, on which computer, and its free-run scores on "
        "validation. Notes flag what to know before relying on it (a training the wall-time "
        "cap cut short, a joint that validated poorly, no end stops or coverage record).",
    )
    p.add_argument(
        "ckpt", metavar="CKPT", help="checkpoint file (.pt), e.g. runs/quick/model/best.pt"
    )
    p.add_argument(
        "--json", action="store_true", help="print the description as one JSON object instead"
    )
    p.set_defaults(func=run, shows=True)  # -q does not mute what it was asked to show


def run(args: argparse.Namespace) -> int:
    """Handler of ``exsur info``: prints the card, returns 0."""
    import json

    from ..evaluate.card import card_markdown, model_card, public

    card = model_card(args.ckpt)
    if args.json:
        print(json.dumps(public(card), indent=2, allow_nan=False))
    else:
        print(card_markdown(card), end="")
    return 0
