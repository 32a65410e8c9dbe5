"""A dataset is one machine and names each episode once: an episode whose command range,
periodic flag, joint kind or exogenous inputs differ from the manifest's spec (or, without
one, from the first episode's), and two episodes of one stored name, are refused in one line
where the dataset is loaded, so validate, train and evaluate all refuse them."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from excavator_surrogate.cli import main
from excavator_surrogate.data import load_dataset, write_dataset
from excavator_surrogate.errors import DataError
from tests.data.test_contract import make_episode


def _dataset(tmp_path: Path) -> Path:
    """Entries 0 a (train), 1 b (train), 2 v (val), 3 t (test) of the excavator at 20 Hz."""
    return write_dataset(
        tmp_path / "ds",
        [
            (make_episode(name="a"), "train"),
            (make_episode(name="b", n=60), "train"),
            (make_episode(name="v", n=40), "val"),
            (make_episode(name="t", n=45), "test"),
        ],
    )


def _edit_episode(
    path: Path,
    meta_edit: Callable[[dict[str, Any]], None],
    table_edit: Callable[[pa.Table], pa.Table] | None = None,
) -> None:
    """Rewrite one episode file with its metadata (and optionally columns) edited."""
    table = pq.read_table(path)
    meta = json.loads(table.schema.metadata[b"exsur"])
    meta_edit(meta)
    table = table_edit(table) if table_edit else table
    pq.write_table(table.replace_schema_metadata({b"exsur": json.dumps(meta).encode()}), path)


def _unit_commands(meta: dict[str, Any]) -> None:
    for j in meta["spec"]["joints"]:
        j["u_min"], j["u_max"] = -1.0, 1.0


def _scaled_commands(table: pa.Table) -> pa.Table:
    for j in ("swing", "boom", "arm", "bucket"):
        c = f"u_{j}"
        i = table.column_names.index(c)
        table = table.set_column(i, c, pa.array(table.column(c).to_numpy() / 1000.0))
    return table


def _linear_arm(meta: dict[str, Any]) -> None:
    meta["spec"]["joints"][2].update(kind="linear", unit="mm")


def _swing_not_periodic(meta: dict[str, Any]) -> None:
    meta["spec"]["joints"][0]["periodic"] = False


def _rpm_input(meta: dict[str, Any]) -> None:
    meta["spec"]["inputs"] = [{"name": "rpm", "u_min": 1000.0, "u_max": 2000.0, "unit": "rpm"}]


def _rpm_column(table: pa.Table) -> pa.Table:
    return table.append_column("u_rpm", pa.array(np.full(table.num_rows, 1500.0)))


# case -> (episode b's metadata edit, its columns' edit, what differs, dataset vs episode)
CASES: dict[str, tuple[Callable[..., None], Callable[..., pa.Table] | None, str]] = {
    "commands in [-1, 1]": (
        _unit_commands,
        _scaled_commands,
        "joint 'swing' command range [-1000, 1000] vs [-1, 1]",
    ),
    "a linear arm": (_linear_arm, None, "joint 'arm' revolute vs linear"),
    "swing not periodic": (_swing_not_periodic, None, "joint 'swing' periodic True vs False"),
    "an exogenous input": (_rpm_input, _rpm_column, "exogenous inputs [] vs [('rpm', 1000.0"),
}


@pytest.mark.parametrize("case", list(CASES))
def test_an_episode_of_another_machine_is_refused(
    tmp_path: Path, case: str, capsys: pytest.CaptureFixture[str]
) -> None:
    meta_edit, table_edit, differs = CASES[case]
    ds = _dataset(tmp_path)
    path = ds / "episodes" / "b.parquet"
    _edit_episode(path, meta_edit, table_edit)
    with pytest.raises(DataError) as e:
        load_dataset(ds, splits=("train", "val"))
    msg = str(e.value)
    assert "\n" not in msg and msg.startswith(
        f"{path}: manifest entry 1: the episode is of another machine than the manifest's spec "
        f"({differs}"
    ), msg
    assert "dataset vs episode) (a dataset holds one machine" in msg, msg
    assert main(["validate", str(ds)]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert lines == [f"exsur: error: {msg}"], lines


def test_a_manifest_spec_of_another_command_range_is_refused(tmp_path: Path) -> None:
    """The manifest says [-1, 1], every episode [-1000, 1000]: the model would scale the
    commands by the manifest's range."""
    ds = _dataset(tmp_path)
    mpath = ds / "manifest.json"
    m = json.loads(mpath.read_text())
    _unit_commands(m)
    mpath.write_text(json.dumps(m))
    with pytest.raises(DataError) as e:
        load_dataset(ds)
    assert str(e.value).startswith(
        f"{ds / 'episodes' / 'a.parquet'}: manifest entry 0: the episode is of another machine "
        "than the manifest's spec (joint 'swing' command range [-1, 1] vs [-1000, 1000]"
    )


def test_without_a_manifest_spec_every_episode_is_the_first_ones_machine(tmp_path: Path) -> None:
    ds = _dataset(tmp_path)
    mpath = ds / "manifest.json"
    m = json.loads(mpath.read_text())
    m.pop("spec")
    mpath.write_text(json.dumps(m))
    assert load_dataset(ds).n_samples() == 195  # an old manifest of one machine still loads
    _edit_episode(ds / "episodes" / "v.parquet", _unit_commands, _scaled_commands)
    with pytest.raises(DataError) as e:
        load_dataset(ds)
    assert str(e.value).startswith(
        f"{ds / 'episodes' / 'v.parquet'}: manifest entry 2: the episode is of another machine "
        "than the first episode's (episodes/a.parquet) spec (joint 'swing' command range"
    )


def test_limits_and_speed_bounds_are_not_the_machine(tmp_path: Path) -> None:
    """What mismatch does not compare (an episode's limits and speed bounds) loads as before,
    with the manifest's spec."""
    ds = _dataset(tmp_path)

    def widen(meta: dict[str, Any]) -> None:
        meta["spec"]["joints"][1].update(theta_min=-3.0, theta_max=3.0, omega_max=2.0)

    _edit_episode(ds / "episodes" / "b.parquet", widen)
    loaded = load_dataset(ds)
    assert loaded.spec.joints[1].theta_min == -0.75
    assert loaded.train[1].spec.joints[1].theta_min == -3.0


def test_two_episodes_of_one_name_are_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Two datasets' files merged into one folder keep their stored names: test episode 't'
    and a val episode also named 't' (other samples) would be reported under one name."""
    ds = _dataset(tmp_path)
    path = ds / "episodes" / "v.parquet"
    _edit_episode(path, lambda m: m.update(name="t"))
    with pytest.raises(DataError) as e:
        load_dataset(ds)
    msg = str(e.value)
    assert msg == (
        f"{ds / 'episodes' / 't.parquet'}: manifest entry 3 (test): the episode is named 't' "
        "(its metadata), as is entry 2 (val, episodes/v.parquet): reports would show two "
        "episodes under one name (give each episode its own name (Episode.name) and write the "
        "dataset again with write_dataset)"
    )
    assert main(["validate", str(ds)]) == 2
    assert capsys.readouterr().err.strip().splitlines() == [f"exsur: error: {msg}"]
    assert len(load_dataset(ds, splits=("train", "val")).val) == 1  # one of the pair loaded


@pytest.mark.parametrize("root", [None, 5], ids=["none", "int"])
def test_a_dataset_that_is_no_path_is_one_line(root: Any) -> None:
    from excavator_surrogate.errors import ConfigError

    with pytest.raises(ConfigError, match=f"dataset: a path is needed, got {type(root).__name__}"):
        load_dataset(root)
