"""The bands' calibration after training: which runs count as held out."""

from __future__ import annotations

import logging
from types import SimpleNamespace

from excavator_surrogate.training import calibration
from tests.helpers.training import tiny_dataset, tiny_train_config


def test_validation_trained_on_is_calibrated_as_training_runs(monkeypatch, caplog, tmp_path):
    """With train_on_val the validation runs are the model's own data: no held-out run is
    passed to the calibration, they join the training runs, and the log says the bands are
    in-sample; otherwise validation is the held-out group."""
    seen: list[tuple[list[str], list[str]]] = []

    # what the log line reads of a Calibration
    cal = SimpleNamespace(n_step=100, n_run=0, n_train_run=3, levels=(0.9,), theta=[[1.0, 2.0]])

    def fake(best, val, train):
        seen.append(([e.name for e in val], [e.name for e in train]))
        return cal, None

    monkeypatch.setattr(calibration, "calibrate_checkpoint", fake)
    data = tiny_dataset(2, n_train=2, n_step=120)
    with caplog.at_level(logging.INFO, logger=calibration.__name__):
        calibration.calibrate_best(tiny_train_config(train_on_val=True), data, tmp_path / "b.pt")
        calibration.calibrate_best(tiny_train_config(), data, tmp_path / "b.pt")
    (on_val, on_train), (off_val, off_train) = seen
    names = [e.name for e in data.val]
    assert on_val == [] and on_train[-len(names) :] == names
    assert off_val == names and not set(names) & set(off_train)
    assert "validation is trained on" in caplog.records[0].getMessage()
    assert "validation and 3 training runs" in caplog.records[1].getMessage()
