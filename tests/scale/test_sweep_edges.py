"""Edge cases of the sweep: its search space's ranges, storages that cannot be opened, the
trials' config from one base, and reports of studies without a completed or reachable trial.
No trial trains here."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import pytest

from excavator_surrogate.cli import main
from excavator_surrogate.errors import ConfigError
from excavator_surrogate.scale.sweep import (
    SweepConfig,
    open_study,
    run_sweep,
    safe_url,
    trial_config,
)
from excavator_surrogate.surrogate.synthetic import synthetic_spec, write_synthetic_dataset
from excavator_surrogate.training import TrainConfig

optuna = pytest.importorskip("optuna")


@pytest.fixture(scope="module")
def data(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("sweep_edges") / "data"
    return write_synthetic_dataset(root, synthetic_spec(2), n_train=1, n_val=1, n_test=0, n_step=60)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"lambda_bias": (-0.1, 0.5)}, "[sweep] lambda_bias = [-0.1, 0.5] needs 0 <= low <= high"),
        ({"lr": (0.0, 1e-3)}, "[sweep] lr = [0.0, 0.001] needs 0 < low <= high"),
        ({"epochs": 0}, "[sweep] epochs = 0 must be >= 1"),
        ({"top": 0}, "[sweep] top = 0 must be >= 1"),
        ({"pruner_warmup": -1}, "[sweep] pruner_warmup = -1 must be >= 0"),
        ({"sampler_startup": -2}, "[sweep] sampler_startup = -2 must be >= 0"),
    ],
)
def test_search_space_ranges_name_the_key_and_value(kwargs: dict, message: str) -> None:
    with pytest.raises(ConfigError) as e:
        SweepConfig(**kwargs)
    assert str(e.value) == message


def test_a_database_without_its_driver_is_one_line_without_the_password() -> None:
    url = "postgresql://me:secret@127.0.0.1:1/db"
    try:
        import psycopg2  # noqa: F401
    except ImportError:
        pass
    else:
        pytest.skip("psycopg2 is installed: the driver is not missing")
    with pytest.raises(ConfigError) as e:
        open_study(storage=url, study_name="s", scfg=SweepConfig())
    msg = str(e.value)
    assert msg.startswith("storage 'postgresql://me:***@127.0.0.1:1/db': database driver missing")
    assert "pip install psycopg2-binary" in msg and "secret" not in msg and "\n" not in msg


@pytest.mark.parametrize(
    ("url", "shown"),
    [
        ("postgresql://me:secret@db:5432/x", "postgresql://me:***@db:5432/x"),
        # an empty user: the pattern needed one, and showed the password
        ("postgresql://:secret@127.0.0.1:1/db", "postgresql://:***@127.0.0.1:1/db"),
        # a password query parameter: shown as it was
        (
            "postgresql://me@127.0.0.1:1/db?password=secret",
            "postgresql://me@127.0.0.1:1/db?password=***",
        ),
        # an '@' in the query: the pattern masked up to it, and lost the host
        (
            "postgresql://me:secret@host/db?sslmode=require&application_name=a@b",
            "postgresql://me:***@host/db?application_name=a%40b&sslmode=require",
        ),
        ("sqlite:////tmp/a b/study.db", "sqlite:////tmp/a b/study.db"),  # nothing to hide
        ("nosuchdb://x", "nosuchdb://x"),
        # not a URL SQLAlchemy parses: masked by pattern
        ("my-db://me:secret@db/x?password=secret&a=1", "my-db://me:***@db/x?password=***&a=1"),
    ],
)
def test_storage_passwords_are_masked_in_every_url_form(url: str, shown: str) -> None:
    assert safe_url(url) == shown


def test_a_storage_that_cannot_be_opened_is_one_line(tmp_path: Path) -> None:
    with pytest.raises(ConfigError) as e:
        open_study(storage="nosuchdb://x", study_name="s", scfg=SweepConfig())
    assert str(e.value).startswith("storage 'nosuchdb://x': cannot open the study (")
    with pytest.raises(ConfigError, match="cannot open the study"):
        open_study(storage=f"sqlite:///{tmp_path}/no/dir/s.db", study_name="s", scfg=SweepConfig())


def test_an_error_that_is_not_the_storages_is_not_hidden(monkeypatch) -> None:
    def broken(**kwargs: object) -> None:
        raise RuntimeError("a bug")

    monkeypatch.setattr(optuna, "create_study", broken)
    with pytest.raises(RuntimeError, match="a bug"):
        open_study(storage="sqlite:///:memory:", study_name="s", scfg=SweepConfig())


def test_a_failed_storage_leaves_no_output_folder(data: Path, tmp_path: Path, capsys) -> None:
    out = tmp_path / "new" / "sw"
    argv = ["sweep", data, "--out", out, "--trials", "1", "--storage", "nosuchdb://x"]
    assert main([str(a) for a in argv]) == 2
    err = capsys.readouterr().err
    assert err.startswith("exsur: error: storage 'nosuchdb://x': cannot open the study")
    assert not out.exists()  # no folder that holds nothing but the marker
    kept = tmp_path / "kept"
    kept.mkdir()
    argv[3] = kept
    assert main([str(a) for a in argv]) == 2
    assert kept.is_dir()  # a folder that was there stays


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [({"trials": 0}, "--trials must be >= 1, got 0"), ({"timeout": 0.0}, "--timeout must be > 0")],
)
def test_trials_and_timeout_are_checked_before_anything_is_written(
    data: Path, tmp_path: Path, kwargs: dict, message: str
) -> None:
    with pytest.raises(ConfigError, match=message):
        run_sweep(data, out=tmp_path / "sw", **{"trials": 1, **kwargs})
    assert not (tmp_path / "sw").exists()


def test_a_trial_from_one_base_of_the_other_mode() -> None:
    base = TrainConfig(mode="windowed", window=5)
    scfg = SweepConfig(epochs=3)
    cfg = trial_config(base, scfg, {"mode": "stateful", "window": 40})
    assert cfg.mode == "stateful" and cfg.burn_in == 40 and cfg.seq_len >= 40 + cfg.tbptt
    assert cfg.epochs == 3 and not cfg.tensorboard
    same = trial_config(base, scfg, {"window": 7})  # no mode sampled: the base's
    assert same.mode == "windowed" and same.window == 7


def _study() -> optuna.Study:
    return optuna.create_study(direction="minimize", study_name="edges")


def test_a_report_without_completed_trials(tmp_path: Path) -> None:
    from excavator_surrogate.scale.sweep_report import write_report

    study = _study()
    study.add_trial(optuna.trial.create_trial(state=optuna.trial.TrialState.FAIL))
    res = write_report(study, out=tmp_path, storage="memory")
    assert (res.n_complete, res.n_fail, res.best_value, res.best_checkpoint) == (0, 1, None, None)
    assert "| – | no completed trial yet | | | |" in (tmp_path / "sweep.md").read_text()
    summary = json.loads((tmp_path / "sweep.json").read_text())
    assert summary["trials"] == [] and summary["fail"] == 1
    assert (tmp_path / "sweep.png").stat().st_size > 0


def test_a_best_trial_of_another_machine_is_named_not_copied(tmp_path: Path, caplog) -> None:
    from excavator_surrogate.scale.sweep_report import write_report

    study = _study()
    dist = {"lr": optuna.distributions.FloatDistribution(1e-4, 1e-2, log=True)}
    gone = tmp_path / "elsewhere" / "best.pt"
    trial = optuna.trial.create_trial(
        params={"lr": 1e-3},
        distributions=dist,
        value=0.25,
        intermediate_values={0: 0.5, 1: 0.25},
        user_attrs={"checkpoint": str(gone), "host": "node7"},
    )
    study.add_trial(trial)
    with caplog.at_level(logging.INFO, logger="excavator_surrogate"):
        res = write_report(study, out=tmp_path / "out", storage="memory")
    assert res.best_trial == 0 and res.best_value == pytest.approx(0.25)
    assert res.best_checkpoint is None and not (tmp_path / "out" / "best.pt").exists()
    assert f"best trial 0 ran on node7; its checkpoint {gone} is not reachable" in caplog.text
    assert "copy it by hand" in caplog.text


@pytest.mark.parametrize(
    ("train", "message"),
    [
        (
            {"members": 2},
            "[train] members = 2: a sweep trial trains one network; give --set train.members=1",
        ),
        (
            {"members": 3, "prior_choice": True},
            "[train] members = 3, prior_choice = true: a sweep trial trains one network; "
            "give --set train.members=1 --set train.prior_choice=false",
        ),
    ],
)
def test_a_base_every_trial_would_fail_on_is_one_line_before_any_trial(
    data: Path, tmp_path: Path, capsys, train: dict, message: str
) -> None:
    """Each trial failed on its own with training's advice ("on_epoch works per member ...
    merge them with 'exsur merge'"), then the sweep ended "no trial completed", its folder
    left behind."""
    out = tmp_path / "sw"
    sets = [f"--set=train.{k}={str(v).lower()}" for k, v in train.items()]
    assert main(["sweep", str(data), "--out", str(out), "--trials", "2", *sets]) == 2
    assert capsys.readouterr().err.strip() == f"exsur: error: {message}"
    assert not out.exists()


def test_exogenous_choose_and_a_missing_device_of_the_base_are_refused() -> None:
    import dataclasses

    from excavator_surrogate.scale.sweep_checks import check_base
    from excavator_surrogate.spec import InputSpec

    spec = synthetic_spec(2)
    with_input = dataclasses.replace(spec, inputs=(InputSpec("rpm", 0.0, 2000.0, "rpm"),))
    choose = TrainConfig(exogenous="choose")
    check_base({"windowed": choose}, spec)  # no inputs: nothing to choose, nothing refused
    with pytest.raises(ConfigError) as e:
        check_base({"windowed": TrainConfig(), "stateful": choose}, with_input)
    assert str(e.value) == (
        '[train] exogenous = "choose": a sweep trial trains one network; give '
        "--set train.exogenous=use"
    )
    if not __import__("torch").cuda.is_available():  # --set train.device=cuda ran the trials
        with pytest.raises(ConfigError, match="device 'cuda' is not available"):
            check_base(TrainConfig(device="cuda"), spec)
