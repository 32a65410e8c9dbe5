"""``exsur run``: simulate -> [clean] -> train -> evaluate, into one report folder.

The report folder (written atomically: built in a temporary sibling, renamed when done)::

    OUT/
      report.md          # everything a person wants to read: tables, figures, timings
      metrics.json       # CBE of the LSTM (+ "compare" baselines, "cleaning", "against_cleaned");
                         # its paths are relative to OUT ("model/best.pt"), absolute outside it
      table.md           # the paper-layout CBE table (and baselines)
      cbe.png            # Figure-2-style closed-loop comparison
      fusion_<joint>.png # Figure-3-style Kalman fusion (Stage II presets)
      config.toml        # the resolved preset that produced the folder
      data/              # the simulated or imported dataset (measured; with *_true columns
                         # for Stage II); not with --data, whose dataset stays where it is
      data_clean/        # the cleaned dataset (Stage II)
      model/best.pt      # the surrogate checkpoint (+ log.csv, tb/)
      model_gru/, model_raw/   # baselines: GRU, and the LSTM trained on uncleaned data
"""

from __future__ import annotations

import dataclasses
import logging
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, Literal, TypedDict, Unpack

from .config import dumps_toml, load_preset, merge_tables, to_dict
from .errors import ConfigError
from .evaluate.data_card import describe_dataset
from .evaluate.run_report import ReportContext, render_run_report
from .io_utils import atomic_dir, write_json, write_text
from .stages import DEFAULT_PRESET, RUN_SECTIONS, RunConfig, build_configs, check_preset

_log = logging.getLogger(__name__)


class RunOptions(TypedDict, total=False):
    """What ``exsur run`` is asked for: the keyword arguments of :func:`run_pipeline` and
    :func:`resolve_run` (every one optional)."""

    preset: str | Path
    """Shipped preset name or TOML path with ``[simulate]``, ``[train]``, ``[evaluate]`` and
    optional ``[run]``/``[clean]`` tables (default: :data:`DEFAULT_PRESET`)."""
    data: str | Path | None
    """Use this existing dataset instead of simulating (e.g. imported logs)."""
    workers: int | None
    """Simulation processes (default: the preset's)."""
    seed: int | None
    """Overrides the simulation and training seeds."""
    max_train_seconds: float | None
    """Overrides the training wall-time budget (per model)."""
    epochs: int | None
    """Overrides the maximum number of epochs."""
    members: int | None
    """Overrides the seed-ensemble size of every trained model (1: single networks)."""
    logs: Sequence[str | Path] | None
    """Import these logs (files, folders, globs) with ``mapping`` instead of simulating."""
    mapping: str | Path | None
    """The mapping TOML of ``logs`` (see ``docs/import.md``)."""
    sets: Mapping[str, Mapping[str, Any]] | None
    """Further overrides by table, e.g. ``{"train": {"lr": 3e-4}}`` (``--set``; the named
    options above win)."""


