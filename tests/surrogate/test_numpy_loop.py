"""The NumPy free run equals the torch closed loop and the plain loop."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
import torch

from excavator_surrogate.surrogate.numpy_loop import (
    numpy_capable,
    rollout_episodes_numpy,
    rollout_numpy,
)
from excavator_surrogate.surrogate.reference import rollout_reference
from excavator_surrogate.surrogate.rollout import rollout, rollout_episodes
from excavator_surrogate.surrogate.stacked import stack
from tests.helpers.surrogates import VARIANTS, tiny_surrogate, variant_surrogate
from tests.surrogate.test_stacked import _candidates

CAPABLE = ["free", "stops", "play", "velocity", "prior", "delayed-map"]


def _batch(episodes, n: int) -> tuple[np.ndarray, np.ndarray]:
    theta = np.stack([e.theta[:n] for e in episodes])
    u = np.stack([e.u[:n] for e in episodes])
    return theta, u


@pytest.mark.parametrize("variant", CAPABLE)
def test_numpy_free_run_equals_the_closed_loop_and_the_plain_loop(variant):
    """Every feature the NumPy loop covers: end stops (driven into them), play features,
    the velocity feature with a residual head, a speed prior, a map on delayed commands."""
    sur = variant_surrogate(mode="stateful", cell="lstm", **VARIANTS[variant])
    assert numpy_capable(sur)
    rng = np.random.default_rng(2)
    n_step = 80
    theta0 = rng.uniform(-0.3, 0.3, (3, 1, 4)) + np.array([0.0, 0.0, 1.5, 0.5])
    theta = np.repeat(theta0, n_step, axis=1)
    u = np.repeat(rng.uniform(-1000, 1000, (3, n_step // 10, 4)), 10, axis=1)
    th, om = rollout_numpy(sur, theta, u, warmup=sur.window)
    th_t, om_t = rollout(sur, theta, u)
    np.testing.assert_allclose(th, th_t, atol=1e-5)
    np.testing.assert_allclose(om, om_t, atol=1e-4, equal_nan=True)
    th_ref, om_ref = rollout_reference(sur, theta[0], u[0])
    np.testing.assert_allclose(th[0], th_ref, atol=1e-5)
    w = sur.window
    assert np.isnan(om[:, :w]).all()
    np.testing.assert_allclose(om[0, w:], om_ref[w:], atol=1e-4)
    # the test can fail: the free run moves away from its start
    assert np.abs(th[:, -1] - theta[:, -1]).max() > 1e-2
    if VARIANTS[variant]["end_stops"]:  # driven into the stops: they bind
        lo, hi = sur.limits_np()[:2]
        assert np.isclose(th, lo, atol=1e-6).any() or np.isclose(th, hi, atol=1e-6).any()


@pytest.mark.parametrize(
    "kw", [{}, {"omega_in": True, "residual": True, "play": (0.1,)}, {"prior": True}]
)
def test_stacked_candidates_in_numpy_equal_each_run_alone(spec, episodes, kw):
    cands = _candidates(spec, episodes, 3, drive=2.0, **kw)
    st = stack(cands)
    assert numpy_capable(st)
    theta, u = _batch(episodes, 60)
    b = len(episodes)
    th_s, om_s = rollout_numpy(
        st, np.concatenate([theta] * 3), np.concatenate([u] * 3), warmup=st.window
    )
    for c, cand in enumerate(cands):
        th, om = rollout(cand, theta, u)
        np.testing.assert_allclose(th_s[c * b : (c + 1) * b], th, atol=1e-5)
        np.testing.assert_allclose(om_s[c * b : (c + 1) * b], om, atol=1e-4, equal_nan=True)
    assert np.abs(th_s[:b] - th_s[b : 2 * b]).max() > 1e-3


def test_episodes_of_different_lengths(spec, episodes):
    sur = tiny_surrogate(spec, episodes, end_stops=True)
    eps = [replace(episodes[0].slice(0, 40), name="short"), *episodes[1:]]
    got = rollout_episodes_numpy(sur, eps, max_steps=70)
    want = rollout_episodes(sur, eps, max_steps=70)
    for g, w in zip(got, want, strict=True):
        assert g.name == w.name and g.theta_hat.shape == w.theta_hat.shape == w.theta_ref.shape
        np.testing.assert_allclose(g.theta_hat, w.theta_hat, atol=1e-5)
        np.testing.assert_array_equal(g.theta_ref, w.theta_ref)


def test_a_diverging_candidate_stays_on_its_own_rows(spec, episodes):
    good, bad = _candidates(spec, episodes, 2)
    good, bad = replace(good, end_stops=False), replace(bad, end_stops=False)
    with torch.no_grad():
        bad.net.head[-1].bias.fill_(math.inf)
    theta, u = _batch(episodes, 50)
    b = len(episodes)
    th, _ = rollout_numpy(
        stack([good, bad]), np.concatenate([theta] * 2), np.concatenate([u] * 2), warmup=good.window
    )
    assert not np.isfinite(th[b:, -1]).all()
    np.testing.assert_allclose(th[:b], rollout(good, theta, u)[0], atol=1e-5)


def test_what_numpy_does_not_step(spec, episodes):
    parallel = variant_surrogate(mode="stateful", cell="lstm", **VARIANTS["parallel-map"])
    assert not numpy_capable(parallel)  # its own angles of the map joints
    assert not numpy_capable(tiny_surrogate(spec, episodes, mode="windowed"))
    assert not numpy_capable(tiny_surrogate(spec, episodes, cell="gru"))
    with pytest.raises(ValueError, match="NumPy"):
        rollout_numpy(parallel, *_batch(episodes, 20), warmup=parallel.window)
