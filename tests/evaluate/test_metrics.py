"""CBE metrics against hand-computed values; tables; figure."""

from __future__ import annotations

import math
from dataclasses import dataclass

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


@dataclass
class _Run:
    theta_hat: np.ndarray
    omega_hat: np.ndarray
    theta_ref: np.ndarray
    omega_ref: np.ndarray
    warmup: int


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
    r1 = _Run(th_hat, om_hat, wrapped, om_ref, w)
    r2 = _Run(th_ref.copy(), om_ref.copy(), th_ref, om_ref, w)
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
