"""How many CPUs exsur plans for and runs on.

The data-driven recipe plans its training from the CPU count (``training/plan.py``: members,
how many train at once, each one's share of the budget, and with it the epochs a budget
fits), and every pool of worker processes is sized by it.  So the count must be the CPUs
this process can really use:

- the least of the computer's CPUs, this process's affinity mask (``taskset``) and a
  container's CPU quota (cgroup v1 or v2, what ``docker run --cpus 2`` and Kubernetes limits
  set), as ``joblib.cpu_count`` reads them.  A container that sees 16 cores but may use 2
  would otherwise plan 8 networks at once on 2 CPUs' time, each 4x slower, and the wall-time
  caps would cut them;
- or :data:`ENV` (``exsur train/run --cpus N`` sets it), to plan as a computer of ``N`` CPUs
  does: the README's real-machine figures were taken on 2 CPUs, and a computer of 8 plans
  more members at once, so another model.

NumPy's BLAS follows the same count (:func:`blas_threads`, around every ``exsur`` command):
its thread pool otherwise starts one thread per CPU of the affinity mask, which a quota makes
wait on each other, and a least-squares fit over many rows (the ARX baseline's normal matrix)
rounds by its thread count: ``exsur evaluate``'s ARX row of a 16-core computer would not be a
2-CPU computer's.

No torch import here: the simulation and the record of a run read it too.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager

from .errors import ConfigError

ENV = "EXSUR_CPUS"
"""Environment variable: the CPUs to plan for and run on (a whole number >= 1), instead of
those this process may use; inherited by worker processes."""


def parse_cpus(text: str) -> int | None:
    """``text`` as a CPU count (a whole number >= 1), None when it is not one."""
    try:
        n = int(text)
    except ValueError:
        return None
    return n if n >= 1 else None


def _from_env() -> int | None:
    """:data:`ENV` as a CPU count, None when unset or empty.

    Raises:
        ConfigError: not a whole number >= 1.
    """
    text = os.environ.get(ENV, "").strip()
    if not text:
        return None
    n = parse_cpus(text)
    if n is None:
        raise ConfigError(
            f"{ENV}={text!r}: give a whole number of CPUs >= 1 (or unset it to use the CPUs "
            "this process may use)"
        )
    return n


@contextmanager
def environ_set(name: str, value: str | None) -> Iterator[None]:
    """Within the block, the environment variable ``name`` is ``value`` (None: left as it
    is), for this process and the workers it starts; restored after."""
    before = os.environ.get(name)
    if value is not None:
        os.environ[name] = value
    try:
        yield
    finally:
        if before is None:
            os.environ.pop(name, None)
        else:
            os.environ[name] = before


def affinity_cpus() -> int:
    """CPUs in this process's affinity mask (all of the computer's where the OS has none)."""
    if hasattr(os, "sched_getaffinity"):
        return max(1, len(os.sched_getaffinity(0)))
    return os.cpu_count() or 1


def available_cpus() -> int:
    """CPUs this process may use: the least of the computer's, its affinity mask's and its
    container's CPU quota (rounded up; ``joblib.cpu_count``, which also honours
    ``LOKY_MAX_CPU_COUNT``).  At least 1."""
    from joblib import cpu_count  # imported here: ~0.1 s, and only where CPUs are counted

    return max(1, min(int(cpu_count()), affinity_cpus()))


def usable_cpus() -> int:
    """CPUs to plan for and run on: :data:`ENV` if set, else :func:`available_cpus`.

    Raises:
        ConfigError: a bad :data:`ENV` value.
    """
    given = _from_env()
    return given if given is not None else available_cpus()


def cpus_note() -> str:
    """:func:`usable_cpus` and where the count comes from, for logs and records, e.g.
    ``"2 CPU(s) (this process's affinity mask)"``, ``"2 CPU(s) (a CPU quota; 16 in the
    affinity mask)"`` or ``"2 CPU(s) (EXSUR_CPUS; this process may use 8)"``."""
    given = _from_env()
    available = available_cpus()
    if given is not None:
        more = "" if given == available else f"; this process may use {available}"
        return f"{given} CPU(s) ({ENV}{more})"
    mask = affinity_cpus()
    if available < mask:
        limit = "LOKY_MAX_CPU_COUNT" if os.environ.get("LOKY_MAX_CPU_COUNT") else "a CPU quota"
        return f"{available} CPU(s) ({limit}; {mask} in the affinity mask)"
    return f"{available} CPU(s) (this process's affinity mask)"


def oversubscribed() -> str | None:
    """A one-line warning when :data:`ENV` asks for more CPUs than this process may use (the
    planned workers then share fewer CPUs, and the wall-time caps may cut them), else None."""
    given = _from_env()
    available = available_cpus()
    if given is None or given <= available:
        return None
    return (
        f"{ENV}={given}, but this process may use {available} CPU(s): the plan is a "
        f"{given}-CPU computer's, its parallel workers share {available}, each runs slower, and "
        "a wall-time cap may cut them (the log and the report say so if it does)"
    )


BLAS_ENV = "OPENBLAS_NUM_THREADS"
"""What NumPy's OpenBLAS reads at load time: :func:`blas_threads` sets it for the worker
processes a command starts (unless the user has set it)."""


@contextmanager
def blas_threads() -> Iterator[None]:
    """Within the block, NumPy's BLAS runs at most :func:`usable_cpus` threads: in this process
    (``threadpoolctl``) and, through :data:`BLAS_ENV` where the user has not set it, in the
    worker processes it starts.  Nothing changes where the affinity mask is the count (a
    plain 2-core computer); everything is restored after.

    Raises:
        ConfigError: a bad :data:`ENV` value.
    """
    from threadpoolctl import threadpool_limits

    n = usable_cpus()
    unset = os.environ.get(BLAS_ENV) is None and n < affinity_cpus()
    with environ_set(BLAS_ENV, str(n) if unset else None):
        with threadpool_limits(limits=n, user_api="blas"):
            yield
