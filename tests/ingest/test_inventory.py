"""``exsur info LOG``: what a raw log holds (every channel, its unit, rate and range), in every
format the import reads."""

from __future__ import annotations

import json

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from excavator_surrogate.data.episode import write_episode
from excavator_surrogate.errors import DataError
from excavator_surrogate.ingest.inventory import summarize_log
from excavator_surrogate.ingest.summary import LogSummary
from tests.helpers import arm3_plant


def _by_name(summary: LogSummary) -> dict[str, object]:
    return {c.name: c for c in summary.channels}


def _check_ranges(summary: LogSummary, cols: dict[str, np.ndarray], names) -> None:
    got = _by_name(summary)
    for n in names:
        c = got[n]
        assert c.n_sample == cols[n].size and c.n_missing == 0, n
        assert c.lo == pytest.approx(cols[n].min(), rel=1e-5, abs=1e-6)
        assert c.hi == pytest.approx(cols[n].max(), rel=1e-5, abs=1e-6)


def test_csv_and_parquet_tables(tmp_path, short_cols):
    """A plain CSV log lists its header's columns with their ranges; a ;-separated one with
    decimal commas says which [csv] settings read it; a raw Parquet table lists its columns,
    text ones as text, and its metadata."""
    log = arm3_plant.write_csv(tmp_path / "run.csv", short_cols)
    s = summarize_log(log)
    assert s.kind == "csv" and [c.name for c in s.channels] == list(arm3_plant.LOG_COLUMNS)
    _check_ranges(s, short_cols, arm3_plant.LOG_COLUMNS)
    assert s.notes == []
    eu = tmp_path / "eu.csv"
    rows = [
        f"{t / 1e3:.3f};{b:.4f}".replace(".", ",")
        for t, b in zip(short_cols["t_ms"], short_cols["boom_deg"], strict=True)
    ]
    eu.write_text("t;boom\n" + "\n".join(rows) + "\n")
    s = summarize_log(eu)
    assert any("';'" in n and "[csv] delimiter" in n for n in s.notes)
    boom = _by_name(s)["boom"]
    assert "decimal commas" in boom.note
    assert boom.lo == pytest.approx(short_cols["boom_deg"].min(), abs=1e-4)
    table = pa.table({"t": short_cols["t_ms"], "mode": ["H"] * short_cols["t_ms"].size})
    pq.write_table(table.replace_schema_metadata({"Engine/Mode": "H"}), tmp_path / "raw.parquet")
    s = summarize_log(tmp_path / "raw.parquet")
    got = _by_name(s)
    assert s.kind == "parquet" and got["mode"].note == "text, e.g. 'H'" and got["mode"].lo is None
    assert got["t"].hi == pytest.approx(short_cols["t_ms"].max())
    assert s.meta == {"Engine/Mode": "H"}


