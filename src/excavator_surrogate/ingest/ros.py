"""ROS logs: ROS 2 bags (rosbag2 folders, sqlite3 or MCAP storage), bare MCAP files and ROS 1
bags, read through ``rosbags`` / ``mcap`` into one :class:`~.sources.Series` per topic."""

from __future__ import annotations

import re
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import ConfigError, DataError
from .mapping import Channel, Mapping
from .sources import RawLog, Reader, Series, has_suffix


def _bag_folder(path: Path, _fmt: str) -> bool:
    if path.is_dir():
        return (path / "metadata.yaml").exists()
    name = path.name.lower()
    return name.endswith((".mcap", ".db3")) and (path.parent / "metadata.yaml").exists()


# --------------------------------------------------------------------------------------
# ROS bags

_TOKEN = re.compile(r"([A-Za-z_][A-Za-z0-9_]*)|\[([^\]]+)\]|\.")


def parse_field_path(path: str) -> list[tuple[str, Any]]:
    """``"position[1]"`` -> ``[("attr", "position"), ("index", 1)]``; ``[boom]`` is a name lookup."""
    out: list[tuple[str, Any]] = []
    pos = 0
    for m in _TOKEN.finditer(path):
        if m.start() != pos:
            break
        pos = m.end()
        if m.group(1):
            out.append(("attr", m.group(1)))
        elif m.group(2) is not None:
            idx = m.group(2).strip().strip("'\"")
            out.append(("index", int(idx)) if re.fullmatch(r"-?\d+", idx) else ("name", idx))
    if pos != len(path) or not out or out[0][0] != "attr":
        raise ValueError(
            f"cannot parse field path {path!r}; write e.g. position[1] or pose.position.x"
        )
    return out


def message_fields(obj: Any) -> list[str]:
    """The field names of a deserialised message (none for other values)."""
    return [f for f in getattr(obj, "__dataclass_fields__", {}) if not f.startswith("__")]


def is_ros2_schema(schema: Any) -> bool:
    """An MCAP channel's schema describes ROS 2 messages (CDR with a ``ros2msg`` schema), the
    only ones exsur reads."""
    return schema is not None and schema.encoding == "ros2msg"


def _is_array(obj: Any) -> bool:
    return (
        not isinstance(obj, str | bytes) and hasattr(obj, "__len__") and hasattr(obj, "__getitem__")
    )


def _what(obj: Any) -> tuple[str, str]:
    """What a value that is not a number is, and how to reach a number in it ("": no way)."""
    if isinstance(obj, str | bytes):
        return "text", ""
    fields = message_fields(obj)
    if fields:
        msgtype = getattr(obj, "__msgtype__", type(obj).__name__)
        return f"a {msgtype} message", f"add one of its fields ({', '.join(fields)})"
    if _is_array(obj):
        return f"an array of {len(obj)} values", "add an index, e.g. [0]"
    number = isinstance(obj, bool | int | float | np.number)
    return f"{'a number' if number else 'a value'} ({type(obj).__name__})", ""


def _extract(msg: Any, tokens: list[tuple[str, Any]]) -> float:
    obj = msg
    parent = msg
    for kind, arg in tokens:
        if kind == "attr":
            parent = obj
            if not hasattr(obj, arg):
                fields = message_fields(obj)
                if fields:
                    raise ValueError(f"no field '{arg}' (fields: {', '.join(fields)})")
                what, hint = _what(obj)
                raise ValueError(
                    f"no field '{arg}': the value before it is {what}"
                    + (f"; {hint}" if hint else "")
                )
            obj = getattr(obj, arg)
            continue
        if not _is_array(obj):
            what, hint = _what(obj)
            raise ValueError(
                f"[{arg}] indexes an array, but the value is {what}" + (f"; {hint}" if hint else "")
            )
        if kind == "name":
            names = list(getattr(parent, "name", []) or [])
            if arg not in names:
                raise ValueError(f"no joint named '{arg}' in the message's name list {names}")
            k = names.index(arg)
            if k >= len(obj):
                raise ValueError(
                    f"'{arg}' is entry {k} of the name list, but the array has {len(obj)} "
                    "values (the message does not fill this field for every joint)"
                )
            obj = obj[k]
        else:
            if arg >= len(obj) or arg < -len(obj):
                raise ValueError(f"index {arg} out of range (the array has {len(obj)} values)")
            obj = obj[arg]
    if isinstance(obj, bool | int | float | np.number):
        return float(obj)
    what, hint = _what(obj)
    raise ValueError(f"the value is {what}, not a number" + (f"; {hint}" if hint else ""))


