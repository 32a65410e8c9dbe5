"""``exsur merge A.pt B.pt ... --out ens.pt``: merge surrogates into one seed ensemble."""

from __future__ import annotations

import argparse
from pathlib import Path


def register(sub: argparse._SubParsersAction) -> None:
    """Add the ``merge`` subcommand."""
    p = sub.add_parser(
        "merge",
        help="merge trained surrogates into one ensemble checkpoint (omega = the members' mean)",
        description="Merge K checkpoints of the same machine and architecture (LSTM/GRU, same "
        "depth, window, mode, end stops and play features; trained on the same or other data of "
        "the machine, the widest of their end stops and speed bounds kept) into ONE checkpoint "
        "whose network "
        "averages the members' angular velocities every step. The merged network is a plain, "
        "wider LSTM/GRU with block-diagonal weights, so it runs everywhere a single checkpoint "
        "does (evaluate, env, export). 'exsur train --members K' trains and merges in one go.",
    )
    p.add_argument("ckpts", type=Path, nargs="+", help="member checkpoints (best.pt)")
    p.add_argument("--out", type=Path, required=True, help="merged checkpoint .pt")
    p.add_argument(
        "--overwrite",
        action="store_true",
        help="replace --out even if exsur did not write it (docs/design.md)",
    )
    p.add_argument("--name", default=None, help="model label (default <cell>-ensemble-K)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Load every member (``weights_only``), merge, write atomically, print a summary."""
    from ..errors import CheckpointError
    from ..outdir import check_out_file
    from ..surrogate.checkpoint import load_checkpoint, save_checkpoint
    from ..surrogate.ensemble import merge, n_member, non_finite_weight

    check_out_file(args.out, inputs=args.ckpts, example="ensemble.pt", overwrite=args.overwrite)
    if len(args.ckpts) < 2:
        from ..errors import ConfigError

        raise ConfigError(
            f"exsur merge needs at least 2 checkpoints, got only {args.ckpts[0]}: one is already "
            "a model (give the members to merge, e.g. the best.pt of each seed)"
        )
    _check_distinct(args.ckpts)
    members = [load_checkpoint(p) for p in args.ckpts]
    for p, m in zip(args.ckpts, members):
        bad = non_finite_weight(m)
        if bad is not None:
            raise CheckpointError(
                f"{p}: non-finite weights ({bad}): its training diverged; re-train it (lower "
                "train.lr) or leave it out of the merge"
            )
    sur = merge(members, name=args.name, labels=[str(p) for p in args.ckpts])
    sur.metrics["ensemble"]["sources"] = [str(p) for p in args.ckpts]
    args.out.parent.mkdir(parents=True, exist_ok=True)
    out = save_checkpoint(args.out, sur)
    print(
        f"{out}: {sur.name}, {n_member(sur)} members ({len(members)} checkpoints), "
        f"{sur.model_cfg.cell} "
        f"{sur.model_cfg.n_layer} x {sur.model_cfg.hidden} ({sur.mode})"
    )
    return 0


def _check_distinct(paths: list[Path]) -> None:
    """Refuse the same checkpoint given twice (also through another path or a link)."""
    from ..errors import ConfigError

    seen: dict[Path, Path] = {}
    for p in paths:
        key = p.resolve()
        if key in seen:
            raise ConfigError(
                f"{p}: given twice (also as {seen[key]}); the same model twice is no ensemble: "
                "give each member once"
            )
        seen[key] = p
