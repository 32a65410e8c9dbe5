"""The option tables of an import mapping: ``[csv]``, ``[import]`` and ``[split]``.

Re-exported by :mod:`.mapping`, which parses them with the rest of the file.
"""

from __future__ import annotations

import codecs
import math
from dataclasses import dataclass
from typing import Literal

from ..errors import ConfigError


@dataclass(frozen=True)
class CsvOptions:
    """``[csv]``: how to parse CSV files."""

    delimiter: str = ","
    skip_rows: int = 0
    """Lines before the header line to skip (logger preambles)."""
    skip_rows_after_header: int = 0
    """Lines between the header and the first sample to skip (a row of units: ``s;deg;%``)."""
    format: Literal["auto", "plain", "dspace"] = "auto"
    """``dspace``: read .csv files as dSPACE ControlDesk exports; ``plain``: never; ``auto``:
    by content (first cell ``descriptions`` or a ``trace_...`` row) or a ``.dspace.csv`` name."""
    decimal: Literal[".", ","] = "."
    """The numbers' decimal mark: ``","`` for logs written with a European locale (``1,25``;
    their delimiter is then ``;`` or a tab). Applies to plain CSV and dSPACE exports."""
    thousands: Literal["", ".", ",", " ", "'"] = ""
    """The mark grouping the digits of large numbers, removed before a text cell is read:
    ``"."`` with ``decimal = ","`` for ``-1.000,5`` (an Excel export with separators on);
    ``""``: none (a cell holding one is then refused, naming this option)."""
    encoding: str = "utf-8"
    """The text encoding of the names and cells, a Python codec name: ``"cp1252"`` for a
    Windows export with ``°`` or umlauts in its header (a UTF-8 byte-order mark is skipped)."""

    def __post_init__(self) -> None:
        if self.thousands and self.thousands == self.decimal:
            raise ConfigError(
                f"[csv] thousands and decimal are both {self.decimal!r}: one mark cannot group "
                "the digits and end the whole part"
            )
        for name in ("skip_rows", "skip_rows_after_header"):
            if getattr(self, name) < 0:
                raise ConfigError(f"[csv] {name} must be >= 0, got {getattr(self, name)}")
        try:
            codecs.lookup(self.encoding)
        except LookupError:
            raise ConfigError(
                f"[csv] encoding {self.encoding!r} is not a known text encoding "
                '(e.g. "utf-8", "cp1252", "latin-1")'
            ) from None

    @property
    def is_utf8(self) -> bool:
        """Whether the files are UTF-8 (the readers' default path)."""
        return codecs.lookup(self.encoding).name == "utf-8"

    @property
    def text_encoding(self) -> str:
        """The codec to open the text with: UTF-8 skips a byte-order mark."""
        return "utf-8-sig" if self.is_utf8 else self.encoding


@dataclass(frozen=True)
class ImportOptions:
    """``[import]``: options of the import (CLI flags override them)."""

    rate_hz: float | None = None
    """Target rate [Hz]; None: ``[machine] rate_hz``."""
    nan: Literal["fail", "fill"] = "fail"
    """Missing/non-finite values: ``fail``, or ``fill`` runs of up to ``max_fill`` samples."""
    max_fill: int = 5
    """Longest run of missing samples (input rows) that ``nan = "fill"`` interpolates."""
    max_gap_s: float | None = None
    """Time gaps longer than this split the episode [s]; None: max(5 input steps, 2 output steps)."""
    min_steps: int = 50
    """Episodes (after resampling) shorter than this are dropped; use the model window."""
    velocity: Literal["diff", "kalman"] = "diff"
    """How to derive velocities that the log does not contain."""
    lowpass: float = 0.8
    """Anti-alias cutoff as a fraction of the output Nyquist rate; 0 disables the filter."""
    clip_commands: bool = False
    """Clip commands outside the range instead of failing (clipped samples are reported)."""
    on_error: Literal["fail", "skip"] = "fail"
    """A file that fails validation stops the import (``fail``) or is skipped and reported."""
    outliers: Literal["fail", "drop", "clip"] = "fail"
    """Angle spikes, impossible samples and angles beyond the joint limits: ``fail``, ``drop``
    the rows, or ``clip`` to the limits (spikes and impossible samples are dropped); found
    before resampling (docs/import.md)."""
    max_upsample: float = 10.0
    """The target rate may be at most this multiple of a log's own rate (higher is refused)."""
    max_memory_mb: float | None = None
    """Bound on a log's decompressed text and its resampled output [MB]; None: a quarter of
    the memory available when the import starts."""
    log_units: Literal["check", "ignore"] = "check"
    """``check``: a position or velocity whose log gives it a unit (an MDF channel's, a dSPACE
    ``trace_units`` entry) other than the mapping's is an error; ``ignore``: for a log whose
    unit labels are wrong."""

    def __post_init__(self) -> None:
        if self.rate_hz is not None and not (self.rate_hz > 0 and math.isfinite(self.rate_hz)):
            raise ConfigError(
                f"[import] rate_hz (--rate) must be positive and finite, got {self.rate_hz:.6g}"
            )
        if not (self.max_upsample >= 1 and math.isfinite(self.max_upsample)):
            raise ConfigError(
                "[import] max_upsample (--max-upsample) must be >= 1 and finite, "
                f"got {self.max_upsample:.6g}"
            )
        if self.max_memory_mb is not None and not (
            self.max_memory_mb > 0 and math.isfinite(self.max_memory_mb)
        ):
            raise ConfigError(
                "[import] max_memory_mb (--max-memory) must be positive and finite, "
                f"got {self.max_memory_mb:.6g}"
            )
        if self.max_fill < 0:
            raise ConfigError(f"[import] max_fill (--max-fill) must be >= 0, got {self.max_fill}")
        if self.max_gap_s is not None and not self.max_gap_s > 0:
            raise ConfigError(
                f"[import] max_gap_s (--max-gap) must be positive, got {self.max_gap_s}"
            )
        if self.min_steps < 2:
            raise ConfigError(
                f"[import] min_steps (--min-steps) must be >= 2, got {self.min_steps}"
            )
        if not 0.0 <= self.lowpass < 1.0:
            raise ConfigError(
                "[import] lowpass (--lowpass) must be in [0, 1) (a fraction of the output Nyquist "
                f"rate; 0: off), got {self.lowpass}"
            )


@dataclass(frozen=True)
class SplitOptions:
    """``[split]``: how episodes are assigned to train/val/test (always by source file)."""

    by: Literal["fraction", "glob", "file"] = "fraction"
    fractions: tuple[float, float, float] = (0.7, 0.15, 0.15)
    """train/val/test shares of the samples (``by = "fraction"``)."""
    seed: int = 0
    """Shuffle seed for ``by = "fraction"``."""
    train: tuple[str, ...] = ()
    """Glob patterns (``glob``) or file names (``file``) of training files."""
    val: tuple[str, ...] = ()
    test: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if self.seed < 0:
            raise ConfigError(f"[split] seed (--seed) must be >= 0, got {self.seed}")
        f = self.fractions
        if any(x < 0 for x in f) or not math.isclose(sum(f), 1.0, abs_tol=1e-6):
            raise ConfigError(
                f"[split] fractions (--fractions) {list(f)} must be >= 0 and sum to 1, "
                "e.g. [0.7, 0.15, 0.15]"
            )
