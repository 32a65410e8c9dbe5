"""CBE metrics against hand-computed values; tables; figure."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from excavator_surrogate.evaluate import (
    PAPER_TABLE_II,
    cbe_metrics,
    comparison_table,
    markdown_table,
    min_r2,
    regression_metrics,
)
from excavator_surrogate.plotting.cbe import plot_cbe
from excavator_surrogate.spec import JointSpec, MachineSpec
from tests.helpers.runs import Run


def test_regression_metrics_hand_computed():
    ref = np.array([[1.0, 0.0], [2.0, 0.0], [3.0, 0.0], [4.0, 0.0]])
    pred = np.array([[1.0, 1.0], [2.5, -1.0], [2.0, 1.0], [4.0, -1.0]])
    m = regression_metrics(pred, ref)
    # joint 0: errors 0, .5, -1, 0 -> MSE = 1.25/4, MAE = 1.5/4; SS_tot = 5 -> R2 = 1 - 1.25/5
    assert m["rmse"][0] == pytest.approx(math.sqrt(1.25 / 4))
    assert m["mae"][0] == pytest.approx(1.5 / 4)
    assert m["r2"][0] == pytest.approx(0.75)
    assert m["rmse"][1] == pytest.approx(1.0) and m["mae"][1] == pytest.approx(1.0)
    assert math.isnan(m["r2"][1])  # constant reference


def test_cbe_metrics_excludes_warmup_pools_episodes_and_unwraps():
    spec = MachineSpec(joints=(JointSpec("swing", periodic=True), JointSpec("boom")))
    n, w = 10, 3
    t = np.linspace(0, 1, n)
    th_ref = np.stack([np.linspace(3.0, 3.5, n), t], axis=1)
    wrapped = th_ref.copy()
    wrapped[:, 0] = (wrapped[:, 0] + np.pi) % (2 * np.pi) - np.pi  # crosses +pi: stored wrapped
    om_ref = np.ones((n, 2))
    th_hat = th_ref.copy()
    th_hat[w:, 1] += 0.1
    th_hat[:w] = 99.0  # garbage in the warm-up must not count
    om_hat = om_ref + 0.2
    om_hat[:w] = np.nan
    r1 = Run(th_hat, om_hat, wrapped, om_ref, w)
    r2 = Run(th_ref.copy(), om_ref.copy(), th_ref, om_ref, w)
    m = cbe_metrics([r1, r2], spec)
    assert set(m) == {"omega", "theta"} and list(m["theta"]) == ["swing", "boom"]
    assert m["theta"]["swing"]["rmse"] == pytest.approx(0.0, abs=1e-12)
    # boom: 7 samples off by 0.1, 7 exact
    assert m["theta"]["boom"]["rmse"] == pytest.approx(math.sqrt(0.01 / 2))
    assert m["theta"]["boom"]["mae"] == pytest.approx(0.05)
    ref = np.concatenate([t[w:], t[w:]])
    r2_boom = 1 - 7 * 0.01 / np.sum((ref - ref.mean()) ** 2)
    assert m["theta"]["boom"]["r2"] == pytest.approx(r2_boom)
    assert m["omega"]["swing"]["rmse"] == pytest.approx(math.sqrt(0.04 / 2))
    assert m["omega"]["swing"]["r2"] is None  # constant reference -> undefined
    assert min_r2(m, "omega") == -math.inf


def _metrics(names):
    return {
        k: {n: {"rmse": 0.01, "mae": 0.005, "r2": 0.99} for n in names} for k in ("omega", "theta")
    }


def test_tables_in_paper_layout():
    names = ["swing", "boom", "arm", "bucket"]
    md = markdown_table(_metrics(names), paper=True)
    lines = md.strip().splitlines()
    assert lines[0].startswith("| Type | Joint | RMSE | MAE | R² |")
    assert len(lines) == 2 + 8 and all(line.count("|") == lines[0].count("|") for line in lines)
    assert f"{PAPER_TABLE_II['theta']['arm'][2]:.4f}" in md
    cmp = comparison_table({"LSTM": _metrics(names), "ARX": _metrics(names)})
    assert "LSTM R²" in cmp and "ARX RMSE" in cmp and len(cmp.strip().splitlines()) == 10
    six = markdown_table(_metrics(["swing", "boom", "arm", "bucket", "wrist", "tilt"]), paper=True)
    assert "| Tilt | 0.0100 | 0.0050 | 0.9900 | — | — | — |" in six


def test_plot_cbe_writes_png(tmp_path):
    n, nj = 50, 3
    t = np.arange(n) * 0.05
    ref = np.random.default_rng(0).normal(size=(n, nj))
    p = plot_cbe(
        tmp_path / "f.png",
        time=t,
        omega_ref=ref,
        theta_ref=ref.cumsum(0),
        predictions={"LSTM": (ref + 0.1, ref.cumsum(0)), "ARX": (ref, ref)},
        names=["a", "b", "c"],
        warmup=5,
        title="t",
    )
    assert p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_r2_of_a_reference_constant_up_to_rounding_is_undefined_not_minus_1e11():
    """Issue 25: a constant truth whose mean is off by rounding gave SS_tot ~ 1e-29 > 0 and an
    R^2 of -4.8e11; it is undefined (NaN, None in JSON) like an exactly constant one."""
    n = 1001
    ref = np.column_stack([np.full(n, 0.1), np.linspace(-1.0, 1.0, n)])
    assert np.sum((ref[:, 0] - ref[:, 0].mean()) ** 2) > 0  # the rounding noise of the issue
    pred = ref + 0.01
    r2 = regression_metrics(pred, ref)["r2"]
    assert np.isnan(r2[0])
    assert r2[1] > 0.99  # a moving column keeps its R^2


def test_each_panel_names_its_episodes_r2_first_model_first():
    from excavator_surrogate.plotting.cbe import _score_text

    scores = {"LSTM": ([0.5, 0.25], [0.9771, None]), "ARX": ([0.1, 0.2], [-4.6912, 0.3])}
    assert _score_text(scores, ["LSTM", "ARX"], 1, 0) == "R² 0.977\nARX R² -4.691"
    assert _score_text(scores, ["LSTM", "ARX"], 1, 1) == "R² —\nARX R² 0.300"  # undefined
    assert _score_text(scores, ["ARX", "GRU"], 0, 1) == "R² 0.200"  # GRU has none: left out


def test_evaluate_writes_each_episodes_scores_into_its_figure(tmp_path, monkeypatch):
    """The corner scores are the episode's own CBE metrics, per model; with one test episode
    they are the table's."""
    import excavator_surrogate.plotting.cbe as plots
    from excavator_surrogate.data import write_dataset
    from excavator_surrogate.data.dataset import load_dataset
    from excavator_surrogate.evaluate import evaluate_checkpoint
    from excavator_surrogate.surrogate.checkpoint import save_checkpoint
    from excavator_surrogate.surrogate.synthetic import synthetic_spec, synthetic_split
    from tests.helpers.surrogates import make_surrogate

    spec = synthetic_spec(2)
    items = synthetic_split(spec, n_train=2, n_val=1, n_test=1, n_step=120, noise=0.001)
    ds = load_dataset(write_dataset(tmp_path / "data", items))
    ckpt = save_checkpoint(
        tmp_path / "m.pt", make_surrogate(ds.spec, ds.train, mode="stateful", window=5)
    )
    seen = {}
    real = plots.plot_cbe

    def spy(path, **kw):
        seen.update(kw)
        return real(path, **kw)

    monkeypatch.setattr(plots, "plot_cbe", spy)
    res = evaluate_checkpoint(ckpt, ds, out=tmp_path / "ev", max_figures=1)
    assert set(seen["scores"]) == set(seen["predictions"]) == {"LSTM", "ARX", "Structured"}
    for label, part in (("LSTM", res), *res["compare"].items()):
        omega_r2, theta_r2 = seen["scores"][label]
        assert omega_r2 == [part["omega"][n]["r2"] for n in ds.spec.names]
        assert theta_r2 == [part["theta"][n]["r2"] for n in ds.spec.names]
    assert (tmp_path / "ev" / "cbe.png").stat().st_size > 0


