"""Per-run constant inputs (``[[inputs]]`` with ``from_name`` / ``from_metadata``): what the
user knows about a run (a load condition in the file name, a header property) becomes a
constant ``u_<name>`` column, validated like every other input."""

from __future__ import annotations

import tomllib
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from excavator_surrogate.data import load_dataset
from excavator_surrogate.errors import ConfigError, DataError
from excavator_surrogate.ingest import convert_log, parse_mapping
from tests.helpers import arm3_plant
from tests.helpers.ingest import assert_nothing_written

CONDITION = """
[[inputs]]
name = "condition"
from_name = '-(?P<value>[HL])$'
values = { H = 1.0, L = 0.0 }
"""


def _mapping(tmp_path: Path, extra: str, base: str = arm3_plant.MAPPING_TOML):
    text = base + extra
    (tmp_path / "m.toml").write_text(text)
    return parse_mapping(tomllib.loads(text), path=tmp_path / "m.toml")


def _log(folder: Path, name: str, cols: dict[str, np.ndarray]) -> Path:
    return arm3_plant.write_csv(folder / "logs" / name, cols)


def test_condition_from_the_file_name(cli, tmp_path, short_cols):
    """run-H / run-L: u_condition is 1 / 0 on every sample, range [0, 1] from values; the
    joints' columns are those of the mapping without the input."""
    (tmp_path / "m.toml").write_text(arm3_plant.MAPPING_TOML + CONDITION)
    for k, name in enumerate(("a-H.csv", "b-L.csv", "c-H.csv", "d-L.csv")):
        _log(tmp_path, name, arm3_plant.simulate(duration_s=10.0, seed=k))
    out = tmp_path / "ds"
    rc, _, err = cli("import", tmp_path / "logs", "--mapping", tmp_path / "m.toml", "--out", out)
    assert rc == 0, err
    ds = load_dataset(out)
    (spec_in,) = ds.spec.inputs
    assert (spec_in.name, spec_in.u_min, spec_in.u_max, spec_in.unit) == (
        "condition",
        0.0,
        1.0,
        "level",
    )
    episodes = ds.train + ds.val + ds.test
    assert len(episodes) == 4
    for ep in episodes:
        assert ep.u.shape[1] == 4
        want = 1.0 if ep.name.endswith("-H") else 0.0
        assert np.all(ep.u[:, 3] == want), ep.name
        assert ep.extra["import"]["run_inputs"]["condition"]["value"] == want
    # the joints' commands are unchanged by the input
    plain = convert_log(
        tmp_path / "logs" / "a-H.csv", parse_mapping(tomllib.loads(arm3_plant.MAPPING_TOML))
    )
    with_input = convert_log(tmp_path / "logs" / "a-H.csv", _mapping(tmp_path, CONDITION))
    np.testing.assert_allclose(with_input.episodes[0].u[:, :3], plain.episodes[0].u, atol=1e-9)
    assert "run_inputs" not in plain.episodes[0].extra["import"]


def test_numeric_capture_and_default(tmp_path, short_cols):
    """A numeric capture is the value (inside its declared range); a name that does not
    match takes the default."""
    extra = """
[[inputs]]
name = "payload"
from_name = 'p(\\d+)kg'
range = [0.0, 2000.0]
physical_unit = "kg"
default = 0.0
"""
    m = _mapping(tmp_path, extra)
    assert m.spec().inputs[0].unit == "kg"
    ep = convert_log(_log(tmp_path, "run_p750kg.csv", short_cols), m).episodes[0]
    assert np.all(ep.u[:, 3] == 750.0)
    res = convert_log(_log(tmp_path, "run_empty.csv", short_cols), m)
    assert np.all(res.episodes[0].u[:, 3] == 0.0)
    assert res.entry["run_inputs"]["payload"]["from"] == "default"


