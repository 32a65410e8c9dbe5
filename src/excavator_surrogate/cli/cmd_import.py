"""``exsur import SOURCE... --mapping MAP.toml --out DIR``: real logs -> dataset folder."""

from __future__ import annotations

import argparse
import dataclasses
import tomllib
from pathlib import Path

from ..errors import ConfigError
from ..ingest import SplitOptions, import_logs, load_mapping, options_with, render_markdown
from .common import add_out


def register(sub: argparse._SubParsersAction) -> None:
    """Add the ``import`` subcommand."""
    p = sub.add_parser(
        "import",
        help="import CSV/Parquet/dSPACE/MDF4/ROS-bag logs of any machine into a dataset",
        description="Validate logs, convert units, split at time gaps, resample anti-aliased to the "
        "target rate, assign train/val/test by file and write a dataset folder (atomically) with "
        "import_report.json. Options default to the mapping's [import] and [split] tables. "
        "See docs/import.md.",
    )
    p.add_argument(
        "sources",
        nargs="+",
        metavar="SOURCE",
        help="log files (.csv, .csv.gz, dSPACE .csv exports, .parquet, .mf4, .mcap, .bag), rosbag2 folders, "
        "folders of logs, or glob patterns",
    )
    p.add_argument(
        "--mapping",
        required=True,
        type=Path,
        metavar="MAP.toml",
        help="mapping file (docs/import.md)",
    )
    add_out(p, "dataset folder to write", replaced=True, required=False)
    p.add_argument(
        "--rate",
        type=float,
        metavar="HZ",
        help="target sample rate [Hz] (default: [machine] rate_hz)",
    )
    p.add_argument(
        "--nan",
        choices=("fail", "fill"),
        help="missing values: fail, or fill short gaps by interpolation",
    )
    p.add_argument(
        "--max-fill",
        type=int,
        metavar="N",
        help="longest run of missing samples that --nan fill fills",
    )
    p.add_argument(
        "--max-gap",
        type=float,
        metavar="S",
        help="time gaps longer than S seconds split an episode",
    )
    p.add_argument(
        "--min-steps",
        type=int,
        metavar="N",
        help="drop episodes shorter than N samples (the model window)",
    )
    p.add_argument(
        "--velocity", choices=("diff", "kalman"), help="how to derive velocities the log lacks"
    )
    p.add_argument(
        "--lowpass",
        type=float,
        metavar="F",
        help="anti-alias cutoff, fraction of the output Nyquist (0: off)",
    )
    p.add_argument(
        "--clip-commands",
        action="store_true",
        default=None,
        help="clip commands outside their range instead of failing",
    )
    p.add_argument(
        "--outliers",
        choices=("fail", "drop", "clip"),
        help="angle spikes, impossible samples (no limits needed) and angles beyond the joint "
        "limits: fail, drop the rows, or clip to the limits (docs/import.md)",
    )
    p.add_argument(
        "--log-units",
        choices=("check", "ignore"),
        help="a position or velocity whose log (MDF, dSPACE) gives it another unit than the "
        "mapping is an error (check, the default), or not (ignore: the log's labels are wrong)",
    )
    p.add_argument(
        "--max-upsample",
        type=float,
        metavar="X",
        help="refuse a target rate above X times a log's own rate (default 10)",
    )
    p.add_argument(
        "--max-memory",
        type=float,
        metavar="MB",
        help="bound on a log's decompressed text and resampled output [MB] "
        "(default: a quarter of the available memory)",
    )
    p.add_argument(
        "--on-error",
        choices=("fail", "skip"),
        help="a bad file stops the import, or is skipped and reported",
    )
    p.add_argument(
        "--split-by",
        choices=("fraction", "glob", "file"),
        help="how files are assigned to train/val/test",
    )
    p.add_argument(
        "--fractions",
        metavar="TR,VA,TE",
        help="train,val,test shares for --split-by fraction, e.g. 0.7,0.15,0.15",
    )
    p.add_argument("--seed", type=int, help="shuffle seed for --split-by fraction")
    for s in ("train", "val", "test"):
        p.add_argument(
            f"--{s}",
            action="append",
            metavar="PATTERN",
            help=f"glob pattern (or file name with --split-by file) of {s} files; repeatable",
        )
    p.add_argument(
        "--split-file",
        type=Path,
        metavar="FILE",
        help="TOML file with train = [...], val = [...], test = [...] file names (implies --split-by file)",
    )
    p.add_argument(
        "--dry-run", action="store_true", help="validate and print the report; write nothing"
    )
    p.set_defaults(func=run)


