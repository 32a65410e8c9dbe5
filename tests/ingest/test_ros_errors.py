"""ROS logs: every error of a field path, a bag, an MCAP file or a topic is one line naming
the file, the topic (and field) and the fix; topics without a common time span."""

from __future__ import annotations

import importlib.util
import shutil
from pathlib import Path

import numpy as np
import pytest

from excavator_surrogate.errors import ConfigError
from excavator_surrogate.ingest import convert_log, load_mapping
from excavator_surrogate.ingest.ros import ros_metadata
from tests.helpers import arm3_plant
from tests.helpers.ingest import import_fails
from tests.helpers.ros_bags import T0, write_bag
from tests.ingest.test_ingest_ros_resample import ROS_MAPPING

pytest.importorskip("rosbags")


@pytest.fixture(scope="module")
def bags(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A folder with a 4 s rosbag2 folder (MCAP storage), its MCAP file alone and a ROS 1 bag."""
    root = tmp_path_factory.mktemp("ros_errors")
    cols = arm3_plant.simulate(duration_s=4.0, seed=5, log_rate_hz=50.0)
    write_bag(root / "bag", cols)
    write_bag(root / "ros1.bag", cols, storage="rosbag1")
    shutil.copy(next((root / "bag").glob("*.mcap")), root / "bare.mcap")
    return root


def _fail(cli, log: Path, mapping: str, tmp_path: Path) -> str:
    """Import ``log`` with the mapping text ``mapping``: exit 2, one line, nothing written."""
    (tmp_path / "m.toml").write_text(mapping)
    return import_fails(cli, log, tmp_path / "m.toml", tmp_path / "ds")


def _angle(field: str) -> str:
    """The ROS mapping with the arm's angle read from ``field`` of /joint_states."""
    return ROS_MAPPING.replace("position[arm_joint]", field)


@pytest.mark.parametrize("field", ["position x", "position[]", "[0]"])
def test_a_field_path_that_cannot_be_parsed_names_the_mapping(cli, bags, tmp_path, field):
    err = _fail(cli, bags / "bag", _angle(field), tmp_path)
    assert f"m.toml, column '/joint_states:{field}': cannot parse field path '{field}'" in err
    assert "write e.g. position[1] or pose.position.x" in err


@pytest.mark.parametrize(
    ("field", "problem"),
    [
        ("positon[1]", "no field 'positon' (fields: header, name, position, velocity, effort)"),
        (
            "position[stick_joint]",
            "no joint named 'stick_joint' in the message's name list "
            "['boom_joint', 'arm_joint', 'bucket_joint']",
        ),
        (
            "velocity[arm_joint]",  # a JointState without velocities
            "'arm_joint' is entry 1 of the name list, but the array has 0 values",
        ),
        ("position", "the value is an array of 3 values, not a number; add an index, e.g. [0]"),
        ("position.x", "no field 'x': the value before it is an array of 3 values; add an index"),
        ("position[0][1]", "[1] indexes an array, but the value is a number (float64)"),
        (
            "header[0]",
            "[0] indexes an array, but the value is a std_msgs/msg/Header message; add one of "
            "its fields (stamp, frame_id)",
        ),
        (
            "header.stamp",
            "the value is a builtin_interfaces/msg/Time message, not a number; add one of its "
            "fields (sec, nanosec)",
        ),
        ("name[0]", "the value is text, not a number"),
    ],
)
def test_a_field_the_messages_do_not_have_is_named(cli, bags, tmp_path, field, problem):
    """Each wrong field path names the bag, topic:field, row, what the value is and the fix."""
    err = _fail(cli, bags / "bag", _angle(field), tmp_path)
    assert f"bag, column '/joint_states:{field}', row 0: field path '{field}': {problem}" in err
    assert f"(fix the field in {tmp_path / 'm.toml'})" in err


def test_header_stamps_of_a_topic_without_a_header(cli, bags, tmp_path):
    err = _fail(cli, bags / "bag", ROS_MAPPING.replace('"auto"', '"header"'), tmp_path)
    assert "bag, column '/valves', row 0: message has no header.stamp" in err
    assert 'set [time] stamp = "log" to use the bag time' in err


def test_a_bag_that_cannot_be_opened(cli, bags, tmp_path):
    """A damaged ROS 1 bag, a file that is no bag, a rosbag2 folder with a broken
    metadata.yaml: each names the fix for its kind."""
    blob = (bags / "ros1.bag").read_bytes()
    (tmp_path / "cut.bag").write_bytes(blob[: len(blob) // 2])
    err = _fail(cli, tmp_path / "cut.bag", ROS_MAPPING, tmp_path)
    assert "cut.bag: cannot open the bag (" in err and "'rosbag reindex'" in err
    (tmp_path / "junk.bag").write_text("not a bag\n")
    err = _fail(cli, tmp_path / "junk.bag", ROS_MAPPING, tmp_path)
    assert "junk.bag: cannot open the bag (" in err and "complete ROS 1 bag" in err
    shutil.copytree(bags / "bag", tmp_path / "broken")
    (tmp_path / "broken" / "metadata.yaml").write_text("rosbag2_bagfile_information: [\n")
    err = _fail(cli, tmp_path / "broken", ROS_MAPPING, tmp_path)
    assert "broken: cannot open the bag (" in err
    assert "a rosbag2 folder with a readable metadata.yaml; 'ros2 bag reindex'" in err
    # exsur info opens them the same way, with the same fixes
    for name, fix in [("cut.bag", "'rosbag reindex'"), ("broken", "'ros2 bag reindex'")]:
        rc, _, err = cli("info", tmp_path / name)
        assert rc != 0 and f"{name}: cannot open the bag (" in err and fix in err


def test_mcap_errors(cli, bags, tmp_path):
    """A bare MCAP file without a mapped topic, cut short, or not MCAP at all."""
    err = _fail(cli, bags / "bare.mcap", ROS_MAPPING.replace('"/valves"', '"/cmd"', 1), tmp_path)
    assert (
        "bare.mcap: topic '/cmd' is not in the file (topics present: /joint_states, /valves)" in err
    )
    blob = (bags / "bare.mcap").read_bytes()
    for name, data in (("cut.mcap", blob[: len(blob) // 2]), ("junk.mcap", b"hello")):
        (tmp_path / name).write_bytes(data)
        err = _fail(cli, tmp_path / name, ROS_MAPPING, tmp_path)
        assert (
            f"{name}: cannot read the MCAP file (" in err
            and "check that the file is complete" in err
        )


def test_mcap_topics_that_are_not_ros2(cli, tmp_path):
    """JSON messages (Foxglove, a script's MCAP log) are named, with their encoding."""
    from mcap.writer import Writer

    with open(tmp_path / "json.mcap", "wb") as fh:
        w = Writer(fh)
        w.start()
        schema = w.register_schema(name="Valves", encoding="jsonschema", data=b"{}")
        for topic in ("/joint_states", "/valves"):
            ch = w.register_channel(topic=topic, message_encoding="json", schema_id=schema)
            w.add_message(ch, log_time=T0, data=b"{}", publish_time=T0)
        w.finish()
    err = _fail(cli, tmp_path / "json.mcap", ROS_MAPPING, tmp_path)
    assert (
        "json.mcap: topic '/joint_states' holds 'json' messages (schema encoding 'jsonschema')"
        in err
    )
    assert "only ROS 2 messages can be imported from MCAP; map a ROS 2 topic" in err


def test_a_mapped_topic_without_messages(cli, tmp_path):
    cols = arm3_plant.simulate(duration_s=2.0, seed=1, log_rate_hz=50.0)
    bag = write_bag(tmp_path / "quiet.bag", cols, storage="rosbag1", valve_rows=np.arange(0))
    err = _fail(cli, bag, ROS_MAPPING, tmp_path)
    assert "quiet.bag: topic '/valves' has no messages (record the topic or map another one)" in err


def test_reading_bags_needs_the_ros_extra(bags, tmp_path, monkeypatch):
    real = importlib.util.find_spec
    mapping = tmp_path / "m.toml"
    mapping.write_text(ROS_MAPPING)
    for missing, log in (("rosbags", bags / "ros1.bag"), ("mcap", bags / "bare.mcap")):
        monkeypatch.setattr(
            importlib.util,
            "find_spec",
            lambda name, *a, m=missing: None if name == m else real(name, *a),
        )
        with pytest.raises(
            ConfigError, match=rf"{log.name}: reading ROS bags needs the '{missing}'"
        ):
            convert_log(log, load_mapping(mapping))
        monkeypatch.undo()


def test_stray_files_in_a_bag_folder_are_not_read(cli, bags, tmp_path):
    """A damaged .mcap file and a folder named .mcap next to the bag's own file (not in its
    metadata.yaml): the bag imports, its user metadata read from the files that can be."""
    bag = tmp_path / "bag"
    shutil.copytree(bags / "bag", bag)
    (bag / "stray.mcap").write_bytes(b"\x89MCAP0\r\n cut")
    (bag / "old.mcap").mkdir()
    (tmp_path / "m.toml").write_text(ROS_MAPPING.replace("min_steps = 20", "min_steps = 10"))
    rc, _, err = cli("import", bag, "--mapping", tmp_path / "m.toml", "--dry-run", "--quiet")
    assert rc == 0, err


def test_metadata_of_a_folder_with_a_broken_metadata_yaml_is_empty(tmp_path):
    """The bag reader reports a broken metadata.yaml; the metadata reader only finds none."""
    (tmp_path / "metadata.yaml").write_text("rosbag2_bagfile_information: [\n")
    assert ros_metadata(tmp_path, "rosbag2") == {}


def test_topics_without_a_common_span(bags, tmp_path):
    """/valves only after /joint_states ends: the file is dropped with the reason; a gap
    in /joint_states alone cuts the span that both topics cover into two episodes."""
    cols = arm3_plant.simulate(duration_s=6.0, seed=2, log_rate_hz=50.0)
    n = cols["t_ms"].size
    (tmp_path / "m.toml").write_text(ROS_MAPPING.replace("min_steps = 20", "min_steps = 5"))
    mapping = load_mapping(tmp_path / "m.toml")
    apart = write_bag(
        tmp_path / "apart.bag",
        cols,
        storage="rosbag1",
        joint_rows=np.arange(n // 2 - 10),
        valve_rows=np.arange(n // 2 + 10, n),
    )
    res = convert_log(apart, mapping)
    assert res.episodes == []
    assert [s["reason"] for s in res.entry["segments"]] == [
        "the topics share no gap-free time span"
    ]
    gap = np.r_[0 : n // 3, n // 2 : n]  # /joint_states: no message from 2 s to 3 s
    res = convert_log(
        write_bag(tmp_path / "gap.bag", cols, storage="rosbag1", joint_rows=gap), mapping
    )
    assert [e.name for e in res.episodes] == ["gap_s0", "gap_s1"]
    t_ms = cols["t_ms"]
    spans = [(s["t_start_s"], s["t_end_s"]) for s in res.entry["segments"]]
    assert spans[0][1] <= t_ms[n // 3 - 1] * 1e-3 + 1e-9
    assert spans[1][0] >= t_ms[n // 2] * 1e-3 - 1e-9
    assert any("/joint_states: gap of" in note for note in res.entry["notes"])
