"""Independent trainings side by side: one process per job, up to ``workers`` at a time.

The members of a seed ensemble (:mod:`.ensembles`) and the models of one run (the LSTM, its
raw-data baseline, the GRU; :func:`~excavator_surrogate.training.api.train_parallel`) are
independent jobs.  The small networks of this package do not scale past one or two threads
per process, so two jobs on two cores finish in about the time of one: the quick Stage II
demos train their LSTM and its raw-data baseline at once this way.

Workers are spawned (never forked from a process that holds torch threads) and die with their
parent (:mod:`.orphans`); a user error in a job crosses the process boundary as its one-line
message, prefixed with the job's tag.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
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
        return str(fn(job, False)), None
    except ExsurError as e:  # user errors cross the process boundary as their one-line message
        return "", str(e)


def run_jobs(
    fn: JobFn, jobs: Sequence[TrainJob], *, workers: int, show_progress: bool | None = None
) -> list[Path]:
    """``fn`` on every job, in up to ``workers`` spawned processes (``workers <= 1``: one after
    the other in this process, with progress bars as ``show_progress`` says).

    Returns:
        The jobs' ``best.pt`` paths, in the order of ``jobs``.

    Raises:
        ExsurError: a job failed with a user error (the first one, with its tag).
    """
    if workers <= 1 or len(jobs) <= 1:
        return [fn(job, show_progress) for job in jobs]
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
