"""ASAM MDF logs (``.mf4``; MDF 3 ``.mdf`` and ``.dat``), read with asammdf (the ``mdf`` extra).

A ``.dat`` file (the MDF 3 ending of Vector CANape and ETAS INCA) is an MDF log only when it
starts with MDF's file identifier (``MDF     ``); other ``.dat`` files are not logs exsur
reads (a folder's are left out; one given by name is refused, saying it is not MDF).

Channel names are the names in the file's channel database: the channel name, or
``<source path>.<name>`` for a channel with a source (asammdf's convention).  A name that
several channel groups hold is refused with the names that tell them apart.  Values are
physical (the file's conversions applied); samples flagged invalid become missing (NaN).

Time: every channel group has its own master channel (time in s).  The log is one
:class:`~.sources.Series` per channel group that holds mapped channels (``channel group
2``), on its own master, as a bag's topics are: the import checks each group's times, fills
and counts its missing values on its own rows, cuts at its gaps and resamples each channel
from its own samples (:attr:`~.sources.RawLog.placement` says which group holds which
channel).  Times count from the earliest group's first sample.  ``[time]`` is not used
(the masters are in seconds).
"""

from __future__ import annotations

import gc
import importlib.util
import logging
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from datetime import timedelta
from pathlib import Path
from typing import Any
from xml.etree import ElementTree

import numpy as np

from ..errors import ConfigError, DataError
from .mapping import Mapping
from .sources import RawLog, Reader, Series, missing_channel

SUFFIXES = (".mf4", ".mdf", ".dat")
MAGIC = b"MDF     "
"""The first 8 bytes of every MDF file (the identification block's file identifier)."""


def is_mdf(path: Path, _csv_format: str = "auto") -> bool:
    """A ``Reader.match``: an ``.mf4`` or ``.mdf`` file, or a ``.dat`` file that starts with
    :data:`MAGIC` (``.dat`` also names many other formats)."""
    if path.is_dir():
        return False
    name = path.name.lower()
    if name.endswith((".mf4", ".mdf")):
        return True
    if not name.endswith(".dat"):
        return False
    try:
        with open(path, "rb") as f:
            return f.read(len(MAGIC)) == MAGIC
    except OSError:  # unreadable: not recognised here (the caller names the file)
        return False


@contextmanager
def quiet_asammdf() -> Iterator[None]:
    """asammdf logs its own errors (and a half-opened file complains when it is collected);
    ours are the one-line DataErrors."""
    lg = logging.getLogger("asammdf")
    level, hook = lg.level, sys.unraisablehook
    lg.setLevel(logging.CRITICAL)
    sys.unraisablehook = lambda _: None
    try:
        yield
    finally:
        gc.collect()
        lg.setLevel(level)
        sys.unraisablehook = hook


def _locate(path: Path, db: Any, name: str, mapping: Mapping) -> tuple[int, int]:
    """``(group, index)`` of the channel called ``name``; DataError if missing or ambiguous."""
    occ = sorted({tuple(o) for o in db.get(name, ())})
    if not occ:
        raise missing_channel(path, name, sorted(k for k in db if k != "time"), mapping)
    if len(occ) > 1:
        unique = {tuple(o[0]): k for k, o in db.items() if len({tuple(x) for x in o}) == 1}
        cands = [f"'{unique[o]}'" if o in unique else f"group {o[0]}" for o in occ]
        fix = (
            f"map one of {', '.join(cands)} in {mapping.where}"
            if all(o in unique for o in occ)
            else f"the channel is in channel groups {', '.join(cands)}; rename it in the recording"
        )
        raise DataError(
            path,
            f"channel name is ambiguous: {len(occ)} channel groups hold it",
            column=name,
            fix=fix,
        )
    return int(occ[0][0]), int(occ[0][1])


def numeric_samples(sig: Any) -> np.ndarray | None:
    """An asammdf ``Signal``'s samples as float64, those flagged invalid NaN (see
    :func:`read_signal`); None when they are not one number each."""
    x = np.asarray(sig.samples)
    if x.dtype.kind not in "fiub" or x.ndim != 1:
        return None
    out = x.astype(np.float64)
    inv = getattr(sig, "invalidation_bits", None)
    if inv is not None:
        out[np.asarray(inv, dtype=bool)] = np.nan
    return out


def _numeric(path: Path, sig: Any, name: str) -> np.ndarray:
    out = numeric_samples(sig)
    if out is None:
        x = np.asarray(sig.samples)
        raise DataError(
            path,
            f"values are of type {x.dtype} (shape {x.shape}), not numbers",
            column=name,
            fix="map a numeric channel",
        )
    return out