@pytest.mark.parametrize(
    ("extra", "name", "needle"),
    [
        (CONDITION, "run.csv", "does not match"),  # no match, no default
        (CONDITION.replace("[HL]", "[A-Z]"), "run-X.csv", "'X' (name) is not one of ['H', 'L']"),
        (
            "[[inputs]]\nname = 'load'\nfrom_name = '_(?P<value>[a-z]+)$'\nrange = [0.0, 1.0]\n",
            "run_heavy.csv",
            "'heavy' (name) is not a number",
        ),
        (
            "[[inputs]]\nname = 'load'\nfrom_name = '_(\\d+)$'\nrange = [0.0, 100.0]\n",
            "run_250.csv",
            "250 (name '250') is outside range [0.0, 100.0]",
        ),
        (
            "[[inputs]]\nname = 'load'\nfrom_metadata = 'Test/Load'\nrange = [0.0, 1.0]\n",
            "run.csv",
            "no metadata key 'Test/Load' (it carries no metadata)",
        ),
    ],
)
def test_run_value_errors(cli, tmp_path, short_cols, extra, name, needle):
    """Each problem is one line naming the file and the fix; nothing is written."""
    log = _log(tmp_path, name, short_cols)
    with pytest.raises(DataError) as e:
        convert_log(log, _mapping(tmp_path, extra))
    msg = str(e.value)
    assert "\n" not in msg and str(log) in msg and needle in msg, msg
    out = tmp_path / "ds"
    rc, _, err = cli("import", log, "--mapping", tmp_path / "m.toml", "--out", out)
    assert rc == 2 and err.startswith("exsur: error: ") and err.count("\n") == 1, err
    assert needle in err
    assert_nothing_written(out)


def test_no_match_names_the_default_fix(tmp_path, short_cols):
    log = _log(tmp_path, "run.csv", short_cols)
    with pytest.raises(DataError, match=r"set default = \.\.\. to allow a fallback"):
        convert_log(log, _mapping(tmp_path, CONDITION))


def test_the_source_is_named_as_the_mapping_writes_it():
    from excavator_surrogate.ingest.run_inputs import RunInputMap

    assert RunInputMap(from_name="-(H)$").source == "from_name = '-(H)$'"
    assert RunInputMap(from_metadata="Test/Load").source == "from_metadata = 'Test/Load'"


@pytest.mark.parametrize(
    ("extra", "needle"),
    [
        (
            CONDITION.replace('"condition"', '"boom"'),
            "input 'boom': the name is already used by a joint",
        ),
        (CONDITION + CONDITION, "input 'condition': the name is already used by another input"),
        (
            CONDITION + "[[inputs]]\nname = 'condition'\ncolumn = 'boom_deg'\nunit = 'physical'\n"
            "range = [0.0, 1.0]\n",
            "already used by another input",
        ),
        (
            CONDITION.replace("values", "from_metadata = 'x'\nvalues"),
            "either from_name or from_metadata",
        ),
        (CONDITION.replace("[HL])$", "[HL]$"), "from_name is not a valid regex"),
        (CONDITION.replace("(?P<value>[HL])", "([HL])([SC])"), "name the one that holds the value"),
        (CONDITION.replace("values =", "valeus ="), "unknown key(s) ['valeus']"),
        ("[[inputs]]\nname = 'x'\nfrom_name = '(\\d+)'\n", "range = [lo, hi] is required"),
        (CONDITION.replace("L = 0.0", "L = 'low'"), "values.L must be a finite number"),
        (CONDITION.replace("}", "}\nrange = [0.5, 1.0]"), "values.L is outside range [0.5, 1.0]"),
        (CONDITION.replace("}", "}\ndefault = 2.0"), "default 2 is outside range [0.0, 1.0]"),
        (CONDITION.replace("L = 0.0", "L = 1.0"), "values all map to 1; add range"),
        (CONDITION.replace("'-(?P<value>[HL])$'", "''"), "from_name must be a regex string"),
        (
            CONDITION.replace("from_name = '-(?P<value>[HL])$'", "from_metadata = ' '"),
            'from_metadata must be a key, e.g. "Engine/Mode"',
        ),
        (CONDITION.replace("}", "}\ndefault = 'H'"), "default must be a number, got 'H'"),
        (CONDITION.replace("}", "}\nphysical_unit = ''"), "physical_unit must be a unit name"),
        (
            CONDITION.replace("{ H = 1.0, L = 0.0 }", "{}"),
            "values must be a table of text -> number",
        ),
        (
            CONDITION.replace("}", "}\nrange = [1.0]"),
            "range must be [lo, hi] with hi > lo, got [1.0]",
        ),
    ],
)
def test_mapping_errors(tmp_path, extra, needle):
    """A bad per-run input is one ConfigError line naming the mapping and the input."""
    with pytest.raises(ConfigError) as e:
        _mapping(tmp_path, extra)
    msg = str(e.value)
    assert "\n" not in msg and "m.toml" in msg and needle in msg, msg


# --------------------------------------------------------------------------------------
# metadata: Parquet key-value metadata, dSPACE descriptions rows, MDF4 header, rosbag2


def _metadata_input(key: str) -> str:
    return f"""
[[inputs]]
name = "condition"
from_metadata = "{key}"
values = {{ heavy = 1.0, light = 0.0 }}
"""


