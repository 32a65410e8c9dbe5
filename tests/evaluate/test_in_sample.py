"""An evaluation of the split the model trained on says its scores are in-sample."""

from __future__ import annotations

import json

from excavator_surrogate.evaluate.cbe import evaluate_checkpoint
from excavator_surrogate.evaluate.run_report import ReportContext, render_run_report
from excavator_surrogate.training import train
from tests.helpers.training import tiny_dataset, tiny_train_config


def test_metrics_and_table_say_which_splits_the_model_trained_on(tmp_path):
    ds = tiny_dataset(2, n_train=2, n_step=120)
    on_val = train(tiny_train_config(epochs=2, train_on_val=True), ds, out=tmp_path / "on_val")
    plain = train(tiny_train_config(epochs=2), ds, out=tmp_path / "plain")
    cases = [
        (on_val, "val", True),  # the recipe's train_on_val: validation is training data
        (on_val, "test", False),
        (plain, "val", False),  # validation only selected the checkpoint
        (plain, "train", True),
    ]
    for k, (ckpt, split, in_sample) in enumerate(cases):
        out = tmp_path / f"ev{k}"
        res = evaluate_checkpoint(ckpt, ds, out=out, split=split, arx=False, figure=False)
        assert res["run"]["in_sample"] is in_sample, (split, in_sample)
        saved = json.loads((out / "metrics.json").read_text())
        assert saved["run"]["in_sample"] is in_sample
        table = (out / "table.md").read_text()
        note = f"**In-sample: the model trained on the '{split}' split it is scored on"
        assert (note in table) is in_sample


def _metrics(split: str, in_sample: bool | None) -> dict:
    joint = {"rmse": 0.1, "mae": 0.1, "r2": 0.9}
    run = {"split": split, "n_step_scored": 10, "reference": "measured"}
    if in_sample is not None:
        run["in_sample"] = in_sample
    return {"theta": {"boom": joint}, "omega": {"boom": joint}, "run": run}


def test_the_run_report_names_in_sample_scores_apart_from_optimistic_ones():
    ctx = ReportContext(name="real", spec_names=("boom",), table_md="")
    in_sample = render_run_report(_metrics("val", True), ctx)
    assert "which the networks also trained on, so these numbers are in-sample" in in_sample
    assert "`test = [...]`" in in_sample and "optimistic" not in in_sample
    for flag in (False, None):  # None: metrics.json written before the flag
        selected = render_run_report(_metrics("val", flag), ctx)
        assert "which also selected the checkpoint, so these numbers are optimistic" in selected
        assert "in-sample" not in selected
    scored_on_test = render_run_report(_metrics("test", False), ctx)
    assert "No test split" not in scored_on_test