@contextmanager
def open_mdf(path: Path) -> Iterator[Any]:
    """The MDF file at ``path`` opened with asammdf (its own logging quiet), closed after.

    Raises:
        ConfigError: asammdf is not installed.
        DataError: not a readable MDF file (one line naming it).
    """
    if importlib.util.find_spec("asammdf") is None:
        raise ConfigError(
            f"{path}: reading MDF logs needs the 'asammdf' package; "
            "install the extra: pip install 'excavator-surrogate[mdf]'"
        )
    from asammdf import MDF

    with quiet_asammdf():
        problem = ""
        try:
            mdf = MDF(path)
        except Exception as e:  # asammdf raises many types for damaged files
            problem = f"{type(e).__name__}: {e}"
        if problem:  # raised outside the handler, so the half-opened file is freed here
            raise DataError(
                path,
                f"not a readable MDF file ({problem})",
                fix="the file may be truncated; record or export it again",
            )
        try:
            yield mdf
        finally:
            mdf.close()


def read_signal(path: Path, mdf: Any, group: int, index: int, *, name: str) -> Any:
    """Channel ``index`` of channel group ``group`` of the open ``mdf`` (asammdf's
    ``Signal``: physical values and their master's times), every sample of its group: those
    flagged invalid are kept, with the flags in ``invalidation_bits`` (asammdf would leave
    them out, and the channel would no longer match its group's times;
    :func:`numeric_samples` makes them NaN).

    Raises:
        DataError: damaged samples (one line naming the file and the channel ``name``).
    """
    try:
        return mdf.get(group=group, index=index, ignore_invalidation_bits=True)
    except Exception as e:  # asammdf raises many types for damaged data
        raise DataError(
            path,
            f"cannot read the samples ({type(e).__name__}: {e})",
            column=name,
            fix="the file may be truncated; record or export it again",
        ) from e


def read_mdf(path: Path, mapping: Mapping) -> RawLog:
    """Read the channels ``mapping`` needs from an MDF file (see the module doc).

    Raises:
        ConfigError: asammdf is not installed.
        DataError: unreadable/truncated file, missing or ambiguous channel, non-numeric
            values, a channel without samples.
    """
    chans = mapping.channels()
    with open_mdf(path) as mdf:
        where = {c.key: _locate(path, mdf.channels_db, c.key, mapping) for c in chans}
        sigs = {k: read_signal(path, mdf, g, i, name=k) for k, (g, i) in where.items()}
        start = mdf.header.start_time
        meta = header_metadata(mdf.header)
        columns = sorted(k for k in mdf.channels_db if k != "time")
    raw = _by_group(path, sigs, where, start, columns)
    raw.meta = meta
    raw.placement = {c: _group_name(where[c.key][0]) for c in chans}
    return raw


def header_metadata(header: Any) -> dict[str, str]:
    """The file header's properties: ``{"Engine/Mode": "H", "author": ..., "comment": ...}``.

    MDF4 keeps them in the header comment's ``<common_properties>`` (``<e name=...>`` elements,
    ``<tree name=...>`` for groups, joined with ``/``), next to ``<TX>`` (``comment``); MDF 3
    has a plain-text comment and the author/project/subject fields.
    """
    out: dict[str, str] = {}
    text = str(getattr(header, "comment", "") or "")
    try:
        root = ElementTree.fromstring(text) if text.lstrip().startswith("<") else None
    except ElementTree.ParseError:
        root = None
    if root is None:
        if text.strip():
            out["comment"] = text.strip()
    else:
        tx = root.find("TX")
        if tx is not None and (tx.text or "").strip():
            out["comment"] = (tx.text or "").strip()
        props = root.find("common_properties")
        if props is not None:
            out.update(_properties(props, ""))
    for key in ("author", "department", "project", "subject"):
        value = str(getattr(header, key, "") or "").strip()
        if value:
            out.setdefault(key, value)
    return out


def _properties(node: Any, prefix: str) -> dict[str, str]:
    out: dict[str, str] = {}
    for child in node:
        name = child.get("name")
        if not name:
            continue
        if child.tag == "tree":
            out.update(_properties(child, f"{prefix}{name}/"))
        elif child.tag == "e":
            out[f"{prefix}{name}"] = (child.text or "").strip()
    return out


def _group_name(group: int) -> str:
    """The series name of channel group ``group``."""
    return f"channel group {group}"


def _by_group(
    path: Path,
    sigs: dict[str, Any],
    where: dict[str, tuple[int, int]],
    start: Any,
    columns: list[str],
) -> RawLog:
    """The mapped signals, one series per channel group on its own master (see the module
    doc); samples flagged invalid are NaN."""
    for k, s in sigs.items():
        if len(s.timestamps) == 0:
            raise DataError(
                path, "the channel has no samples", column=k, fix="map a recorded channel"
            )
    t0 = min(float(s.timestamps[0]) for s in sigs.values())
    series: dict[str, Series] = {}
    for k, s in sigs.items():
        name = _group_name(where[k][0])
        if name not in series:
            t = np.asarray(s.timestamps, dtype=np.float64) - t0
            series[name] = Series(name, t, {}, f"master of {name}")
        series[name].values[k] = _numeric(path, s, k)
        if s.unit:
            series[name].units[k] = str(s.unit).strip()
    origin = start + timedelta(seconds=t0)
    return RawLog(path=path, kind="mdf", series=series, origin=origin.isoformat(), columns=columns)


READER = Reader("mdf", "ASAM MDF (.mf4, .mdf, MDF 3 .dat)", SUFFIXES, is_mdf, read_mdf)
