"""How much CPU other processes took while a benchmark ran: the basis of its load flag.

The 1-minute load average cannot tell a benchmark's own work from another job's: a bench
that trains two members side by side leaves a load near 2 behind it, and a run started just
after another job sees that job's load.  On Linux this reads the whole machine's busy CPU
time from ``/proc/stat`` and subtracts the benchmark's own (``getrusage`` of the process and
of its children, which counts the member processes once they have been waited for):

    foreign = (busy(t1) - busy(t0)) - (own(t1) - own(t0))      [CPU seconds]
    share   = foreign / (t1 - t0)                              [cores]

A share above :data:`BUSY_SHARE` (a tenth of a core on average) marks the timings as taken
under load.  Where ``/proc/stat`` is missing the share is ``None`` and the caller falls back
to the load average.  Usage::

    meter = ForeignCpu.start()
    ...  # the benchmark, its children waited for
    share = meter.share()
"""

from __future__ import annotations

import os
import resource
import time
from dataclasses import dataclass
from pathlib import Path

BUSY_SHARE = 0.1
"""Cores of other processes' CPU time, on average over the run, above which the timings are
flagged as taken under load."""

_PROC_STAT = Path("/proc/stat")


def busy_cpu_seconds(stat: Path = _PROC_STAT) -> float | None:
    """The machine's busy CPU time since boot [s]: every state of ``/proc/stat``'s ``cpu``
    line but idle and iowait; ``None`` where the file is missing or unreadable."""
    try:
        first = stat.read_text().splitlines()[0].split()
    except (OSError, IndexError):
        return None
    if not first or first[0] != "cpu":
        return None
    ticks = [int(v) for v in first[1:]]
    # user nice system [idle iowait] irq softirq steal (guest, guest_nice: already in user)
    busy = sum(ticks[:3]) + sum(ticks[5:8])
    return busy / os.sysconf("SC_CLK_TCK")


def own_cpu_seconds() -> float:
    """This process's and its waited-for children's CPU time, user + system [s]."""
    total = 0.0
    for who in (resource.RUSAGE_SELF, resource.RUSAGE_CHILDREN):
        r = resource.getrusage(who)
        total += r.ru_utime + r.ru_stime
    return total


@dataclass(frozen=True)
class ForeignCpu:
    """A reading at the benchmark's start; :meth:`share` compares the end against it."""

    wall: float
    busy: float | None
    own: float

    @classmethod
    def start(cls) -> ForeignCpu:
        return cls(wall=time.monotonic(), busy=busy_cpu_seconds(), own=own_cpu_seconds())

    def share(self) -> float | None:
        """Other processes' CPU time since :meth:`start`, in cores on average (>= 0); ``None``
        where the machine's busy time cannot be read."""
        busy = busy_cpu_seconds()
        if self.busy is None or busy is None:
            return None
        wall = max(time.monotonic() - self.wall, 1e-9)
        foreign = (busy - self.busy) - (own_cpu_seconds() - self.own)
        return max(foreign, 0.0) / wall
