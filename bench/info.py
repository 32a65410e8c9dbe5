"""Benchmark ``exsur info`` on ROS bags: its cost must not grow with the bag.

``exsur info BAG`` takes a topic's count and the bag's duration from the bag's index and
reads only each topic's first ``ROS_RANGE_MESSAGES`` messages (the range and the rate).
This writes two rosbag2 bags of the same topics, a short one whose every topic just passes
that many messages and one ``--long-factor`` times longer: joint states at ``--rate`` Hz and
a small camera image at ``--camera-hz`` (a stand-in for the big topics of a real bag; its
messages are a few kB so that writing the bag stays quick).  It times, in alternation
(medians of ``--repeats``, the page cache warm):

- ``summarize_log`` on the short and on the long bag;
- a whole read of the long bag (every message's time, the first ones deserialised): what a
  summary that counts by reading costs.

Goals: the long bag's summary within 1.5x the short one's; within half of the whole read;
and the two summaries agree (the same ranges and rates, the counts and the duration in the
ratio of the lengths).  The goals are for MCAP storage, the default (rosbag2's since ROS 2
Iron).  With ``--storage sqlite3`` the bag reader's own opening scans the message table's
index (about 0.25 s per 460,000 messages here; the summary opens the bag once), so the
long bag costs more, though no more than a whole read of it, whose blobs of a real camera
topic would cost far more::

    python bench/info.py                       # 200 s and 2000 s at 200 Hz + 30 Hz
    python bench/info.py --long-factor 20
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

GOAL_LONG_OVER_SHORT = 1.5
"""The long bag's summary against the short bag's."""

GOAL_OVER_WHOLE_READ = 0.5
"""The long bag's summary against a whole read of it."""


