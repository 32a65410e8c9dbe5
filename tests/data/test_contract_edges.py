"""The episode contract's rarer rejections: metadata that lies, nulls, partial optional
columns, corrupt data pages, malformed manifests; each one line naming the file, the
column or row, and the fix."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from excavator_surrogate.cli import main
from excavator_surrogate.data import (
    load_dataset,
    read_episode,
    validate_episode,
    write_dataset,
    write_episode,
)
from excavator_surrogate.errors import DataError
from excavator_surrogate.spec import MachineSpec, excavator_spec
from tests.data.test_contract import _set, _write_table, make_episode


def _with_meta(table: pa.Table, **changes: object) -> pa.Table:
    meta = json.loads(table.schema.metadata[b"exsur"])
    meta.update(changes)
    return table.replace_schema_metadata({b"exsur": json.dumps(meta).encode()})


def _null_at(table: pa.Table, col: str, row: int, *, nan_at: int | None = None) -> pa.Table:
    values: list[object] = table.column(col).to_pylist()
    values[row] = None
    if nan_at is not None:
        values[nan_at] = float("nan")
    return table.set_column(table.column_names.index(col), col, pa.array(values))


CASES = {
    "metadata not JSON": (
        lambda t: t.replace_schema_metadata({b"exsur": b"{not json"}),
        "",
        "not valid JSON",
        "re-write the episode",
    ),
    "metadata a JSON string": (
        lambda t: t.replace_schema_metadata({b"exsur": b'"just a string"'}),
        "",
        "the 'exsur' metadata is a JSON string, not an object",
        "re-write the episode",
    ),
    "metadata a JSON array": (
        lambda t: t.replace_schema_metadata({b"exsur": b"[1, 2]"}),
        "",
        "the 'exsur' metadata is a JSON array, not an object",
        "re-write the episode",
    ),
    "schema_version": (
        lambda t: _with_meta(t, schema_version=99),
        "",
        "schema_version 99 is not supported",
        "re-create the dataset",
    ),
    "spec malformed": (
        lambda t: _with_meta(t, spec={"rate_hz": 20.0}),
        "",
        "metadata 'spec' is malformed",
        "re-write the episode",
    ),
    "spec rate not a number": (
        lambda t: _with_meta(t, spec={**excavator_spec().to_dict(), "rate_hz": "fast"}),
        "",
        "metadata 'spec' is malformed",
        "re-write the episode",
    ),
    "rate_hz disagrees": (
        lambda t: _with_meta(t, rate_hz=10.0),
        "",
        "rate_hz 10.0 disagrees with the spec's 20.0",
        "re-write the episode",
    ),
    "rate_hz missing": (
        lambda t: _with_meta(t, rate_hz=None),
        "",
        "rate_hz None disagrees",
        "re-write the episode",
    ),
    "null in a float column": (
        # the NaN before the null is not the null: the row is the null's
        lambda t: _null_at(t, "omega_boom", 10, nan_at=3),
        "column 'omega_boom', row 10",
        "contains a null value",
        "fill or drop the gap",
    ),
    "null in an integer column": (
        lambda t: _null_at(
            t.set_column(1, "u_swing", pa.array(np.zeros(50, np.int64))), "u_swing", 7
        ),
        "column 'u_swing', row 7",
        "contains a null value",
        "fill or drop the gap",
    ),
    "NaN time": (
        lambda t: _set(t, "time", np.r_[np.arange(7) * 0.05, np.nan, np.arange(8, 50) * 0.05]),
        "column 'time', row 7",
        "non-finite time",
        "drop rows with missing timestamps",
    ),
    "partial ground truth": (
        lambda t: t.drop(["omega_arm_true"]),
        "column 'omega_arm_true'",
        "'omega_true' columns must be given for every joint",
        "drop all omega_*_true columns",
    ),
    "partial trusted flags": (
        lambda t: t.drop(["trusted_bucket"]),
        "column 'trusted_bucket'",
        "trusted flags must be given for every joint",
        "drop all trusted_* columns",
    ),
    "trusted as text": (
        lambda t: _set(t, "trusted_arm", ["x"] * 50),
        "column 'trusted_arm'",
        "not bool",
        "store true/false",
    ),
    "trusted with a null": (
        lambda t: _null_at(t, "trusted_arm", 12),
        "column 'trusted_arm', row 12",
        "contains a null value",
        "store true/false",
    ),
    "trusted neither 0 nor 1": (
        lambda t: _set(t, "trusted_boom", np.r_[np.ones(4, np.int8), 2, np.ones(45, np.int8)]),
        "column 'trusted_boom', row 4",
        "flag 2 is not true/false",
        "store true/false",
    ),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_reader_rejects(tmp_path: Path, case: str, capsys: pytest.CaptureFixture[str]) -> None:
    mutate, where, what, fix = CASES[case]
    path = _write_table(tmp_path / "ep.parquet", make_episode(), mutate)
    with pytest.raises(DataError) as err:
        read_episode(path)
    msg = str(err.value)
    assert "\n" not in msg and msg.startswith(str(path))
    assert where in msg and what in msg and fix in msg, msg
    assert main(["validate", str(path)]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("exsur: error:") and what in lines[0]


def test_trusted_flags_stored_as_integers_are_read(tmp_path: Path) -> None:
    ep = make_episode()
    flags = np.ones(50, np.int8)
    flags[5] = 0
    path = _write_table(tmp_path / "ep.parquet", ep, lambda t: _set(t, "trusted_arm", flags))
    back = read_episode(path)
    assert back.trusted is not None and back.trusted.dtype == bool
    assert back.trusted[:, 2].tolist() == (flags == 1).tolist()


def test_joints_of_another_machine(tmp_path: Path) -> None:
    path = write_episode(tmp_path / "ep.parquet", make_episode())
    other = MachineSpec(joints=excavator_spec().joints[:3], rate_hz=20.0)
    with pytest.raises(
        DataError, match=r"ep\.parquet: the episode is of another machine \(joi"
    ) as e:
        read_episode(path, spec=other)
    assert "use data recorded for the same machine" in str(e.value)


def test_commands_of_another_scale_are_another_machine(tmp_path: Path) -> None:
    """Same joint names, commands in [-1, 1]: not the expected machine (only the names were
    compared, and the episode was read)."""
    path = write_episode(tmp_path / "ep.parquet", make_episode())
    joints = tuple(replace(j, u_min=-1.0, u_max=1.0) for j in excavator_spec().joints)
    unit_range = MachineSpec(joints=joints, rate_hz=20.0)
    with pytest.raises(DataError) as e:
        read_episode(path, spec=unit_range)
    assert str(e.value).startswith(
        f"{path}: the episode is of another machine (joint 'swing' command range [-1, 1] vs "
        "[-1000, 1000], expected vs episode)"
    )
    with pytest.raises(DataError, match=r"rate 10 Hz vs 20 Hz, expected vs episode"):
        read_episode(path, spec=excavator_spec(10.0))


def test_corrupt_data_pages_behind_a_valid_footer(tmp_path: Path) -> None:
    path = write_episode(tmp_path / "ep.parquet", make_episode())
    chunk = pq.ParquetFile(path).metadata.row_group(0).column(0)  # the 'time' column
    start = chunk.dictionary_page_offset or chunk.data_page_offset
    raw = bytearray(path.read_bytes())
    raw[start : start + chunk.total_compressed_size] = bytes(chunk.total_compressed_size)
    path.write_bytes(bytes(raw))
    pq.read_schema(path)  # the footer still reads
    with pytest.raises(DataError, match="cannot read Parquet data") as e:
        read_episode(path)
    msg = str(e.value)
    assert "\n" not in msg and msg.startswith(str(path)) and "the file is corrupt" in msg


def test_metadata_of_numpy_types_and_paths_is_written_as_plain_json(tmp_path: Path) -> None:
    ep = make_episode().replace(
        generator={"seed": np.int64(3), "gain": np.float32(0.5), "lags": np.arange(3)},
        extra={"source_file": tmp_path / "log.csv"},
    )
    back = read_episode(write_episode(tmp_path / "ep.parquet", ep))
    assert back.generator == {"seed": 3, "gain": 0.5, "lags": [0, 1, 2]}
    assert back.extra == {"source_file": str(tmp_path / "log.csv")}
    with pytest.raises(TypeError, match="not JSON serialisable: object"):
        write_episode(tmp_path / "bad.parquet", ep.replace(extra={"x": object()}))
    assert not (tmp_path / "bad.parquet").exists()


def test_in_memory_shapes(tmp_path: Path) -> None:
    ep = make_episode()
    with pytest.raises(DataError, match=r"<memory>, column 'time': time must be 1-D") as e:
        validate_episode(ep.replace(time=ep.time[:, None]))
    assert "one timestamp per sample" in str(e.value)
    with pytest.raises(
        DataError, match=r"x\.parquet, column 'u_swing': 'u' has shape \(50, 3\)"
    ) as e:
        write_episode(tmp_path / "x.parquet", ep.replace(u=ep.u[:, :3]))
    assert "one column per command of the spec" in str(e.value)
    with pytest.raises(
        DataError, match=r"column 'trusted_swing': 'trusted' has shape \(49, 4\)"
    ) as e:
        validate_episode(ep.replace(trusted=ep.trusted[1:]))
    assert "one column per joint of the spec" in str(e.value)
    assert list(tmp_path.iterdir()) == []


def test_write_dataset_refusals_leave_nothing(tmp_path: Path) -> None:
    out = tmp_path / "ds"
    with pytest.raises(DataError, match=r"ds: no episodes to write \(check the generator"):
        write_dataset(out, [])
    with pytest.raises(DataError, match=r"unknown split 'dev' for episode b \(use one of"):
        write_dataset(out, [(make_episode(name="a"), "train"), (make_episode(name="b"), "dev")])
    ten_hz = make_episode(excavator_spec(10.0), name="b")
    with pytest.raises(DataError, match=r"episode b is of another machine than episode a \(rate"):
        write_dataset(out, [(make_episode(name="a"), "train"), (ten_hz, "val")])
    a = make_episode(name="a")
    unit_range = replace(a.spec, joints=tuple(replace(j, u_min=-1.0) for j in a.spec.joints))
    with pytest.raises(
        DataError,
        match=r"episode b is of another machine than episode a \(joint 'swing' command range "
        r"\[-1000, 1000\] vs \[-1, 1000\]\) \(write one dataset per machine, rate and command",
    ):
        write_dataset(out, [(a, "train"), (make_episode(unit_range, name="b"), "val")])
    with pytest.raises(DataError, match="duplicate episode name 'a' .give episodes unique names"):
        write_dataset(out, [(make_episode(name="a"), "train"), (make_episode(name="a"), "val")])
    assert list(tmp_path.iterdir()) == []


def _dataset(tmp_path: Path) -> Path:
    return write_dataset(
        tmp_path / "ds", [(make_episode(name="a"), "train"), (make_episode(name="b"), "test")]
    )


def _edit_manifest(ds: Path, edit) -> Path:
    mpath = ds / "manifest.json"
    m = json.loads(mpath.read_text())
    mpath.write_text(json.dumps(edit(m)))
    return mpath


MANIFEST_CASES = {
    "not a dict": (lambda m: [m], "no 'episodes' list"),
    "no episodes": (lambda m: {**m, "episodes": "a.parquet"}, "no 'episodes' list"),
    "entry without file": (
        lambda m: {**m, "episodes": [{"split": "train"}]},
        "episode entry 0 needs 'file' and 'split'",
    ),
    "file not a string": (
        lambda m: {**m, "episodes": [m["episodes"][0], {"file": 3, "split": "test"}]},
        "episode entry 1 needs 'file' and 'split'",
    ),
    "unknown split": (
        lambda m: {**m, "episodes": [{**m["episodes"][0], "split": "dev"}]},
        "episode entry 0 needs 'file' and 'split' in ('train', 'val', 'test')",
    ),
    "spec malformed": (lambda m: {**m, "spec": {"joints": "abc"}}, "'spec' is malformed"),
    "no spec, no episodes": (
        lambda m: {k: v for k, v in m.items() if k != "spec"} | {"episodes": []},
        "dataset has no episodes and no spec",
    ),
}


@pytest.mark.parametrize("case", sorted(MANIFEST_CASES))
def test_malformed_manifest(tmp_path: Path, case: str, capsys: pytest.CaptureFixture[str]) -> None:
    edit, what = MANIFEST_CASES[case]
    mpath = _edit_manifest(_dataset(tmp_path), edit)
    with pytest.raises(DataError) as e:
        load_dataset(mpath.parent)
    msg = str(e.value)
    assert "\n" not in msg and msg.startswith(f"{mpath}: ") and what in msg, msg
    assert "regenerate" in msg or "fix or regenerate the manifest" in msg
    assert main(["validate", str(mpath.parent)]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and what in lines[0]


def test_missing_manifest_and_an_old_manifest_without_spec(tmp_path: Path) -> None:
    ds = _dataset(tmp_path)
    _edit_manifest(ds, lambda m: {k: v for k, v in m.items() if k != "spec"})
    loaded = load_dataset(ds)  # the spec comes from the first episode read
    assert loaded.spec == excavator_spec() and len(loaded.train) == len(loaded.test) == 1
    (ds / "manifest.json").unlink()
    with pytest.raises(DataError, match=r"ds/manifest.json: manifest.json is missing \(a dataset"):
        load_dataset(ds)
