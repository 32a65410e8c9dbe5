"""Another process holding an output folder's writer lock, as a running ``exsur train`` does."""

from __future__ import annotations

import contextlib
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

_HOLD = (
    "import sys; from excavator_surrogate.outlock import lock_out; lock_out(sys.argv[1]); "
    "print('locked', flush=True); sys.stdin.read()"
)


@contextlib.contextmanager
def lock_held_elsewhere(out: Path) -> Iterator[subprocess.Popen]:
    """A child process holds ``out``'s writer lock within the block (its pid: ``.pid``); it
    ends, and the lock with it, when the block closes its stdin."""
    proc = subprocess.Popen(
        [sys.executable, "-c", _HOLD, str(out)], stdin=subprocess.PIPE, stdout=subprocess.PIPE
    )
    try:
        assert proc.stdout is not None and proc.stdout.readline().strip() == b"locked"
        yield proc
    finally:
        assert proc.stdin is not None
        proc.stdin.close()
        proc.wait()
