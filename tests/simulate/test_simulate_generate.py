"""Dataset generation, presets and the ``exsur simulate`` / ``exsur plot`` commands."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

from excavator_surrogate.cli import main
from excavator_surrogate.config import from_dict, load_preset
from excavator_surrogate.data import load_dataset
from excavator_surrogate.errors import ConfigError
from excavator_surrogate.simulate.config import SimulateConfig
from excavator_surrogate.simulate.generate import plan_episodes, simulate_dataset


def _tiny() -> SimulateConfig:
    return from_dict(SimulateConfig, load_preset("tiny")["simulate"])


@pytest.mark.parametrize("name", ["tiny", "quick", "paper-stage1"])
def test_presets_load(name: str) -> None:
    cfg = from_dict(SimulateConfig, load_preset(name)["simulate"])
    if name == "paper-stage1":
        assert cfg.n_train * cfg.steps_train == 63_600 and cfg.train_signals == ("multisine",)
        assert cfg.n_test == 1 and cfg.steps_test == 1800 and cfg.test_signals == ("steps",)


def test_episode_seeds_are_per_split() -> None:
    cfg = _tiny()
    a = plan_episodes(cfg)
    b = plan_episodes(dataclasses.replace(cfg, n_train=5))
    assert [j.seed for j in a if j.split == "test"] == [j.seed for j in b if j.split == "test"]
    assert len({j.seed for j in a}) == len(a)


def test_output_does_not_depend_on_workers(tmp_path: Path) -> None:
    cfg = _tiny()
    d1 = simulate_dataset(cfg, out=tmp_path / "w1", workers=1)
    d2 = simulate_dataset(cfg, out=tmp_path / "w2", workers=2)
    files = sorted(p.name for p in (d1 / "episodes").iterdir())
    assert files == sorted(p.name for p in (d2 / "episodes").iterdir()) and len(files) == 4
    for f in files:
        assert pq.read_table(d1 / "episodes" / f).equals(pq.read_table(d2 / "episodes" / f))
    ds = load_dataset(d1)
    assert [len(ds.train), len(ds.val), len(ds.test)] == [2, 1, 1]
    assert cfg.episode_lengths() == {  # known before anything is simulated
        s: [e.n_step for e in ds.split(s)] for s in ("train", "val", "test")
    }
    ep = ds.train[0]
    np.testing.assert_array_equal(ep.omega[1:], np.diff(ep.theta, axis=0) / ep.dt)


def test_cli_simulate_and_plot(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "ds"
    assert (
        main(["simulate", "--preset", "tiny", "--out", str(out), "--seed", "5", "--workers", "1"])
        == 0
    )
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["preset"] == "tiny" and manifest["config"]["simulate"]["seed"] == 5
    assert manifest["n_samples"] == {"train": 400, "val": 200, "test": 200}
    # the computer's numerics and library versions, beside the config that made the data
    assert manifest["environment"]["numpy"] == np.__version__
    assert manifest["environment"]["mujoco"] and manifest["environment"]["cpu"]
    path = out / manifest["episodes"][0]["file"]
    table = pq.read_table(path)  # independent reader
    names = ("swing", "boom", "arm", "bucket")
    expected = ["time"] + [f"{r}_{j}" for r in ("u", "theta", "omega") for j in names]
    expected += [f"{r}_{j}_true" for r in ("theta", "omega") for j in names]
    assert sorted(table.column_names) == sorted(expected)
    meta = json.loads(table.schema.metadata[b"exsur"])
    assert meta["source"] == "mujoco-ideal" and meta["rate_hz"] == 20.0
    assert meta["condition"] == "noload" and isinstance(meta["seed"], int)
    assert meta["generator"]["signal"] in ("multisine", "steps")
    assert meta["generator"]["config"]["seed"] == 5
    assert [j["name"] for j in meta["spec"]["joints"]] == list(names)
    t = table.column("time").to_numpy()
    np.testing.assert_allclose(np.diff(t), 0.05)
    png = tmp_path / "ep.png"
    capsys.readouterr()
    assert main(["plot", str(path), "--out", str(png)]) == 0
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_cli_user_errors(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["simulate", "--preset", "no-such-preset", "--out", str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("exsur: error:") and err.count("\n") == 1
    bad = tmp_path / "bad.toml"
    bad.write_text('[simulate]\ntrain_signals = ["sawtooth"]\n')
    assert main(["simulate", "--preset", str(bad), "--out", str(tmp_path / "y")]) == 2
    assert "sawtooth" in capsys.readouterr().err
    assert main(["plot", str(tmp_path / "missing.parquet")]) == 2
    assert not (tmp_path / "x").exists() and not (tmp_path / "y").exists()


def test_config_validation() -> None:
    with pytest.raises(ConfigError):
        SimulateConfig(n_train=0, n_val=0, n_test=0)
    with pytest.raises(ConfigError):
        from_dict(SimulateConfig, {"n_trian": 3})


def test_wrong_argument_types_are_one_line_before_simulating(tmp_path: Path) -> None:
    from excavator_surrogate.errors import ConfigError
    from excavator_surrogate.simulate import SimulateConfig, simulate_dataset

    with pytest.raises(ConfigError, match="cfg: a SimulateConfig is needed, got dict"):
        simulate_dataset({"n_train": 1}, out=tmp_path / "s")  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match="out: a path is needed, got NoneType"):
        simulate_dataset(SimulateConfig.from_preset("tiny"), out=None)  # type: ignore[arg-type]
    assert list(tmp_path.iterdir()) == []


def test_a_folder_exsur_did_not_write_is_refused_before_simulating(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The write's own output-folder rule, applied before the episodes are simulated: a
    user's folder costs one line, not a whole simulation first."""
    from excavator_surrogate.simulate import generate

    def must_not_run(cfg: SimulateConfig) -> list:
        raise AssertionError("simulated into a folder it was going to refuse")

    monkeypatch.setattr(generate, "plan_episodes", must_not_run)
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("keep")
    with pytest.raises(ConfigError, match=r"mine: output folder holds 'notes.txt'"):
        simulate_dataset(_tiny(), out=mine, workers=1)
    assert [p.name for p in mine.iterdir()] == ["notes.txt"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mine"]  # no temporary folder left
