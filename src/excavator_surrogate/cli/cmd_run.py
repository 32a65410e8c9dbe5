"""``exsur run``: the end-to-end pipeline (simulate -> [clean] -> train -> evaluate)."""

from __future__ import annotations

import argparse
from pathlib import Path

from .common import add_cpus_option, add_overwrite
from .knobs import add_set_option, configs, overrides, positive_seconds


def register(sub: argparse._SubParsersAction) -> None:
    """Add the ``run`` subcommand."""
    from ..stages import DEFAULT_PRESET, RUN_SECTIONS

    p = sub.add_parser(
        "run",
        help="end to end: simulate -> [clean] -> train -> evaluate, one report folder",
        description="Run the whole pipeline for a preset and write a report folder with "
        "report.md, metrics.json, the CBE table, figures, config.toml and the model. "
        "Without --preset this is the README's 5-minute demo.",
    )
    p.add_argument(
        "--out",
        type=Path,
        default=None,
        metavar="DIR",
        help="report folder (replaced when complete; required to run)",
    )
    p.add_argument(
        "--dry-run",
        action="store_true",
        help="print what the run would do: the data's sizes (logs are imported into a "
        "temporary folder, nothing is simulated), the recipe's reasons, the trainings, "
        "epochs and caps and their time on the reference machine, and the config.toml it "
        "would record; write and train nothing",
    )
    p.add_argument(
        "--preset",
        default=None,
        metavar="NAME|FILE.toml",
        help=f"preset (default: {DEFAULT_PRESET}, or 'real' with --logs; e.g. paper-stage1, "
        "quick-noload, paper-compound)",
    )
    p.add_argument(
        "--data",
        type=Path,
        default=None,
        metavar="DATASET",
        help="train and evaluate on this dataset instead of simulating",
    )
    p.add_argument(
        "--logs",
        nargs="+",
        default=None,
        metavar="PATH",
        help="your machine's logs (files, folders or quoted globs): import them with --mapping "
        "and train the data-driven recipe (preset 'real' unless --preset is given)",
    )
    p.add_argument(
        "--mapping",
        type=Path,
        default=None,
        metavar="MAP.toml",
        help="the mapping file of --logs (see docs/import.md)",
    )
    p.add_argument("--workers", type=int, default=None, metavar="N", help="simulation processes")
    p.add_argument(
        "--seed", type=int, default=None, metavar="N", help="simulation and training seed"
    )
    p.add_argument(
        "--max-train-seconds",
        type=positive_seconds("--max-train-seconds"),
        default=None,
        metavar="S",
        help="wall-time budget per trained model [s], > 0 (default: the preset's; none: no budget)",
    )
    p.add_argument("--epochs", type=int, default=None, metavar="N", help="maximum epochs per model")
    p.add_argument(
        "--members",
        type=int,
        default=None,
        metavar="K",
        help="seed-ensemble members per trained model (1: a single network; default: the preset's)",
    )
    add_cpus_option(p)
    add_overwrite(p, replaced=True)
    add_set_option(p, RUN_SECTIONS)
    p.set_defaults(func=checked_run)


def checked_run(args: argparse.Namespace) -> int:
    """:func:`run` under the output-folder rule: no input inside ``--out``; ``--overwrite``.
    With ``--dry-run``: :func:`dry_run`, which needs no ``--out``."""
    from ..errors import ConfigError
    from ..outdir import out_dir, preset_files

    if args.dry_run:
        return dry_run(args)
    if args.out is None:
        raise ConfigError("--out DIR is required (or --dry-run to only print the plan)")

    inputs = [*preset_files(args.preset)]
    for key in ("data", "mapping", "logs"):  # the dataset, or the logs and their mapping
        value = getattr(args, key, None)
        inputs += [] if value is None else value if isinstance(value, list) else [value]
    with out_dir(args.out, overwrite=args.overwrite, inputs=inputs, kind="run"):
        return run(args)


def run(args: argparse.Namespace) -> int:
    """Handler of ``exsur run``."""
    from ..evaluate.metrics import worst_r2_text
    from ..pipeline import run_pipeline

    metrics = run_pipeline(out=args.out, **_request(args))
    print(
        f"{args.out}: worst-joint angle R² {worst_r2_text(metrics, 'theta')}, "
        f"worst-joint ω R² {worst_r2_text(metrics, 'omega')} (report: {args.out / 'report.md'})"
    )
    return 0


def dry_run(args: argparse.Namespace) -> int:
    """Handler of ``exsur run --dry-run``: print :func:`~excavator_surrogate.run_plan.plan_run`
    (printed, not logged), write nothing."""
    from ..pipeline import resolve_run
    from ..run_plan import plan_run

    print(plan_run(resolve_run(**_request(args))), end="")
    return 0


def _request(args: argparse.Namespace) -> dict:
    """The keyword arguments of :func:`~excavator_surrogate.pipeline.run_pipeline` (and of
    :func:`~excavator_surrogate.pipeline.resolve_run`) that ``args`` ask for, after
    :func:`_check_request`."""
    from ..stages import DEFAULT_PRESET, RUN_SECTIONS

    preset = args.preset or ("real" if args.logs else DEFAULT_PRESET)
    _check_request(args, preset)
    return dict(
        preset=preset,
        logs=args.logs,
        mapping=args.mapping,
        data=args.data,
        workers=args.workers,
        seed=args.seed,
        max_train_seconds=args.max_train_seconds,
        epochs=args.epochs,
        members=args.members,
        sets=overrides(args, RUN_SECTIONS),
    )


def _check_request(args: argparse.Namespace, preset: str) -> None:
    """Before anything runs: refuse ``--set`` knobs this run will not read, and a dataset to
    simulate that cannot fit in memory or on disk."""
    from ..config import parse_sets
    from ..errors import ConfigError
    from ..stages import RUN_SECTIONS, check_dataset_size, check_sets_read

    sets = parse_sets(args.sets or [], sections=RUN_SECTIONS)
    cfgs = configs(args, RUN_SECTIONS, preset=preset)
    skipped = {}
    if not cfgs["run"].clean:
        skipped["clean"] = "this run does not clean (run.clean = false; add --set run.clean=true)"
    if args.data is not None or args.logs is not None:
        given = "--data" if args.data is not None else "--logs"
        skipped["simulate"] = f"this run trains on {given} and simulates nothing"
    check_sets_read(sets, cfgs, skipped=skipped)
    if "reference" in (sets.get("evaluate") or {}):
        raise ConfigError(
            "--set evaluate.reference: not read, exsur run scores against run.reference "
            f"(now {cfgs['run'].reference!r}); use --set run.reference=... instead"
        )
    if "simulate" not in skipped:
        check_dataset_size(cfgs["simulate"], out=args.out or Path.cwd())
