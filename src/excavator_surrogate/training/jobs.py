"""Independent trainings side by side: one process per job, up to ``workers`` at a time.

The members of a seed ensemble (:mod:`.ensembles`) and the models of one run (the LSTM, its
raw-data baseline, the GRU; :func:`~excavator_surrogate.training.api.train_parallel`) are
independent jobs.  The small networks of this package do not scale past one or two threads
per process, so two jobs on two cores finish in about the time of one: the quick Stage II
demos train their LSTM and its raw-data baseline at once this way.

Workers are spawned (never forked from a process that holds torch threads) and die with their
parent (:mod:`.orphans`); a user error in a job crosses the process boundary as its one-line
message, prefixed with the job's tag.

A pool's single-network jobs with a wall-time cap share one deadline: ``n`` jobs on ``w``
workers take ``ceil(n / w)`` rounds, so the pool's trainings must end by ``rounds * cap``
after it starts.  A job that waits for an earlier one has its cap shortened at its start to
what is left of that (:func:`job_cap`): on a computer so slow or busy that the caps bind,
the time the jobs spend outside their own caps (starting a process, loading the data,
fitting the map) no longer pushes the last round past the budget.  Where the caps do not
bind, every job keeps its cap and trains the same model.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from ..data.dataset import Dataset
from ..errors import ExsurError
from ..orphans import die_with_parent, parent_args
from .config import TrainConfig


@dataclass(frozen=True)
class TrainJob:
    """One training: ``cfg`` on ``dataset`` into ``out``."""

    cfg: TrainConfig
    """Training options (a single network or a seed ensemble)."""
    dataset: Dataset
    """Episodes with ``train`` and ``val`` splits."""
    out: Path
    """Output folder of the training (``best.pt`` and the rest)."""
    tag: str = ""
    """Log prefix inside a worker process, e.g. ``exsur member 1``."""
    notes: Mapping[str, Any] | None = None
    """Extra tables for ``config.toml`` (see :func:`~.records.write_config`)."""
    deadline: float | None = None
    """Wall time (:func:`wall_time`) by which the training must end, or None: set by
    :func:`run_jobs` for the single networks of a capped pool (:func:`with_deadlines`)."""


_log = logging.getLogger(__name__)


def wall_time() -> float:
    """The wall clock [s] the pools' deadlines are kept on (the same in every process)."""
    return time.time()


MIN_CAP_SHARE = 0.1
"""A job whose pool is already past its deadline still trains this share of its own cap
(its planned epochs cut, and saying so), so every job leaves a network."""


def with_deadlines(jobs: Sequence[TrainJob], *, workers: int, now: float) -> list[TrainJob]:
    """``jobs`` as a pool of ``workers`` processes runs them from ``now`` [s, wall time]: each
    single network with a wall-time cap that waits for an earlier job (every job after the
    first ``workers``) gets the pool's deadline, ``now + rounds * cap`` with
    ``rounds = ceil(len(jobs) / workers)``.  The first round starts on time, so it keeps its
    caps as they are; a whole ensemble (``members > 1``) plans its own rounds inside the job
    and keeps none."""
    workers = max(1, min(workers, len(jobs)))
    rounds = math.ceil(len(jobs) / workers)
    return [
        replace(job, deadline=now + rounds * job.cfg.max_train_seconds)
        if i >= workers and job.cfg.members == 1 and job.cfg.max_train_seconds > 0
        else job
        for i, job in enumerate(jobs)
    ]


def job_cap(cap: float, deadline: float | None, *, now: float) -> float:
    """A job's wall-time cap [s] when it starts at ``now``: its own ``cap``, or what is left
    before ``deadline`` if that is less, but at least :data:`MIN_CAP_SHARE` of ``cap``
    (``cap = 0``, no cap, and no deadline leave it as it is)::

        cap' = max(MIN_CAP_SHARE * cap, min(cap, deadline - now))
    """
    if deadline is None or cap <= 0:
        return cap
    return max(MIN_CAP_SHARE * cap, min(cap, deadline - now))


def started(job: TrainJob) -> TrainJob:
    """``job`` as it starts (now, on the wall clock): its cap shortened to its deadline
    (:func:`job_cap`), which the job's log says."""
    if job.deadline is None:
        return job
    cap = job.cfg.max_train_seconds
    new = job_cap(cap, job.deadline, now=wall_time())
    if new == cap:
        return job
    _log.warning(
        f"wall-time cap {new:.0f} s instead of {cap:.0f} s: the trainings before this one "
        "ran past their share of the budget (on this computer's speed and load)"
    )
    return replace(job, cfg=replace(job.cfg, max_train_seconds=new))


JobFn = Callable[[TrainJob, "bool | None"], Path]
"""``fn(job, show_progress) -> best.pt``: a module-level function (it is pickled)."""


def _in_worker(fn: JobFn, job: TrainJob, log_config: tuple[int, bool]) -> tuple[str, str | None]:
    """Run ``fn(job)`` in a worker process; returns ``(best_path, error message or None)``.

    ``log_config``: the parent's :func:`~excavator_surrogate.io_utils.worker_log_config`; the
    worker logs at the parent's level, its lines tagged with the job (``[seed1] ...``).
    """
    from ..io_utils import init_worker_logging

    init_worker_logging(log_config, tag=job.tag)
    try:
        return str(fn(started(job), False)), None
    except ExsurError as e:  # user errors cross the process boundary as their one-line message
        return "", str(e)


def run_jobs(
    fn: JobFn, jobs: Sequence[TrainJob], *, workers: int, show_progress: bool | None = None
) -> list[Path]:
    """``fn`` on every job, in up to ``workers`` spawned processes (``workers <= 1``: one after
    the other in this process, with progress bars as ``show_progress`` says).  The capped
    single networks that wait for an earlier job start with what is left of the pool's
    deadline (:func:`with_deadlines`, :func:`started`).

    Returns:
        The jobs' ``best.pt`` paths, in the order of ``jobs``.

    Raises:
        ExsurError: a job failed with a user error (the first one, with its tag).
    """
    jobs = with_deadlines(jobs, workers=workers, now=wall_time())
    if workers <= 1 or len(jobs) <= 1:
        return [fn(started(job), show_progress) for job in jobs]
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor
    from concurrent.futures.process import BrokenProcessPool

    from ..io_utils import worker_log_config

    ctx = multiprocessing.get_context("spawn")  # no fork of a process holding torch threads
    try:
        with ProcessPoolExecutor(
            min(workers, len(jobs)),
            mp_context=ctx,
            initializer=die_with_parent,  # a killed parent leaves no worker training on
            initargs=parent_args(),
        ) as pool:
            log_config = worker_log_config()
            futures = [pool.submit(_in_worker, fn, job, log_config) for job in jobs]
            results = [f.result() for f in futures]
    except BrokenProcessPool as e:  # killed (out of memory?) or its code changed under it
        raise ExsurError(
            f"a training process died abruptly ({e.__class__.__name__}); rerun with the jobs "
            "one after the other (--set train.member_workers=1) or with less data per process"
        ) from e
    for job, (_, err) in zip(jobs, results):
        if err is not None:
            raise ExsurError(f"{job.tag or job.out}: {err}")
    return [Path(p) for p, _ in results]
