"""``exsur info PATH``: what a trained checkpoint or a dataset is, without running anything;
``exsur info --computer``: what this computer computes with."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from ..ingest.options import CsvOptions
    from ..ingest.summary import LogSummary


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``info`` subcommand."""
    p = subparsers.add_parser(
        "info",
        help="describe a checkpoint (machine, network, training, validation), an ONNX export "
        "(its graph's inputs and outputs, units, the checkpoint's card), a dataset (splits, "
        "what each covers) or a raw log (its channels, units, rates and ranges)",
        description="Describe a trained checkpoint (best.pt) without running it: the machine "
        "it models (joints, units, limits, command ranges, inputs), its network, how its "
        "training ended against the plan, on which computer, and its free-run scores on "
        "validation. Or describe an ONNX export (model.onnx from 'exsur export'): the name, "
        "type and shape of every graph input and output, the units and sample period, how it "
        "steps, and the card of the checkpoint it was exported from. Or describe a dataset "
        "folder (the one holding manifest.json): its "
        "splits, and per joint how far each split moves it and commands it; or one episode "
        "file the same way. Or list what a raw log holds before you write its mapping (a CSV, "
        "dSPACE, Parquet, MDF or ROS log, as exsur import reads them): every channel's name "
        "as a mapping gives it, its unit, samples, rate and range. Notes flag what "
        "to know first (a training the wall-time cap cut short, a joint that validated "
        "poorly; validation that drives a joint over too little of the training's commands, "
        "a test that leaves the training's positions).",
    )
    p.add_argument(
        "path",
        metavar="PATH",
        nargs="?",
        default=None,
        help="a checkpoint file (.pt, e.g. runs/quick/model/best.pt), an ONNX export (.onnx), "
        "a dataset folder (e.g. runs/quick/data), one of its episode files (.parquet) or a "
        "raw log (.csv, .parquet, .mf4, .mdf, .dat, .mcap, .bag, a rosbag2 folder)",
    )
    p.add_argument(
        "--computer",
        action="store_true",
        help="instead of PATH, describe this computer as a run's record would: the CPU, the "
        "CPUs a training plans for and why, and the kernels torch, NumPy and MuJoCo compute "
        "with (what to compare first when a figure differs from the README's)",
    )
    p.add_argument(
        "--json", action="store_true", help="print the description as one JSON object instead"
    )
    p.add_argument(
        "--set",
        action="append",
        default=[],
        dest="sets",
        metavar="csv.KEY=VALUE",
        help="a raw CSV log or dSPACE export: read it as a mapping's [csv] table would, e.g. "
        "csv.skip_rows=3, csv.delimiter=';', csv.decimal=',', csv.encoding=cp1252 "
        "(repeatable; default: the delimiter is sniffed and decimal commas recognised)",
    )
    p.add_argument(
        "--draft-mapping",
        metavar="MAP.toml",
        default=None,
        help="a raw log: also write a first import mapping for it, guessed from its channels' "
        "names, units and ranges (joints, angle/velocity/command channels, units, the time "
        "column), each guess marked '# guessed' and what it could not decide '# TODO'",
    )
    p.add_argument(
        "--overwrite",
        action="store_true",
        help="with --draft-mapping: replace an existing file",
    )
    p.set_defaults(func=run, shows=True)  # -q does not mute what it was asked to show