def test_from_parquet_metadata(tmp_path, short_cols):
    table = pa.table({c: short_cols[c] for c in arm3_plant.LOG_COLUMNS})
    path = tmp_path / "run.parquet"
    pq.write_table(table.replace_schema_metadata({"Test/Load": "heavy"}), path)
    ep = convert_log(path, _mapping(tmp_path, _metadata_input("Test/Load"))).episodes[0]
    assert np.all(ep.u[:, 3] == 1.0)
    with pytest.raises(DataError, match=r"no metadata key 'Load' \(its keys: Test/Load\)"):
        convert_log(path, _mapping(tmp_path, _metadata_input("Load")))


def test_from_dspace_descriptions(tmp_path, short_cols):
    from tests.ingest.test_ingest_dspace import dspace_mapping_toml, dspace_traces, write_dspace

    log = write_dspace(tmp_path / "run.dspace.csv", dspace_traces(short_cols))
    extra = _metadata_input("General/User").replace("heavy", "tester")
    ep = convert_log(log, _mapping(tmp_path, extra, dspace_mapping_toml())).episodes[0]
    assert np.all(ep.u[:, 3] == 1.0)
    with pytest.raises(DataError, match="value 'tester' \\(metadata\\) is not one of"):
        convert_log(log, _mapping(tmp_path, _metadata_input("General/User"), dspace_mapping_toml()))


def test_from_mdf_header(tmp_path, short_cols):
    asammdf = pytest.importorskip("asammdf")
    from tests.ingest.test_ingest_mdf import MAPPING

    names = [c for c in arm3_plant.LOG_COLUMNS if c != "t_ms"]
    t = short_cols["t_ms"] * 1e-3
    mdf = asammdf.MDF(version="4.10")
    mdf.append([asammdf.Signal(short_cols[n], t, name=n) for n in names])
    mdf.header.comment = (
        "<HDcomment><TX>step test</TX><common_properties>"
        '<tree name="Test"><e name="Load">light</e></tree>'
        "</common_properties></HDcomment>"
    )
    path = tmp_path / "run.mf4"
    mdf.save(path, overwrite=True)
    mdf.close()
    ep = convert_log(path, _mapping(tmp_path, _metadata_input("Test/Load"), MAPPING)).episodes[0]
    assert np.all(ep.u[:, 3] == 0.0)


def test_from_rosbag2_custom_data(tmp_path):
    pytest.importorskip("rosbags")
    from ruamel.yaml import YAML

    from tests.ingest.test_ingest_ros_resample import ROS_MAPPING, _write_bag

    cols = arm3_plant.simulate(duration_s=5.0, seed=5, log_rate_hz=50.0)
    bag = tmp_path / "bag"
    _write_bag(bag, cols, storage="sqlite3")
    # what `ros2 bag record --custom-data Test/Load=heavy` (ROS 2 Iron and later) writes
    yaml = YAML()
    doc = yaml.load((bag / "metadata.yaml").read_text())
    doc["rosbag2_bagfile_information"]["custom_data"] = {"Test/Load": "heavy"}
    with open(bag / "metadata.yaml", "w") as f:
        yaml.dump(doc, f)
    ep = convert_log(bag, _mapping(tmp_path, _metadata_input("Test/Load"), ROS_MAPPING)).episodes[0]
    assert np.all(ep.u[:, 3] == 1.0)


def test_a_bare_mcap_keeps_its_custom_data(tmp_path):
    """rosbag2's MCAP storage copies ``metadata.yaml`` into the file: an ``.mcap`` copied out
    of its bag folder still gives its ``custom_data`` keys, and not the copy itself."""
    pytest.importorskip("rosbags")
    import shutil

    from excavator_surrogate.ingest.inventory import summarize_log
    from tests.helpers.ros_bags import write_bag
    from tests.ingest.test_ingest_ros_resample import ROS_MAPPING

    cols = arm3_plant.simulate(duration_s=5.0, seed=5, log_rate_hz=50.0)
    bag = write_bag(tmp_path / "bag", cols, storage="mcap", custom_data={"Test/Load": "heavy"})
    bare = tmp_path / "run.mcap"
    shutil.copy(next(bag.glob("*.mcap")), bare)
    for log in (bag, bare):
        meta = summarize_log(log).meta
        assert meta.get("Test/Load") == "heavy", (log, meta)
        assert not any("serialized_metadata" in k for k in meta)
    mapping = _mapping(tmp_path, _metadata_input("Test/Load"), ROS_MAPPING)
    assert np.all(convert_log(bare, mapping).episodes[0].u[:, 3] == 1.0)