def _split_options(args: argparse.Namespace, base: SplitOptions) -> SplitOptions:
    changes: dict[str, object] = {}
    if args.split_file is not None:
        if not args.split_file.is_file():
            raise ConfigError(
                f"{args.split_file}: --split-file not found; give a TOML file with "
                "train = [...], val = [...], test = [...] file names"
            )
        try:
            data = tomllib.loads(args.split_file.read_text(encoding="utf-8"))
        except UnicodeDecodeError as e:
            raise ConfigError(
                f"{args.split_file}: --split-file is not a TOML text file (not UTF-8: {e.reason})"
            ) from e
        except tomllib.TOMLDecodeError as e:
            raise ConfigError(f"{args.split_file}: invalid TOML ({e})") from e
        unknown = sorted(set(data) - {"train", "val", "test"})
        if unknown:
            raise ConfigError(
                f"{args.split_file}: unknown key(s) {unknown}; use train, val, test lists of file names"
            )
        for s in ("train", "val", "test"):
            v = data.get(s, [])
            if not isinstance(v, list) or not all(isinstance(x, str) for x in v):
                raise ConfigError(f"{args.split_file}: '{s}' must be a list of file names")
            changes[s] = tuple(v)
        changes["by"] = "file"
    for s in ("train", "val", "test"):
        if getattr(args, s):
            changes[s] = tuple(getattr(args, s))
            changes.setdefault("by", "glob")
    if args.split_by is not None:
        changes["by"] = args.split_by
    if args.fractions is not None:
        try:
            fr = tuple(float(x) for x in args.fractions.split(","))
        except ValueError:
            raise ConfigError(
                f"--fractions {args.fractions!r}: give three numbers, e.g. 0.7,0.15,0.15"
            ) from None
        if len(fr) != 3:
            raise ConfigError(
                f"--fractions {args.fractions!r}: give three numbers (train,val,test)"
            )
        changes["fractions"] = fr
    if args.seed is not None:
        changes["seed"] = args.seed
    return dataclasses.replace(base, **changes)  # type: ignore[arg-type]


def run(args: argparse.Namespace) -> int:
    """Import the logs; print the Markdown summary; return 0."""
    if args.out is None and not args.dry_run:
        raise ConfigError("--out DIR is required (or --dry-run to only validate)")
    read = [args.mapping, *([args.split_file] if args.split_file is not None else [])]
    if not args.dry_run:  # the rule's one-line errors first, then one writer for the import
        from ..outdir import check_out_dir

        inputs = [*args.sources, *read]
        check_out_dir(args.out, overwrite=args.overwrite, inputs=inputs, lock=True, kind="dataset")
    mapping = load_mapping(args.mapping)
    options = options_with(
        mapping.options,
        rate_hz=args.rate,
        nan=args.nan,
        max_fill=args.max_fill,
        max_gap_s=args.max_gap,
        min_steps=args.min_steps,
        velocity=args.velocity,
        lowpass=args.lowpass,
        clip_commands=args.clip_commands,
        on_error=args.on_error,
        outliers=args.outliers,
        max_upsample=args.max_upsample,
        max_memory_mb=args.max_memory,
        log_units=args.log_units,
    )
    split = _split_options(args, mapping.split)
    report = import_logs(
        args.sources,
        mapping,
        out=None if args.dry_run else args.out,
        options=options,
        split=split,
        quiet=args.quiet,
        overwrite=args.overwrite,
        inputs=read,
    )
    print(render_markdown(report), end="")
    return 0