def run_pipeline(*, out: str | Path, **options: Unpack[RunOptions]) -> dict[str, Any]:
    """Run the whole pipeline for a preset and write the report folder ``out``.

    Args:
        out: report folder (replaced only when the run completes).
        **options: what to run (:class:`RunOptions`), resolved by :func:`resolve_run`.

    Returns:
        The content of ``metrics.json``.
    """
    from .data import load_dataset
    from .evaluate.cbe import evaluate_checkpoint
    from .simulate.generate import simulate_dataset
    from .training import TrainJob, train_parallel

    t_start = time.monotonic()
    req = resolve_run(**options)
    name, cfgs = req.name, req.configs
    logs, mapping, data = req.logs, req.mapping, req.data
    run_cfg: RunConfig = cfgs["run"]
    sim_cfg = cfgs["simulate"]
    train_cfg = cfgs["train"]
    recipe: list[str] = []
    eval_cfg = cfgs["evaluate"]
    timings: dict[str, float] = {}
    out = Path(out)

    with atomic_dir(out, kind="run") as tmp:
        # ---- simulate (or take the user's dataset) --------------------------------------
        t0 = time.monotonic()
        if logs is not None:
            from .ingest import import_logs
            from .ingest.mapping_toml import load_mapping

            _log.info(f"run[{name}]: import {len(logs)} source(s) with {mapping} -> {out / 'data'}")
            import_logs(list(logs), load_mapping(mapping), out=tmp / "data", quiet=True)
            data_dir = tmp / "data"
        elif data is None:
            _log.info(f"run[{name}]: simulate -> {out / 'data'}")
            data_dir = simulate_dataset(sim_cfg, out=tmp / "data", extra={"preset": name})
        else:
            data_dir = Path(data)
            _log.info(f"run[{name}]: using dataset {data_dir}")
        timings["import" if logs is not None else "simulate"] = time.monotonic() - t0
        raw_ds = load_dataset(data_dir)
        train_ds = raw_ds
        if run_cfg.auto_train:
            from .training.auto import recipe_table
            from .training.estimate import describe_work, estimate_work

            train_cfg, recipe = req.train_recipe(raw_ds)
            for line in recipe:
                _log.info(f"run[{name}]: recipe: {line}")
            for line in describe_work(estimate_work(train_cfg, raw_ds)):
                _log.info(f"run[{name}]: planned work: {line}")
        eval_cfg, why_val = evaluated_split(
            eval_cfg,
            splits={s: len(raw_ds.split(s)) for s in ("train", "val", "test")},
            train_on_val=train_cfg.train_on_val,
        )
        if why_val:
            _log.info(f"run[{name}]: {why_val}")
        result_extra: dict[str, Any] = {}

        # ---- clean ----------------------------------------------------------------------
        if run_cfg.clean:
            from .clean import clean_dataset

            t0 = time.monotonic()
            _log.info(f"run[{name}]: clean ({cfgs['clean'].method})")
            clean_dir = clean_dataset(data_dir, tmp / "data_clean", config=cfgs["clean"])
            train_ds = load_dataset(clean_dir)
            result_extra["cleaning"] = train_ds.manifest.get("cleaning", {})
            timings["clean"] = time.monotonic() - t0
            if run_cfg.fusion_figures and raw_ds.test and train_ds.test:
                from .plotting.fusion import plot_fusion

                for j in raw_ds.spec.names:
                    plot_fusion(
                        raw_ds.test[0], train_ds.test[0], joint=j, path=tmp / f"fusion_{j}.png"
                    )

        # ---- train ----------------------------------------------------------------------
        # the LSTM, then the baselines the run asks for: side by side when they fit the CPUs
        t0 = time.monotonic()
        notes = {"recipe": recipe_table(recipe)} if recipe else None
        jobs = [TrainJob(train_cfg, train_ds, tmp / "model", tag="exsur lstm", notes=notes)]
        if run_cfg.gru:
            gru_cfg = dataclasses.replace(train_cfg, cell="gru")
            jobs.append(TrainJob(gru_cfg, train_ds, tmp / "model_gru", tag="exsur gru"))
        if run_cfg.clean and run_cfg.raw_baseline:
            jobs.append(TrainJob(train_cfg, raw_ds, tmp / "model_raw", tag="exsur lstm-raw"))
        _log.info(
            f"run[{name}]: train LSTM ({train_cfg.mode})"
            + "".join(f", {j.tag.split()[-1]} baseline" for j in jobs[1:])
        )
        bests = dict(zip((j.out.name for j in jobs), train_parallel(jobs)))
        timings["train"] = time.monotonic() - t0
        best = bests["model"]
        compare: dict[str, Path] = {"GRU": bests["model_gru"]} if "model_gru" in bests else {}
        raw_best: Path | None = bests.get("model_raw")
        from .plotting.training import plot_learning_curves

        curves = tuple(
            plot_learning_curves(b.parent, out=b.parent / "learning_curve.png")
            .relative_to(tmp)
            .as_posix()
            for b in bests.values()
        )

        # ---- evaluate -------------------------------------------------------------------
        t0 = time.monotonic()
        _log.info(
            f"run[{name}]: evaluate (closed-loop free run on '{eval_cfg.split}', reference {run_cfg.reference})"
        )
        ev = dataclasses.asdict(eval_cfg)
        ev["arx"] = run_cfg.arx and ev["arx"]
        ev["structured"] = run_cfg.structured and ev["structured"]
        ev["paper"] = run_cfg.paper_table == "II" and ev["paper"]
        # Paths inside the run folder are recorded relative to it ("model/best.pt"), so they
        # stay right when the temporary folder is renamed into place.
        metrics = evaluate_checkpoint(
            best,
            train_ds,
            out=tmp,
            overwrite=True,  # this run's own folder, being built: its evaluation is part of it
            root=tmp,
            compare=compare,
            **{**ev, "reference": run_cfg.reference},
        )
        if run_cfg.clean:
            # Also score against the cleaned data (the only reference a real machine gives).
            against = evaluate_checkpoint(
                best,
                train_ds,
                out=tmp / "eval_cleaned",
                root=tmp,
                compare=None,
                **{
                    **ev,
                    "reference": "measured",
                    "arx": False,
                    "structured": False,
                    "paper": False,
                },
            )
            result_extra["against_cleaned"] = {k: against[k] for k in ("omega", "theta")}
        if raw_best is not None:
            result_extra["cleaning_effect"] = _score_models(
                {"trained on cleaned": best, "trained on raw": raw_best}, train_ds, eval_cfg
            )
        member_paths = {  # none where the members live elsewhere (choices of two kinds)
            f"member {i}": p
            for i in range(train_cfg.members)
            if (p := best.parent / f"member_{i}" / "best.pt").is_file()
        }
        if len(member_paths) > 1:
            result_extra["ensemble_members"] = _score_models(
                {"ensemble": best, **member_paths},
                train_ds,
                eval_cfg,
                reference=run_cfg.reference,
            )
        timings["evaluate"] = time.monotonic() - t0
        timings["total"] = time.monotonic() - t_start
        metrics.update(result_extra)
        metrics["run"] = {
            **metrics.get("run", {}),
            "preset": name,
            "split": eval_cfg.split,
            "timings_s": {k: round(v, 1) for k, v in timings.items()},
            "out": str(out.resolve()),
        }
        write_json(tmp / "metrics.json", metrics)
        write_text(
            tmp / "config.toml",
            dumps_toml(req.record(train=train_cfg, evaluate=eval_cfg, recipe=recipe)),
        )
        write_text(
            tmp / "report.md",
            render_run_report(
                metrics,
                ReportContext(
                    name=name,
                    spec_names=raw_ds.spec.names,
                    table_md=(tmp / "table.md").read_text(encoding="utf-8"),
                    paper_table=run_cfg.paper_table,
                    learning_curves=curves,
                    data=describe_dataset(train_ds, path=_in_run(train_ds.root, tmp)),
                    horizon_figure=(tmp / "horizon.png").is_file(),
                    datasets=tuple(d for d in ("data", "data_clean") if (tmp / d).is_dir()),
                ),
            ),
        )
    _log.info(f"run[{name}]: done in {timings['total']:.0f} s -> {out / 'report.md'}")
    return metrics


