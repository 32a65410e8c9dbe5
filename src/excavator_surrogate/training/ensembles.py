"""Seed ensembles: train ``members`` networks (seeds ``seed, seed + 1, ...``) and merge them."""

from __future__ import annotations

import logging
import time
from collections.abc import Mapping, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

from ..config import to_dict
from ..data.dataset import Dataset
from ..data.episode import Episode
from ..devices import usable_cpus
from ..io_utils import mark_output
from ..surrogate.checkpoint import load_checkpoint, save_checkpoint
from ..surrogate.ensemble import merge
from ..surrogate.model import Surrogate
from ..surrogate.scores import worst_r2
from ..surrogate.validation import free_run_error
from .batches import split_episodes
from .config import TrainConfig
from .jobs import TrainJob, run_jobs
from .loop import train_network
from .records import write_config, write_log

_log = logging.getLogger(__name__)


def member_configs(cfg: TrainConfig) -> list[TrainConfig]:
    """The single-network configs of ``cfg``'s ensemble members (seeds ``seed + i``; with
    ``bootstrap`` each seed also draws the member's own resample of the training episodes)."""
    return [
        replace(cfg, members=1, member_workers=0, seed=cfg.seed + i) for i in range(cfg.members)
    ]


def open_run(
    cfg: TrainConfig,
    dataset: Dataset,
    out: str | Path,
    *,
    notes: Mapping[str, Any] | None,
    trainings: int,
) -> tuple[list[Episode], Path, int]:
    """Start a run of several trainings: the validation episodes (bad data fails here, before
    any member starts), the output folder marked as exsur's with ``config.toml`` written, and
    the number of worker processes for ``trainings`` trainings at once."""
    _, val_eps = split_episodes(cfg, dataset)
    out = mark_output(out, "model")  # before the first file; members mark their own
    write_config(out, cfg, notes=notes)
    return val_eps, out, min(cfg.member_workers or usable_cpus(), trainings)


def train_member(job: TrainJob, show_progress: bool | None) -> Path:
    """One member, trained exactly as a single network (a :func:`~.jobs.run_jobs` job)."""
    return train_network(job.cfg, job.dataset, out=job.out, show_progress=show_progress)


def train_groups(
    cfgs: Mapping[str, Sequence[TrainConfig]],
    dataset: Dataset,
    *,
    out: Path,
    workers: int,
    show_progress: bool | None = None,
) -> dict[str, list[Surrogate]]:
    """Train every group's single-network configs side by side (up to ``workers`` processes),
    group ``g``'s ``i``-th into ``out/g/member_i`` (log tag ``exsur g i``), and return each
    group's selected networks, loaded, in the order of ``cfgs``."""
    jobs = [
        TrainJob(cfg=c, dataset=dataset, out=out / g / f"member_{i}", tag=f"exsur {g} {i}")
        for g, group in cfgs.items()
        for i, c in enumerate(group)
    ]
    paths = iter(run_jobs(train_member, jobs, workers=workers, show_progress=show_progress))
    return {g: [load_checkpoint(next(paths)) for _ in group] for g, group in cfgs.items()}


def train_ensemble(
    cfg: TrainConfig,
    dataset: Dataset,
    *,
    out: str | Path,
    show_progress: bool | None = None,
    notes: Mapping[str, Any] | None = None,
) -> Path:
    """Train ``cfg.members`` networks with seeds ``seed, seed + 1, ...`` and merge them.

    Each member is trained exactly as one network is trained, into ``OUT/member_<i>/`` (its own
    ``best.pt``, ``log.csv``, selection by its own validation free run), in up to
    ``cfg.member_workers`` parallel processes.  The members' best checkpoints are merged by
    :func:`~excavator_surrogate.surrogate.ensemble.merge` into ``OUT/best.pt`` (omega = the
    members' mean), whose validation free run is scored and stored in its metrics;
    ``OUT/log.csv`` has one row per member and one for the ensemble.

    Returns:
        Path of ``OUT/best.pt``.
    """
    val_eps, out, workers = open_run(cfg, dataset, out, notes=notes, trainings=cfg.members)
    cfgs = member_configs(cfg)
    _log.info(
        f"seed ensemble: {cfg.members} members (seeds {cfg.seed}..{cfg.seed + cfg.members - 1}"
        + ("; each on its own bootstrap resample of the training episodes" if cfg.bootstrap else "")
        + "), "
        f"{workers} in parallel, into {out}/member_*"
    )
    t0 = time.monotonic()
    members = train_members(cfgs, dataset, out=out, workers=workers, show_progress=show_progress)
    return merge_members(cfg, cfgs, members, val_eps, out=out, t0=t0)


