"""Equivalence check (exsur compare) and the MuJoCo env against the plant's batched rollout."""

from __future__ import annotations

import json
import tomllib
from pathlib import Path

import numpy as np
import pytest

from excavator_surrogate.cli import main
from excavator_surrogate.config import load_preset
from excavator_surrogate.data.episode import Episode, write_episode
from excavator_surrogate.env import ExcavatorMujocoEnv
from excavator_surrogate.env.compare import compare, load_commands, run_commands
from excavator_surrogate.errors import ConfigError, DataError
from excavator_surrogate.simulate.plant import MujocoExcavator
from excavator_surrogate.spec import EXCAVATOR


def _csv(path: Path, u: np.ndarray, theta0: np.ndarray | None = None) -> Path:
    cols = [f"u_{j}" for j in EXCAVATOR.names]
    data = u
    if theta0 is not None:
        cols += [f"theta_{j}" for j in EXCAVATOR.names]
        data = np.concatenate([u, np.tile(theta0, (len(u), 1))], axis=1)
    np.savetxt(path, data, delimiter=",", header=",".join(cols), comments="")
    return path


def test_mujoco_env_matches_batched_rollout() -> None:
    rng = np.random.default_rng(0)
    u = rng.uniform(-600, 600, (12, 4))
    theta0 = np.array([0.3, 0.1, 1.4, 0.7])
    theta, omega, _ = run_commands(ExcavatorMujocoEnv(), u, theta0)
    ref = MujocoExcavator().rollout(u[None], theta0=theta0[None])
    np.testing.assert_allclose(theta, ref["theta"][0], atol=1e-12)
    np.testing.assert_allclose(omega[1:], ref["omega"][0, 1:], atol=1e-9)


def test_compare_csv_writes_metrics_table_plot(stateful_ckpt: Path, tmp_path: Path) -> None:
    u = np.zeros((30, 4))
    u[5:, 1] = 400.0
    theta0 = np.array([0.2, 0.0, 1.5, 0.5])
    src = _csv(tmp_path / "cmds.csv", u, theta0)
    res = compare(stateful_ckpt, src, out=tmp_path / "out")
    assert res.theta_ref.shape == res.theta_hat.shape == (30, 4)
    np.testing.assert_allclose(res.theta_ref[0], theta0)
    np.testing.assert_allclose(res.theta_hat[0], theta0)
    assert res.theta_ref[-1, 1] > 0.1  # the boom moved on the plant
    m = json.loads((tmp_path / "out" / "metrics.json").read_text())
    assert set(m["omega"]) == set(EXCAVATOR.names) and m["run"]["n_step_scored"] == 29
    assert {"rmse", "mae", "r2"} <= set(m["theta"]["boom"])
    assert "| Type | Joint | RMSE" in (tmp_path / "out" / "table.md").read_text()
    assert (tmp_path / "out" / "compare.png").stat().st_size > 1000
    npz = np.load(tmp_path / "out" / "trajectories.npz")
    np.testing.assert_array_equal(npz["theta_mujoco"], res.theta_ref)


def test_command_sources(tmp_path: Path) -> None:
    named = load_commands("steps:seed=1,seconds=2", EXCAVATOR)
    assert named.u.shape == (41, 4)
    again = load_commands("steps:seed=1,n_step=41", EXCAVATOR)
    np.testing.assert_array_equal(named.u, again.u)
    n = 25
    ep = Episode(
        spec=EXCAVATOR,
        time=np.arange(n) * EXCAVATOR.dt,
        u=np.full((n, 4), 100.0),
        theta=np.tile([0.1, 0.2, 1.5, 0.5], (n, 1)),
        omega=np.zeros((n, 4)),
    )
    pq = write_episode(tmp_path / "ep.parquet", ep)
    cmds = load_commands(pq, EXCAVATOR)
    np.testing.assert_array_equal(cmds.theta0, [0.1, 0.2, 1.5, 0.5])
    bad = np.zeros((10, 4))
    bad[3, 2] = 2000.0
    with pytest.raises(DataError, match=r"column 'u_arm', row 3: command 2000 outside"):
        load_commands(_csv(tmp_path / "bad.csv", bad), EXCAVATOR)
    np.savetxt(
        tmp_path / "nocol.csv",
        np.zeros((5, 2)),
        delimiter=",",
        header="u_swing,u_boom",
        comments="",
    )
    with pytest.raises(DataError, match="u_arm"):
        load_commands(tmp_path / "nocol.csv", EXCAVATOR)
    with pytest.raises(ConfigError, match="named excitation"):
        load_commands("wiggle:seed=1", EXCAVATOR)
    with pytest.raises(ConfigError, match="unknown option"):
        load_commands("steps:sed=1", EXCAVATOR)
    with pytest.raises(DataError, match="not found"):
        load_commands(tmp_path / "missing.csv", EXCAVATOR)


