"""The log-format registry: every reader exsur knows, and what is derived from it.

:data:`READERS` lists the formats in detection order (the first match wins): dSPACE
ControlDesk CSV exports (:mod:`.dspace`), plain CSV and Parquet
(:mod:`.tables`), ROS bags (:mod:`.ros`), ASAM MDF 4 and 3 (:mod:`.mdf`).  :func:`log_kind`, :func:`read_log`,
:func:`log_stem`, :func:`expand_sources` and :data:`SUPPORTED` all derive from it, so adding
a log format is one reader module plus one entry here.
"""

from __future__ import annotations

import glob
import os
from collections.abc import Sequence
from pathlib import Path

from ..errors import DataError
from .dspace import READER as _DSPACE
from .mapping import Mapping
from .mdf import READER as _MDF
from .ros import ROS_READERS
from .sources import RawLog, Reader
from .tables import TABLE_READERS

READERS: tuple[Reader, ...] = (_DSPACE, *TABLE_READERS, *ROS_READERS, _MDF)
"""Every log format, in detection order (the first match wins)."""

SUPPORTED = ", ".join(r.label for r in READERS)
"""The supported formats, for messages."""


def reader_for(path: Path, *, csv_format: str = "auto") -> Reader | None:
    """The first reader of :data:`READERS` that matches ``path``, or None."""
    for r in READERS:
        if r.match(path, csv_format):
            return r
    return None


def log_kind(path: Path, *, csv_format: str = "auto") -> str | None:
    """Kind of the log at ``path`` (``csv``, ``dspace``, ``parquet``, ``rosbag2``, ``mdf`` ...), or None."""
    r = reader_for(path, csv_format=csv_format)
    return r.kind if r is not None else None


def log_stem(path: Path) -> str:
    """The file name without its log suffix (``run.dspace.csv.gz`` -> ``run``)."""
    name = path.name
    ends = sorted({s for r in READERS for s in r.suffixes}, key=len, reverse=True)
    for suf in ends:
        if name.lower().endswith(suf):
            return name[: -len(suf)]
    return name


def expand_sources(sources: Sequence[str | Path]) -> list[Path]:
    """Turn SOURCE arguments (files, folders, glob patterns) into a sorted-per-argument file list.

    A folder contributes its supported files and rosbag2 sub-folders (not recursive); a
    rosbag2 folder (with ``metadata.yaml``) is one log.  Duplicates (the same file, also
    spelled differently or through a link) are removed.

    Raises:
        DataError: a source that does not exist, is unsupported, or matches nothing.
    """
    out: list[Path] = []
    seen: set[str] = set()  # one file reached by two spellings (./a, a, /abs/a, a link) is one log

    def add(p: Path) -> None:
        r = reader_for(p)
        if r is None and p.name.lower().endswith(".dat") and not p.is_dir():
            raise DataError(
                p,
                "a .dat file that is not an ASAM MDF log (its first bytes are not 'MDF')",
                fix=f"export the log as {SUPPORTED}",
            )
        if r is None:
            raise DataError(p, "unsupported log type", fix=f"give {SUPPORTED}")
        if r.whole_folder and not p.is_dir():
            p = p.parent  # a storage file inside a bag folder: read the whole bag
        key = os.path.realpath(p)
        if key not in seen:
            seen.add(key)
            out.append(p)

    for s in sources:
        p = Path(s)
        if p.exists():
            if p.is_dir() and log_kind(p) is None:
                found = [
                    c for c in sorted(p.iterdir()) if not c.name.startswith(".") and log_kind(c)
                ]
                if not found:
                    deeper = nested_logs(p)
                    fix = (
                        f"its sub-folders hold {len(deeper)} log(s), and a folder is not searched "
                        f"recursively: give the sub-folders, or {nested_glob(p, deeper)}"
                        if deeper
                        else f"put {SUPPORTED} in it"
                    )
                    raise DataError(p, "folder holds no log files", fix=fix)
                for c in found:
                    add(c)
            else:
                add(p)
        elif any(ch in str(s) for ch in "*?["):
            hits = [Path(h) for h in sorted(glob.glob(str(s), recursive=True))]
            hits = [h for h in hits if log_kind(h)]
            if not hits:
                raise DataError(
                    s,
                    "glob pattern matches no log files",
                    fix=f"check the pattern; supported: {SUPPORTED}",
                )
            for h in hits:
                add(h)
        else:
            raise DataError(p, "file not found", fix="check the path")
    return out


def nested_logs(folder: Path, *, limit: int = 10_000) -> list[Path]:
    """The logs in ``folder``'s sub-folders at any depth (not its own files; hidden entries
    skipped; at most ``limit``): what a folder source leaves out."""
    out: list[Path] = []
    subs = [c for c in sorted(folder.iterdir()) if c.is_dir() and not c.name.startswith(".")]
    for sub in subs:
        if log_kind(sub):  # a rosbag2 folder is one log, and the folder source takes it
            continue
        for root, dirs, files in os.walk(sub):
            dirs[:] = sorted(d for d in dirs if not d.startswith("."))
            here = Path(root)
            if log_kind(here):
                out.append(here)
                dirs[:] = []
                continue
            out += [here / f for f in sorted(files) if not f.startswith(".") and log_kind(here / f)]
            if len(out) >= limit:
                return out[:limit]
    return out


def nested_glob(folder: Path, deeper: list[Path]) -> str:
    """The advice that takes the logs :func:`nested_logs` found below ``folder``: a quoted
    recursive glob of the first one's suffix (``a quoted glob such as "logs/**/*.csv"``)."""
    return f'a quoted glob such as "{folder}/**/*{log_suffix(deeper[0])}"'


def log_suffix(path: Path) -> str:
    """The log suffix of ``path`` (``.csv.gz``), or ``""`` for a folder."""
    return "" if path.is_dir() else path.name[len(log_stem(path)) :]


def read_log(path: Path, mapping: Mapping) -> RawLog:
    """Read the channels ``mapping`` needs from the log at ``path`` (see :data:`READERS`).

    Raises:
        DataError: unreadable file, missing/duplicated columns, non-numeric values, bad time.
    """
    r = reader_for(path, csv_format=mapping.csv.format)
    if r is None:
        raise DataError(path, "unsupported log type", fix=f"give {SUPPORTED}")
    if r.maps == "columns" and mapping.is_ros:
        raise DataError(
            path,
            f"this is a {r.kind} log but the mapping maps ROS topics",
            fix="map columns (column = ...) for CSV/Parquet/dSPACE/MDF logs",
        )
    if r.maps == "topics" and not mapping.is_ros:
        raise DataError(
            path,
            "this is a ROS bag but the mapping maps table columns",
            fix="map topic = ... and field = ... for bags",
        )
    return r.read(path, mapping)
