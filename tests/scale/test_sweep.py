"""Optuna sweep: tiny trials on a tiny synthetic dataset, SQLite storage, a second worker joining."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from excavator_surrogate.cli import main
from excavator_surrogate.config import load_preset
from excavator_surrogate.errors import ConfigError
from excavator_surrogate.scale.sweep import SweepConfig, run_sweep, safe_url
from excavator_surrogate.surrogate import load_checkpoint
from excavator_surrogate.surrogate.synthetic import synthetic_spec, write_synthetic_dataset
from excavator_surrogate.training import TrainConfig, train

optuna = pytest.importorskip("optuna")

PRESET = """
[train]
batch_size = 64
seq_len = 40
burn_in = 6
tbptt = 10
seq_batch = 4
val_steps = 100
tensorboard = false

[sweep]
window = [4, 8]
hidden = [6, 16]
layers = [1, 2]
horizon = [1, 3]
lambda_bias = [0.0, 0.5]
lr = [1e-3, 1e-2]
mode = ["windowed", "stateful"]
epochs = 3
pruner_startup = 2
pruner_warmup = 1
sampler_startup = 4
seed = 7
top = 4
"""


def test_sweep_eight_trials_report_and_join(tmp_path: Path) -> None:
    data = write_synthetic_dataset(
        tmp_path / "data", synthetic_spec(2), n_train=2, n_val=1, n_test=0, n_step=160
    )
    (tmp_path / "sweep.toml").write_text(PRESET)
    preset = load_preset(tmp_path / "sweep.toml")
    out = tmp_path / "sweep"
    res = run_sweep(
        data,
        out=out,
        trials=7,
        sweep=SweepConfig.from_preset(preset),
        base=TrainConfig.mode_bases(preset),
    )
    assert (out / "study.db").is_file()
    assert res.n_complete + res.n_pruned + res.n_fail == 7 and res.n_fail == 0
    # a second worker joins the same study through the CLI
    rc = main(
        [
            "sweep",
            str(data),
            "--out",
            str(out),
            "--trials",
            "1",
            "--preset",
            str(tmp_path / "sweep.toml"),
            "--storage",
            res.storage,
        ]
    )
    assert rc == 0
    summary = json.loads((out / "sweep.json").read_text())
    assert summary["complete"] + summary["pruned"] == 8
    best = summary["best"]
    assert math.isfinite(best["value"]) and best["params"]
    table = (out / "sweep.md").read_text()
    assert "| rank | trial | val_error |" in table and f"| 1 | {best['trial']} |" in table
    assert (out / "sweep.png").stat().st_size > 10_000
    sur = load_checkpoint(out / "best.pt")
    assert sur.metrics["best_val_error"] == pytest.approx(best["value"])
    for row in summary["trials"]:  # every trial reported its per-epoch validation error
        assert 1 <= len(row["curve"]) <= 3
        assert row["train"]["epochs"] == 3 and row["train"]["tensorboard"] is False


def test_trials_report_only_the_validated_epochs(tmp_path: Path) -> None:
    """With ``select_after``, the epochs before it are not validated: the trials report the
    epochs after it, and none is pruned for the missing scores."""
    data = write_synthetic_dataset(
        tmp_path / "data", synthetic_spec(2), n_train=2, n_val=1, n_test=0, n_step=160
    )
    preset_text = PRESET.replace(
        "tensorboard = false",
        'tensorboard = false\nlr_schedule = "cosine"\nselect_after = 0.5\nselect_smooth = 0',
    ).replace("epochs = 3", "epochs = 4")
    (tmp_path / "sweep.toml").write_text(preset_text)
    preset = load_preset(tmp_path / "sweep.toml")
    res = run_sweep(
        data,
        out=tmp_path / "sweep",
        trials=3,
        sweep=SweepConfig.from_preset(preset),
        base=TrainConfig.mode_bases(preset),
    )
    assert res.n_fail == 0
    summary = json.loads((tmp_path / "sweep" / "sweep.json").read_text())
    for row in summary["trials"]:
        assert row["train"]["select_after"] == 0.5
        epochs = [e for e, _ in row["curve"]]
        assert epochs and min(epochs) >= 2  # epochs 0 and 1 were not validated
        assert all(math.isfinite(v) for _, v in row["curve"])


def test_on_epoch_hook_stops_training(tmp_path: Path) -> None:
    data = write_synthetic_dataset(
        tmp_path / "d", synthetic_spec(2), n_train=1, n_val=1, n_test=0, n_step=120
    )
    from excavator_surrogate.data import load_dataset

    seen: list[tuple[int, float]] = []

    def hook(epoch: int, row: dict) -> bool:
        seen.append((epoch, row["val_error"]))
        return epoch == 1

    cfg = TrainConfig(window=5, hidden=6, head_hidden=6, layers=1, epochs=10, tensorboard=False)
    train(cfg, load_dataset(data), out=tmp_path / "m", show_progress=False, on_epoch=hook)
    assert [e for e, _ in seen] == [0, 1]
    assert (tmp_path / "m" / "best.pt").is_file()


def test_sweep_config_validation_and_url_masking() -> None:
    with pytest.raises(ConfigError, match="window"):
        SweepConfig(window=(10, 5))
    with pytest.raises(ConfigError, match="mode"):
        SweepConfig(mode=("recurrent",))
    with pytest.raises(ConfigError, match="unknown key"):
        SweepConfig.from_preset({"sweep": {"widow": [1, 2]}})
    assert SweepConfig.from_preset({"sweep": {"lr": [1e-3, 1e-3]}}, epochs=4).epochs == 4
    assert safe_url("postgresql://me:secret@db:5432/x") == "postgresql://me:***@db:5432/x"


def test_a_sweep_whose_every_trial_fails_says_why_and_exits_2(tmp_path: Path, capsys) -> None:
    """A window longer than the episodes fails every trial: each failure is one logged line
    (no traceback), and the command ends in one error line with exit code 2 (it exited 0)."""
    data = write_synthetic_dataset(
        tmp_path / "data", synthetic_spec(2), n_train=2, n_val=1, n_test=0, n_step=120
    )
    (tmp_path / "s.toml").write_text(PRESET.replace("window = [4, 8]", "window = [300, 300]"))
    argv = ["sweep", str(data), "--out", str(tmp_path / "s"), "--trials", "1"]
    assert main([*argv, "--preset", str(tmp_path / "s.toml")]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and "trial 0 failed: " in err
    assert (
        err.strip()
        .splitlines()[-1]
        .startswith(f"exsur: error: {tmp_path / 's'}: no trial of the study completed (1 failed")
    )
    # a device this computer lacks: one line before anything is written
    if not __import__("torch").cuda.is_available():
        assert (
            main(
                [
                    "sweep",
                    str(data),
                    "--out",
                    str(tmp_path / "c"),
                    "--device",
                    "cuda",
                    "--trials",
                    "1",
                ]
            )
            == 2
        )
        assert "device 'cuda' is not available" in capsys.readouterr().err
        assert not (tmp_path / "c").exists()


def test_a_trial_the_cap_cut_is_marked_in_the_report(tmp_path: Path) -> None:
    """A trial the wall-time cap stopped at 1 of its planned epochs ranked as ``epochs 1``,
    ``state: complete``, like one that ran its plan: ``sweep.json`` now records
    ``budget_cut`` and ``sweep.md`` marks it."""
    data = write_synthetic_dataset(
        tmp_path / "data", synthetic_spec(2), n_train=1, n_val=1, n_test=0, n_step=120
    )
    (tmp_path / "sweep.toml").write_text(PRESET.replace("pruner_startup = 2", "pruner_startup = 9"))
    preset = load_preset(tmp_path / "sweep.toml")
    scfg = SweepConfig.from_preset(preset, epochs=20, max_train_seconds=1e-3)
    res = run_sweep(
        data, out=tmp_path / "s", trials=1, sweep=scfg, base=TrainConfig.mode_bases(preset)
    )
    assert res.n_complete == 1
    (row,) = json.loads((tmp_path / "s" / "sweep.json").read_text())["trials"]
    assert row["budget_cut"] is True and row["epochs_run"] == 1
    md = (tmp_path / "s" / "sweep.md").read_text()
    assert "| 1 (cut) |" in md and "cut trial(s) 0 short" in md


def test_a_sweep_records_the_config_that_repeats_it(tmp_path: Path) -> None:
    """A sweep's folder held no ``config.toml`` (only its trials'): the search space, the
    sampler seed, the pruner and the base ``[train]`` were lost.  Its record loads back to
    the same ``[sweep]`` and the same bases (this ``[train]`` sets both modes' knobs)."""
    import tomllib

    from excavator_surrogate.stages import load_preset as load_checked

    data = write_synthetic_dataset(
        tmp_path / "data", synthetic_spec(2), n_train=1, n_val=1, n_test=0, n_step=120
    )
    (tmp_path / "sweep.toml").write_text(PRESET)
    preset = load_preset(tmp_path / "sweep.toml")
    scfg, base = SweepConfig.from_preset(preset, epochs=1), TrainConfig.mode_bases(preset)
    run_sweep(data, out=tmp_path / "s", trials=1, sweep=scfg, base=base, timeout=600.0)
    record = tmp_path / "s" / "config.toml"
    back = load_checked(record)
    assert SweepConfig.from_preset(back) == scfg and scfg.seed == 7
    assert TrainConfig.mode_bases(back) == base
    assert tomllib.loads(record.read_text())["command"] == {
        "name": "sweep",
        "dataset": str(data.resolve()),
        "trials": 1,
        "study": "exsur",
        "storage": f"sqlite:///{(tmp_path / 's' / 'study.db').resolve()}",
        "timeout": 600.0,
    }


def test_quiet_silences_optunas_info_lines_too(tmp_path: Path) -> None:
    """Under ``-q`` (the package logger at WARNING) Optuna still logged ``A new study
    created`` and ``Trial 0 finished`` at INFO; its lines now follow exsur's level, and its
    own level is restored afterwards."""
    import logging

    data = write_synthetic_dataset(
        tmp_path / "data", synthetic_spec(2), n_train=1, n_val=1, n_test=0, n_step=120
    )
    (tmp_path / "sweep.toml").write_text(PRESET)
    preset = load_preset(tmp_path / "sweep.toml")
    seen: list[logging.LogRecord] = []
    handler = logging.Handler()
    handler.emit = seen.append  # type: ignore[method-assign]
    optuna_logger, pkg = logging.getLogger("optuna"), logging.getLogger("excavator_surrogate")
    before, level = optuna.logging.get_verbosity(), pkg.level
    optuna_logger.addHandler(handler)
    pkg.setLevel(logging.WARNING)
    try:
        run_sweep(
            data,
            out=tmp_path / "s",
            trials=1,
            sweep=SweepConfig.from_preset(preset, epochs=1),
            base=TrainConfig.mode_bases(preset),
        )
        assert optuna.logging.get_verbosity() == before
        assert [r.getMessage() for r in seen if r.levelno < logging.WARNING] == []
        pkg.setLevel(logging.INFO)  # without -q they are shown
        run_sweep(
            data,
            out=tmp_path / "s",
            trials=1,
            sweep=SweepConfig.from_preset(preset, epochs=1),
            base=TrainConfig.mode_bases(preset),
        )
        assert any("Trial 1 finished" in r.getMessage() for r in seen)
    finally:
        optuna_logger.removeHandler(handler)
        pkg.setLevel(level)


def test_a_resumed_seeded_sweep_goes_on_searching(tmp_path: Path) -> None:
    """The sampler started from the same seed on every run, so a seeded sweep run again in
    its folder trained its first configuration again (same params, same val_error).  It
    now seeds with ``seed`` plus the trials already in the study."""
    data = write_synthetic_dataset(
        tmp_path / "data", synthetic_spec(2), n_train=1, n_val=1, n_test=0, n_step=120
    )
    (tmp_path / "sweep.toml").write_text(PRESET)
    preset = load_preset(tmp_path / "sweep.toml")
    kw = dict(sweep=SweepConfig.from_preset(preset, epochs=1), base=TrainConfig.mode_bases(preset))
    first = run_sweep(data, out=tmp_path / "a", trials=1, **kw)
    run_sweep(data, out=tmp_path / "a", trials=1, **kw)  # the same command again
    rows = json.loads((tmp_path / "a" / "sweep.json").read_text())["trials"]
    assert [r["trial"] for r in rows] == [0, 1]
    assert rows[0]["params"] != rows[1]["params"]
    again = run_sweep(data, out=tmp_path / "b", trials=1, **kw)  # a fresh sweep: reproducible
    assert again.best_params == first.best_params


def test_trials_rank_on_the_error_of_the_checkpoint_they_ship(tmp_path: Path) -> None:
    """With ``average_last`` a trial's ``best.pt`` holds the selected epoch averaged with the
    last one, scored again; the trial was ranked on the selected epoch's error
    (``best_val_error``), so the table's val_error was not the copied ``best.pt``'s."""
    data = write_synthetic_dataset(
        tmp_path / "data", synthetic_spec(2), n_train=1, n_val=1, n_test=0, n_step=120
    )
    (tmp_path / "sweep.toml").write_text(
        PRESET.replace("tensorboard = false", "tensorboard = false\naverage_last = true")
        .replace('mode = ["windowed", "stateful"]', 'mode = ["windowed"]')
        .replace("pruner_startup = 2", "pruner_startup = 9")
    )
    preset = load_preset(tmp_path / "sweep.toml")
    res = run_sweep(
        data,
        out=tmp_path / "s",
        trials=2,
        sweep=SweepConfig.from_preset(preset),
        base=TrainConfig.mode_bases(preset),
    )
    assert res.n_complete == 2
    for row in json.loads((tmp_path / "s" / "sweep.json").read_text())["trials"]:
        metrics = load_checkpoint(row["checkpoint"]).metrics
        assert "averaged_with_last" in metrics
        assert metrics["val_error"] != metrics["best_val_error"]  # the average scores apart
        assert row["value"] == pytest.approx(metrics["val_error"], rel=1e-12)
    assert load_checkpoint(tmp_path / "s" / "best.pt").metrics["val_error"] == pytest.approx(
        res.best_value, rel=1e-12
    )


def test_a_second_study_in_the_folder_of_another_is_refused(tmp_path: Path, capsys) -> None:
    """Trial numbers restart at 0 in every study: a second study (``--study other``, or the
    same name in another database) in a sweep's ``--out`` trained into the first study's
    ``trials/trial_NNNN`` and replaced its checkpoints, ``best.pt`` and ``config.toml``.
    It is now one line before anything is written, unless ``--overwrite``."""
    import shutil

    from excavator_surrogate.scale.sweep_checks import default_storage

    data = write_synthetic_dataset(
        tmp_path / "data", synthetic_spec(2), n_train=1, n_val=1, n_test=0, n_step=120
    )
    (tmp_path / "sweep.toml").write_text(PRESET.replace("epochs = 3", "epochs = 1"))
    out = tmp_path / "s"
    argv = ["sweep", str(data), "--out", str(out), "--trials", "1"]
    argv += ["--preset", str(tmp_path / "sweep.toml"), "-q"]
    assert main(argv) == 0
    before = {p: p.read_bytes() for p in out.rglob("*") if p.is_file()}
    other_db = f"sqlite:///{tmp_path / 'other.db'}"
    for extra, held in (
        (["--study", "other"], "study 'exsur'; study 'other' would write"),
        (["--storage", other_db], f"study 'exsur' at {default_storage(out)}; study 'exsur' at"),
    ):
        assert main([*argv, *extra]) == 2
        err = capsys.readouterr().err.strip()
        assert (
            err == (f"exsur: error: {out}: --out holds the sweep of {held}" + err.split(held, 1)[1])
            and "\n" not in err
        )
        assert "give it another --out" in err and "--overwrite" in err
        assert {p: p.read_bytes() for p in out.rglob("*") if p.is_file()} == before
    assert not (tmp_path / "other.db").exists()
    # the same study goes on in its folder, also when the folder moved
    from excavator_surrogate.scale.sweep_checks import check_owner

    moved = tmp_path / "moved"
    shutil.copytree(out, moved)
    check_owner(moved, study_name="exsur", storage=default_storage(moved), overwrite=False)
    check_owner(out, study_name="other", storage=default_storage(out), overwrite=True)
