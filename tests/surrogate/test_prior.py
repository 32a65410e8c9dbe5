"""The speed prior: the static map the head corrects, fitted, stored, merged and refused."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from excavator_surrogate.config import from_dict, to_dict
from excavator_surrogate.data import Episode
from excavator_surrogate.errors import CheckpointError, ConfigError
from excavator_surrogate.surrogate.checkpoint import load_checkpoint, save_checkpoint
from excavator_surrogate.surrogate.ensemble import merge
from excavator_surrogate.surrogate.features import Normalization
from excavator_surrogate.surrogate.model import ModelConfig
from excavator_surrogate.surrogate.structured import fit_prior
from excavator_surrogate.training.config import TrainConfig
from tests.helpers.surrogates import make_surrogate
from tests.surrogate.test_structured import SPEC, TRUTH, _commands


def _speed(sur, theta: np.ndarray, u: np.ndarray) -> np.ndarray:
    """The network's omega [rad/s] of one sequence ``theta``, ``u``: (n_step, .)."""
    x = sur.norm.encode(torch.tensor(theta, dtype=torch.float32), torch.tensor(u).float())
    with torch.no_grad():
        y, _ = sur.net.forward_seq(x[None])
    return sur.norm.omega(y)[0].double().numpy()


def _static_episode(seed: int, n_step: int = 600) -> Episode:
    """test_structured's plant without its delays: theta[t+1] = theta[t] + dt g(u[t])."""
    rng = np.random.default_rng(seed)
    u = _commands(rng, n_step)
    theta = np.empty_like(u)
    theta[0] = rng.uniform(-0.5, 0.5, 2)
    for t in range(n_step - 1):
        theta[t + 1] = theta[t] + SPEC.dt * np.array(
            [f.speed(u[t, j]) for j, f in enumerate(TRUTH)]
        )
    omega = np.vstack([np.zeros((1, 2)), np.diff(theta, axis=0) / SPEC.dt])
    t = np.arange(n_step) * SPEC.dt
    return Episode(spec=SPEC, time=t, u=u, theta=theta, omega=omega, name=f"e{seed}")


def test_fit_prior_recovers_a_static_map() -> None:
    """Without delay in the plant, the delay-0 fit finds its dead zones and gains."""
    fit = fit_prior([_static_episode(s) for s in range(3)], SPEC)
    assert fit["cols"] == [2, 3]  # two angles, then the commands
    np.testing.assert_allclose(fit["a_pos"], [f.a_pos for f in TRUTH])
    np.testing.assert_allclose(fit["a_neg"], [f.a_neg for f in TRUTH])
    np.testing.assert_allclose(fit["k_pos"], [f.k_pos for f in TRUTH], rtol=1e-6)
    np.testing.assert_allclose(fit["k_neg"], [f.k_neg for f in TRUTH], rtol=1e-6)
    assert max(fit["rmse"]) < 1e-6  # rad/s: the map is exact (up to rounding)


def test_gain_spread_is_the_stretch_wise_gain_spread_around_the_map() -> None:
    """An exact map strays by nothing (the floor); a plant whose speed is 1.2x or 0.8x the
    map's in alternate 10-s stretches strays by 0.2."""
    from excavator_surrogate.surrogate.structured import (
        CHUNK_S,
        MIN_GAIN_SPREAD,
        JointFit,
        gain_spread,
    )

    fit = JointFit(delay=0, a_pos=100.0, a_neg=-100.0, k_pos=1e-3, k_neg=2e-3, rmse=0.0)
    rate = 20.0
    n = int(CHUNK_S * rate)
    rng = np.random.default_rng(0)
    u = rng.uniform(-1000, 1000, 8 * n)
    w = np.concatenate([[0.0], fit.speed(u[:-1])])  # w[t] = s(u[t-1])
    assert gain_spread(fit, [u], [w], rate) == MIN_GAIN_SPREAD
    gain = np.where((np.arange(8 * n) - 1) // n % 2 == 0, 1.2, 0.8)
    assert gain_spread(fit, [u], [w * gain], rate) == pytest.approx(0.2, rel=1e-3)


def test_a_silent_head_is_the_map_and_the_head_adds_to_it(spec, episodes) -> None:
    """omega = s(u) + y_std * head: with the last layer zeroed the network is the map exactly
    (whatever the angles and the recurrent state); the head's output adds in y_std units."""
    sur = make_surrogate(spec, episodes, mode="stateful", prior=True)
    ep = episodes[0]
    theta, u = ep.theta[:80], ep.u[:80]
    p = sur.net.prior
    s = p.speed(torch.tensor(u[:, : spec.n_joint], dtype=torch.float32)).double().numpy()
    assert np.abs(s).max() > 0.01  # the commands leave the dead zones
    last = sur.net.head[2]
    with torch.no_grad():
        last.weight.zero_()
        last.bias.zero_()
    np.testing.assert_allclose(_speed(sur, theta, u), s, atol=1e-5)
    with torch.no_grad():
        last.bias.fill_(1.0)
    np.testing.assert_allclose(
        _speed(sur, theta, u), s + sur.norm.y_std.double().numpy(), atol=1e-5
    )


def test_checkpoint_keeps_the_prior(spec, episodes, tmp_path: Path) -> None:
    sur = make_surrogate(spec, episodes, mode="stateful", prior=True)
    path = save_checkpoint(tmp_path / "best.pt", sur)
    back = load_checkpoint(path)
    assert back.model_cfg.prior and back.net.prior is not None
    ep = episodes[1]
    np.testing.assert_array_equal(
        _speed(back, ep.theta[:40], ep.u[:40]), _speed(sur, ep.theta[:40], ep.u[:40])
    )
    old = ModelConfig.from_dict({k: v for k, v in sur.model_cfg.to_dict().items() if k != "prior"})
    assert not old.prior  # checkpoints written before the prior load as before


def test_members_with_other_maps_do_not_merge(spec, episodes) -> None:
    a = make_surrogate(spec, episodes, mode="stateful", prior=True)
    b = make_surrogate(spec, episodes, mode="stateful", prior=True, seed=1)
    with torch.no_grad():
        b.net.prior.k_pos *= 2.0
    with pytest.raises(ConfigError, match="speed prior"):
        merge([a, b])
    c = make_surrogate(spec, episodes, mode="stateful", seed=2)
    with pytest.raises(ConfigError, match="speed prior"):
        merge([a, c])


def test_prior_is_refused_with_a_residual_head_or_arx() -> None:
    with pytest.raises(ConfigError, match="prior and residual"):
        from_dict(
            TrainConfig,
            {**to_dict(TrainConfig()), "prior": True, "residual": True, "velocity_input": True},
        )
    with pytest.raises(CheckpointError, match="speed prior"):
        ModelConfig.from_dict(dict(n_feature=9, n_joint=4, cell="arx", prior=True))


def test_a_merged_prior_reads_member_zeros_features(spec, episodes) -> None:
    """Members normalised on other data share one map; the merged network re-reads it from
    member 0's features, and its omega is the members' mean."""
    a = make_surrogate(spec, episodes[:2], mode="stateful", prior=True)
    b = make_surrogate(spec, episodes[1:], mode="stateful", prior=True, seed=1, hidden=8)
    assert not torch.equal(a.norm.x_mean, b.norm.x_mean)
    ens = merge([a, b])
    ep = episodes[2]
    th, u = ep.theta[:60], ep.u[:60]
    mean = (_speed(a, th, u) + _speed(b, th, u)) / 2
    np.testing.assert_allclose(_speed(ens, th, u), mean, atol=2e-5)
    assert isinstance(ens.norm, Normalization)
