"""``exsur plot``: draw an episode's commands, angles and angular velocities to a PNG."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any


def register(subparsers: Any) -> None:
    """Add the ``plot`` subcommand."""
    p = subparsers.add_parser(
        "plot",
        help="plot an episode (commands, angles, angular velocities) to a PNG",
        description="Draw one column per joint and rows u / theta / omega of an episode file.",
    )
    p.add_argument("episode", metavar="EPISODE.parquet", help="episode file")
    p.add_argument(
        "--out",
        default=None,
        metavar="PNG",
        help="output image (default: next to the episode, .png)",
    )
    p.add_argument(
        "--overwrite",
        action="store_true",
        help="replace the image even if exsur did not write it (docs/design.md)",
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Handler of ``exsur plot``."""
    from ..data import read_episode
    from ..outdir import check_out_file
    from ..plotting.episode import plot_episode

    out = Path(args.out) if args.out else Path(args.episode).with_suffix(".png")
    check_out_file(out, inputs=[args.episode], example="episode.png", overwrite=args.overwrite)
    ep = read_episode(args.episode)
    print(plot_episode(ep, out=out))
    return 0
