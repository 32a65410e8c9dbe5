"""How much memory this process may still allocate.

The import's size bounds (``ingest/limits.py``) and the surrogate's size check
(``surrogate/sizes.py``) read it.  No torch import here: ``exsur import`` and ``exsur --help``
need none, and torch takes seconds to load.
"""

from __future__ import annotations

import os


def available_memory() -> int | None:
    """Memory this process may still allocate [bytes]: ``MemAvailable`` of ``/proc/meminfo``
    (Linux), else the free physical pages (``os.sysconf``); None when neither is known."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return int(os.sysconf("SC_AVPHYS_PAGES")) * int(os.sysconf("SC_PAGE_SIZE"))
    except (ValueError, OSError, AttributeError):
        return None