@dataclasses.dataclass(frozen=True)
class RunRequest:
    """What ``exsur run`` was asked for, resolved: the preset with the command's options and
    ``--set`` applied, and where its data comes from.  :func:`run_pipeline` runs it and
    :func:`plan_run` describes it."""

    name: str
    """The preset's name."""
    raw_preset: Mapping[str, Any]
    """The preset's tables as loaded."""
    overrides: Mapping[str, Mapping[str, Any]]
    """The command's options and ``--set`` by table (the named options win)."""
    configs: Mapping[str, Any]
    """The resolved config of each of :data:`RUN_SECTIONS`."""
    data: Path | None
    """The dataset to train on (None: simulate, or import ``logs``)."""
    logs: tuple[str, ...] | None
    """The logs to import with ``mapping``: files, folders or glob patterns (None: none)."""
    mapping: Path | None
    """The mapping file of ``logs``."""

    def train_recipe(self, dataset: Any, *, cpus: int | None = None) -> tuple[Any, list[str]]:
        """The data-driven recipe's ``[train]`` config for ``dataset`` and its reasons
        (``[run] auto_train``): the preset's ``[train]`` keys and the command's override its
        choices.  ``cpus``: those it plans for (default: those this process may use)."""
        from .training.auto import auto_config

        over = merge_tables(self.raw_preset.get("train", {}), self.overrides.get("train", {}))
        return auto_config(dataset, overrides=over, cpus=cpus)

    def record(self, *, train: Any, evaluate: Any, recipe: Sequence[str] = ()) -> dict[str, Any]:
        """The content of ``config.toml``: every table the run reads, with the command's
        overrides, the recipe's ``train`` and the ``evaluate`` actually used."""
        from .training.auto import recipe_table

        run_cfg: RunConfig = self.configs["run"]
        used = {k: v for k, v in self.configs.items() if k != "clean" or run_cfg.clean}
        # a run scores against run.reference, whatever [evaluate] says: record what it used
        evaluate = dataclasses.replace(evaluate, reference=run_cfg.reference)
        used.update(train=train, evaluate=evaluate)
        if self.logs is not None or self.data is not None:
            used.pop("simulate")
        record: dict[str, Any] = {"name": self.name, **{k: to_dict(v) for k, v in used.items()}}
        if run_cfg.auto_train:  # [train] is the recipe's plan for this data, as it ran: read
            # back with auto_train on, its per-network time cap would be planned as the budget
            record["run"]["auto_train"] = False
        if self.data is not None:
            record["data"] = str(self.data)
        if self.logs is not None:
            record["logs"] = {"sources": list(self.logs), "mapping": str(self.mapping)}
        if recipe:
            record["recipe"] = recipe_table(list(recipe))
        return record