def run(args: argparse.Namespace) -> int:
    """Handler of ``exsur info``: prints the card, returns 0."""
    import json

    from ..data.dataset import MANIFEST

    if args.computer or args.path is None:
        return _computer(args)
    path = Path(args.path)
    if not path.exists():
        from ..errors import ConfigError

        raise ConfigError(
            f"{path}: not found; give a checkpoint file (.pt), an ONNX export (.onnx), a "
            "dataset folder, an episode file (.parquet) or a raw log"
        )
    csv = _csv_options(args.sets)
    if _is_raw_log(path, csv_format=csv.format if csv is not None else "auto"):
        from ..ingest.readers import log_kind

        if csv is not None and log_kind(path, csv_format=csv.format) not in ("csv", "dspace"):
            from ..errors import ConfigError

            raise ConfigError(
                f"{path}: --set csv.* reads a CSV log or a dSPACE export; this log needs none"
            )
        from ..ingest.inventory import summarize_log

        draft_out = None
        if args.draft_mapping is not None:
            from ..errors import ConfigError
            from ..outdir import check_out_file

            if Path(args.draft_mapping).is_file() and not args.overwrite:
                raise ConfigError(  # exsur's own draft too: the user may have edited it since
                    f"{args.draft_mapping}: --draft-mapping exists (a mapping, perhaps edited "
                    "since it was drafted); give a new file name, or pass --overwrite to "
                    "replace it"
                )
            draft_out = check_out_file(
                args.draft_mapping,
                inputs=[path],
                flag="--draft-mapping",
                example="mapping.toml",
                overwrite=args.overwrite,
            )
        summary = summarize_log(path, csv=csv)
        if args.json:
            print(json.dumps(summary.to_dict(), indent=2, allow_nan=False))
        else:
            print(_log_markdown(summary), end="")
        if draft_out is not None:
            _write_draft(summary, draft_out, csv=csv)
        return 0
    if args.draft_mapping is not None:
        from ..errors import ConfigError

        logs = _raw_logs_in(path) if path.is_dir() else []
        if logs:
            raise ConfigError(
                f"{path}: a folder of {len(logs)} raw log(s); draft from one of them, e.g. "
                f"exsur info {logs[0]} --draft-mapping {args.draft_mapping}"
            )
        raise ConfigError(
            f"{path}: --draft-mapping drafts a mapping for a raw log (.csv, .parquet, .mf4, "
            "a ROS bag ...), not for this"
        )
    if csv is not None:
        from ..errors import ConfigError

        raise ConfigError(
            f"{path}: --set csv.* reads a raw CSV log or dSPACE export, not this; leave it out"
        )
    if path.is_dir() and (path / MANIFEST).is_file():
        from ..evaluate.card import public
        from ..evaluate.data_card import dataset_card, dataset_card_markdown

        card = dataset_card(path)
        text = dataset_card_markdown
    elif path.is_dir():
        from ..errors import ConfigError
        from ..surrogate.checkpoint import checkpoint_in

        ckpt = checkpoint_in(path)
        logs = [] if ckpt.is_file() else _raw_logs_in(path)
        if logs:  # a folder of raw logs: one of them is what info describes
            raise ConfigError(
                f"{path}: a folder of {len(logs)} raw log(s), not a dataset; give one of "
                f"them, e.g. exsur info {logs[0]}, to list its channels"
            )
        raise ConfigError(
            f"{path}: a folder without {MANIFEST} is not a dataset; give a checkpoint file, "
            f"e.g. {ckpt}, or a dataset folder"
        )
    elif path.suffix.lower() == ".parquet":
        from ..evaluate.card import public
        from ..evaluate.data_card import dataset_card_markdown, episode_card

        card = episode_card(path)
        text = dataset_card_markdown
    elif path.suffix.lower() == ".onnx":
        from ..env.onnx_card import onnx_card, onnx_card_json, onnx_card_markdown

        card = onnx_card(path)
        if args.json:
            print(json.dumps(onnx_card_json(card), indent=2, allow_nan=False))
        else:
            print(onnx_card_markdown(card), end="")
        return 0
    else:
        from ..errors import CheckpointError
        from ..evaluate.card import card_markdown, model_card, public

        try:
            card = model_card(path)
        except CheckpointError as e:
            if path.suffix.lower() in (".pt", ".pth"):
                raise
            raise CheckpointError(  # not named as a checkpoint: say what info reads
                f"{path}: not a file exsur info reads; it describes a checkpoint (.pt), an "
                "ONNX export (.onnx), a dataset folder, an episode file (.parquet) or a raw "
                "log exsur import reads"
            ) from e
        text = card_markdown
    if args.json:
        print(json.dumps(public(card), indent=2, allow_nan=False))
    else:
        print(text(card), end="")
    return 0


def _write_draft(summary: LogSummary, out: Path, *, csv: CsvOptions | None) -> None:
    """Write the drafted mapping of ``summary`` to ``out`` and say what it holds (stderr)."""
    import sys

    from ..ingest.draft import draft_mapping
    from ..io_utils import write_text

    draft = draft_mapping(summary, csv=csv)
    write_text(out, draft.text)
    joints = ", ".join(draft.joints) if draft.joints else "no joint"
    print(
        f"wrote {out}: {joints}; {len(draft.todo)} TODO, {len(draft.unused)} channel(s) not "
        f"mapped. Check the lines marked '# guessed', then: exsur import {summary.path} "
        f"--mapping {out} --dry-run",
        file=sys.stderr,
    )


def _csv_options(sets: list[str]) -> CsvOptions | None:
    """``--set csv.KEY=VALUE`` as the ``[csv]`` options (None without any)."""
    if not sets:
        return None
    from ..config import from_dict, parse_sets
    from ..ingest.options import CsvOptions

    table = parse_sets(sets, sections=["csv"])["csv"]
    return from_dict(CsvOptions, table, where="--set csv")


