"""What a ROS log holds (:func:`summarize_ros`, for :func:`~.inventory.summarize_log`).

Per topic: its message type, count and rate, and every numeric field path of its messages
(``position[1]``, ``pose.position.x``; not the header, whose stamp ``[time] stamp`` reads)
with the range over its first :data:`ROS_RANGE_MESSAGES` messages.  An MCAP file's topics
whose messages are not ROS 2 CDR are listed as such: the import cannot read them.

The counts and the duration come from the log's index (a rosbag2 ``metadata.yaml``, an
MCAP file's statistics, a ROS 1 bag's index), so the reading stops once every topic has
given its first messages: a bag of many GB is summarised in the time its first
:data:`ROS_RANGE_MESSAGES` messages per topic take.  A log without counts is read whole.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import closing
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import DataError
from .ros import is_ros2_schema, message_fields
from .summary import ChannelSummary, LogSummary, sample_rate, value_range

ROS_RANGE_MESSAGES = 5000
"""A field's range and its topic's rate are taken over this many first messages of the
topic, the only ones read where the log's index gives the counts (the only ones
deserialised where it does not); the count is the whole topic's."""

ARRAY_FIELDS = 16
"""A numeric array field lists at most this many entries (``position[0]`` ...)."""


def numeric_fields(msg: Any, prefix: str = "") -> Iterator[tuple[str, float]]:
    """Every numeric field path of a deserialised message and its value: ``pose.position.x``,
    ``position[1]`` (arrays: their first :data:`ARRAY_FIELDS` entries; not the header, whose
    stamp ``[time] stamp`` reads)."""
    for name in message_fields(msg):
        if not prefix and name == "header":
            continue
        value = getattr(msg, name)
        path = f"{prefix}{name}"
        if isinstance(value, bool | int | float | np.number):
            yield path, float(value)
        elif isinstance(value, np.ndarray) and value.dtype.kind in "fiub" and value.ndim == 1:
            for k in range(min(value.size, ARRAY_FIELDS)):
                yield f"{path}[{k}]", float(value[k])
        elif isinstance(value, list | tuple):
            for k, item in enumerate(value[:ARRAY_FIELDS]):
                if isinstance(item, bool | int | float | np.number):
                    yield f"{path}[{k}]", float(item)
                elif hasattr(item, "__dataclass_fields__"):
                    yield from numeric_fields(item, f"{path}[{k}].")
        elif hasattr(value, "__dataclass_fields__"):
            yield from numeric_fields(value, f"{path}.")


def summarize_ros(path: Path, kind: str, label: str) -> LogSummary:
    """What a ROS log (a rosbag2 folder, an MCAP file, a ROS 1 bag) holds, per topic and
    numeric field (:func:`~.inventory.summarize_log` for ROS logs)."""
    from .ros import need_ros, open_bag

    need_ros(path)
    if kind == "mcap":
        return _summarize(path, kind, label, _mcap_index(path), reader=None)
    with open_bag(path, kind) as reader:  # opened once: a sqlite3 bag's opening scans its index
        return _summarize(path, kind, label, _bag_index(path, reader), reader=reader)