def test_models_of_other_windows_are_scored_on_the_same_samples():
    """A compared model with a longer window was scored from its own warm-up on, on fewer
    samples than the model beside it; every model is now scored after the longest one."""
    from excavator_surrogate.evaluate.cbe import evaluate_models
    from excavator_surrogate.surrogate.rollout import rollout_episodes
    from tests.helpers.surrogates import tiny_surrogate
    from tests.helpers.training import tiny_dataset

    ds = tiny_dataset(3, n_train=1, n_step=120)
    short = tiny_surrogate(ds.spec, ds.train, window=4, seed=1)
    long = tiny_surrogate(ds.spec, ds.train, window=12, seed=2)
    metrics, runs = evaluate_models({"short": short, "long": long}, ds.test)
    assert {r.warmup for rs in runs.values() for r in rs} == {12}
    own = rollout_episodes(short, ds.test)  # scored from its own warm-up of 4
    assert own[0].warmup == 4
    want = cbe_metrics([dataclasses.replace(r, warmup=12) for r in own], ds.spec)
    for j in ds.spec.names:
        assert metrics["short"]["theta"][j]["rmse"] == pytest.approx(want["theta"][j]["rmse"])
        assert metrics["short"]["theta"][j]["rmse"] != pytest.approx(
            cbe_metrics(own, ds.spec)["theta"][j]["rmse"]
        )
