"""Device selection: ``cpu``, ``cuda``, ``cuda:N`` or ``auto``.

Every place that accepts a device string (``[train] device``, ``exsur train/evaluate --device``,
the surrogate environments) resolves it with :func:`resolve_device`, so ``auto`` means the same
thing everywhere: the first (or the process's local-rank) CUDA GPU when one is usable, else
the CPU.  Apple ``mps`` and other backends are accepted when named explicitly but are never
chosen by ``auto`` (the LSTM kernels there are not faster than the CPU for these small nets).
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager

import torch

from . import cpus
from .errors import ConfigError

DEVICE_CHOICES = ("cpu", "cuda", "auto")
"""Device names offered by the command line (``cuda:N`` is accepted as well)."""


def cuda_usable() -> bool:
    """True if at least one CUDA device can be used by this process."""
    try:
        return bool(torch.cuda.is_available()) and torch.cuda.device_count() > 0
    except Exception:  # broken driver installs raise instead of returning False
        return False


def resolve_device(
    name: str | torch.device | None = "auto", *, local_rank: int | None = None
) -> torch.device:
    """Turn a device name into a usable :class:`torch.device`.

    Args:
        name: ``"cpu"``, ``"cuda"``, ``"cuda:N"``, ``"auto"`` (None means ``auto``), another
            torch device string (``"mps"``), or a :class:`torch.device`.
        local_rank: for ``cuda`` / ``auto`` without an index: the GPU of this process in a
            multi-process (torchrun) job.  Default: ``$LOCAL_RANK`` if set, else the current GPU.

    Returns:
        The device; ``auto`` gives ``cuda:<local_rank>`` when CUDA is usable, else ``cpu``.

    Raises:
        ConfigError: CUDA asked for but not available, a GPU index out of range, or an
            unknown device string.
    """
    if isinstance(name, torch.device):
        text = str(name)
    else:
        text = (name or "auto").strip().lower()
    if text == "auto":
        if not cuda_usable():
            return torch.device("cpu")
        text = "cuda"
    try:
        dev = torch.device(text)
    except (RuntimeError, ValueError) as e:
        raise ConfigError(
            f"unknown device '{name}': use one of {', '.join(DEVICE_CHOICES)} or cuda:N"
        ) from e
    if dev.type == "cuda":
        if not cuda_usable():
            raise ConfigError(
                f"device '{name}' is not available (torch {torch.__version__} sees no CUDA GPU); "
                "use --device cpu or auto"
            )
        n = torch.cuda.device_count()
        index = dev.index
        if index is None:
            if local_rank is None and os.environ.get("LOCAL_RANK", "").isdigit():
                local_rank = int(os.environ["LOCAL_RANK"])
            index = (local_rank % n) if local_rank is not None else torch.cuda.current_device()
        if not 0 <= index < n:
            raise ConfigError(f"device '{name}': only {n} CUDA device(s) visible (0..{n - 1})")
        return torch.device("cuda", index)
    if dev.type == "mps" and not (
        getattr(torch.backends, "mps", None) and torch.backends.mps.is_available()
    ):
        raise ConfigError(f"device '{name}' is not available here; use --device cpu or auto")
    return dev


def device_label(dev: torch.device) -> str:
    """Short human-readable description, e.g. ``cuda:0 (NVIDIA A100)`` or ``cpu (8 threads)``."""
    if dev.type == "cuda":
        return f"{dev} ({torch.cuda.get_device_name(dev)})"
    if dev.type == "cpu":
        return f"cpu ({torch.get_num_threads()} threads)"
    return str(dev)


def usable_cpus() -> int:
    """CPUs to plan for and run on (:func:`excavator_surrogate.cpus.usable_cpus`: ``EXSUR_CPUS``,
    else the least of the affinity mask and a container's CPU quota; at least 1)."""
    return cpus.usable_cpus()


@contextmanager
def torch_threads(n: int) -> Iterator[None]:
    """Run the block with ``n`` torch intra-op threads (0: torch's count unchanged), restored after.

    Small-batch free runs gain little from a second thread, and on a busy computer OpenMP
    barriers waiting for a descheduled thread made them up to 4x slower than one thread.
    """
    prev = torch.get_num_threads()
    if n > 0 and n != prev:
        torch.set_num_threads(n)
    try:
        yield
    finally:
        if torch.get_num_threads() != prev:
            torch.set_num_threads(prev)


_FORK_HOOK = False


def one_thread_in_forked_children() -> None:
    """Make every child this process forks from now on run torch on ONE thread (registered once).

    A process that ran torch on several threads holds an OpenMP thread pool, and a child it
    forks (gymnasium's ``AsyncVectorEnv`` on Linux, a ``multiprocessing`` pool) inherits the
    pool's state without its threads: its first parallel torch op (copying a 128-wide LSTM's
    weights into a fresh network) waits on them forever. One thread never enters the pool.
    ``torch.utils.data`` does the same in its workers; a spawned child is not affected.
    """
    global _FORK_HOOK
    if not _FORK_HOOK and hasattr(os, "register_at_fork"):
        os.register_at_fork(after_in_child=lambda: torch.set_num_threads(1))
        _FORK_HOOK = True


class OneThread:
    """Context manager: ``torch.set_num_threads(1)`` inside, previous count restored after."""

    __slots__ = ("prev",)

    def __init__(self) -> None:
        self.prev = 1

    def __enter__(self) -> None:
        self.prev = torch.get_num_threads()
        if self.prev != 1:
            torch.set_num_threads(1)

    def __exit__(self, *exc: object) -> None:
        if self.prev != 1:
            torch.set_num_threads(self.prev)


class NoOp:
    """Context manager that does nothing (the threads of a large batch stay as they are)."""

    __slots__ = ()

    def __enter__(self) -> None:
        return None

    def __exit__(self, *exc: object) -> None:
        return None
