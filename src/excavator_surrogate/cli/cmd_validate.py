"""``exsur validate PATH...``: check episode files or dataset folders against the data contract."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..data import load_dataset, read_episode


def register(sub: argparse._SubParsersAction) -> None:
    """Add the ``validate`` subcommand."""
    p = sub.add_parser(
        "validate",
        help="check episode files or dataset folders against the data contract",
        description="Validate episodes (Parquet) or dataset folders (manifest.json). "
        "Prints one line per path; exits non-zero at the first violation.",
    )
    p.add_argument("paths", nargs="+", type=Path, help="episode .parquet files or dataset folders")
    p.add_argument(
        "--min-steps", type=int, default=1, help="minimum samples per episode (model window + 1)"
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Validate each path; raise :class:`DataError` on the first violation."""
    for path in args.paths:
        if path.is_dir():
            ds = load_dataset(path, min_steps=args.min_steps)
            counts = {s: len(ds.split(s)) for s in ("train", "val", "test")}
            print(
                f"{path}: ok, joints {list(ds.spec.names)} at {ds.spec.rate_hz:g} Hz, "
                f"episodes {counts}, samples {ds.n_samples()}"
            )
        else:
            ep = read_episode(path, min_steps=args.min_steps)
            print(
                f"{path}: ok, joints {list(ep.spec.names)} at {ep.spec.rate_hz:g} Hz, "
                f"{ep.n_step} samples, source {ep.source}"
            )
    return 0