def _summarize(path: Path, kind: str, label: str, index: _Index, *, reader: Any) -> LogSummary:
    """:func:`summarize_ros` from the log's index; ``reader``: the bag opened by
    :func:`~.ros.open_bag` (None for an MCAP file)."""
    from .ros import iter_messages, ros_metadata

    topics, foreign, counts = index.types, index.foreign, index.counts
    times: dict[str, list[int]] = {t: [] for t in topics}
    values: dict[str, dict[str, list[float]]] = {t: {} for t in topics}
    names: dict[str, list[str]] = {}
    readable = {t for t in topics if t not in foreign}
    cap = ROS_RANGE_MESSAGES
    # the topics still short of their first `cap` messages; with no counts, every message
    pending = {t for t in readable if counts is None or min(counts.get(t, 0), cap) > 0}
    if readable and pending:
        with closing(
            iter_messages(path, kind, readable, max_decoded=cap, reader=reader)
        ) as messages:
            for topic, ns, msg in messages:
                times[topic].append(ns)
                if msg is not None:
                    if topic not in names:
                        names[topic] = [str(n) for n in (getattr(msg, "name", None) or [])]
                    for key, v in numeric_fields(msg):
                        values[topic].setdefault(key, []).append(v)
                if counts is not None and len(times[topic]) >= min(counts[topic], cap):
                    pending.discard(topic)
                    if not pending:
                        break
    channels = []
    for topic, msgtype in topics.items():
        t = np.sort(np.asarray(times[topic][:cap], dtype=np.float64) * 1e-9)
        n = counts.get(topic, 0) if counts is not None else len(times[topic])
        rate = sample_rate(t)
        group = f"{topic} ({msgtype})" if msgtype else topic
        if topic in foreign:
            note = f"{foreign[topic]} messages, not ROS 2: the import cannot read them"
            channels.append(ChannelSummary("", group=group, note=note))
        elif not values[topic]:
            channels.append(
                ChannelSummary("", group=group, n_sample=n, rate_hz=rate, note="no numeric field")
            )
        for key, vals in values[topic].items():
            lo, hi, miss = value_range(np.asarray(vals, dtype=np.float64))
            joint = _joint_name(key, names.get(topic, []))
            note = f"= {key.split('[')[0]}[{joint[1]}]" if joint else ""
            channels.append(
                ChannelSummary(
                    key,
                    group=group,
                    n_sample=n,
                    rate_hz=rate,
                    lo=lo,
                    hi=hi,
                    n_missing=miss,
                    note=note,
                )
            )
    notes = []
    if any(c.n_sample is not None and c.n_sample > cap for c in channels):
        notes.append(f"ranges over each topic's first {cap} messages")
    duration = index.duration_s
    if duration is None:
        seen = [ns for t in times.values() for ns in t]
        duration = (max(seen) - min(seen)) * 1e-9 if seen else None
    return LogSummary(
        path, kind, label, channels, duration_s=duration, meta=ros_metadata(path, kind), notes=notes
    )


def _joint_name(key: str, names: list[str]) -> tuple[int, str] | None:
    """For ``position[1]`` of a message with a ``name`` list, ``(1, names[1])``."""
    if "[" not in key or "." in key or not names:
        return None
    try:
        k = int(key.split("[", 1)[1].rstrip("]"))
    except ValueError:
        return None
    return (k, names[k]) if k < len(names) else None


@dataclass(frozen=True)
class _Index:
    """What a ROS log's index says, before any message is read."""

    types: dict[str, str]
    """Topic -> message type."""
    foreign: dict[str, str]
    """The topics whose messages are not ROS 2 CDR (an MCAP file's JSON or Protobuf
    channels) -> their encoding."""
    counts: dict[str, int] | None
    """Topic -> its number of messages; None where the log does not say (then every message
    is read to count them)."""
    duration_s: float | None
    """From the first message to the last [s], or None where the log does not say."""


def _mcap_index(path: Path) -> _Index:
    """An MCAP file's topics, their types and counts and its duration, from its summary."""
    try:
        from mcap.reader import make_reader

        with open(path, "rb") as fh:
            summary = make_reader(fh).get_summary()
        if summary is None:
            raise ValueError("the file has no summary section")
        types, foreign, by_id = {}, {}, {}
        for c in sorted(summary.channels.values(), key=lambda c: c.topic):
            schema = summary.schemas.get(c.schema_id)
            types[c.topic] = schema.name if schema is not None else ""
            by_id[c.id] = c.topic
            if not is_ros2_schema(schema):
                foreign[c.topic] = c.message_encoding or "schema-less"
        stats = summary.statistics
        if stats is None or not stats.channel_message_counts:
            return _Index(types, foreign, None, None)
        counts = dict.fromkeys(types, 0)
        for cid, n in stats.channel_message_counts.items():
            if cid in by_id:
                counts[by_id[cid]] += int(n)
        span = (stats.message_end_time - stats.message_start_time) * 1e-9
        return _Index(types, foreign, counts, span if stats.message_count else None)
    except Exception as e:  # the MCAP reader raises several types for broken files
        raise DataError(
            path,
            f"cannot open the log ({type(e).__name__}: {e})",
            fix="check that it is a complete MCAP file",
        ) from e


def _bag_index(path: Path, reader: Any) -> _Index:
    """A bag's topics, their types and counts and its duration, from the index of its
    :func:`~.ros.open_bag` reader (a rosbag2 ``metadata.yaml``, a ROS 1 bag's index)."""
    try:
        items = sorted(reader.topics.items())
        types = {t: info.msgtype or "" for t, info in items}
        counts = {t: int(info.msgcount) for t, info in items}
        span = reader.duration * 1e-9 if sum(counts.values()) else None
    except Exception as e:  # an index that opened but does not read: a damaged bag
        raise DataError(
            path,
            f"cannot read the bag's index ({type(e).__name__}: {e})",
            fix="check that it is a complete ROS bag; 'ros2 bag reindex' or 'rosbag reindex' "
            "writes the index again",
        ) from e
    return _Index(types, {}, counts, span)
