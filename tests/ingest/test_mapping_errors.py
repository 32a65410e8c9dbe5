"""Every malformed mapping: one ConfigError line naming the file, the table/joint and key,
and what to write instead; from the CLI exit code 2 and nothing written."""

from __future__ import annotations

import copy
import tomllib
from pathlib import Path
from typing import Any

import pytest

from excavator_surrogate.errors import ConfigError
from excavator_surrogate.ingest import parse_mapping
from tests.helpers import arm3_plant
from tests.helpers.ingest import assert_nothing_written, write_lines

BASE = tomllib.loads(arm3_plant.MAPPING_TOML)
DROP = object()
"""An edit's value that removes the key."""


def _edited(edits: dict[str, Any]) -> dict[str, Any]:
    """The test arm's mapping with ``edits`` applied: ``{"joints.0.angle.unit": "rad"}``;
    a value of :data:`DROP` removes the key."""
    data = copy.deepcopy(BASE)
    for dotted, value in edits.items():
        *parents, last = dotted.split(".")
        node: Any = data
        for part in parents:
            node = node[int(part)] if isinstance(node, list) else node[part]
        key = int(last) if isinstance(node, list) else last
        if value is DROP:
            del node[key]
        else:
            node[key] = value
    return data


def _refusal(data: dict[str, Any]) -> str:
    with pytest.raises(ConfigError) as e:
        parse_mapping(data, path="m.toml")
    msg = str(e.value)
    assert "\n" not in msg and msg.startswith("m.toml: "), msg
    return msg


ROS_ANGLE = {"topic": "/joint_states", "field": "position[0]", "unit": "deg"}
LINEAR = {"joints.0.angle.unit": "mm", "joints.0.limits": [0.0, 100.0]}

