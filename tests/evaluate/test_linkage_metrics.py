"""The angles a linear joint's linkage gives: scored where the triangle reaches both strokes,
and a joint with a stroke beyond it scored None (not a clipped angle's 0.0000)."""

from __future__ import annotations

import numpy as np
import pytest

from excavator_surrogate.evaluate.cbe import linkage_metrics
from excavator_surrogate.evaluate.report import linkage_markdown
from excavator_surrogate.spec import JointSpec, Linkage, MachineSpec
from excavator_surrogate.surrogate.rollout import EpisodeRollout

LINK = Linkage(a=1.25, b=3.4, phi=1.15, l0=2.05)
"""Reaches strokes 0.1 .. 2.6 m."""


def _spec(link: Linkage) -> MachineSpec:
    return MachineSpec((JointSpec("boom", kind="linear", unit="mm", linkage=link),))


def _run(ref: np.ndarray, hat: np.ndarray, warmup: int = 2) -> EpisodeRollout:
    n = ref.shape[0]
    nan = np.full((n, 1), np.nan)
    return EpisodeRollout(
        name="ep",
        time=np.arange(n) * 0.05,
        theta_hat=hat[:, None],
        omega_hat=nan,
        theta_ref=ref[:, None],
        omega_ref=nan,
        warmup=warmup,
    )


def test_reachable_strokes_are_scored_as_angles() -> None:
    ref = np.linspace(1.4, 1.9, 40)
    hat = ref + 0.01
    (m,) = linkage_metrics([_run(ref, hat)], _spec(LINK)).values()
    err = LINK.angle(hat[2:]) - LINK.angle(ref[2:])
    assert m["rmse"] == pytest.approx(float(np.sqrt(np.mean(err**2))), rel=1e-12)
    assert m["rmse"] > 0 and "unreachable" not in m


def test_a_linkage_in_the_wrong_unit_scores_no_angle() -> None:
    """The audit's case: a, b, l0 in m read as mm reach 0.1 .. 2.6 mm; every stroke of 1.4 ..
    1.9 m clipped to one angle had scored RMSE and MAE 0.0."""
    mm = Linkage(a=LINK.a / 1000, b=LINK.b / 1000, phi=LINK.phi, l0=LINK.l0 / 1000)
    ref = np.linspace(1.4, 1.9, 40)
    out = linkage_metrics([_run(ref, ref + 0.01), _run(ref, ref)], _spec(mm))
    assert out == {
        "boom": {"rmse": None, "mae": None, "r2": None, "unreachable": 76, "samples": 76}
    }
    text = linkage_markdown(out)
    assert "| Boom | — | — | — |" in text
    assert (
        "Boom: no angle: 76 of 76 strokes (free run or reference) lie beyond what its "
        "linkage's triangle can reach; check its a, b and l0 against the position's unit."
    ) in text


def test_a_free_run_beyond_the_triangle_scores_no_angle() -> None:
    """One predicted stroke beyond the reach (2.6 m) is counted, not clipped to an end."""
    ref = np.linspace(1.4, 1.9, 40)
    hat = ref.copy()
    hat[30] = 2.7
    (m,) = linkage_metrics([_run(ref, hat)], _spec(LINK)).values()
    assert (m["rmse"], m["unreachable"], m["samples"]) == (None, 1, 38)
