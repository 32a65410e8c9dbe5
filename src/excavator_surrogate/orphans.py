"""Worker processes die with their parent: no orphan trains to its budget after a ``kill -9``.

A worker learns of its parent's death only when it next talks to it, and a training member
talks once, at the end: killed with ``kill -9``, ``exsur train --members 2`` left both members
training for their whole budget, then hanging in a futex wait.  :func:`die_with_parent`,
called first thing in every worker (a pool ``initializer``, or the worker's entry point), makes
the worker leave within about a second of its parent:

- on Linux, ``prctl(PR_SET_PDEATHSIG, SIGKILL)``: the kernel kills the worker when the parent
  *thread* that started it ends, so it is armed only when that thread is the main thread;
- everywhere, a daemon thread compares ``os.getppid()`` with the parent's pid every
  ``poll_s`` seconds (a dead parent's children are re-parented) and calls ``os._exit``.

``os.getppid()`` is also compared right after arming, which closes the race of a parent that
died while the worker started.  The multiprocessing resource tracker needs nothing: it exits
when the last process holding its pipe (the parent and its workers) is gone.
"""

from __future__ import annotations

import os
import signal
import sys
import threading
import time

PR_SET_PDEATHSIG = 1
"""``prctl`` option: the signal a process gets when its parent thread dies (``linux/prctl.h``)."""
ORPHAN_EXIT = 70
"""Exit status of a worker that left because its parent died."""


def parent_args() -> tuple[int, bool]:
    """``(pid, started_on_main_thread)`` of the calling process: the arguments a parent passes
    to :func:`die_with_parent` of the workers it starts now."""
    return os.getpid(), threading.current_thread() is threading.main_thread()


def die_with_parent(parent_pid: int, main_thread: bool = True, poll_s: float = 1.0) -> None:
    """In a worker process: exit (status :data:`ORPHAN_EXIT`) soon after ``parent_pid`` dies.

    Args:
        parent_pid: the pid of the process that started this worker.
        main_thread: the worker was started from the parent's main thread (only then is the
            Linux parent-death signal armed: it fires when the starting thread ends).
        poll_s: period of the ``getppid`` watchdog [s].
    """
    if main_thread and sys.platform.startswith("linux"):
        _arm_pdeathsig()
    if threading.current_thread() is threading.main_thread():
        # Ctrl-C reaches the whole process group: the parent says 'exsur: interrupted' and
        # its workers leave quietly instead of printing one KeyboardInterrupt traceback each
        signal.signal(signal.SIGINT, _leave_quietly)
    if os.getppid() != parent_pid:  # the parent died before the signal was armed
        os._exit(ORPHAN_EXIT)
    watch = threading.Thread(
        target=_watch, args=(parent_pid, poll_s), name="exsur-parent-watch", daemon=True
    )
    watch.start()


def _leave_quietly(signum: int, frame: object) -> None:
    os._exit(128 + signum)


def _arm_pdeathsig() -> None:
    import ctypes

    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0)
    except (OSError, AttributeError):  # no prctl (another libc): the watchdog remains
        pass


def _watch(parent_pid: int, poll_s: float) -> None:
    while True:
        time.sleep(poll_s)
        if os.getppid() != parent_pid:
            os._exit(ORPHAN_EXIT)