CASES: dict[str, tuple[dict[str, Any], list[str]]] = {
    # the file's tables
    "unknown table": ({"machin": {}}, ["unknown table(s) ['machin']", "valid: ['csv'"]),
    "machine not a table": ({"machine": 3}, ["'machine' must be a table ([machine])"]),
    "import not a table": ({"import": [1]}, ["'import' must be a table ([import])"]),
    "no joints": ({"joints": DROP}, ["no joints; add one [[joints]] table per joint"]),
    "[joints] single table": (
        {"joints": {"name": "boom"}},
        ["'joints' must be a list of tables: write [[joints]] (two brackets)"],
    ),
    "duplicate joint": (
        {"joints.1.name": "boom"},
        ["joint name 'boom' appears twice; joint names must be unique"],
    ),
    "[inputs] single table": (
        {"inputs": {"name": "rpm"}},
        ["'inputs' must be a list of tables ([[inputs]])"],
    ),
    "columns and topics": (
        {"joints.1.angle": ROS_ANGLE},
        ["mixes table columns ('boom_deg') and ROS topics ('/joint_states:position[0]')"],
    ),
    # a joint
    "joint not a table": ({"joints.2": 3}, ["joints[2] must be a table"]),
    "joint without name": ({"joints.0.name": DROP}, ["joints[0]: 'name' is required"]),
    "no angle": (
        {"joints.0.angle": DROP},
        ["joint 'boom': 'angle' table is required, e.g. angle = { column ="],
    ),
    "no command": ({"joints.0.command": DROP}, ["joint 'boom': 'command' table is required"]),
    "velocity not a table": (
        {"joints.0.velocity": "boom_rate"},
        ["joint 'boom': 'velocity' must be a table { column = ..., unit = ... }"],
    ),
    "angle without unit": (
        {"joints.0.angle.unit": DROP},
        ['joint \'boom\': angle.unit (or position.unit) is required: one of "deg", "rad"'],
    ),
    "velocity without unit": (
        {"joints.0.velocity": {"column": "boom_rate"}},
        ['joint \'boom\': velocity.unit is required: "deg/s" or "rad/s"'],
    ),
    "stroke velocity without unit": (
        {**LINEAR, "joints.0.velocity": {"column": "boom_rate"}},
        ["joint 'boom': velocity.unit is required: m/s, cm/s or mm/s"],
    ),
    "limits reversed": (
        {"joints.0.limits": [60.0, -40.0]},
        ["joint 'boom': limits [60.0, -40.0] must be [low, high] with high > low"],
    ),
    # a channel
    "column and topic": (
        {"joints.0.angle.topic": "/js"},
        ["joint 'boom': angle: give either column (CSV/Parquet) or topic + field (ROS)"],
    ),
    "topic without field": (
        {"joints.0.angle": {"topic": "/js", "unit": "deg"}},
        ["joint 'boom': angle: topic '/js' needs field, e.g. field = \"position[0]\""],
    ),
    "no channel": (
        {"joints.0.angle": {"unit": "deg"}},
        ["joint 'boom': angle: column (CSV/Parquet) or topic + field (ROS) is required"],
    ),
    "field with column": (
        {"joints.0.angle.field": "x"},
        ["joint 'boom': angle: field is only used with topic; for tables use column"],
    ),
    # a command
    "up without down": (
        {"joints.0.command.down": DROP},
        ["joint 'boom': command: two-channel commands need both up and down"],
    ),
    "up, down and column": (
        {"joints.0.command.column": "boom_cmd"},
        ["joint 'boom': command: give either up + down or one signed column/field"],
    ),
    "command without unit": (
        {"joints.0.command.unit": DROP},
        ['joint \'boom\': command: unit is required: "%", "raw" or "physical"'],
    ),
    "range reversed": (
        {"joints.0.command.range": [1.0, -1.0]},
        ["joint 'boom': command: range [1.0, -1.0] must be [u_min, u_max] with u_max > u_min"],
    ),
    "raw_range empty": (
        {"joints.0.command.unit": "raw", "joints.0.command.raw_range": [5.0, 5.0]},
        ["joint 'boom': command: raw_range [5.0, 5.0] must be [low, high] with high > low"],
    ),
    "raw_range without raw": (
        {"joints.0.command.raw_range": [0.0, 5.0]},
        ["joint 'boom': command: raw_range is only used with unit = \"raw\""],
    ),
    "scale 0": ({"joints.0.command.scale": 0.0}, ["joint 'boom': command: scale must not be 0"]),
    # an input
    "input without name": (
        {"inputs": [{"column": "rpm"}]},
        ["inputs[0] must be a table with a name"],
    ),
    "input without range": (
        {"inputs": [{"name": "rpm", "column": "rpm", "unit": "physical"}]},
        ["input 'rpm': range = [lo, hi] is required"],
    ),
    "input scale 0": (
        {"inputs": [{"name": "rpm", "column": "rpm", "unit": "%", "range": [0, 1], "scale": 0}]},
        ["input 'rpm': scale must not be 0"],
    ),
    # a linear joint's linkage
    "linkage not a table": ({**LINEAR, "joints.0.linkage": 3}, ["linkage must be a table { a ="]),
    "linkage text": (
        {**LINEAR, "joints.0.linkage": {"a": "1200", "b": 3400}},
        ["joint 'boom': linkage.a must be a finite number, got '1200'"],
    ),
    "linkage true": (
        {**LINEAR, "joints.0.linkage": {"a": 1200, "b": True}},
        ["joint 'boom': linkage.b must be a finite number, got True"],
    ),
    "linkage nan": (
        {**LINEAR, "joints.0.linkage": {"a": 1200, "b": 3400, "phi": float("nan")}},
        ["joint 'boom': linkage.phi must be a finite number, got nan"],
    ),
    "linkage negative": (
        {**LINEAR, "joints.0.linkage": {"a": -1200, "b": 3400}},
        ["joint 'boom': linkage a = -1200 and b = 3400 must be positive", "(lengths in mm)"],
    ),
    "linkage beyond the limits": (  # 2200 .. 4600 mm: not the limits' 0 .. 100 mm
        {**LINEAR, "joints.0.linkage": {"a": 1200, "b": 3400}},
        [
            "joint 'boom': the linkage reaches strokes 2200 .. 4600 mm only",
            "not the limits 0 .. 100 mm: check a, b and l0 (in mm, the position's unit)",
        ],
    ),
    "linkage l0 negative": (
        {**LINEAR, "joints.0.linkage": {"a": 1200, "b": 3400, "l0": -5}},
        ["l0 = -5 >= 0 (lengths in mm)"],
    ),
    # the option tables, named as the table key and the CLI flag that set them
    "rate_hz": ({"import.rate_hz": 0.0}, ["[import] rate_hz (--rate) must be positive"]),
    "max_upsample": ({"import.max_upsample": 0.5}, ["[import] max_upsample (--max-upsample)"]),
    "max_memory_mb": ({"import.max_memory_mb": 0.0}, ["[import] max_memory_mb (--max-memory)"]),
    "max_fill": ({"import.max_fill": -1}, ["[import] max_fill (--max-fill) must be >= 0, got -1"]),
    "max_gap_s": ({"import.max_gap_s": 0.0}, ["[import] max_gap_s (--max-gap) must be positive"]),
    "min_steps": ({"import.min_steps": 1}, ["[import] min_steps (--min-steps) must be >= 2"]),
    "lowpass": ({"import.lowpass": 1.0}, ["[import] lowpass (--lowpass) must be in [0, 1)"]),
    "seed": ({"split.seed": -1}, ["[split] seed (--seed) must be >= 0, got -1"]),
    "fractions": (
        {"split.fractions": [0.5, 0.5, 0.5]},
        ["[split] fractions (--fractions) [0.5, 0.5, 0.5] must be >= 0 and sum to 1"],
    ),
    "negative fraction": ({"split.fractions": [1.5, -0.5, 0.0]}, ["must be >= 0 and sum to 1"]),
}