def train_members(
    cfgs: Sequence[TrainConfig],
    dataset: Dataset,
    *,
    out: Path,
    workers: int,
    show_progress: bool | None = None,
) -> list[Surrogate]:
    """Train the single-network configs side by side (up to ``workers`` processes), the
    ``i``-th into ``out/member_i`` (log tag ``exsur member i``), and return their selected
    networks, loaded, in order."""
    jobs = [
        TrainJob(cfg=c, dataset=dataset, out=out / f"member_{i}", tag=f"exsur member {i}")
        for i, c in enumerate(cfgs)
    ]
    bests = run_jobs(train_member, jobs, workers=workers, show_progress=show_progress)
    return [load_checkpoint(b) for b in bests]


def merge_members(
    cfg: TrainConfig,
    cfgs: list[TrainConfig],
    members: list[Surrogate],
    val_eps: list[Episode],
    *,
    out: Path,
    t0: float,
    training: Mapping[str, Any] | None = None,
    merged: Surrogate | None = None,
    column: tuple[str, Sequence[Any], Any] | None = None,
) -> Path:
    """Merge the ``members`` (trained with ``cfgs``) into ``out/best.pt``, score its validation
    free run and write ``out/log.csv`` (one row per member, one for the ensemble);
    ``training`` entries are added to the merged metrics' ``training`` summary.  ``merged``:
    the model built from them another way (a composite, :mod:`.kinds`); ``column``: ``(name,
    each member's value, the model's value)``, one more column of the log (e.g. how each
    member treated the exogenous inputs)."""
    sur = merge(members) if merged is None else merged
    sur.train_config = to_dict(cfg)
    val = free_run_error(sur, val_eps, max_steps=cfg.val_steps or None)
    rows: list[dict[str, Any]] = []
    for i, m in enumerate(members):
        mm = m.metrics or {}
        rows.append(
            {
                "member": i,
                "seed": cfgs[i].seed,
                "epoch": mm.get("epoch"),
                "val_error": mm.get("val_error"),
                "val_theta_r2_min": worst_r2((mm.get("val") or {}).get("theta_r2") or []),
            }
        )
        if column is not None:
            rows[-1][column[0]] = column[1][i]
    rows.append(
        {
            "member": "ensemble",
            "seed": "",
            "epoch": "",
            "val_error": val["val_error"],
            "val_theta_r2_min": worst_r2(val["theta_r2"]),
        }
    )
    if column is not None:
        rows[-1][column[0]] = column[2]
    sur.metrics = {
        **(sur.metrics or {}),
        "val_error": val["val_error"],
        "val": val,
        "best_val_error": val["val_error"],
        "training": {
            **ensemble_training([m.metrics.get("training") for m in members]),
            **(training or {}),
        },
    }
    best = save_checkpoint(out / "best.pt", sur, history=rows)  # no wall-clock entries
    train_s = time.monotonic() - t0
    write_log(out / "log.csv", rows, fields=list(rows[0]))
    member_vals = ", ".join(f"{r['val_error']:.4g}" for r in rows[:-1])
    _log.info(
        f"seed ensemble: members' val_error {member_vals}; merged {val['val_error']:.4g} "
        f"(min theta R2 {worst_r2(val['theta_r2']):.3f}) -> {best} ({train_s:.0f} s)"
    )
    return best


def ensemble_training(members: list[dict[str, Any] | None]) -> dict[str, Any]:
    """The ``training`` summary of a merged ensemble from its members' (``budget_cut`` if the
    wall-time cap cut any member; ``members`` keeps each one's)."""
    known = [m for m in members if m]
    # the members train side by side on one computer: the first one's record stands for all
    env = next((m["environment"] for m in known if "environment" in m), None)
    return {
        **({"environment": env} if env is not None else {}),
        "budget_cut": any(m.get("budget_cut", False) for m in known),
        "epochs_planned": max((int(m.get("epochs_planned", 0)) for m in known), default=0),
        "numerics": "/".join(sorted({str(m.get("numerics", "native")) for m in known})) or "native",
        "members": known,
    }
