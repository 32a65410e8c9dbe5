"""The episode data contract: round trip, and each malformed file rejected with a one-line error."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from excavator_surrogate.cli import main
from excavator_surrogate.data import (
    Episode,
    columns_for,
    load_dataset,
    read_episode,
    write_dataset,
    write_episode,
)
from excavator_surrogate.errors import DataError
from excavator_surrogate.spec import EXCAVATOR, JointSpec, MachineSpec


def make_episode(spec: MachineSpec = EXCAVATOR, n: int = 50, *, name: str = "ep") -> Episode:
    rng = np.random.default_rng(0)
    t = np.arange(n) * spec.dt
    u = rng.uniform(-1000, 1000, (n, spec.n_joint))
    omega = rng.normal(size=(n, spec.n_joint)) * 0.1
    theta = np.cumsum(omega, axis=0) * spec.dt
    return Episode(
        spec=spec,
        time=t,
        u=u,
        theta=theta,
        omega=omega,
        theta_true=theta.copy(),
        omega_true=omega.copy(),
        trusted=np.ones((n, spec.n_joint), bool),
        source="test",
        condition="noload",
        seed=7,
        generator={"kind": "unit"},
        name=name,
    )


def test_roundtrip_exact(tmp_path: Path) -> None:
    ep = make_episode()
    write_episode(tmp_path / "ep.parquet", ep)
    back = read_episode(tmp_path / "ep.parquet")
    for role in ("time", "u", "theta", "omega", "theta_true", "omega_true", "trusted"):
        np.testing.assert_array_equal(getattr(back, role), getattr(ep, role))
    assert back.spec == ep.spec
    assert (back.source, back.condition, back.seed, back.generator) == (
        "test",
        "noload",
        7,
        {"kind": "unit"},
    )


def test_independent_reader_sees_columns_and_metadata(tmp_path: Path) -> None:
    write_episode(tmp_path / "ep.parquet", make_episode())
    table = pq.read_table(tmp_path / "ep.parquet")
    for j in ("swing", "boom", "arm", "bucket"):
        for c in (f"u_{j}", f"theta_{j}", f"omega_{j}", f"theta_{j}_true", f"trusted_{j}"):
            assert c in table.column_names
    meta = json.loads(table.schema.metadata[b"exsur"])
    assert meta["schema_version"] == 1 and meta["rate_hz"] == 20.0
    assert [j["name"] for j in meta["spec"]["joints"]] == ["swing", "boom", "arm", "bucket"]
    assert meta["units"]["theta"] == "rad"


def test_any_joint_count(tmp_path: Path) -> None:
    spec = MachineSpec(
        joints=tuple(JointSpec(f"j{i}", periodic=i == 0) for i in range(6)), rate_hz=50.0
    )
    ep = make_episode(spec)
    write_episode(tmp_path / "six.parquet", ep)
    assert read_episode(tmp_path / "six.parquet").spec.n_joint == 6
    assert spec.n_feature == 7 + 6


def _write_table(path: Path, ep: Episode, mutate) -> Path:
    table = ep.to_table()
    meta = table.schema.metadata
    table = mutate(table)
    if table.schema.metadata is None:
        table = table.replace_schema_metadata(meta)
    pq.write_table(table, path)
    return path


def _set(table: pa.Table, col: str, values) -> pa.Table:
    i = table.column_names.index(col)
    return table.set_column(i, col, pa.array(values))


CASES = {
    "missing column": (lambda t: t.drop(["theta_arm"]), "column 'theta_arm'", "missing"),
    "nan value": (
        lambda t: _set(t, "omega_boom", np.r_[np.zeros(10), np.nan, np.zeros(39)]),
        "column 'omega_boom', row 10",
        "non-finite",
    ),
    "inf value": (
        lambda t: _set(t, "theta_swing", np.r_[np.zeros(3), np.inf, np.zeros(46)]),
        "column 'theta_swing', row 3",
        "non-finite",
    ),
    "time not increasing": (
        lambda t: _set(t, "time", np.r_[np.arange(20), 19, np.arange(21, 50)] * 0.05),
        "column 'time', row 20",
        "strictly increasing",
    ),
    "wrong rate": (
        lambda t: _set(t, "time", np.arange(50) * 0.1),
        "column 'time', row 1",
        "1/rate_hz",
    ),
    "command out of range": (
        lambda t: _set(t, "u_bucket", np.r_[np.zeros(5), 1500.0, np.zeros(44)]),
        "column 'u_bucket', row 5",
        "outside [-1000, 1000]",
    ),
    "non-numeric": (lambda t: _set(t, "u_arm", ["x"] * 50), "column 'u_arm'", "not numeric"),
    "no metadata": (lambda t: t.replace_schema_metadata({}), "ep.parquet", "no 'exsur' metadata"),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_loader_rejects(tmp_path: Path, case: str, capsys: pytest.CaptureFixture[str]) -> None:
    mutate, where, what = CASES[case]
    path = _write_table(tmp_path / "ep.parquet", make_episode(), mutate)
    with pytest.raises(DataError) as err:
        read_episode(path)
    msg = str(err.value)
    assert "\n" not in msg and where in msg and what in msg and str(path) in msg
    # The CLI turns it into one line on stderr and a non-zero exit code.
    assert main(["validate", str(path)]) != 0
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("exsur: error:") and where in lines[0]


def test_too_short_and_corrupt(tmp_path: Path) -> None:
    write_episode(tmp_path / "ep.parquet", make_episode(n=20))
    with pytest.raises(DataError, match="fewer than the 31"):
        read_episode(tmp_path / "ep.parquet", min_steps=31)
    bad = tmp_path / "bad.parquet"
    bad.write_bytes(b"PAR1 this is not parquet")
    with pytest.raises(DataError, match="not a readable Parquet file"):
        read_episode(bad)
    # a dataset folder where an episode file belongs (exsur plot DATA): named, with a file
    folder = tmp_path / "data"
    write_episode(folder / "episodes" / "train_000.parquet", make_episode(n=20))
    with pytest.raises(DataError, match=r"is a folder, not an episode file .*train_000\.parquet"):
        read_episode(folder)


def test_write_refuses_invalid_and_leaves_nothing(tmp_path: Path) -> None:
    ep = make_episode()
    ep.u[3, 1] = 5000.0
    with pytest.raises(DataError, match="row 3"):
        write_episode(tmp_path / "x.parquet", ep)
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(DataError):
        write_dataset(
            tmp_path / "ds", [(make_episode(name="a"), "train"), (ep.replace(name="b"), "test")]
        )
    assert list(tmp_path.iterdir()) == []


def test_dataset_manifest(tmp_path: Path) -> None:
    eps = [(make_episode(name=f"e{i}"), s) for i, s in enumerate(["train", "train", "val", "test"])]
    write_dataset(tmp_path / "ds", eps, config={"simulate": {"seed": 3}})
    ds = load_dataset(tmp_path / "ds")
    assert [len(ds.split(s)) for s in ("train", "val", "test")] == [2, 1, 1]
    assert ds.n_samples("train") == 100
    assert "seed = 3" in (tmp_path / "ds" / "config.toml").read_text()
    assert main(["validate", str(tmp_path / "ds")]) == 0
    (tmp_path / "ds" / "manifest.json").write_text("{not json")
    with pytest.raises(DataError, match="manifest.json: invalid JSON"):
        load_dataset(tmp_path / "ds")


def test_columns_follow_spec() -> None:
    cols = columns_for(EXCAVATOR)
    assert cols["u"] == ["u_swing", "u_boom", "u_arm", "u_bucket"]
    assert cols["trusted"][-1] == "trusted_bucket"
