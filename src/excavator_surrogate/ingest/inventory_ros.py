"""What a ROS log holds (:func:`summarize_ros`, for :func:`~.inventory.summarize_log`).

Per topic: its message type, count and rate, and every numeric field path of its messages
(``position[1]``, ``pose.position.x``; not the header, whose stamp ``[time] stamp`` reads)
with the range over its first :data:`ROS_RANGE_MESSAGES` messages.  An MCAP file's topics
whose messages are not ROS 2 CDR are listed as such: the import cannot read them.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import DataError
from .summary import ChannelSummary, LogSummary, sample_rate, value_range

ROS_RANGE_MESSAGES = 5000
"""A field's range is taken over this many first messages of its topic, the only ones
deserialised (every message of a long bag takes minutes); the count and rate use all."""

ARRAY_FIELDS = 16
"""A numeric array field lists at most this many entries (``position[0]`` ...)."""


def numeric_fields(msg: Any, prefix: str = "") -> Iterator[tuple[str, float]]:
    """Every numeric field path of a deserialised message and its value: ``pose.position.x``,
    ``position[1]`` (arrays: their first :data:`ARRAY_FIELDS` entries; not the header, whose
    stamp ``[time] stamp`` reads)."""
    for name in getattr(msg, "__dataclass_fields__", {}):
        if name.startswith("__") or (not prefix and name == "header"):
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
    from .ros import iter_messages, need_ros, ros_metadata

    need_ros(path)
    topics, foreign = _topics(path, kind)
    times: dict[str, list[int]] = {t: [] for t in topics}
    values: dict[str, dict[str, list[float]]] = {t: {} for t in topics}
    names: dict[str, list[str]] = {}
    readable = {t for t in topics if t not in foreign}
    messages = iter_messages(path, kind, readable, max_decoded=ROS_RANGE_MESSAGES)
    for topic, ns, msg in messages if readable else ():
        times[topic].append(ns)
        if msg is None:  # past the first ROS_RANGE_MESSAGES: its time only
            continue
        if topic not in names:
            names[topic] = [str(n) for n in (getattr(msg, "name", None) or [])]
        for key, v in numeric_fields(msg):
            values[topic].setdefault(key, []).append(v)
    channels, spans = [], []
    for topic, msgtype in topics.items():
        t = np.asarray(times[topic], dtype=np.float64) * 1e-9
        if t.size:
            spans.append((float(t.min()), float(t.max())))
        rate = sample_rate(np.sort(t))
        group = f"{topic} ({msgtype})" if msgtype else topic
        if topic in foreign:
            note = f"{foreign[topic]} messages, not ROS 2: the import cannot read them"
            channels.append(ChannelSummary("", group=group, note=note))
        elif not values[topic]:
            channels.append(
                ChannelSummary(
                    "", group=group, n_sample=t.size, rate_hz=rate, note="no numeric field"
                )
            )
        for key, vals in values[topic].items():
            lo, hi, miss = value_range(np.asarray(vals, dtype=np.float64))
            joint = _joint_name(key, names.get(topic, []))
            note = f"= {key.split('[')[0]}[{joint[1]}]" if joint else ""
            channels.append(
                ChannelSummary(
                    key,
                    group=group,
                    n_sample=t.size,
                    rate_hz=rate,
                    lo=lo,
                    hi=hi,
                    n_missing=miss,
                    note=note,
                )
            )
    notes = []
    if any(len(v) > ROS_RANGE_MESSAGES for v in times.values()):
        notes.append(f"ranges over each topic's first {ROS_RANGE_MESSAGES} messages")
    duration = max(b for _, b in spans) - min(a for a, _ in spans) if spans else None
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


def _topics(path: Path, kind: str) -> tuple[dict[str, str], dict[str, str]]:
    """Topic -> message type of a bag or MCAP file, and the topics whose messages are not
    ROS 2 CDR (an MCAP file's JSON or Protobuf channels) -> their encoding."""
    try:
        if kind == "mcap":
            from mcap.reader import make_reader

            with open(path, "rb") as fh:
                summary = make_reader(fh).get_summary()
            if summary is None:
                raise ValueError("the file has no summary section")
            types, foreign = {}, {}
            for c in sorted(summary.channels.values(), key=lambda c: c.topic):
                schema = summary.schemas.get(c.schema_id)
                types[c.topic] = schema.name if schema is not None else ""
                if schema is None or schema.encoding != "ros2msg":
                    foreign[c.topic] = c.message_encoding or "schema-less"
            return types, foreign
        from rosbags.highlevel import AnyReader
        from rosbags.typesys import Stores, get_typestore

        with AnyReader([path], default_typestore=get_typestore(Stores.ROS2_HUMBLE)) as reader:
            return {t: info.msgtype or "" for t, info in sorted(reader.topics.items())}, {}
    except Exception as e:  # the bag readers raise several types for broken files
        raise DataError(
            path,
            f"cannot open the log ({type(e).__name__}: {e})",
            fix="check that it is a complete ROS bag or MCAP file",
        ) from e