def write_bag(
    path: Path, *, seconds: float, rate_hz: float, camera_hz: float, storage: str
) -> dict[str, int]:
    """A rosbag2 folder: ``/joint_states`` (3 joints, slow sines) at ``rate_hz`` and
    ``/camera`` (a 32 x 24 RGB image) at ``camera_hz``; the messages per topic."""
    from rosbags.rosbag2 import Writer
    from rosbags.rosbag2.enums import StoragePlugin
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    js, hdr, tm, img = (
        ts.types[k]
        for k in (
            "sensor_msgs/msg/JointState",
            "std_msgs/msg/Header",
            "builtin_interfaces/msg/Time",
            "sensor_msgs/msg/Image",
        )
    )
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    t0 = 1_717_000_000_000_000_000
    n = round(seconds * rate_hz)
    every = max(1, round(rate_hz / camera_hz))
    pix = np.zeros(32 * 24 * 3, np.uint8)
    amp = np.array([0.4, 0.6, 0.8])
    with Writer(path, version=9, storage_plugin=plugin) as w:
        cj = w.add_connection("/joint_states", js.__msgtype__, typestore=ts)
        ci = w.add_connection("/camera", img.__msgtype__, typestore=ts)
        for k in range(n):
            ns = t0 + round(k * 1e9 / rate_hz)
            h = hdr(stamp=tm(sec=ns // 10**9, nanosec=ns % 10**9), frame_id="arm")
            position = amp * np.sin(2 * np.pi * 0.05 * k / rate_hz)
            m = js(
                header=h,
                name=["boom_joint", "arm_joint", "bucket_joint"],
                position=position,
                velocity=np.zeros(0),
                effort=np.zeros(0),
            )
            w.write(cj, ns, ts.serialize_cdr(m, js.__msgtype__))
            if k % every == 0:
                im = img(
                    header=h,
                    height=24,
                    width=32,
                    encoding="rgb8",
                    is_bigendian=0,
                    step=96,
                    data=pix,
                )
                w.write(ci, ns, ts.serialize_cdr(im, img.__msgtype__))
    return {"/joint_states": n, "/camera": len(range(0, n, every))}


def whole_read(path: Path, cap: int) -> int:
    """Every message's time, the first ``cap`` per topic deserialised (a summary that counts
    by reading); the messages read."""
    from excavator_surrogate.ingest.ros import iter_messages

    topics = {"/joint_states", "/camera"}
    return sum(1 for _ in iter_messages(path, "rosbag2", topics, max_decoded=cap))


def _agree(short, long, factor: float, rate_hz: float) -> bool:
    """The same channels, ranges and rates; counts and duration in the ratio of lengths."""
    a = {(c.group, c.name): c for c in short.channels}
    b = {(c.group, c.name): c for c in long.channels}
    if a.keys() != b.keys():
        return False
    for key, ca in a.items():
        cb = b[key]
        if (ca.lo, ca.hi) != (cb.lo, cb.hi) or not np.isclose(ca.rate_hz, cb.rate_hz):
            return False
        if abs(cb.n_sample - factor * ca.n_sample) > factor:
            return False
    return abs(long.duration_s - factor * short.duration_s) <= factor / rate_hz


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark; print a summary and one JSON line."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=200.0, help="the short bag's length [s]")
    ap.add_argument("--long-factor", type=int, default=10, help="the long bag's length / short")
    ap.add_argument("--rate", type=float, default=200.0, help="joint states [Hz]")
    ap.add_argument("--camera-hz", type=float, default=30.0, help="camera images [Hz]")
    ap.add_argument("--storage", choices=["mcap", "sqlite3"], default="mcap")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument(
        "--cap",
        type=int,
        default=None,
        help="messages read per topic (default: exsur's ROS_RANGE_MESSAGES; smaller for a toy run)",
    )
    args = ap.parse_args(argv)
    try:
        import rosbags  # noqa: F401
    except ImportError:
        print("bench/info.py needs the ros extra: pip install 'excavator-surrogate[ros]'")
        return 2
    from excavator_surrogate.ingest import inventory_ros
    from excavator_surrogate.ingest.inventory import summarize_log

    if args.cap is not None:
        inventory_ros.ROS_RANGE_MESSAGES = args.cap
    cap = inventory_ros.ROS_RANGE_MESSAGES
    with tempfile.TemporaryDirectory(prefix="exsur-bench-info-") as tmp:
        root = Path(tmp)
        opts = dict(rate_hz=args.rate, camera_hz=args.camera_hz, storage=args.storage)
        t0 = time.perf_counter()
        short_n = write_bag(root / "short", seconds=args.seconds, **opts)
        long_n = write_bag(root / "long", seconds=args.seconds * args.long_factor, **opts)
        t_write = time.perf_counter() - t0
        mb = sum(f.stat().st_size for f in (root / "long").iterdir()) / 1e6
        print(
            f"wrote {args.seconds:g} s and {args.seconds * args.long_factor:g} s bags "
            f"({short_n} / {long_n} messages, the long one {mb:.0f} MB) in {t_write:.1f} s",
            file=sys.stderr,
        )
        short = summarize_log(root / "short")  # warm-up: modules and page cache
        long = summarize_log(root / "long")
        whole_read(root / "long", cap)
        t_short, t_long, t_whole = [], [], []
        for _ in range(args.repeats):
            for times, call in (
                (t_short, lambda: summarize_log(root / "short")),
                (t_long, lambda: summarize_log(root / "long")),
                (t_whole, lambda: whole_read(root / "long", cap)),
            ):
                t0 = time.perf_counter()
                call()
                times.append(time.perf_counter() - t0)
    med_short, med_long, med_whole = (statistics.median(t) for t in (t_short, t_long, t_whole))
    agree = _agree(short, long, args.long_factor, args.rate)
    long_over_short = med_long / med_short
    over_whole = med_long / med_whole
    reached = min(short_n.values()) >= cap
    print(
        f"exsur info: short bag {med_short:.3f} s, long bag {med_long:.3f} s "
        f"({long_over_short:.2f}x); a whole read of the long bag {med_whole:.3f} s "
        f"(the summary {over_whole:.2f}x that); the summaries agree: {agree}"
    )
    if not reached:
        print(
            f"note: the short bag's topics hold fewer than {cap} messages each; "
            "lengthen it (--seconds) for the long/short goal to mean anything",
            file=sys.stderr,
        )
    print(
        json.dumps(
            {
                "bench": "info",
                "storage": args.storage,
                "cap": cap,
                "messages_short": short_n,
                "messages_long": long_n,
                "long_mb": round(mb, 1),
                "short_seconds": round(med_short, 4),
                "long_seconds": round(med_long, 4),
                "whole_read_seconds": round(med_whole, 4),
                "long_over_short": round(long_over_short, 3),
                "long_over_whole_read": round(over_whole, 3),
                "goals": {
                    "long_le_1_5x_short": long_over_short <= GOAL_LONG_OVER_SHORT,
                    "long_le_half_whole_read": over_whole <= GOAL_OVER_WHOLE_READ,
                    "summaries_agree": agree,
                },
            }
        )
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