def _header_ns(msg: Any) -> int | None:
    h = getattr(msg, "header", None)
    st = getattr(h, "stamp", None)
    if st is None:
        return None
    return int(st.sec) * 1_000_000_000 + int(st.nanosec)


def need_ros(path: Path) -> None:
    import importlib.util

    for mod in ("rosbags", "mcap"):
        if importlib.util.find_spec(mod) is None:
            raise ConfigError(
                f"{path}: reading ROS bags needs the '{mod}' package; "
                "install the extra: pip install 'excavator-surrogate[ros]'"
            )


def iter_messages(
    path: Path,
    kind: str,
    topics: set[str],
    *,
    max_decoded: int | None = None,
    reader: Any = None,
) -> Iterator[tuple[str, int, Any]]:
    """Yield ``(topic, log_time_ns, msg)``; raises DataError for missing topics.

    ``max_decoded``: each topic's messages past this many are yielded as ``None``, not
    deserialised (their times only; None: every message is deserialised).  ``reader``: a bag
    already opened by :func:`open_bag` (not an MCAP file), read instead of opening it again."""
    count = dict.fromkeys(topics, 0)

    def wanted(topic: str) -> bool:
        count[topic] += 1
        return max_decoded is None or count[topic] <= max_decoded

    if kind == "mcap":
        yield from _iter_mcap(path, topics, wanted)
    elif reader is not None:
        yield from _bag_messages(reader, path, topics, wanted)
    else:
        with open_bag(path, kind) as opened:
            yield from _bag_messages(opened, path, topics, wanted)


@contextmanager
def open_bag(path: Path, kind: str) -> Iterator[Any]:
    """A rosbags ``AnyReader`` opened on a rosbag2 folder or ROS 1 bag, closed on exit.

    Raises:
        DataError: the bag cannot be opened (with the fix for its kind).
    """
    need_ros(path)
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    try:
        reader = AnyReader([path], default_typestore=get_typestore(Stores.ROS2_HUMBLE))
        reader.open()
    except Exception as e:  # rosbags raises several types for broken bags
        fix = (
            "check that it is a complete ROS 1 bag; one left unindexed by a crash can be "
            "repaired with 'rosbag reindex'"
            if kind == "rosbag1"
            else "check that it is a complete ROS 2 bag (a rosbag2 folder with a readable "
            "metadata.yaml; 'ros2 bag reindex' writes a lost one again)"
        )
        raise DataError(path, f"cannot open the bag ({type(e).__name__}: {e})", fix=fix) from e
    try:
        yield reader
    finally:
        reader.close()


def _bag_messages(
    reader: Any, path: Path, topics: set[str], wanted: Callable[[str], bool]
) -> Iterator[tuple[str, int, Any]]:
    """``(topic, log_time_ns, msg)`` of ``topics`` from an :func:`open_bag` reader; ``msg`` is
    None where ``wanted(topic)`` is false.  Raises DataError for a topic not in the bag."""
    present = sorted(reader.topics)
    for t in sorted(topics):
        if t not in present:
            raise DataError(
                path, f"topic '{t}' is not in the bag", fix=f"topics present: {', '.join(present)}"
            )
    conns = [c for c in reader.connections if c.topic in topics]
    for con, ts, raw in reader.messages(connections=conns):
        msg = reader.deserialize(raw, con.msgtype) if wanted(con.topic) else None
        yield con.topic, int(ts), msg


