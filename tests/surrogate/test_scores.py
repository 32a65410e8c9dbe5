"""What a free run is scored on (surrogate.scores), shared by validation and the CBE report:
a swing's turn, a swing wrapped in the warm-up, joints still in every episode."""

from __future__ import annotations

import math

import numpy as np
import pytest

from excavator_surrogate.evaluate.metrics import cbe_metrics
from excavator_surrogate.spec import excavator_spec
from excavator_surrogate.surrogate.angles import wrap_angle
from excavator_surrogate.surrogate.scores import scored_angles, worst_r2
from excavator_surrogate.surrogate.validation import score_runs
from tests.helpers.runs import Run

SPEC = excavator_spec(20.0)  # swing periodic, boom, arm, bucket


def _run(theta_ref: np.ndarray, theta_hat: np.ndarray, *, warmup: int = 10) -> Run:
    """A free run whose omega is the backward difference of its angles."""
    om = np.vstack([np.zeros((1, 4)), np.diff(theta_ref, axis=0) * 20.0])
    om_hat = np.vstack([np.zeros((1, 4)), np.diff(theta_hat, axis=0) * 20.0])
    return Run(theta_hat, om_hat, theta_ref, om, warmup)


def _motion(seed: int, *, n: int = 200, start: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """A reference (swing from ``start``) and a prediction that drifts off it: (n, 4) each."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / 20.0
    ref = np.stack(
        [start + 1.5 * np.sin(0.4 * t + seed)]
        + [0.5 * np.sin((0.3 + 0.1 * j) * t + j + seed) for j in range(3)],
        axis=1,
    )
    hat = ref + np.cumsum(rng.normal(0.0, 0.01, ref.shape), axis=0)
    hat[:10] = ref[:10]  # recorded during the warm-up
    return ref, hat


def _sur() -> object:
    class Sur:  # what score_runs reads of a surrogate
        spec = SPEC

    return Sur()


def test_a_swing_on_another_turn_scores_the_same() -> None:
    """theta and theta + 2 pi are one pose: shifting an episode's swing (reference and free
    run) by whole turns leaves every score unchanged (the pooled R^2 had moved with it)."""
    a, b = _motion(1, start=-0.2), _motion(2, start=1.6)
    base = cbe_metrics([_run(*a), _run(*b)], SPEC)
    shift = np.array([2 * math.pi, 0.0, 0.0, 0.0])
    for k in (-2, 1, 3):
        moved = _run(b[0] + k * shift, b[1] + k * shift)
        got = cbe_metrics([_run(*a), moved], SPEC)
        np.testing.assert_array_equal(moved.theta_hat, b[1] + k * shift)  # not shifted in place
        for key in ("rmse", "mae", "r2"):
            assert got["theta"]["swing"][key] == pytest.approx(base["theta"]["swing"][key])
        # training's validation keeps each run on its turn (so its selection is unchanged)
        val = score_runs([_run(*a), moved], _sur())
        ref = np.concatenate([a[0][10:, 0], moved.theta_ref[10:, 0]])
        hat = np.concatenate([a[1][10:, 0], moved.theta_hat[10:, 0]])
        want = 1 - np.sum((hat - ref) ** 2) / np.sum((ref - ref.mean()) ** 2)
        assert val["theta_r2"][0] == pytest.approx(want)


def test_a_swing_wrapped_in_the_warm_up_is_scored_as_it_moves() -> None:
    """A swing stored in [-pi, pi) that crosses +pi during the warm-up: the free run starts
    from the stored (wrapped) last warm-up sample, and is scored against the reference on
    that branch, not a turn away."""
    ref, hat = _motion(3)
    ref[:, 0] = 3.0 + 0.6 * np.arange(len(ref)) / 20.0  # crosses +pi at sample 5
    hat[:, 0] = ref[:, 0] + np.linspace(0.0, 0.2, len(ref))
    hat[:10, 0] = ref[:10, 0]
    stored = ref.copy()
    stored[:, 0] = wrap_angle(ref[:, 0])
    w = 10
    hat_stored = hat.copy()
    hat_stored[:, 0] += stored[w - 1, 0] - ref[w - 1, 0]  # the run starts a turn lower
    cont = cbe_metrics([_run(ref, hat)], SPEC)["theta"]["swing"]
    wrapped = cbe_metrics([_run(stored, hat_stored)], SPEC)["theta"]["swing"]
    assert wrapped["rmse"] == pytest.approx(cont["rmse"])
    assert wrapped["r2"] == pytest.approx(cont["r2"])
    assert cont["rmse"] < 0.2


def test_a_joint_still_in_every_episode_has_no_r2() -> None:
    """A bucket held still in each episode, at a different pose in each: pooled, its
    reference 'moves', but there is nothing to explain (R^2 had been 0.6 or 0.9)."""
    runs = []
    for seed, pose in ((4, -0.3), (5, 0.6)):
        ref, hat = _motion(seed)
        ref[:, 3] = pose
        hat[:, 3] = pose + np.linspace(0.0, 0.05, len(hat))
        runs.append(_run(ref, hat))
    m = cbe_metrics(runs, SPEC)
    assert m["theta"]["bucket"]["r2"] is None and m["omega"]["bucket"]["r2"] is None
    assert m["theta"]["bucket"]["rmse"] > 0
    assert all(m["theta"][j]["r2"] is not None for j in ("swing", "boom", "arm"))
    # validation: no R^2 and no say in val_error (it had been RMSE / 1e-6 of the floor)
    val = score_runs(runs, _sur())
    assert math.isnan(val["theta_r2"][3]) and val["theta_rmse"][3] > 0
    _, ref, still = scored_angles(runs, SPEC)
    assert still.tolist() == [False, False, False, True]
    scaled = np.array(val["theta_rmse"][:3]) / ref[:, :3].std(axis=0)
    assert val["val_error"] == pytest.approx(scaled.mean())
    assert worst_r2(val["theta_r2"]) == min(val["theta_r2"][:3])


def test_val_error_of_moving_joints_is_the_normalised_rmse() -> None:
    """Without a still joint or a turn: mean_j RMSE_j / std_j of the pooled reference."""
    runs = [_run(*_motion(6)), _run(*_motion(7, n=150))]
    e = np.concatenate([r.theta_hat[10:] - r.theta_ref[10:] for r in runs])
    ref = np.concatenate([r.theta_ref[10:] for r in runs])
    want = np.mean(np.sqrt(np.mean(e**2, axis=0)) / ref.std(axis=0))
    assert score_runs(runs, _sur())["val_error"] == pytest.approx(want, rel=1e-12)


def test_worst_r2_skips_undefined_joints() -> None:
    assert worst_r2([0.9, math.nan, 0.5]) == 0.5
    assert math.isnan(worst_r2([math.nan]))
    assert worst_r2([0.9, -math.inf]) == -math.inf
