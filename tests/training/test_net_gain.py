"""The network joints at validation's speed (``training/net_gain.py``): the batched short runs
against a plain loop, the output scale against the velocity it should scale, the rule, and
the checkpoint rewritten (or not) on a machine whose validation days run faster."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from excavator_surrogate.surrogate.angles import wrap_periodic
from excavator_surrogate.surrogate.checkpoint import (
    checkpoint_dict,
    load_checkpoint,
    read_checkpoint,
    write_checkpoint_dict,
)
from excavator_surrogate.surrogate.own_angles import network_inputs
from excavator_surrogate.surrogate.rollout import ClosedLoop, rollout
from excavator_surrogate.surrogate.synthetic import synthetic_episode, synthetic_spec
from excavator_surrogate.surrogate.validation import free_run_error
from excavator_surrogate.training import net_gain
from excavator_surrogate.training.map_fit import GAIN_RANGE
from excavator_surrogate.training.net_gain import (
    MIN_SHIFT,
    apply_network_gains,
    choose_network_gains,
    displacement_sums,
    network_gains,
    scaled_outputs,
)
from tests.helpers.surrogates import on_parallel_map, tiny_surrogate

SPEC = synthetic_spec(4, periodic_first=True)


def _episodes(n: int, seed: int, n_step: int = 90):
    return [
        synthetic_episode(SPEC, kind="sine" if i % 2 else "step", n_step=n_step, seed=seed + i)
        for i in range(n)
    ]


@pytest.mark.parametrize("mode", ["stateful", "windowed"])
def test_the_batched_short_runs_are_a_plain_loop_of_single_ones(mode, monkeypatch):
    """Every start in one batch, or in chunks of 4, gives the sums of one run per start,
    each alone."""
    eps = _episodes(3, 0)
    sur = tiny_surrogate(SPEC, eps, mode=mode, window=6, seed=1)
    ep, n_h, stride = eps[1], 5, 3
    num, den = displacement_sums(sur, ep, n_h=n_h, stride=stride)
    ref_num, ref_den = np.zeros(SPEC.n_joint), np.zeros(SPEC.n_joint)
    w = sur.window
    for k in range(w - 1, ep.n_step - n_h, stride):
        loop = ClosedLoop(sur)
        loop.reset(ep.theta[None, k - w + 1 : k + 1], ep.u[None, k - w + 1 : k])
        for j in range(n_h):
            theta, _ = loop.step(ep.u[None, k + j])
        d_net = wrap_periodic(theta[0].double().numpy() - ep.theta[k], SPEC.periodic)
        d_meas = wrap_periodic(ep.theta[k + n_h] - ep.theta[k], SPEC.periodic)
        ref_num += d_meas * d_net
        ref_den += d_net * d_net
    np.testing.assert_allclose(num, ref_num, rtol=1e-4, atol=1e-9)
    np.testing.assert_allclose(den, ref_den, rtol=1e-4, atol=1e-9)
    monkeypatch.setattr(net_gain, "CHUNK", 4)
    chunked = displacement_sums(sur, ep, n_h=n_h, stride=stride)
    np.testing.assert_allclose(chunked[0], ref_num, rtol=1e-4, atol=1e-9)
    np.testing.assert_allclose(chunked[1], ref_den, rtol=1e-4, atol=1e-9)


@pytest.mark.parametrize("kind", ["plain", "prior", "parallel-map"])
def test_the_scaled_outputs_are_the_velocity_times_the_gain(kind):
    """From the same history, the scaled model's next velocity is ``g_j`` times the model's,
    with a speed prior (whose own normalisation stays) and with joints on a parallel map
    (the network's velocity of them, which it integrates into its own angles, scales too)."""
    eps = _episodes(2, 5)
    sur = tiny_surrogate(SPEC, eps, window=6, seed=2, prior=kind == "prior")
    if kind == "parallel-map":
        sur = on_parallel_map(sur)
    gains = [1.0, 1.2, 0.85, 1.1]
    scaled = scaled_outputs(sur, gains)
    ep = eps[0]
    omegas = []
    for model in (sur, scaled):
        loop = ClosedLoop(model)
        loop.reset(ep.theta[None, :6], ep.u[None, :5])
        omegas.append(model.norm.omega(_normalised(loop, ep.u[None, 5])))
    np.testing.assert_allclose(omegas[1], omegas[0] * torch.tensor(gains), rtol=1e-5, atol=1e-9)
    assert torch.equal(sur.norm.y_std, tiny_surrogate(SPEC, eps, window=6, seed=2).norm.y_std)
    with pytest.raises(ValueError, match="omega_in"):
        scaled_outputs(tiny_surrogate(SPEC, eps, omega_in=True), gains)


def _normalised(loop: ClosedLoop, u: np.ndarray) -> torch.Tensor:
    """The network's normalised output for the step on ``u`` (what ``norm.omega`` scales),
    as :meth:`ClosedLoop.step` computes it before the map joints' speeds replace the
    network's (which a parallel map's network still integrates into its own angles)."""
    norm = loop.norm
    z = norm.play_update(loop.z, loop._t(u))
    theta_in, omega_in = network_inputs(norm, loop.theta, z, loop.omega)
    row = norm.encode(theta_in, loop._t(u), z, omega_in)
    with torch.no_grad():
        y, _ = loop.sur.net.step(row, loop._state)
    return y


def test_the_rule_needs_every_episode_beyond_the_shift_on_one_side():
    up, down, near = 1 + 2 * MIN_SHIFT, 1 - 2 * MIN_SHIFT, 1 + MIN_SHIFT / 2
    per = np.array([[up, up, up, near, up, 1.6], [up, down, near, near, up, 1.5]])
    pooled = np.array([1.1, 1.0, 1.05, 1.02, 1.12, 1.55])
    eligible = [True, True, True, True, False, True]
    got = network_gains(per, pooled, eligible)
    assert got == [1.1, 1.0, 1.0, 1.0, 1.0, GAIN_RANGE[1]]
    assert network_gains(per[:1], pooled, eligible) == [1.0] * 6  # one episode: never
    assert network_gains(np.array([[down], [down]]), np.array([0.5]), [True]) == [GAIN_RANGE[0]]
    nan = np.array([[up], [np.nan]])
    assert network_gains(nan, np.array([1.1]), [True]) == [1.0]


def _model_and_days(speed: float, n_val: int = 2):
    """A network whose speed is its static map's, a function of the commands alone (its head
    zeroed: ``omega = s(u)``), its training episodes, and validation episodes of the model's
    own free runs with every displacement times ``speed``: a machine whose validation days
    run ``speed`` times as fast."""
    train = _episodes(4, 10)
    sur = tiny_surrogate(SPEC, train, window=6, seed=3, prior=True)
    with torch.no_grad():
        sur.net.head[-1].weight.zero_()
        sur.net.head[-1].bias.zero_()
    val = []
    for ep in _episodes(n_val, 40, n_step=120):
        th, _ = rollout(sur, ep.theta[None], ep.u[None])
        th = th[0, :1] + speed * (th[0] - th[0, :1])
        val.append(ep.replace(theta=th, omega=np.gradient(th, SPEC.dt, axis=0)))
    return sur, train, val


def test_validation_days_that_run_faster_scale_the_network_joints(tmp_path):
    sur, train, val = _model_and_days(1.2)
    best = tmp_path / "best.pt"
    write_checkpoint_dict(best, checkpoint_dict(sur))
    record = apply_network_gains(best, train, val, min_span=0.0, trained_on_val=False)
    assert record["joints"] == list(SPEC.names)
    np.testing.assert_allclose(record["gain"], 1.2, rtol=1e-4)
    np.testing.assert_allclose(record["ratios"], 1.2, rtol=1e-3)
    assert "scaled to validation's" in record["why"]
    new = load_checkpoint(best)
    assert (new.metrics or {})["training"]["net_val_gain"] == record
    np.testing.assert_allclose(new.norm.y_std, sur.norm.y_std * 1.2, rtol=1e-6)
    # the checkpoint's validation scores are the scaled model's: it runs the faster days
    assert new.metrics["val_error"] == free_run_error(new, val)["val_error"]
    assert new.metrics["val_error"] < 0.1 * free_run_error(sur, val)["val_error"]
    # the training's speed on validation, or one validation episode: nothing changes
    for speed, n_val, why in ((1.0, 2, "no joint a network drives"), (1.2, 1, "fewer than 2")):
        sur, train, val = _model_and_days(speed, n_val)
        write_checkpoint_dict(best, checkpoint_dict(sur))
        before = read_checkpoint(best)["norm"]
        record = apply_network_gains(best, train, val, min_span=0.0, trained_on_val=False)
        assert record["joints"] == [] and why in record["why"]
        after = read_checkpoint(best)["norm"]
        assert all(torch.equal(before[k], after[k]) for k in before)


def test_map_joints_unspanned_joints_and_validation_trained_on_keep_their_speed():
    sur, _, val = _model_and_days(1.2)
    on_map = [True, False, False, False]
    spanned = [True, True, False, True]
    new, record = choose_network_gains(
        sur, val, on_map=on_map, spanned=spanned, trained_on_val=False
    )
    assert new is not None and record["joints"] == [SPEC.names[1], SPEC.names[3]]
    np.testing.assert_allclose(new.norm.y_std / sur.norm.y_std, [1.0, 1.2, 1.0, 1.2], rtol=1e-4)
    new, record = choose_network_gains(sur, val, on_map=on_map, spanned=None, trained_on_val=True)
    assert new is None and "trained on the validation episodes" in record["why"]
