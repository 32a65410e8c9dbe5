"""``exsur simulate``: generate a simulated dataset with the Stage I MuJoCo excavator."""

from __future__ import annotations

import argparse
from typing import Any

from ..config import parse_sets, preset_names
from ..errors import ConfigError
from ..outdir import out_dir, preset_files
from ..stages import check_dataset_size, check_sets_read, load_preset
from .common import add_out
from .knobs import add_set_option, configs

DEFAULT_PRESET = "paper-stage1"


def register(subparsers: Any) -> None:
    """Add the ``simulate`` subcommand."""
    p = subparsers.add_parser(
        "simulate",
        help="generate a dataset with the built-in MuJoCo excavator (ideal or hydraulic)",
        description=(
            "Simulate episodes on the built-in MuJoCo excavator, as the preset says: the ideal "
            "plant (50 ms delay, 20 Hz; Stage I) or the hydraulic stand-in (dead zones, "
            "hysteresis, soil and payload, sensor faults, exogenous inputs; Stage II), and "
            "write a dataset folder (manifest.json, config.toml, episodes/*.parquet)."
        ),
    )
    p.add_argument(
        "--preset",
        default=DEFAULT_PRESET,
        metavar="NAME|FILE.toml",
        help=f"shipped preset name ({', '.join(preset_names())}) or a TOML file with a "
        f"[simulate] table (default: {DEFAULT_PRESET})",
    )
    add_out(p, "output dataset folder", replaced=True)
    p.add_argument(
        "--workers",
        type=int,
        default=None,
        metavar="N",
        help="parallel processes (default: preset)",
    )
    p.add_argument(
        "--seed", type=int, default=None, metavar="N", help="root seed (default: preset)"
    )
    add_set_option(p, ("simulate",))
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Handler of ``exsur simulate``."""
    from ..simulate.config import SimulateConfig
    from ..simulate.generate import simulate_dataset

    preset = load_preset(args.preset)
    table = preset.get("simulate")
    if not isinstance(table, dict):
        raise ConfigError(
            f"preset '{args.preset}' has no [simulate] table; add one or choose another preset"
        )
    if args.workers is not None and args.workers < 1:
        raise ConfigError(f"--workers must be >= 1, got {args.workers}")
    named = {"simulate": {"seed": args.seed, "workers": args.workers}}
    cfg: SimulateConfig = configs(args, ("simulate",), named)["simulate"]
    check_sets_read(parse_sets(args.sets, sections=("simulate",)), {"simulate": cfg})
    check_dataset_size(cfg, out=args.out)
    with out_dir(
        args.out, overwrite=args.overwrite, inputs=preset_files(args.preset), kind="dataset"
    ):
        path = simulate_dataset(
            cfg, out=args.out, extra={"preset": str(preset.get("name", args.preset))}
        )
    print(path)
    return 0
