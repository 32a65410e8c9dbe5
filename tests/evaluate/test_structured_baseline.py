"""The evaluation's structured baseline (dead zone, gain, delay, end stops per joint) and the
line that says, per model of the comparison, on how many joints the surrogate beats it."""

from __future__ import annotations

import math

from excavator_surrogate.data import write_dataset
from excavator_surrogate.data.dataset import load_dataset
from excavator_surrogate.evaluate.cbe import STRUCTURED, evaluate_checkpoint, evaluate_models
from excavator_surrogate.evaluate.report import against_others
from excavator_surrogate.evaluate.run_report import ReportContext, render_run_report
from excavator_surrogate.spec import EXCAVATOR
from excavator_surrogate.surrogate.checkpoint import save_checkpoint
from excavator_surrogate.surrogate.structured import fit_structured
from excavator_surrogate.surrogate.synthetic import synthetic_split
from tests.helpers.surrogates import tiny_surrogate


def _theta(rmse: dict[str, float | None]) -> dict:
    return {"theta": {j: {"rmse": v, "mae": v, "r2": None} for j, v in rmse.items()}}


def test_the_structured_baseline_is_the_fit_on_the_training_split(tmp_path):
    items = synthetic_split(EXCAVATOR, n_train=3, n_val=1, n_test=1, n_step=200, noise=0.001)
    ds = load_dataset(write_dataset(tmp_path / "data", items))
    sur = tiny_surrogate(mode="stateful", window=5)
    ckpt = save_checkpoint(tmp_path / "m.pt", sur)
    res = evaluate_checkpoint(ckpt, ds, out=tmp_path / "ev", figure=False, horizons=())
    assert list(res["compare"]) == ["ARX", STRUCTURED]
    # the reference path: the baseline fitted alone on the training split, run alone
    alone, _ = evaluate_models({"s": fit_structured(ds.train, window=5, spec=ds.spec)}, ds.test)
    for key in ("omega", "theta"):
        for j in ds.spec.names:
            assert res["compare"][STRUCTURED][key][j] == alone["s"][key][j], (key, j)
    table = (tmp_path / "ev" / "table.md").read_text()
    assert "Structured RMSE" in table and "**Free-run angle RMSE of " in table
    # off: not fitted, not in the table, nor in the line
    res = evaluate_checkpoint(
        ckpt, ds, out=tmp_path / "ev", figure=False, horizons=(), structured=False
    )
    assert list(res["compare"]) == ["ARX"]
    assert "Structured" not in (tmp_path / "ev" / "table.md").read_text()


def test_the_line_counts_the_joints_and_names_each_one_lost():
    deg = math.radians(1.0)
    by_model = {
        "LSTM": _theta({"boom": 2.0 * deg, "arm": 27.15 * deg, "bucket": 0.5 * deg}),
        "ARX": _theta({"boom": 9.0 * deg, "arm": 30.0 * deg, "bucket": 0.6 * deg}),
        "Structured": _theta({"boom": 2.0 * deg, "arm": 5.864 * deg, "bucket": None}),
    }
    line = against_others(by_model, primary="LSTM")
    assert line == (
        "**Free-run angle RMSE of LSTM:** lower than ARX on 3 of 3 joints; lower than "
        "Structured on 1 of 3 joints (not the boom: 2.00° against 2.00°, the arm: 27.1° "
        "against 5.86°)."
    )  # the bucket counts: a model without a finite error there (a diverged run) loses it
    diverged = {**by_model, "LSTM": _theta({"boom": None, "arm": 1.0 * deg, "bucket": 0.5 * deg})}
    assert "lower than ARX on 2 of 3 joints (not the boom: no finite error against 9.00°)" in (
        against_others(diverged, primary="LSTM")
    )
    # a linear joint in its own unit; the table's only model gives no line
    strokes = {"LSTM": _theta({"boom": 0.0512}), "ARX": _theta({"boom": 0.0123})}
    got = against_others(strokes, primary="LSTM", units={"boom": (1000.0, "mm")})
    assert got == (
        "**Free-run position RMSE of LSTM:** lower than ARX on 0 of 1 joints (not the boom: "
        "51.2 mm against 12.3 mm)."
    )
    big = {"LSTM": _theta({"boom": 1.2345}), "ARX": _theta({"boom": 0.5})}
    assert "1234 mm against 500 mm" in against_others(
        big, primary="LSTM", units={"boom": (1000.0, "mm")}
    )  # not 1.23e+03 mm
    assert against_others({"LSTM": by_model["LSTM"]}, primary="LSTM") == ""


def test_the_run_report_says_it_under_the_headline():
    deg = math.radians(1.0)
    metrics = {
        **_theta({"boom": 2.0 * deg, "arm": 4.0 * deg}),
        "omega": {j: {"rmse": 0.1, "mae": 0.1, "r2": 0.9} for j in ("boom", "arm")},
        "run": {"split": "test", "n_step_scored": 100, "reference": "measured"},
        "compare": {"Structured": _theta({"boom": 3.0 * deg, "arm": 3.0 * deg})},
    }
    for j in ("boom", "arm"):
        metrics["theta"][j]["r2"] = 0.9
    text = render_run_report(
        metrics, ReportContext(name="real", spec_names=("boom", "arm"), table_md="")
    )
    head = text[: text.index("![closed-loop comparison]")]
    assert (
        "**Free-run angle RMSE of the surrogate:** lower than Structured on 1 of 2 joints "
        "(not the arm: 4.00° against 3.00°)." in head
    )
