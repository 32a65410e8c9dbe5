"""Resource bounds of the import: decompressed log size, resampled output size, upsampling.

A small ``.csv.gz`` may expand to gigabytes, and a typo in ``--rate`` may ask for millions of
samples per second: both are refused in one line before memory runs out.  The bound is
``[import] max_memory_mb`` (default: :data:`MEMORY_SHARE` of the memory available when the
import starts); the decompressed text of a log is counted while it streams.
"""

from __future__ import annotations

import io
from pathlib import Path
from typing import IO

from ..errors import DataError
from ..memory import available_memory

MEMORY_SHARE = 0.25
"""Default bound: this share of the available memory [bytes]."""
FALLBACK_BYTES = 2 * 1024**3
"""Available memory assumed when the system does not tell."""
MB = 1024**2


def memory_limit(max_memory_mb: float | None) -> int:
    """The bound [bytes]: ``max_memory_mb``, or :data:`MEMORY_SHARE` of the available memory."""
    if max_memory_mb is not None:
        return int(max_memory_mb * MB)
    return int(MEMORY_SHARE * (available_memory() or FALLBACK_BYTES))


def too_big(path: Path, what: str, n_bytes: float, limit: int, *, more: bool = False) -> DataError:
    """The one-line error for ``what`` needing ``n_bytes`` (``more``: at least) above ``limit``."""
    return DataError(
        path,
        f"{what} needs {'more than ' if more else ''}{n_bytes / MB:.6g} MB, above the memory "
        f"bound of {limit / MB:.6g} MB",
        fix="split the log, or raise the bound with --max-memory MB ([import] max_memory_mb) "
        "if the machine has the memory",
    )


class _Bounded(io.RawIOBase):
    """A read-only stream that raises :class:`_TooBig` past ``limit`` bytes."""

    def __init__(self, raw: IO[bytes], limit: int) -> None:
        self._raw, self._limit, self.n_read = raw, limit, 0

    def readable(self) -> bool:
        return True

    def readinto(self, b: memoryview) -> int:  # type: ignore[override]
        n = self._raw.readinto(b)  # type: ignore[attr-defined]
        self.n_read += n or 0
        if self.n_read > self._limit:
            raise TooBig(self.n_read)
        return n

    def close(self) -> None:
        self._raw.close()
        super().close()


class TooBig(Exception):
    """Raised by a bounded stream past its limit (turned into :func:`too_big` by the reader)."""

    def __init__(self, n_read: int) -> None:
        super().__init__(n_read)
        self.n_read = n_read


def bounded_open(path: Path, limit: int) -> io.BufferedReader:
    """``path`` opened for binary reading, decompressed if ``.gz``; reading more than ``limit``
    decompressed bytes raises :class:`TooBig`."""
    import gzip

    raw: IO[bytes] = (
        gzip.open(path, "rb") if path.name.lower().endswith(".gz") else open(path, "rb")
    )
    return io.BufferedReader(_Bounded(raw, limit), buffer_size=1 << 20)