@pytest.mark.parametrize(("edits", "needles"), list(CASES.values()), ids=list(CASES))
def test_a_bad_mapping_is_one_line(edits: dict[str, Any], needles: list[str]) -> None:
    msg = _refusal(_edited(edits))
    for needle in needles:
        assert needle in msg, msg


def test_the_edits_are_the_only_fault() -> None:
    """The unedited mapping and the linear one parse: each case fails for its own edit."""
    parse_mapping(_edited({}), path="m.toml")
    link = {"a": 1200, "b": 3400, "l0": 2200}  # reaches strokes 0 .. 2400 mm: the limits
    m = parse_mapping(_edited({**LINEAR, "joints.0.linkage": link}))
    assert m.joints[0].linear


def test_invalid_toml_names_the_file(cli, work: Path, short_cols) -> None:
    log = write_lines(work / "a.csv", short_cols)
    bad = work / "bad.toml"
    bad.write_text(arm3_plant.MAPPING_TOML.replace('name = "arm3"', 'name = "arm3'))
    out = work / "ds"
    rc, _, err = cli("import", log, "--mapping", bad, "--out", out)
    assert rc == 2 and err.count("\n") == 1, err
    assert f"exsur: error: {bad}: invalid TOML (" in err
    assert_nothing_written(out)
    bad.write_bytes(b"\xff\xfe[machine]\n")  # not UTF-8 text
    rc, _, err = cli("import", log, "--mapping", bad, "--out", out)
    assert rc == 2 and f"{bad}: invalid TOML (" in err and err.count("\n") == 1, err


@pytest.mark.parametrize(
    ("flag", "needle"),
    [
        (["--max-fill", "-1"], "[import] max_fill (--max-fill) must be >= 0, got -1"),
        (["--rate", "0"], "[import] rate_hz (--rate) must be positive and finite, got 0"),
        (["--min-steps", "1"], "[import] min_steps (--min-steps) must be >= 2, got 1"),
        (["--lowpass", "1"], "[import] lowpass (--lowpass) must be in [0, 1)"),
        (["--max-gap", "0"], "[import] max_gap_s (--max-gap) must be positive"),
        (["--max-upsample", "0.5"], "[import] max_upsample (--max-upsample) must be >= 1"),
        (["--max-memory", "0"], "[import] max_memory_mb (--max-memory) must be positive"),
        (["--fractions", "1,1,1"], "[split] fractions (--fractions) [1.0, 1.0, 1.0] must be"),
    ],
)
def test_a_bad_option_flag_names_the_flag(cli, work: Path, short_cols, flag, needle) -> None:
    log = write_lines(work / "a.csv", short_cols)
    out = work / "ds"
    rc, _, err = cli("import", log, "--mapping", work / "arm3.toml", "--out", out, *flag)
    assert rc == 2 and err.startswith("exsur: error: ") and err.count("\n") == 1, err
    assert needle in err
    assert_nothing_written(out)