def _raw_logs_in(folder: Path) -> list[Path]:
    """The raw logs in ``folder``, sorted (what a folder given as PATH points to)."""
    return [c for c in sorted(folder.iterdir()) if _is_raw_log(c)]


def _is_raw_log(path: Path, *, csv_format: str = "auto") -> bool:
    """A log ``exsur import`` reads (not an exsur episode, dataset or checkpoint)."""
    from ..ingest.readers import reader_for

    reader = reader_for(path, csv_format=csv_format)
    if reader is None:
        return False
    if reader.kind != "parquet":
        return True
    from ..errors import DataError
    from ..ingest.tables import open_parquet

    try:
        open_parquet(path)  # the import's own test: not an exsur episode
    except DataError:  # an episode, or unreadable: the episode card names the damage
        return False
    return True


def _number(x: float | None, digits: int = 5) -> str:
    return "" if x is None else f"{x:.{digits}g}"


def _short(text: str, n: int = 60) -> str:
    return text if len(text) <= n else text[: n - 3] + "..."


def _log_markdown(summary: LogSummary) -> str:
    """``exsur info LOG``'s Markdown: the log's format, span and channels."""
    head = [f"# {summary.path.name}: {summary.label}", ""]
    facts = [f"{len(summary.channels)} channel(s)"]
    if summary.start:
        facts.append(f"starts {summary.start}")
    if summary.duration_s is not None:
        facts.append(f"{summary.duration_s:.4g} s long")
    head += ["; ".join(facts), ""]
    chans = summary.channels
    # columns no channel fills are left out (a CSV has no units, rates or groups)
    show = {
        "group": any(c.group for c in chans),
        "unit": any(c.unit for c in chans),
        "rate": any(c.rate_hz is not None for c in chans),
        "missing": any(c.n_missing for c in chans),
        "note": any(c.note for c in chans),
    }
    titles = {"group": "group / topic", "rate": "rate [Hz]"}
    cols = ["channel", *[titles.get(k, k) for k in ("group", "unit") if show[k]], "samples"]
    cols += [*(["rate [Hz]"] if show["rate"] else []), "min", "max"]
    cols += [k for k in ("missing", "note") if show[k]]
    rows = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    for c in chans:
        cells = [f"`{c.name}`" if c.name else ""]
        cells += [v for k, v in (("group", c.group), ("unit", c.unit)) if show[k]]
        cells += [str(c.n_sample), *([_number(c.rate_hz, 4)] if show["rate"] else [])]
        cells += [_number(c.lo), _number(c.hi)]
        cells += [str(c.n_missing) if c.n_missing else ""] if show["missing"] else []
        cells += [c.note] if show["note"] else []
        rows.append("| " + " | ".join(x.replace("|", "\\|") for x in cells) + " |")
    tail = [""]
    if summary.meta:
        tail += ["Metadata (what `[[inputs]] from_metadata` reads):", ""]
        tail += [f"- `{k}` = `{_short(v)!r}`" for k, v in sorted(summary.meta.items())] + [""]
    tail += [f"- {n}" for n in summary.notes]
    tail += [
        "- A mapping names a channel as the first column shows it (`column = ...`; a ROS "
        "log's `topic` and `field`); the ranges are raw, before any unit (docs/import.md).",
        "- `--draft-mapping MAP.toml` writes a first mapping guessed from these channels, "
        "each guess marked.",
        "",
    ]
    return "\n".join(head + rows + tail)


def _computer(args: argparse.Namespace) -> int:
    """``exsur info --computer``: the record a run on this computer would write
    (:func:`~excavator_surrogate.numerics.environment`, torch loaded), as Markdown or JSON."""
    import json

    from ..errors import ConfigError

    if args.path is not None:
        raise ConfigError(
            f"exsur info: give PATH or --computer, not both (got {args.path} and --computer)"
        )
    if not args.computer:
        raise ConfigError(
            "exsur info: give a checkpoint file (.pt), an ONNX export (.onnx), a dataset "
            "folder, or --computer"
        )
    import torch  # noqa: F401  (loaded so that the record names its CPU kernels)

    from ..evaluate.training_report import computer_markdown
    from ..numerics import environment

    env = environment()
    if args.json:
        print(json.dumps(env, indent=2, allow_nan=False))
    else:
        print(computer_markdown(env), end="")
    return 0
