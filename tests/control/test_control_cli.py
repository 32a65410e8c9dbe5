"""``exsur control`` end to end on a tiny untrained checkpoint (tiny K, N, PPO budget)."""

from __future__ import annotations

import json
import tomllib
from pathlib import Path

import pytest

from excavator_surrogate.cli import main


def test_control_writes_the_report_folder(
    tiny_ckpt: Path, tmp_path: Path, capsys, monkeypatch
) -> None:
    scratch = tmp_path / "scratch"  # the process's temp directory
    scratch.mkdir()
    monkeypatch.setattr("tempfile.tempdir", str(scratch))
    monkeypatch.delenv("SB3_LOGDIR", raising=False)
    out = tmp_path / "ctl"
    argv = ["control", str(tiny_ckpt), "--out", str(out), "--samples", "4", "--horizon", "3"]
    argv += ["--time-scale", "0.1", "--rl-steps", "64", "--rl-envs", "2", "--rl-eval", "2"]
    argv += ["--rl-episode-steps", "8", "--cpus", "2", "--mppi-seeds", "2"]
    assert main(argv) == 0
    assert {p.name for p in out.iterdir()} == {
        ".exsur.json",  # the output-folder marker (docs/design.md)
        "config.toml",
        "report.md",
        "metrics.json",
        "tracking.png",
        "learning_curve.png",
        "trajectories.npz",
    }
    assert list(scratch.glob("SB3-*")) == []  # SB3's default logger made one per PPO run
    rl = tomllib.loads((out / "config.toml").read_text())["command"]["rl"]
    assert (rl["total_steps"], rl["n_envs"], rl["plant"]) == (64, 2, "hydraulic")
    m = json.loads((out / "metrics.json").read_text())
    assert set(m["mppi"]["runs"]) == {"mppi_surrogate", "mppi_oracle", "pi"}
    assert m["mppi"]["runs"]["mppi_surrogate"]["n_control_steps"] > 10
    hz = m["mppi"]["runs"]["mppi_surrogate"]["horizon_error_rad"]
    assert hz["n_horizon"] == 3 and len(hz["rms"]) == 4 and all(v >= 0 for v in hz["p95"])
    assert m["cpus"] == 2  # the surrogate planner used a worker process, the oracle 2 threads
    assert m["surrogate"]["velocity_input"] is False and m["surrogate"]["residual"] is False
    assert "velocity_input = true" in (out / "report.md").read_text()  # the advice
    assert m["bias_gain"] == 0.1 and any(m["mppi"]["runs"]["mppi_surrogate"]["bias_rad_s"])
    assert set(m["mppi"]["rmse_ratio"]) == {"swing", "boom", "arm", "bucket"}
    # the seed study: seed 0 is the main run, the target takes the worst seed
    seeds = m["mppi"]["seeds"]
    assert [r["seed"] for r in seeds] == [0, 1]
    assert seeds[0]["rmse_ratio"] == m["mppi"]["rmse_ratio"]
    worst = max(r["rmse_ratio_max"] for r in seeds)
    assert m["mppi"]["rmse_ratio_max_over_seeds"] == worst
    assert m["goals"]["mppi_rmse_within_1.25x_oracle"] == (worst <= 1.25)
    assert "Seed study" in (out / "report.md").read_text()
    assert m["rl"]["surrogate"]["train_s"] > 0 and "success" in m["rl"]["plant"]["plant"]
    assert len(m["rl"]["curve"]) >= 1 and "plant" in m["rl"]["curve"][0]
    assert set(m["goals"]) == {
        "mppi_rmse_within_1.25x_oracle",
        "mppi_10_control_steps_per_s",
        "mppi_10x_faster_than_oracle",
        "rl_success_90pct_of_plant_trained",
        "rl_trains_5x_faster",
    }
    assert "| mppi_oracle |" in capsys.readouterr().out
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temp folders


