"""Tracking helpers: the surrogate's horizon prediction error along a recorded run."""

from __future__ import annotations

import numpy as np

from excavator_surrogate.control.predict import SurrogatePredictor
from excavator_surrogate.control.tracking import prediction_error
from tests.helpers.surrogates import tiny_surrogate


def test_prediction_error_equals_a_fresh_sync_and_predict_per_window() -> None:
    """Each row is the miss of one horizon: a predictor synced to the run up to sample k,
    rolled out under the applied u[k:k+N], against the measured theta[k+N] (swing wrapped)."""
    sur = tiny_surrogate(play=(0.05,), window=5)
    rng = np.random.default_rng(2)
    n, n_h, every = 23, 4, 3
    u = rng.uniform(-900, 900, (n - 1, 4))
    theta = np.array([3.1, 0.1, 1.5, 0.5]) + np.cumsum(rng.normal(0, 0.02, (n, 4)), axis=0)
    theta[0] = [3.1, 0.1, 1.5, 0.5]
    err = prediction_error(sur, theta, u, n_horizon=n_h, every=every)
    starts = [k for k in range(0, n - 1, every) if k + n_h <= n - 1]
    assert err.shape == (len(starts), 4)
    for row, k in enumerate(starts):
        pred = SurrogatePredictor(sur, n_batch=1)
        pred.reset(theta[0])
        for j in range(k):
            pred.observe(u[j], theta[j + 1])
        miss = pred.predict(u[None, k : k + n_h])[0, -1] - theta[k + n_h]
        miss[0] = (miss[0] + np.pi) % (2 * np.pi) - np.pi
        np.testing.assert_allclose(err[row], miss, atol=1e-9)
    assert np.all(np.abs(err[:, 0]) < np.pi)
