"""The test arm's log written as a ROS bag (rosbag2 with MCAP or sqlite3 storage, or ROS 1)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from tests.helpers import arm3_plant

T0 = 1_717_000_000_000_000_000
"""The first message's time [ns]."""


def write_bag(
    path: Path,
    cols: dict[str, np.ndarray],
    *,
    storage: str = "mcap",
    joint_rows: np.ndarray | None = None,
    valve_rows: np.ndarray | None = None,
    order: Sequence[str] = arm3_plant.JOINTS,
    delay_ns: int = 0,
    frame_id: str = "",
    split_valves: tuple[np.ndarray, np.ndarray] | None = None,
    down_delay_ns: int = 0,
    custom_data: dict[str, str] | None = None,
) -> Path:
    """The test arm's log ``cols`` as a bag: ``/joint_states`` (JointState, header stamps,
    the joints in ``order``, received ``delay_ns`` after the stamp) at ``joint_rows`` and
    ``/valves`` (Float64MultiArray of the up/down duties, no header) at ``valve_rows``
    (default: every row); ``storage``: "mcap" or "sqlite3" (a rosbag2 folder) or "rosbag1"
    (a ``.bag`` file).  With ``split_valves = (up_rows, down_rows)`` each duty is a
    ``std_msgs/Float64`` topic of its own instead, ``/<joint>/up`` at ``up_rows`` and
    ``/<joint>/down`` at ``down_rows``, ``down_delay_ns`` after the row's time.
    ``custom_data``: rosbag2 only, what ``ros2 bag record --custom-data KEY=VALUE`` records."""
    from rosbags.typesys import Stores, get_typestore

    ros1 = storage == "rosbag1"
    ts = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    js_t = ts.types["sensor_msgs/msg/JointState"]
    hdr_t, time_t = ts.types["std_msgs/msg/Header"], ts.types["builtin_interfaces/msg/Time"]
    arr_t, lay_t = (
        ts.types["std_msgs/msg/Float64MultiArray"],
        ts.types["std_msgs/msg/MultiArrayLayout"],
    )
    f64_t = ts.types["std_msgs/msg/Float64"]
    serialize = ts.serialize_ros1 if ros1 else ts.serialize_cdr
    n = cols["t_ms"].size
    joints = set(range(n) if joint_rows is None else np.asarray(joint_rows).tolist())
    valves = set(range(n) if valve_rows is None else np.asarray(valve_rows).tolist())
    if ros1:
        from rosbags.rosbag1 import Writer as Writer1

        writer: Any = Writer1(path)
    else:
        from rosbags.rosbag2 import Writer
        from rosbags.rosbag2.enums import StoragePlugin

        plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
        writer = Writer(path, version=9, storage_plugin=plugin)
    with writer as w:
        for key, value in (custom_data or {}).items():
            w.set_custom_data(key, value)
        cj = w.add_connection("/joint_states", js_t.__msgtype__, typestore=ts)
        if split_valves is None:
            cv = w.add_connection("/valves", arr_t.__msgtype__, typestore=ts)
        else:
            one_way = {
                (j, d): (
                    w.add_connection(f"/{j}/{d}", f64_t.__msgtype__, typestore=ts),
                    set(np.asarray(r).tolist()),
                )
                for j in arm3_plant.JOINTS
                for d, r in zip(("up", "down"), split_valves)
            }
        for k in range(n):
            ns = T0 + round(cols["t_ms"][k] * 1e6)
            if k in joints:
                stamp = time_t(sec=ns // 10**9, nanosec=ns % 10**9)
                header = (
                    hdr_t(seq=k, stamp=stamp, frame_id=frame_id) if ros1 else hdr_t(stamp, frame_id)
                )
                msg = js_t(
                    header=header,
                    name=[f"{j}_joint" for j in order],
                    position=np.radians([cols[f"{j}_deg"][k] for j in order]),
                    velocity=np.zeros(0),
                    effort=np.zeros(0),
                )
                w.write(cj, ns + delay_ns, serialize(msg, js_t.__msgtype__))
            if split_valves is not None:
                for (j, d), (con, rows) in one_way.items():
                    if k in rows:
                        msg = f64_t(data=float(cols[f"{j}_{d}_pct"][k]))
                        late = down_delay_ns if d == "down" else 0
                        w.write(con, ns + late, serialize(msg, f64_t.__msgtype__))
            elif k in valves:
                duty = [cols[f"{j}_{d}_pct"][k] for j in arm3_plant.JOINTS for d in ("up", "down")]
                msg = arr_t(layout=lay_t(dim=[], data_offset=0), data=np.array(duty))
                w.write(cv, ns, serialize(msg, arr_t.__msgtype__))
    return path