def test_mdf_groups_units_and_rates(tmp_path, short_cols):
    """Every channel of every MDF channel group, with its unit, rate and range; an MDF 3 .dat
    the same; a truncated file is one DataError naming it."""
    asammdf = pytest.importorskip("asammdf")
    from tests.ingest.test_ingest_mdf import write_mdf

    names = [c for c in arm3_plant.LOG_COLUMNS if c != "t_ms"]
    for path, version in ((tmp_path / "two.mf4", "4.10"), (tmp_path / "old.dat", "3.30")):
        write_mdf(path, short_cols, split_bucket=True, version=version)
        s = summarize_log(path)
        assert s.kind == "mdf" and sorted(c.name for c in s.channels) == sorted(names)
        got = _by_name(s)
        assert got["boom_deg"].group.startswith("group 0") and got["bucket_deg"].group.startswith(
            "group 1"
        )
        assert got["boom_deg"].rate_hz == pytest.approx(100.0, rel=0.05)
        t = short_cols["t_ms"] * 1e-3
        keep = (t >= 2.0) & (t <= 25.0)
        assert got["bucket_deg"].n_sample == keep.sum()
        _check_ranges(s, short_cols, [n for n in names if not n.startswith("bucket")])
        assert s.duration_s == pytest.approx(t[-1] - t[0], abs=1e-6)
    mdf = asammdf.MDF(version="4.10")
    tt = np.arange(10) * 0.1
    mdf.append([asammdf.Signal(tt * 2, tt, name="boom", unit="deg")])
    mdf.save(tmp_path / "unit.mf4", overwrite=True)
    mdf.close()
    assert summarize_log(tmp_path / "unit.mf4").channels[0].unit == "deg"
    good = (tmp_path / "two.mf4").read_bytes()
    (tmp_path / "cut.mf4").write_bytes(good[: len(good) // 2])
    with pytest.raises(DataError, match="cut.mf4: not a readable MDF file"):
        summarize_log(tmp_path / "cut.mf4")


def test_dspace_export(tmp_path, short_cols):
    """A ControlDesk export lists its traces by the names a mapping gives (specific trace
    names, else the path's last segment), their paths, and the x axis as the time base."""
    from tests.ingest.test_ingest_dspace import dspace_traces, write_dspace

    traces = dspace_traces(short_cols)
    s = summarize_log(write_dspace(tmp_path / "rig.csv", traces))
    assert s.kind == "dspace"
    got = _by_name(s)
    assert {"boom_deg", "boom_up_pct", "p_pump"} <= set(got)
    assert "time base" in s.channels[0].note
    assert got["boom_deg"].group == "Model Root/Sensors/boom_deg"
    assert got["boom_deg"].rate_hz == pytest.approx(100.0, rel=0.05)
    _check_ranges(s, short_cols, ["boom_deg", "arm_up_pct"])
    assert s.meta  # the descriptions rows


def test_ros_bag_fields(tmp_path):
    """A bag lists every numeric field path of each topic with its count, rate and range,
    and a JointState's positions by joint name too; the header is left out."""
    pytest.importorskip("rosbags")
    from tests.ingest.test_ingest_ros_resample import _write_bag

    cols = arm3_plant.simulate(duration_s=4.0, seed=5, log_rate_hz=50.0)
    _write_bag(tmp_path / "bag", cols, storage="sqlite3")
    for path in (tmp_path / "bag", next((tmp_path / "bag").glob("*.db3"))):
        s = summarize_log(path)
        assert s.kind == "rosbag2" and s.path == tmp_path / "bag"
        got = _by_name(s)
        assert not any(n.startswith("header") for n in got)
        boom = got["position[1]"]  # the bag's order: bucket, boom, arm
        assert boom.note == "= position[boom_joint]"
        assert boom.group == "/joint_states (sensor_msgs/msg/JointState)"
        assert boom.n_sample == cols["t_ms"].size and boom.rate_hz == pytest.approx(50.0, rel=0.05)
        assert boom.lo == pytest.approx(np.radians(cols["boom_deg"]).min())
        assert got["data[0]"].n_sample == (cols["t_ms"].size + 1) // 2


def test_cli_info_on_a_log(cli, tmp_path, short_cols):
    """``exsur info LOG`` prints the channel table (or ``--json``); an exsur episode file is
    still described as an episode; an unreadable log is one line with exit code 2."""
    log = arm3_plant.write_csv(tmp_path / "run.csv", short_cols)
    rc, out, err = cli("info", log)
    assert rc == 0, err
    assert out.startswith("# run.csv: CSV") and "| `boom_deg` | 1000 |" in out
    rc, out, err = cli("info", log, "--json")
    assert rc == 0, err
    doc = json.loads(out)
    assert doc["kind"] == "csv" and doc["channels"][1]["name"] == "boom_deg"
    (tmp_path / "bad.csv").write_text("a,b\n1,2\n3\n")
    rc, _, err = cli("info", tmp_path / "bad.csv")
    assert rc == 2 and err.count("\n") == 1 and "bad.csv, row 1: ragged rows: line 3" in err
    rc, _, err = cli("info", tmp_path)  # a folder of logs: name one of them
    assert rc == 2 and "a folder of 2 raw log(s), not a dataset; give one of them, e.g. " in err
    assert f"exsur info {tmp_path / 'bad.csv'}, to list its channels" in err
    import tomllib

    from excavator_surrogate.ingest import convert_log, parse_mapping

    ep = convert_log(log, parse_mapping(tomllib.loads(arm3_plant.MAPPING_TOML))).episodes[0]
    ep_path = write_episode(tmp_path / "ep.parquet", ep)
    rc, out, err = cli("info", ep_path)
    assert rc == 0, err
    assert "boom" in out and "| `" not in out.split("\n")[0]
    with pytest.raises(DataError, match="an exsur episode, not a raw log"):
        summarize_log(ep_path)


def test_csv_read_as_a_mapping_would(cli, tmp_path):
    """A logger's CSV (preamble lines, a units row, cp1252, decimal commas and grouped
    thousands) is refused without options, naming csv.skip_rows, and read with ``--set
    csv.*`` as a mapping's [csv] table reads it; the options are refused on other logs."""
    text = "Logger v2\nserial 42\nt;boom;note\ns;deg;-\n0,00;1.000,5;Meßung\n0,05;1.001,0;x\n"
    log = tmp_path / "pre.csv"
    log.write_bytes(text.encode("cp1252"))
    rc, _, err = cli("info", log)
    assert rc == 2 and "--set csv.skip_rows=N" in err and err.count("\n") == 1
    opts = ["skip_rows=2", "skip_rows_after_header=1", "delimiter=';'", "decimal=','"]
    opts += ["thousands='.'", "encoding=cp1252"]
    rc, out, err = cli("info", log, "--json", *[a for o in opts for a in ("--set", f"csv.{o}")])
    assert rc == 0, err
    got = {c["name"]: c for c in json.loads(out)["channels"]}
    assert (got["boom"]["lo"], got["boom"]["hi"]) == (1000.5, 1001.0) and got["t"]["hi"] == 0.05
    assert got["note"]["note"] == "text, e.g. 'Meßung'"
    rc, _, err = cli("info", log, "--set", "csv.skip=2")
    assert rc == 2 and "did you mean 'skip_rows'" in err
    parquet = tmp_path / "raw.parquet"
    pq.write_table(pa.table({"t": [0.0, 1.0]}), parquet)
    rc, _, err = cli("info", parquet, "--set", "csv.skip_rows=2")
    assert rc == 2 and "--set csv.* reads a CSV log or a dSPACE export" in err


def test_mcap_topics_the_import_cannot_read(tmp_path):
    """A bare MCAP file lists its ROS 2 fields; a JSON channel is listed as one the import
    cannot read, instead of failing the whole file."""
    pytest.importorskip("rosbags")
    from mcap.writer import Writer

    from tests.ingest.test_ingest_ros_resample import _write_bag

    cols = arm3_plant.simulate(duration_s=2.0, seed=5, log_rate_hz=50.0)
    _write_bag(tmp_path / "bag", cols, storage="mcap")
    bare = tmp_path / "bare.mcap"  # without its metadata.yaml: read as a bare MCAP file
    bare.write_bytes(next((tmp_path / "bag").glob("*.mcap")).read_bytes())
    s = summarize_log(bare)
    assert s.kind == "mcap" and {c.name for c in s.channels} >= {"position[0]", "data[5]"}
    path = tmp_path / "mixed.mcap"
    with open(path, "wb") as f:
        w = Writer(f)
        w.start()
        schema = w.register_schema(name="Status", encoding="jsonschema", data=b"{}")
        channel = w.register_channel(topic="/status", message_encoding="json", schema_id=schema)
        w.add_message(channel, log_time=1, publish_time=1, data=b'{"ok": true}')
        w.finish()
    s = summarize_log(path)
    assert [(c.group, c.note) for c in s.channels] == [
        ("/status (Status)", "json messages, not ROS 2: the import cannot read them")
    ]


@pytest.mark.parametrize("storage", ["sqlite3", "mcap", "bare mcap", "rosbag1"])
def test_ros_reads_only_the_first_messages(tmp_path, monkeypatch, storage):
    """Where the log's index gives the counts (a rosbag2 folder's metadata, an MCAP file's
    statistics, a ROS 1 bag's index), reading stops once every topic has given its
    first ``ROS_RANGE_MESSAGES`` messages: the count and the duration are the whole log's,
    the rate and the range the first messages', and a note says so."""
    pytest.importorskip("rosbags")
    from excavator_surrogate.ingest import inventory_ros, ros
    from tests.ingest.test_ingest_ros_resample import _write_bag

    cols = arm3_plant.simulate(duration_s=4.0, seed=5, log_rate_hz=50.0)
    log = tmp_path / ("ros1.bag" if storage == "rosbag1" else "bag")
    _write_bag(log, cols, storage=storage.split()[-1])
    if storage == "bare mcap":  # without its metadata.yaml: the MCAP file's statistics
        log = tmp_path / "bare.mcap"
        log.write_bytes(next((tmp_path / "bag").glob("*.mcap")).read_bytes())
    read = []
    real = ros.iter_messages

    def counting(*args, **kwargs):
        for item in real(*args, **kwargs):
            read.append(item[0])
            yield item

    monkeypatch.setattr(ros, "iter_messages", counting)
    monkeypatch.setattr(inventory_ros, "ROS_RANGE_MESSAGES", 20)
    from rosbags.highlevel import AnyReader

    opened = []
    real_open = AnyReader.open

    def open_counted(self):
        opened.append(self)
        return real_open(self)

    monkeypatch.setattr(AnyReader, "open", open_counted)
    s = summarize_log(log)
    # the bag is opened once, for its index and its messages (a sqlite3 bag's opening scans)
    assert len(opened) == (0 if storage == "bare mcap" else 1)
    n = cols["t_ms"].size
    boom = _by_name(s)["position[1]"]
    assert boom.n_sample == n and boom.rate_hz == pytest.approx(50.0, rel=0.05)
    assert _by_name(s)["data[0]"].n_sample == (n + 1) // 2
    first = np.radians(cols["boom_deg"][:20])
    assert (boom.lo, boom.hi) == pytest.approx((first.min(), first.max()))
    assert s.notes == ["ranges over each topic's first 20 messages"]
    # the valves come at half rate: 40 joint states give their 20, and reading stops there
    assert read.count("/valves") == 20 and read.count("/joint_states") <= 41
    assert s.duration_s == pytest.approx((cols["t_ms"][-1] - cols["t_ms"][0]) * 1e-3, abs=0.01)


def test_ros_log_without_counts_is_read_whole(tmp_path, monkeypatch):
    """An MCAP file without statistics gives no counts: every message is read (the first
    ones deserialised) to count them."""
    pytest.importorskip("rosbags")
    from mcap.reader import make_reader
    from mcap.writer import Writer

    from excavator_surrogate.ingest import inventory_ros
    from tests.ingest.test_ingest_ros_resample import _write_bag

    cols = arm3_plant.simulate(duration_s=2.0, seed=5, log_rate_hz=50.0)
    _write_bag(tmp_path / "bag", cols, storage="mcap")
    with open(next((tmp_path / "bag").glob("*.mcap")), "rb") as fh:
        reader = make_reader(fh)
        records = list(reader.iter_messages())
    path = tmp_path / "nostats.mcap"
    with open(path, "wb") as f:  # the same messages, no statistics record
        w = Writer(f, use_statistics=False)
        w.start()
        ids: dict[str, int] = {}
        for schema, channel, message in records:
            if channel.topic not in ids:
                sid = w.register_schema(schema.name, schema.encoding, schema.data)
                ids[channel.topic] = w.register_channel(
                    channel.topic, channel.message_encoding, schema_id=sid
                )
            w.add_message(ids[channel.topic], message.log_time, message.data, message.publish_time)
        w.finish()
    monkeypatch.setattr(inventory_ros, "ROS_RANGE_MESSAGES", 20)
    s = summarize_log(path)
    boom = _by_name(s)["position[1]"]
    assert boom.n_sample == cols["t_ms"].size and boom.rate_hz == pytest.approx(50.0, rel=0.05)
    assert s.notes == ["ranges over each topic's first 20 messages"]
    assert s.duration_s == pytest.approx((cols["t_ms"][-1] - cols["t_ms"][0]) * 1e-3, abs=0.01)


def test_a_gzipped_csv_stays_within_the_memory_bound(tmp_path, short_cols):
    """A gzipped CSV is decompressed within the import's memory bound, as the import reads
    it: past it, one DataError naming the file; a plain one past it likewise."""
    log = arm3_plant.write_csv(tmp_path / "run.csv.gz", short_cols)
    assert summarize_log(log).channels[1].name == "boom_deg"
    with pytest.raises(DataError, match=r"run\.csv\.gz: decompressing the log needs more than"):
        summarize_log(log, max_memory_mb=0.01)
    plain = arm3_plant.write_csv(tmp_path / "run.csv", short_cols)
    with pytest.raises(DataError, match=r"run\.csv: reading the log needs"):
        summarize_log(plain, max_memory_mb=0.01)


def test_mdf_samples_flagged_invalid_are_missing(tmp_path, short_cols):
    """An MDF channel's samples flagged invalid count as missing, as the import reads them,
    and the range leaves them out."""
    asammdf = pytest.importorskip("asammdf")
    from tests.ingest.test_ingest_mdf import _one_group

    t = short_cols["t_ms"] * 1e-3
    bad = np.zeros(t.size, dtype=bool)
    bad[100:110] = True
    arm = short_cols["arm_deg"].copy()
    arm[100:110] = 1e6  # garbage under the invalid flags
    log = _one_group(
        tmp_path / "inv.mf4",
        short_cols,
        asammdf.Signal(arm, t, name="arm_deg", invalidation_bits=bad),
    )
    got = _by_name(summarize_log(log))["arm_deg"]
    assert (got.n_sample, got.n_missing) == (t.size, 10)
    assert got.hi == pytest.approx(np.delete(arm, np.arange(100, 110)).max())


def test_a_bag_index_that_opens_but_does_not_read_is_one_line(tmp_path):
    """A bag whose reader opened but whose index raises (a damaged index) is a DataError that
    names the bag and the reindex tools, not a traceback."""
    from excavator_surrogate.errors import DataError
    from excavator_surrogate.ingest import inventory_ros

    class Broken:
        @property
        def topics(self):
            raise KeyError("connections")

    with pytest.raises(
        DataError, match=r"bag: cannot read the bag's index \(KeyError: 'connections'\)"
    ):
        inventory_ros._bag_index(tmp_path / "bag", Broken())