def test_control_bad_checkpoint_is_one_line(tmp_path: Path, capsys) -> None:
    bad = tmp_path / "nope.pt"
    assert main(["control", str(bad), "--out", str(tmp_path / "o"), "--no-rl"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "nope.pt" in err[0]
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize(
    ("opt", "word"),
    [
        (["--replan", "50"], "replan"),
        (["--cpus", "0"], "--cpus"),
        (["--mppi-seeds", "0"], "--mppi-seeds"),
        (["--samples", "1"], "--samples must be >= 2"),  # it blamed --cpus
        (["--rl-eval", "0"], "--rl-eval"),  # IndexError after MPPI had run
        (["--rl-episode-steps", "-3"], "--rl-episode-steps"),  # gymnasium's ValueError
        # these named the configs' fields (bias_gain, time_scale, n_horizon, n_steps)
        (["--bias-gain", "2"], "--bias-gain must be in [0, 1]"),
        (["--time-scale", "0"], "--time-scale must be > 0"),
        (["--replan", "5", "--horizon", "3"], "--replan must be in [1, --horizon = 3]"),
        (["--horizon", "0"], "--horizon must be >= 1"),
        (["--rl-steps", "1000"], "--rl-steps must be >= --rl-envs x 32 = 4096"),
        (["--rl-envs", "0"], "--rl-envs must be >= 1"),
    ],
)
def test_control_bad_option_is_one_line(
    opt: list[str], word: str, tiny_ckpt: Path, tmp_path: Path, capsys
) -> None:
    rc = main(["control", str(tiny_ckpt), "--out", str(tmp_path / "o"), *opt])
    assert rc == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and word in err[0]
    assert not (tmp_path / "o").exists()


def test_control_reports_the_env_steps_ppo_trained(tiny_ckpt: Path, tmp_path: Path) -> None:
    """PPO trains whole updates (2 envs x 32 steps): of --rl-steps 100 it trains 64, which the
    report said was 100; the learning curve has one point per update at most (there were
    up to 2 x n_curve)."""
    out = tmp_path / "ctl"
    argv = ["control", str(tiny_ckpt), "--out", str(out), "--samples", "4", "--horizon", "3"]
    argv += ["--time-scale", "0.1", "--cpus", "1", "--no-oracle", "--rl-steps", "100"]
    argv += ["--rl-envs", "2", "--rl-eval", "2", "--rl-episode-steps", "8"]
    assert main(argv) == 0
    rl = json.loads((out / "metrics.json").read_text())["rl"]
    assert rl["config"]["total_steps"] == 100  # the request, as given
    assert rl["surrogate"]["train_steps"] == rl["plant"]["train_steps"] == 64
    assert [p["steps"] for p in rl["curve"]] == [p["steps"] for p in rl["curve_plant_trained"]]
    assert [p["steps"] for p in rl["curve"]] == [64]
    report = (out / "report.md").read_text()
    assert "2 envs, 64 env-steps each (the budget 100 rounded down to whole PPO updates" in report


def test_control_refuses_a_time_scale_that_cannot_fit(
    tiny_ckpt: Path, tmp_path: Path, capsys, monkeypatch
) -> None:
    """1e9 ended in numpy's 298-GiB _ArrayMemoryError traceback (and 1e6 in the kernel's OOM
    killer at 21.7 GB, no message: not run here)."""
    from excavator_surrogate.surrogate import sizes

    monkeypatch.setattr(sizes, "available_memory", lambda: 8 * 2**30)
    rc = main(["control", str(tiny_ckpt), "--out", str(tmp_path / "o"), "--time-scale", "1e9"])
    assert rc == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--time-scale 1e+09: a 520000000021-sample" in err[0]
    assert "lower --time-scale" in err[0]
    assert not (tmp_path / "o").exists()


def test_default_cpus_never_exceed_samples(tiny_ckpt: Path, tmp_path: Path, monkeypatch) -> None:
    """On a 4-CPU computer --samples 2 was refused: '--cpus must be in [1, --samples = 2],
    got 4' (a --cpus never given)."""
    monkeypatch.setenv("EXSUR_CPUS", "4")
    out = tmp_path / "ctl"
    argv = ["control", str(tiny_ckpt), "--out", str(out), "--samples", "2", "--horizon", "3"]
    argv += ["--time-scale", "0.1", "--no-oracle", "--no-rl"]
    assert main(argv) == 0
    assert json.loads((out / "metrics.json").read_text())["cpus"] == 2


@pytest.mark.parametrize("n", [0])
def test_rl_config_rejects_too_small_budgets(n: int) -> None:
    from excavator_surrogate.control.rl import RLConfig
    from excavator_surrogate.errors import ConfigError

    with pytest.raises(ConfigError, match="total_steps"):
        RLConfig(total_steps=n)


def test_report_says_what_the_surrogate_reads_of_the_measured_state() -> None:
    from excavator_surrogate.control.report import _surrogate_line

    ok = _surrogate_line({"name": "lstm", "velocity_input": True, "residual": True})
    assert "starts from the measured velocity" in ok and "train with" not in ok
    for info in ({"name": "lstm", "velocity_input": True, "residual": False}, {}):
        assert "train with `velocity_input = true`" in _surrogate_line(info)


def test_control_records_its_options_in_config_toml(tiny_ckpt: Path, tmp_path: Path) -> None:
    """``--time-scale``, ``--mppi-seeds`` and the oracle / RL switches were recorded nowhere:
    the reference could not be run again.  ``config.toml``'s ``[command]`` holds every option
    (MPPI's and PPO's configs as tables), and the file loads as a preset."""
    from excavator_surrogate.stages import load_preset

    out = tmp_path / "ctl"
    argv = ["control", str(tiny_ckpt), "--out", str(out), "--samples", "4", "--horizon", "3"]
    argv += ["--time-scale", "0.1", "--cpus", "1", "--no-oracle", "--no-rl", "--seed", "3"]
    assert main(argv) == 0
    command = tomllib.loads((out / "config.toml").read_text())["command"]
    assert command["checkpoint"] == str(tiny_ckpt.resolve())
    assert {k: command[k] for k in ("name", "time_scale", "mppi_seeds", "oracle", "cpus")} == {
        "name": "control",
        "time_scale": 0.1,
        "mppi_seeds": 1,
        "oracle": False,
        "cpus": 1,
    }
    assert command["mppi"]["n_sample"] == 4 and command["mppi"]["seed"] == 3
    assert "rl" not in command  # --no-rl: no PPO ran
    assert load_preset(out / "config.toml")["command"] == command
