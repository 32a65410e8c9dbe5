"""The CPUs exsur plans for: ``EXSUR_CPUS`` / ``--cpus``, the affinity mask and a container's
CPU quota."""

from __future__ import annotations

import os
from pathlib import Path

import joblib
import pytest

from excavator_surrogate import cpus, devices, numerics
from excavator_surrogate.cli import main
from excavator_surrogate.data import Dataset, write_dataset
from excavator_surrogate.errors import ConfigError
from excavator_surrogate.evaluate.training_report import environment_markdown
from excavator_surrogate.surrogate.synthetic import (
    synthetic_episode,
    synthetic_spec,
    synthetic_split,
)
from excavator_surrogate.training.auto import auto_config


@pytest.fixture(autouse=True)
def _no_cpu_env(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv(cpus.ENV, raising=False)
    monkeypatch.delenv("LOKY_MAX_CPU_COUNT", raising=False)


def test_the_count_is_the_affinity_mask_without_a_quota(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(joblib, "cpu_count", lambda: 64)  # no quota: the computer's count
    assert cpus.usable_cpus() == cpus.affinity_cpus() == devices.usable_cpus()
    assert cpus.cpus_note() == f"{cpus.affinity_cpus()} CPU(s) (this process's affinity mask)"


def test_a_container_quota_below_the_mask_is_the_count(monkeypatch: pytest.MonkeyPatch) -> None:
    # what joblib reads from a cgroup's cpu.max of a `docker run --cpus 1` container
    monkeypatch.setattr(cpus, "affinity_cpus", lambda: 16)
    monkeypatch.setattr(joblib, "cpu_count", lambda: 1)
    assert cpus.usable_cpus() == 1
    assert cpus.cpus_note() == "1 CPU(s) (a CPU quota; 16 in the affinity mask)"


def test_exsur_cpus_wins_and_says_so(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(cpus, "affinity_cpus", lambda: 8)
    monkeypatch.setattr(joblib, "cpu_count", lambda: 8)
    monkeypatch.setenv(cpus.ENV, "2")
    assert cpus.usable_cpus() == devices.usable_cpus() == 2
    assert cpus.cpus_note() == "2 CPU(s) (EXSUR_CPUS; this process may use 8)"
    assert cpus.oversubscribed() is None
    monkeypatch.setenv(cpus.ENV, "12")
    warning = cpus.oversubscribed()
    assert warning is not None and "may use 8 CPU(s)" in warning


@pytest.mark.parametrize("bad", ["0", "-1", "two", "1.5"])
def test_a_bad_exsur_cpus_is_one_clear_error(monkeypatch: pytest.MonkeyPatch, bad: str) -> None:
    monkeypatch.setenv(cpus.ENV, bad)
    with pytest.raises(ConfigError, match=f"EXSUR_CPUS={bad!r}: give a whole number"):
        cpus.usable_cpus()


def test_the_record_and_the_report_name_the_cpus(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(cpus.ENV, "3")
    env = numerics.environment()
    assert env["cpus"].startswith("3 CPU(s) (EXSUR_CPUS")
    assert f"with {env['cpus']}, torch" in environment_markdown(env)
    older = {k: v for k, v in env.items() if k != "cpus"}  # a record from before the key
    assert " with " not in environment_markdown(older).split(",")[0]


def _long_log() -> Dataset:
    spec = synthetic_spec(3)
    ds = Dataset(spec=spec)
    ds.episodes["train"].append(synthetic_episode(spec, kind="step", n_step=8000, seed=0))
    ds.episodes["val"].append(synthetic_episode(spec, kind="step", n_step=2000, seed=9))
    return ds


def test_the_recipe_plans_for_exsur_cpus(monkeypatch: pytest.MonkeyPatch) -> None:
    ds = _long_log()
    monkeypatch.setenv(cpus.ENV, "1")
    one, why = auto_config(ds, budget_s=600)
    assert one == auto_config(ds, budget_s=600, cpus=1)[0]
    assert any("600 s of training in all on 1 CPU(s) (EXSUR_CPUS" in w for w in why)
    monkeypatch.setenv(cpus.ENV, "2")
    two, _ = auto_config(ds, budget_s=600)
    assert two == auto_config(ds, budget_s=600, cpus=2)[0]
    assert two.members > one.members  # the plan follows the count


def test_cli_cpus_plans_the_recipe_and_leaves_no_trace(tmp_path: Path) -> None:
    spec = synthetic_spec(3)
    data = write_dataset(
        tmp_path / "d", synthetic_split(spec, n_train=2, n_val=1, n_test=1, n_step=120)
    )
    out = tmp_path / "m"
    sets = ["hidden=8", "head_hidden=8", "epochs=1", "tensorboard=false", "prior_choice=false"]
    argv = ["train", str(data), "--out", str(out), "--cpus", "1", "--members", "1"]
    for s in sets:
        argv += ["--set", f"train.{s}"]
    assert main(argv) == 0
    assert "on 1 CPU(s) (EXSUR_CPUS" in (out / "config.toml").read_text()
    assert cpus.ENV not in os.environ  # restored after the command


def test_cli_refuses_a_bad_cpus(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code = main(["train", str(tmp_path / "nothing"), "--out", str(tmp_path / "m"), "--cpus", "0"])
    assert code != 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--cpus 0: give a whole number of CPUs >= 1" in err[0]


def _blas_threads() -> list[int]:
    from threadpoolctl import threadpool_info

    return [i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"]


def test_numpys_blas_follows_the_count_here_and_in_workers(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.delenv(cpus.BLAS_ENV, raising=False)
    monkeypatch.setattr(cpus, "affinity_cpus", lambda: 4)
    monkeypatch.setattr(joblib, "cpu_count", lambda: 4)
    monkeypatch.setenv(cpus.ENV, "1")
    before = _blas_threads()
    with cpus.blas_threads():
        assert all(n == 1 for n in _blas_threads())
        assert os.environ[cpus.BLAS_ENV] == "1"  # what a spawned worker's NumPy reads
    assert _blas_threads() == before and cpus.BLAS_ENV not in os.environ


def test_a_users_blas_setting_is_left_alone(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(cpus, "affinity_cpus", lambda: 4)
    monkeypatch.setattr(joblib, "cpu_count", lambda: 4)
    monkeypatch.setenv(cpus.ENV, "1")
    monkeypatch.setenv(cpus.BLAS_ENV, "3")
    with cpus.blas_threads():
        assert os.environ[cpus.BLAS_ENV] == "3"
    assert os.environ[cpus.BLAS_ENV] == "3"


def test_info_computer_shows_what_a_run_would_record(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    import json

    monkeypatch.setenv(cpus.ENV, "3")
    assert main(["info", "--computer"]) == 0
    text = capsys.readouterr().out
    assert "with 3 CPU(s) (EXSUR_CPUS" in text and "| `torch_cpu_capability` |" in text
    assert main(["info", "--computer", "--json"]) == 0
    env = json.loads(capsys.readouterr().out)
    assert env["cpus"].startswith("3 CPU(s)") and env["torch_cpu_capability"]
    assert env.keys() == numerics.environment().keys()


def test_info_takes_a_path_or_computer(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["info"]) == 2
    assert "or --computer" in capsys.readouterr().err
    assert main(["info", str(tmp_path), "--computer"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "not both" in err[0]
