"""``exsur run --dry-run``: what a run would do, and what its training would cost, without
running it.

It resolves the run as :func:`~.pipeline.run_pipeline` does (:func:`~.pipeline.resolve_run`)
and describes each stage:

- **data**: the logs are imported into a temporary folder (removed at once), so a mapping
  or a log that would fail the run fails here, in the same words; a dataset given with
  ``--data`` is read; a dataset to simulate is described from ``[simulate]`` alone
  (:meth:`~.simulate.config.SimulateConfig.episode_lengths`), nothing is simulated;
- **clean**, **train** (the recipe's reasons where the run chooses its config from the data,
  the planned work of :mod:`~.training.estimate`, the baselines and whether they train side
  by side) and **evaluate**;
- the ``config.toml`` the run would record (:meth:`~.pipeline.RunRequest.record`).

Nothing is written and nothing is trained.
"""

from __future__ import annotations

import dataclasses
import tempfile
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from .config import dumps_toml
from .pipeline import RunRequest, evaluated_split


def plan_run(req: RunRequest, *, cpus: int | None = None) -> str:
    """What ``exsur run --dry-run`` prints for ``req``.

    Args:
        req: the resolved run (:func:`~.pipeline.resolve_run`).
        cpus: CPUs the run plans for (default: those this process may use).

    Returns:
        The text, ending with the ``config.toml`` the run would record.

    Raises:
        DataError: a log or the dataset breaks a validation rule (as the run would).
        ConfigError: a bad mapping or option (as the run would).
    """
    from .data import load_dataset

    cfgs = req.configs
    lines = [f"preset: {req.name}"]
    if req.logs is not None:
        from .ingest import import_logs
        from .ingest.mapping_toml import load_mapping

        with tempfile.TemporaryDirectory(prefix="exsur-dry-run-") as tmp:
            report = import_logs(
                list(req.logs), load_mapping(req.mapping), out=Path(tmp) / "data", quiet=True
            )
            ds = load_dataset(Path(tmp) / "data")
            lengths = _lengths(ds)
            totals = report["totals"]
            left = [
                f"{totals[k]} {what}"
                for k, what in (("files_failed", "failed"), ("files_dropped", "dropped whole"))
                if totals[k]
            ]
            lines.append(
                f"data: {totals['files']} log(s) imported with {req.mapping}"
                + (f" ({', '.join(left)}: see `exsur import`'s report)" if left else "")
                + f": {_sizes(lengths, ds.spec.rate_hz)}"
            )
            return _describe(req, lines, lengths, ds=ds, n_input=ds.spec.n_input, cpus=cpus)
    if req.data is not None:
        ds = load_dataset(req.data)
        lengths = _lengths(ds)
        lines.append(f"data: {req.data}: {_sizes(lengths, ds.spec.rate_hz)}")
        return _describe(req, lines, lengths, ds=ds, n_input=ds.spec.n_input, cpus=cpus)
    sim = cfgs["simulate"]
    lengths = sim.episode_lengths()
    lines.append(
        f"data: simulated on the {sim.plant} stand-in (nothing simulated now): "
        f"{_sizes(lengths, sim.rate_hz)}"
    )
    return _describe(req, lines, lengths, n_input=len(sim.inputs), cpus=cpus)


