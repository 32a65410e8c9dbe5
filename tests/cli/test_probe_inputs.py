"""Issue 25 probe: episode files, options and seeds a new user gets wrong, each one line.

Fresh variants: a Parquet episode with a column twice (was pyarrow's schema dump and 'the file
is corrupt'), ``validate --min-steps -5`` (was accepted), an unknown ``--split`` (listed only
the splits evaluate had loaded), a seed beyond what torch takes (was a traceback).
"""

from __future__ import annotations

from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from tests.helpers.cli import fails as _fails

from excavator_surrogate.config import from_dict
from excavator_surrogate.data.episode import read_episode
from excavator_surrogate.errors import ConfigError, DataError
from excavator_surrogate.training import TrainConfig


def _episode(data_dir: Path) -> Path:
    return next((data_dir / "ds3" / "episodes").glob("*.parquet"))


def test_a_duplicated_column_is_named(data_dir: Path, tmp_path: Path, capsys) -> None:
    table = pq.read_table(_episode(data_dir))
    u = next(c for c in table.column_names if c.startswith("u_"))
    dup = pa.Table.from_arrays(
        [*table.columns, table.column(u)], names=[*table.column_names, u]
    ).replace_schema_metadata(table.schema.metadata)
    bad = tmp_path / "dup.parquet"
    pq.write_table(dup, bad)
    line = _fails(capsys, "validate", bad)
    assert (
        line
        == f"exsur: error: {bad}, column '{u}': duplicated column (each column may appear once)"
    )
    with pytest.raises(DataError, match="duplicated column"):
        read_episode(bad)


def test_validate_refuses_a_minimum_below_one(data_dir: Path, capsys) -> None:
    line = _fails(capsys, "validate", data_dir / "ds3", "--min-steps", "-5")
    assert "--min-steps must be >= 1" in line and "got -5" in line


def test_an_empty_split_lists_every_split_with_episodes(
    model3: Path, data_dir: Path, tmp_path: Path, capsys
) -> None:
    out = tmp_path / "ev"
    line = _fails(
        capsys, "evaluate", model3 / "best.pt", data_dir / "ds3", "--split", "bogus", "--out", out
    )
    assert "split 'bogus' has no episodes" in line
    assert "['train', 'val', 'test']" in line
    assert not out.exists()


@pytest.mark.parametrize("seed", [2**32, 99999999999999999999999])
def test_a_seed_torch_cannot_take_is_refused(
    seed: int, data_dir: Path, tmp_path: Path, capsys
) -> None:
    out = tmp_path / "m"
    argv = ["train", data_dir / "ds3", "--preset", data_dir / "tiny.toml", "--epochs", "1"]
    line = _fails(capsys, *argv, "--seed", seed, "--out", out)
    assert f"seed = {seed} must be < 2**32" in line
    assert not out.exists()
    with pytest.raises(ConfigError, match=r"must be < 2\*\*32"):
        from_dict(TrainConfig, {"seed": seed})
    assert from_dict(TrainConfig, {"seed": 2**32 - 1}).seed == 2**32 - 1


@pytest.mark.parametrize("cmd", [["config", "show"], ["train", "DATA", "--out", "OUT", "--preset"]])
def test_a_binary_file_given_as_preset_is_one_line(
    cmd: list[str], data_dir: Path, tmp_path: Path, capsys
) -> None:
    binary = _episode(data_dir)  # a Parquet episode: not UTF-8 text
    argv = [{"DATA": data_dir / "ds3", "OUT": tmp_path / "m"}.get(a, a) for a in cmd]
    line = _fails(capsys, *argv, binary)
    assert line.startswith(f"exsur: error: {binary}: not a TOML text file (not UTF-8")
    assert not (tmp_path / "m").exists()


def test_time_going_backwards_is_shown_in_short_numbers(data_dir: Path, tmp_path: Path, capsys):
    table = pq.read_table(_episode(data_dir))
    t = table.column("time").to_numpy().copy()
    t[0], t[1] = 1.0, 0.1 + 0.2  # 0.30000000000000004 in full
    i = table.column_names.index("time")
    bad = tmp_path / "back.parquet"
    pq.write_table(table.set_column(i, "time", pa.array(t)), bad)
    line = _fails(capsys, "validate", bad)
    assert "column 'time', row 1: time is not strictly increasing (1 -> 0.3)" in line


def test_an_episode_file_given_as_the_dataset_is_named_a_file(
    data_dir: Path, tmp_path: Path, capsys
) -> None:
    ep = _episode(data_dir)
    line = _fails(capsys, "train", ep, "--preset", data_dir / "tiny.toml", "--out", tmp_path / "m")
    assert line.startswith(f"exsur: error: {ep}: is a file, not a dataset folder")
    assert not (tmp_path / "m").exists()


def test_a_huge_ensemble_and_a_text_start_pose_are_one_line(capsys, tmp_path):
    import gymnasium as gym

    import excavator_surrogate  # noqa: F401  (registers the envs)

    with pytest.raises(ConfigError, match=r"members = 100000 must be in \[1, 64\]"):
        TrainConfig(members=100000)
    env = gym.make("ExcavatorMujoco-v0")
    try:
        with pytest.raises(ConfigError, match="theta0 must be 4 finite angles"):
            env.reset(options={"theta0": "x"})
        with pytest.raises(ConfigError, match="theta0 must be 4 finite angles"):
            env.reset(options={"theta0": [0.0, None, [1], 0.0]})
    finally:
        env.close()
