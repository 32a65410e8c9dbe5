"""``exsur validate PATH...``: check episode files or dataset folders against the data contract."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..data import Episode, load_dataset, read_episode
from ..errors import DataError

LIMIT_MARGIN = 0.5
"""Angles may exceed the spec's joint limits by this fraction of the range (sensor noise and
jumps of raw or simulated Stage II data); beyond it an episode is corrupt."""


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
    if args.min_steps < 1:
        from ..errors import ConfigError

        raise ConfigError(f"--min-steps must be >= 1 (samples per episode), got {args.min_steps}")
    for path in args.paths:
        if path.is_dir():
            ds = load_dataset(path, min_steps=args.min_steps)
            for s in ("train", "val", "test"):
                for ep in ds.split(s):
                    _check_limits(ep, path / "episodes" / f"{ep.name}.parquet")
            counts = {s: len(ds.split(s)) for s in ("train", "val", "test")}
            print(
                f"{path}: ok, joints {list(ds.spec.names)} at {ds.spec.rate_hz:g} Hz, "
                f"episodes {counts}, samples {ds.n_samples()}"
            )
        else:
            ep = read_episode(path, min_steps=args.min_steps)
            _check_limits(ep, path)
            print(
                f"{path}: ok, joints {list(ep.spec.names)} at {ep.spec.rate_hz:g} Hz, "
                f"{ep.n_step} samples, source {ep.source}"
            )
    return 0


def _check_limits(ep: Episode, where: Path) -> None:
    """Measured angles within the joint limits (+ :data:`LIMIT_MARGIN` of the range)."""
    from ..ingest.outliers import limit_excursions

    hit = limit_excursions(ep.theta, ep.spec.joints, LIMIT_MARGIN)
    if hit is None:
        return
    row, k, value, lo, hi, n_bad = hit
    name = ep.spec.names[k]
    j = ep.spec.joints[k]  # a linear joint's stroke prints in its own unit (mm ...)
    f, unit, what = j.display_factor, j.display_unit, "stroke" if j.linear else "angle"
    raise DataError(
        where,
        f"joint '{name}': {what} {value * f:.6g} {unit} is outside the limits "
        f"[{lo * f:.6g}, {hi * f:.6g}] {unit} "
        f"(+{LIMIT_MARGIN:.0%} of the range) in {n_bad} sample(s)",
        column=f"theta_{name}",
        row=row,
        fix='re-import the log with [import] outliers = "fail" to find the bad rows (docs/import.md)',
    )