def resolve_run(**options: Unpack[RunOptions]) -> RunRequest:
    """Check and resolve what ``exsur run`` is asked for (:class:`RunOptions`) into a
    :class:`RunRequest`.

    Raises:
        ConfigError: one line: options that do not go together, or a bad value.
    """
    logs, mapping, data = options.get("logs"), options.get("mapping"), options.get("data")
    preset = options.get("preset", DEFAULT_PRESET)
    workers, seed = options.get("workers"), options.get("seed")
    max_train_seconds = options.get("max_train_seconds")
    if (logs is None) != (mapping is None):
        raise ConfigError("--logs and --mapping go together: give both, or neither")
    if logs is not None and data is not None:
        raise ConfigError("give either --logs (with --mapping) or --data, not both")
    raw_preset = load_preset(preset, check=check_preset)
    name = str(raw_preset.get("name", preset))
    if workers is not None and workers < 1:
        raise ConfigError(f"--workers must be >= 1, got {workers}")
    named = {
        "simulate": {"workers": workers, "seed": seed},
        "train": {
            "seed": seed,
            "max_train_seconds": None if max_train_seconds is None else float(max_train_seconds),
            "epochs": options.get("epochs"),
            "members": options.get("members"),
        },
    }
    over = merge_tables(
        options.get("sets") or {},
        {k: {n: v for n, v in t.items() if v is not None} for k, t in named.items()},
    )
    cfgs = build_configs(
        raw_preset, sections=RUN_SECTIONS, overrides=over, where=f"preset '{name}'"
    )
    return RunRequest(
        name=name,
        raw_preset=raw_preset,
        overrides=over,
        configs=cfgs,
        data=None if data is None else Path(data),
        logs=None if logs is None else tuple(str(p) for p in logs),
        mapping=None if mapping is None else Path(mapping),
    )


def evaluated_split(
    eval_cfg: Any, *, splits: Mapping[str, int], train_on_val: bool
) -> tuple[Any, str | None]:
    """The ``[evaluate]`` config a run scores with, and why it is not the one asked for:
    data without the asked split (episodes per split in ``splits``) are scored on ``val``,
    which the networks also train on (``train_on_val``) or which selected the checkpoint."""
    if splits.get(eval_cfg.split) or not splits.get("val"):
        return eval_cfg, None
    why = f"the dataset has no '{eval_cfg.split}' split: evaluating on 'val', " + (
        "which the networks also train on (in-sample: no measure of unseen runs)"
        if train_on_val
        else "which also selected the checkpoint (optimistic)"
    )
    return dataclasses.replace(eval_cfg, split="val"), why


def _in_run(path: Path | None, tmp: Path) -> str:
    """``path`` relative to the run folder being written (``tmp``, renamed into place later)
    when it lies inside, else absolute: what the report names (a path relative to where the
    command ran would not resolve from the run folder, which the report reads from)."""
    if path is None:
        return "the dataset"
    try:
        return Path(path).resolve().relative_to(tmp.resolve()).as_posix()
    except ValueError:
        return str(Path(path).resolve())


def _score_models(
    models: Mapping[str, Path],
    ds: Any,
    eval_cfg: Any,
    *,
    reference: Literal["measured", "true"] = "true",
) -> dict[str, Any]:
    """CBE of several checkpoints on the same test episodes against ``reference`` (the truth
    by default), label -> metrics."""
    from .evaluate.cbe import evaluate_models
    from .surrogate.checkpoint import load_checkpoint

    metrics, _ = evaluate_models(
        {label: load_checkpoint(path) for label, path in models.items()},
        ds.split(eval_cfg.split),
        reference=reference,
        max_steps=eval_cfg.max_steps or None,
    )
    return metrics
