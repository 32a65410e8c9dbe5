"""Candidates stacked into one batched free run equal their separate free runs."""

from __future__ import annotations

import copy
import math
from dataclasses import replace

import numpy as np
import pytest
import torch

from excavator_surrogate.surrogate import free_run_error, rollout
from excavator_surrogate.surrogate.stacked import stack, stackable
from excavator_surrogate.surrogate.validation import free_run_errors
from tests.helpers.surrogates import tiny_surrogate


def _candidates(spec, episodes, n_cand=2, **kw):
    """``n_cand`` surrogates that differ only in their weights (as a training's raw and
    averaged weights): copies of one network, each moved by its own noise."""
    ref = tiny_surrogate(spec, episodes, end_stops=True, **kw)
    out = [ref]
    for c in range(1, n_cand):
        net = copy.deepcopy(ref.net)
        gen = torch.Generator().manual_seed(c)
        with torch.no_grad():
            for p in net.parameters():
                p.add_(0.3 * torch.randn(p.shape, generator=gen) * p.abs().mean())
        out.append(replace(ref, net=net))
    return out


CASES = [
    {},
    {"omega_in": True, "residual": True, "play": (0.1,)},
    {"prior": True},
]


@pytest.mark.parametrize("kw", CASES)
@pytest.mark.parametrize("n_cand", [2, 3])
def test_stacked_free_run_equals_each_candidate_run_alone(spec, episodes, kw, n_cand):
    cands = _candidates(spec, episodes, n_cand, drive=2.0, **kw)
    assert stackable(cands)
    n = 60
    theta = np.stack([e.theta[:n] for e in episodes])
    u = np.stack([e.u[:n] for e in episodes])
    th_s, om_s = rollout(
        stack(cands), np.concatenate([theta] * n_cand), np.concatenate([u] * n_cand)
    )
    b = len(episodes)
    for c, cand in enumerate(cands):
        th, om = rollout(cand, theta, u)  # the reference: one candidate, its own loop
        np.testing.assert_allclose(th_s[c * b : (c + 1) * b], th, atol=1e-5)
        np.testing.assert_allclose(om_s[c * b : (c + 1) * b], om, atol=1e-4, equal_nan=True)
    # the test can fail: the candidates run apart
    assert np.abs(th_s[:b] - th_s[b : 2 * b]).max() > 1e-3


@pytest.mark.parametrize("same_map", [True, False], ids=["one-map", "own-maps"])
def test_candidates_with_a_speed_prior_read_their_own_map(spec, episodes, same_map):
    """Candidates of one training share its map (one call for every row); candidates whose
    maps differ each read their own."""
    cands = _candidates(spec, episodes, 2, prior=True)
    if not same_map:
        with torch.no_grad():
            cands[1].net.prior = copy.deepcopy(cands[1].net.prior)
            cands[1].net.prior.k_pos.mul_(3.0)
    assert stack(cands).net._one_prior is same_map
    n = 60
    theta = np.stack([e.theta[:n] for e in episodes])
    u = np.stack([e.u[:n] for e in episodes])
    th_s, _ = rollout(stack(cands), np.concatenate([theta] * 2), np.concatenate([u] * 2))
    b = len(episodes)
    for c, cand in enumerate(cands):
        np.testing.assert_allclose(th_s[c * b : (c + 1) * b], rollout(cand, theta, u)[0], atol=1e-5)


def test_free_run_errors_score_like_free_run_error(spec, episodes):
    cands = _candidates(spec, episodes, 2, drive=1.0)
    batched = free_run_errors(cands, episodes)
    for got, cand in zip(batched, cands, strict=True):
        want = free_run_error(cand, episodes)
        assert got["val_error"] == pytest.approx(want["val_error"], rel=1e-4)
        np.testing.assert_allclose(got["theta_rmse"], want["theta_rmse"], rtol=1e-4, atol=1e-7)
        np.testing.assert_allclose(got["theta_r2"], want["theta_r2"], rtol=1e-4, atol=1e-6)
    assert batched[0]["val_error"] != batched[1]["val_error"]


@pytest.mark.parametrize(("cell", "mode"), [("gru", "stateful"), ("lstm", "windowed")])
def test_other_cells_and_modes_run_one_by_one(spec, episodes, cell, mode):
    cands = _candidates(spec, episodes, 2, cell=cell, mode=mode)
    assert not stackable(cands)
    assert free_run_errors(cands, episodes) == [free_run_error(c, episodes) for c in cands]


def test_candidates_that_differ_beyond_their_weights_run_one_by_one(spec, episodes):
    a = tiny_surrogate(spec, episodes, hidden=16)
    wider = tiny_surrogate(spec, episodes, hidden=8)
    other_norm = tiny_surrogate(spec, None, seed=1)
    assert not stackable([a, wider]) and not stackable([a, other_norm]) and not stackable([a])
    got = free_run_errors([a, wider], episodes)  # each alone, stepped in NumPy
    for g, cand in zip(got, [a, wider], strict=True):
        want = free_run_error(cand, episodes)
        assert g["val_error"] == pytest.approx(want["val_error"], rel=1e-5)
        np.testing.assert_allclose(g["omega_rmse"], want["omega_rmse"], rtol=1e-5)
    assert got[0]["val_error"] != got[1]["val_error"]
    with pytest.raises(ValueError, match="one by one"):
        stack([a, wider])


def test_a_diverging_candidate_does_not_spread_to_the_others(spec, episodes):
    good, bad = _candidates(spec, episodes, 2)
    good, bad = replace(good, end_stops=False), replace(bad, end_stops=False)
    with torch.no_grad():  # the bad candidate's speed is inf: its angle, then its features
        bad.net.head[-1].bias.fill_(math.inf)
    got = free_run_errors([good, bad], episodes)
    assert got[1]["val_error"] == math.inf
    want = free_run_error(good, episodes)  # its own run: no operation mixes the candidates
    assert math.isfinite(got[0]["val_error"])
    assert got[0]["val_error"] == pytest.approx(want["val_error"], rel=1e-4)
