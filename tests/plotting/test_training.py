"""Learning curves of a training folder (plotting.training): which logs it reads, the figure,
and its errors."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest

from excavator_surrogate.errors import ConfigError, DataError
from excavator_surrogate.outdir import is_exsur_file
from excavator_surrogate.plotting.training import plot_learning_curves, read_curves


def _log(path: Path, val: list[str], loss: list[float], best: list[int] | None = None) -> None:
    """An epoch log as training writes it (extra columns, empty val_error where not run;
    ``best``: 1 where the checkpoint was updated)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    best = best or [0] * len(val)
    with path.open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["epoch", "time_s", "train_loss", "val_error", "best"])
        for k, (v, lo, b) in enumerate(zip(val, loss, best, strict=True)):
            w.writerow([k, k * 1.5, lo, v, b])


def test_reads_every_network_log_and_skips_the_ensemble_summary(tmp_path: Path) -> None:
    _log(tmp_path / "plain" / "member_1" / "log.csv", ["", "0.5", "0.3"], [0.1, 0.05, 0.02])
    _log(tmp_path / "plain" / "member_0" / "log.csv", ["0.9", "0.4", "0.6"], [0.2, 0.1, 0.04])
    _log(tmp_path / "prior" / "member_0" / "log.csv", ["0.3", "0.2"], [0.02, 0.01])
    (tmp_path / "log.csv").write_text("member,seed,epoch,val_error\n0,0,1,0.4\n1,1,2,0.3\n")
    curves = read_curves(tmp_path)
    assert [c.label for c in curves] == ["plain/member_0", "plain/member_1", "prior/member_0"]
    c = curves[1]
    np.testing.assert_array_equal(c.epoch, [0, 1, 2])
    np.testing.assert_array_equal(c.train_loss, [0.1, 0.05, 0.02])
    assert np.isnan(c.val_error[0]) and c.val_error[2] == 0.3

    png = plot_learning_curves(tmp_path, out=tmp_path / "learning_curve.png")
    assert png.stat().st_size > 0 and is_exsur_file(png)
    assert [p.name for p in tmp_path.iterdir() if p.suffix == ".tmp"] == []


def test_a_single_network_folder_is_labelled_network(tmp_path: Path) -> None:
    _log(tmp_path / "log.csv", ["0.5", "0.4"], [0.1, 0.05])
    assert [(c.label, c.free_from) for c in read_curves(tmp_path)] == [("network", None)]


def test_the_switch_to_the_free_run_loss_is_read_from_the_networks_config(tmp_path: Path) -> None:
    for name, train in (
        ("free", 'feedback = "free"\nteacher_epochs = 3\n'),
        ("teacher", 'feedback = "teacher"\nteacher_epochs = 1\n'),
        ("free_no_warmup", 'feedback = "free"\nteacher_epochs = 0\n'),
    ):
        _log(tmp_path / name / "log.csv", ["0.5", "0.4", "0.3", "0.2"], [0.1, 0.05, 0.3, 0.2])
        (tmp_path / name / "config.toml").write_text("[train]\n" + train)
    got = {c.label: c.free_from for c in read_curves(tmp_path)}
    assert got == {"free": 3, "teacher": None, "free_no_warmup": None}
    assert plot_learning_curves(tmp_path, out=tmp_path / "lc.png").is_file()


def test_no_epoch_log_and_a_wrong_suffix_are_clear_errors(tmp_path: Path) -> None:
    with pytest.raises(DataError, match="no epoch log"):
        plot_learning_curves(tmp_path, out=tmp_path / "lc.png")
    _log(tmp_path / "log.csv", ["0.5"], [0.1])
    with pytest.raises(ConfigError, match="ending in .png"):
        plot_learning_curves(tmp_path, out=tmp_path / "lc.jpg")
    assert not (tmp_path / "lc.png").exists() and not (tmp_path / "lc.jpg").exists()


def test_the_dot_marks_the_selected_epoch_not_the_lowest_error(tmp_path: Path) -> None:
    """Selection may start late, smooth the error or average weights: the dot is the epoch the
    log marks best last (the one best.pt holds), not the curve's minimum."""
    from excavator_surrogate.plotting.training import _selected_row

    # epoch 1 has the lowest error, but selection only ran from epoch 2 (marks 2, then 4)
    _log(
        tmp_path / "late" / "log.csv",
        ["0.5", "0.1", "0.4", "0.3", "0.35"],
        [1] * 5,
        best=[0, 0, 1, 0, 1],
    )
    _log(tmp_path / "unmarked" / "log.csv", ["0.5", "0.1", "0.4"], [1] * 3)
    late, unmarked = read_curves(tmp_path)
    assert late.selected == 4 and _selected_row(late) == 4
    assert unmarked.selected is None and _selected_row(unmarked) == 1  # the lowest, as before
    assert plot_learning_curves(tmp_path, out=tmp_path / "lc.png").is_file()