@pytest.mark.parametrize(
    ("text", "match"),
    [
        (
            "u_swing,u_boom,u_arm,u_bucket\n0,1,2,3\n0,1,abc,3\n",
            r"column 'u_arm', row 1: non-numeric value 'abc' \(store numbers only\)",
        ),
        (
            "u_swing;u_boom;u_arm;u_bucket\n0;1;2;3\n",
            r"its header is split by ';': separate the fields by ','",
        ),
    ],
    ids=["text-cell", "semicolons"],
)
def test_a_bad_commands_csv_names_the_cell_or_the_separator(tmp_path: Path, text, match) -> None:
    (tmp_path / "c.csv").write_text(text)
    with pytest.raises(DataError, match=match):
        load_commands(tmp_path / "c.csv", EXCAVATOR)


@pytest.mark.parametrize(
    ("source", "match"),
    [
        ("steps:seed=x", r"seed must be an integer, got 'x'"),
        ("steps:seconds=-5", r"need at least 2 samples \(0.1 s\), got seconds=-5"),
        ("steps:n_step=1", r"need at least 2 samples \(0.1 s\), got n_step=1"),
        (
            "steps:seconds=1e9",
            r"seconds=1e9 is more than a day of machine time \(at most seconds=86400",
        ),
        ("steps:seconds=inf", r"seconds must be a finite number"),
    ],
)
def test_a_bad_named_excitation_says_which_option(source: str, match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        load_commands(source, EXCAVATOR)


def test_cli_compare(
    stateful_ckpt: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "cmp"
    code = main(
        [
            "compare",
            str(stateful_ckpt),
            "--commands",
            "prbs:seed=2,seconds=1",
            "--out",
            str(out),
            "--theta0",
            "0,0.1,1.5,0.5",
        ]
    )
    assert code == 0
    assert "Angle trajectory" in capsys.readouterr().out
    assert json.loads((out / "metrics.json").read_text())["run"]["theta0"] == [0.0, 0.1, 1.5, 0.5]
    # the record of what repeats the replay (it had written none)
    record = tomllib.loads((out / "config.toml").read_text())["command"]
    assert record == {
        "name": "compare",
        "checkpoint": str(stateful_ckpt),
        "source": "prbs:seed=2,seconds=1",
        "theta0": [0.0, 0.1, 1.5, 0.5],
        "plant": "ideal",
        "mode": record["mode"],
        "device": "cpu",
    }
    assert load_preset(out / "config.toml") is not None  # a record loads back as a preset
    assert main(["compare", str(stateful_ckpt), "--commands", "nope:x"]) == 2
    assert "named excitation" in capsys.readouterr().err
    # a --theta0 of the wrong length: named as the option, before any excitation is made
    bad = ["compare", str(stateful_ckpt), "--commands", "steps", "--theta0", "0,0,0"]
    assert main([*bad, "--out", str(tmp_path / "cmp2")]) == 2
    err = capsys.readouterr().err
    assert "compare --theta0: theta0 must be 4 finite angles in rad for joints" in err
    assert "got [0.0, 0.0, 0.0]" in err and not (tmp_path / "cmp2").exists()


def test_a_gap_in_a_commands_csv_names_its_cell(tmp_path: Path) -> None:
    path = tmp_path / "cmds.csv"
    u = np.zeros((5, EXCAVATOR.n_u))
    u[3, 1] = np.nan
    header = ",".join(f"u_{n}" for n in EXCAVATOR.u_names)
    np.savetxt(path, u, delimiter=",", header=header, comments="")
    with pytest.raises(
        DataError, match=r"cmds.csv, column 'u_boom', row 3: non-finite command nan \(fill"
    ):
        load_commands(path, EXCAVATOR)