def _iter_mcap(
    path: Path, topics: set[str], wanted: Callable[[str], bool]
) -> Iterator[tuple[str, int, Any]]:
    need_ros(path)
    from mcap.reader import make_reader
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.EMPTY)
    registered: set[str] = set()
    try:
        with open(path, "rb") as fh:
            reader = make_reader(fh)
            summary = reader.get_summary()
            present = sorted({c.topic for c in summary.channels.values()}) if summary else []
            if summary:
                for t in sorted(topics):
                    if t not in present:
                        raise DataError(
                            path,
                            f"topic '{t}' is not in the file",
                            fix=f"topics present: {', '.join(present)}",
                        )
            for schema, channel, message in reader.iter_messages(topics=sorted(topics)):
                if not is_ros2_schema(schema):
                    enc = f"'{schema.encoding}'" if schema is not None else "none"
                    raise DataError(
                        path,
                        f"topic '{channel.topic}' holds '{channel.message_encoding}' messages "
                        f"(schema encoding {enc}), not ROS 2 CDR messages with a ros2msg schema",
                        fix="only ROS 2 messages can be imported from MCAP; map a ROS 2 topic",
                    )
                if schema.name not in registered:
                    store.register(get_types_from_msg(schema.data.decode(), schema.name))
                    registered.add(schema.name)
                msg = (
                    store.deserialize_cdr(message.data, schema.name)
                    if wanted(channel.topic)
                    else None
                )
                yield channel.topic, int(message.log_time), msg
    except DataError:
        raise
    except Exception as e:
        raise DataError(
            path,
            f"cannot read the MCAP file ({type(e).__name__}: {e})",
            fix="check that the file is complete",
        ) from e


def _read_ros(path: Path, kind: str, mapping: Mapping) -> RawLog:
    chans: list[Channel] = mapping.channels()
    by_topic: dict[str, list[str]] = {}
    for c in chans:
        by_topic.setdefault(c.series, []).append(c.key)
    tokens: dict[tuple[str, str], list[tuple[str, Any]]] = {}
    for c in chans:
        try:
            tokens[(c.series, c.key)] = parse_field_path(c.key)
        except ValueError as e:
            raise DataError(
                mapping.where, str(e), column=c.label, fix="fix the field path in the mapping"
            ) from None
    stamp = mapping.time.stamp
    times: dict[str, list[int]] = {t: [] for t in by_topic}
    vals: dict[str, list[list[float]]] = {t: [] for t in by_topic}
    used_header: dict[str, bool] = {}
    for topic, log_ns, msg in iter_messages(path, kind, set(by_topic)):
        row = len(times[topic])
        hdr = _header_ns(msg) if stamp != "log" else None
        if stamp == "header" and hdr is None:
            raise DataError(
                path,
                "message has no header.stamp",
                column=topic,
                row=row,
                fix='set [time] stamp = "log" to use the bag time',
            )
        from_header = hdr is not None and (stamp == "header" or hdr > 0)
        use = hdr if from_header and hdr is not None else log_ns
        used_header[topic] = used_header.get(topic, False) or from_header
        times[topic].append(use)
        rowvals = []
        for key in by_topic[topic]:
            try:
                rowvals.append(_extract(msg, tokens[(topic, key)]))
            except ValueError as e:
                raise DataError(
                    path,
                    f"field path '{key}': {e}",
                    column=f"{topic}:{key}",
                    row=row,
                    fix=f"fix the field in {mapping.where}",
                ) from None
        vals[topic].append(rowvals)
    empty = [t for t, v in times.items() if not v]
    if empty:
        raise DataError(
            path, f"topic '{empty[0]}' has no messages", fix="record the topic or map another one"
        )
    origin_ns = min(v[0] for v in times.values())
    series: dict[str, Series] = {}
    for topic, keys in by_topic.items():
        t_ns = np.asarray(times[topic], dtype=np.int64)
        arr = np.asarray(vals[topic], dtype=np.float64).reshape(len(t_ns), len(keys))
        label = f"{topic} ({'header.stamp' if used_header.get(topic) else 'log time'})"
        series[topic] = Series(
            topic,
            (t_ns - origin_ns).astype(np.float64) * 1e-9,
            {k: arr[:, i] for i, k in enumerate(keys)},
            label,
        )
    origin = datetime.fromtimestamp(origin_ns / 1e9, tz=UTC).isoformat() if origin_ns > 0 else "0"
    return RawLog(
        path=path,
        kind=kind,
        series=series,
        origin=origin,
        columns=sorted(by_topic),
        meta=ros_metadata(path, kind),
    )