def _describe(
    req: RunRequest,
    lines: list[str],
    lengths: Mapping[str, Sequence[int]],
    *,
    ds: Any = None,
    n_input: int,
    cpus: int | None,
) -> str:
    """The clean, train and evaluate lines after ``lines`` (the data's), and the record.
    ``lengths``: the samples of each episode by split; ``ds``: the dataset (None: not
    simulated yet); ``n_input``: its exogenous inputs."""
    from .training.api import side_by_side
    from .training.estimate import describe_work, estimate_sizes
    from .training.speed_probe import timed_estimate

    cfgs = req.configs
    run_cfg, train_cfg, eval_cfg = cfgs["run"], cfgs["train"], cfgs["evaluate"]
    if run_cfg.clean:
        lines.append(
            f"clean: {cfgs['clean'].method}; the models train on the cleaned data"
            + (" (and a baseline on the raw data)" if run_cfg.raw_baseline else "")
        )
    recipe: list[str] = []
    if run_cfg.auto_train:
        if ds is None:
            lines.append(
                "recipe: chosen from the simulated data, so not before it exists (simulate "
                "it with `exsur simulate`, then `exsur run --data DIR --dry-run`)"
            )
        else:
            train_cfg, recipe = req.train_recipe(ds, cpus=cpus)
            lines.append("recipe (docs/real.md):")
            lines += [f"  - {w}" for w in recipe]
    jobs = ["surrogate"]
    if run_cfg.gru:
        jobs.append("GRU baseline")
    if run_cfg.clean and run_cfg.raw_baseline:
        jobs.append("surrogate on the raw data")
    job_cfgs = [train_cfg] * len(jobs)
    if run_cfg.gru:
        job_cfgs[1] = dataclasses.replace(train_cfg, cell="gru")
    est = estimate_sizes(
        train_cfg,
        train=lengths.get("train", []),
        val=lengths.get("val", []),
        n_input=n_input,
        cpus=cpus,
    )
    if not (run_cfg.auto_train and ds is None):
        # another network than the recipe's: timed against it here (the simulated plant and
        # the synthetic probe have four joints)
        est = timed_estimate(est, train_cfg, n_joint=ds.spec.n_joint if ds is not None else 4)
        lines.append(
            "planned work of the surrogate (the reference machine's time; nothing is trained):"
        )
        lines += [f"  - {w}" for w in describe_work(est)]
    if len(jobs) > 1:
        together = side_by_side(job_cfgs, cpus=cpus)
        lines.append(
            f"also trained with the same plan: {', '.join(jobs[1:])}; "
            + (
                "side by side with the surrogate (every model's members fit on the CPUs)"
                if together
                else "one model after the other (their members do not all fit on the CPUs "
                "at once): "
                + (
                    f"about {len(jobs) * est.total_s:.0f} s on the reference machine"
                    if est and est.timed
                    else f"{len(jobs)}x one model's training time"
                )
            )
        )
    eval_cfg, why_val = evaluated_split(
        eval_cfg,
        splits={s: len(n) for s, n in lengths.items()},
        train_on_val=train_cfg.train_on_val,
    )
    lines.append(
        f"evaluate: {why_val}"
        if why_val
        else f"evaluate: closed-loop free run on the '{eval_cfg.split}' split against the "
        f"{run_cfg.reference} angles" + _beside(run_cfg, eval_cfg)
    )
    record = req.record(train=train_cfg, evaluate=eval_cfg, recipe=recipe)
    return "\n".join(lines) + "\n\nconfig.toml:\n" + dumps_toml(record)


def _beside(run_cfg: Any, eval_cfg: Any) -> str:
    """The baselines the evaluation scores beside the model, as the plan's words ("" for none)."""
    got = [
        what
        for on, what in (
            (run_cfg.arx and eval_cfg.arx, "a linear ARX"),
            (run_cfg.structured and eval_cfg.structured, "the structured model"),
        )
        if on
    ]
    return f", beside {' and '.join(got)}" if got else ""


def _lengths(ds: Any) -> dict[str, list[int]]:
    """Samples of each episode of dataset ``ds``, by split."""
    return {s: [e.n_step for e in ds.split(s)] for s in ("train", "val", "test")}


def _sizes(lengths: Mapping[str, Sequence[int]], rate_hz: float) -> str:
    """:func:`sizes_text` of the splits that hold episodes."""
    return sizes_text({s: n for s, n in lengths.items() if n}, rate_hz)


def sizes_text(lengths: Mapping[str, Sequence[int]], rate_hz: float) -> str:
    """``lengths`` (the samples of each episode, by split) in words: episodes and minutes
    per split, e.g. ``2 train episode(s), 0.2 min; 1 val episode(s), 0.1 min at 20 Hz``
    (what ``exsur run --dry-run`` and ``exsur train --dry-run`` print)."""
    parts = [
        f"{len(n)} {split} episode(s), {sum(n) / rate_hz / 60:.1f} min"
        for split, n in lengths.items()
    ]
    return "; ".join(parts) + f" at {rate_hz:g} Hz"