def ros_metadata(path: Path, kind: str) -> dict[str, str]:
    """A bag's user metadata: rosbag2 ``custom_data`` (``metadata.yaml``, ROS 2 Iron and
    later; ``ros2 bag record --custom-data KEY=VALUE``) and, in MCAP files, the metadata
    records as ``<record name>/<key>``.  Empty when there is none (ROS 1 bags).

    rosbag2's MCAP storage keeps a copy of ``metadata.yaml`` in each file (the record
    ``rosbag2``, key ``serialized_metadata``): its ``custom_data`` is read from there, so an
    ``.mcap`` file copied out of its bag folder keeps its keys, and the copy itself is left
    out (it is the bag's bookkeeping, not a user's key)."""
    out: dict[str, str] = {}
    folder = path if path.is_dir() else path.parent
    yml = folder / "metadata.yaml"
    if kind == "rosbag2" and yml.is_file():
        out.update(_custom_data(yml.read_text(encoding="utf-8"), top=True))
    files = sorted(folder.glob("*.mcap")) if kind == "rosbag2" else [path]
    if kind in ("rosbag2", "mcap"):
        from mcap.reader import make_reader

        for f in files:
            if not f.is_file() or f.suffix.lower() != ".mcap":
                continue
            try:
                with open(f, "rb") as fh:
                    for rec in make_reader(fh).iter_metadata():
                        for k, v in rec.metadata.items():
                            if (rec.name, k) == ("rosbag2", "serialized_metadata"):
                                for ck, cv in _custom_data(v, top=False).items():
                                    out.setdefault(ck, cv)
                                continue
                            out.setdefault(f"{rec.name}/{k}", str(v))
            except Exception:  # the message reader reports a damaged file
                continue
    return out


def _custom_data(text: str, *, top: bool) -> dict[str, str]:
    """The ``custom_data`` map of rosbag2 metadata YAML ``text``: a ``metadata.yaml`` (under
    its ``rosbag2_bagfile_information`` key, ``top``) or the copy an MCAP file holds (without
    it); {} where it has none or does not parse (the bag reader reports a broken file)."""
    from ruamel.yaml import YAML

    try:
        doc = YAML(typ="safe", pure=True).load(text)
    except Exception:
        return {}
    info = doc.get("rosbag2_bagfile_information") if top and isinstance(doc, dict) else doc
    custom = info.get("custom_data") if isinstance(info, dict) else None
    if not isinstance(custom, dict):
        return {}
    return {str(k): str(v) for k, v in custom.items() if v is not None}


# --------------------------------------------------------------------------------------
# the formats read here

ROS_READERS: tuple[Reader, ...] = (
    Reader(
        "rosbag2",
        "ROS 2 bags (rosbag2 folder)",
        (".mcap", ".db3"),
        _bag_folder,
        lambda path, mapping: _read_ros(path, "rosbag2", mapping),
        maps="topics",
        whole_folder=True,
    ),
    Reader(
        "mcap",
        "MCAP (.mcap)",
        (".mcap",),
        has_suffix(".mcap"),
        lambda path, mapping: _read_ros(path, "mcap", mapping),
        maps="topics",
    ),
    Reader(
        "rosbag1",
        "ROS 1 bags (.bag)",
        (".bag",),
        has_suffix(".bag"),
        lambda path, mapping: _read_ros(path, "rosbag1", mapping),
        maps="topics",
    ),
)
"""ROS 2 bags, MCAP files and ROS 1 bags."""
