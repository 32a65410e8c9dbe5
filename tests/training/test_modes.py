"""Training modes: the periodic-joint offsets turn the angles and re-encode them exactly."""

from __future__ import annotations

import numpy as np
import torch

from excavator_surrogate.training.batches import make_data
from excavator_surrogate.training.config import TrainConfig
from excavator_surrogate.training.modes import make_mode
from tests.helpers.surrogates import make_surrogate


def _mode(spec, episodes, **kw):
    cfg = TrainConfig(mode="stateful", seq_len=20, burn_in=5, tbptt=5, seq_batch=4, **kw)
    sur = make_surrogate(spec, episodes, mode="stateful")
    data = make_data(episodes, sur.norm, torch.device("cpu"))
    return make_mode(cfg, data, sur), data, sur


def test_offsets_turn_periodic_angles_and_re_encode_them(spec, episodes) -> None:
    """The turned features equal the normalisation's own encoding of the turned angles (a plain
    reference); the other joints' angles, the commands and the targets are untouched."""
    mode, data, sur = _mode(spec, episodes, periodic_offsets=True)
    index = np.array([0, 3, 11])
    g = torch.as_tensor(index)[:, None] + torch.arange(20)
    x, th = mode._turned(data.x[g], data.theta[g], index, epoch=2)
    periodic = np.array(spec.periodic)
    assert periodic.any()
    phi = (th - data.theta[g]).numpy()  # (n_batch, n_step, n_joint)
    assert np.allclose(phi[..., ~periodic], 0.0)
    # one offset per sub-sequence and periodic joint, constant along it
    np.testing.assert_allclose(
        phi[..., periodic],
        np.broadcast_to(phi[:, :1][..., periodic], phi[..., periodic].shape),
        atol=1e-5,
    )
    assert np.ptp(phi[:, 0, periodic]) > 0.1
    ref = sur.norm.encode(th, data.u[g])
    torch.testing.assert_close(x, ref, atol=1e-5, rtol=0)
    # the same seed, epoch and starts give the same offsets
    x2, _ = mode._turned(data.x[g], data.theta[g], index, epoch=2)
    assert torch.equal(x, x2)


def test_without_offsets_nothing_turns(spec, episodes) -> None:
    mode, data, _ = _mode(spec, episodes)
    index = np.array([1, 4])
    g = torch.as_tensor(index)[:, None] + torch.arange(20)
    x, th = mode._turned(data.x[g], data.theta[g], index, epoch=0)
    assert torch.equal(x, data.x[g]) and torch.equal(th, data.theta[g])


def test_angle_noise_drifts_non_periodic_angles_after_the_burn_in(spec, episodes) -> None:
    """The drift equals a plain reference: each non-periodic joint's angle, re-encoded with a
    per-step random walk from the burn-in's end whose end standard deviation is ``angle_noise``
    of the joint's training std; periodic joints, commands and the burn-in are untouched."""
    mode, data, sur = _mode(spec, episodes, angle_noise=0.1)
    index = np.arange(195)
    g = torch.as_tensor(index)[:, None] + torch.arange(20)
    x = mode._drifted(data.x[g], index, epoch=3)
    periodic = np.array(spec.periodic)
    cols = [k for k, j in enumerate(_angle_cols(spec)) if j is not None and not periodic[j]]
    assert cols
    d = (x - data.x[g]).numpy()
    others = [c for c in range(d.shape[-1]) if c not in cols]
    assert np.all(d[..., others] == 0.0) and np.all(d[:, :4] == 0.0)  # burn_in 5: steps 0-3
    # reference: the same draws, the walk in radians, re-encoded by the normalisation
    rng = np.random.default_rng([0, 3, int(index[0]), 1])
    e = rng.standard_normal((len(index), 16, len(cols)))
    for m, c in enumerate(cols):
        j = _angle_cols(spec)[c]
        sigma = 0.1 * float(data.theta[:, j].std())
        theta = data.theta[g].clone()
        theta[:, 4:, j] += torch.as_tensor(np.cumsum(e[..., m], 1) * sigma / 4.0, dtype=theta.dtype)
        ref = sur.norm.encode(theta, data.u[g])
        np.testing.assert_allclose(x[..., c].numpy(), ref[..., c].numpy(), atol=1e-5)
        # the walk ends with about that std (195 sub-sequences)
        end = d[:, -1, c] * float(sur.norm.x_std[c])
        assert 0.7 * sigma < end.std() < 1.3 * sigma
    assert torch.equal(x, mode._drifted(data.x[g], index, epoch=3))
    assert not torch.equal(x, mode._drifted(data.x[g], index, epoch=4))


def test_without_angle_noise_nothing_drifts(spec, episodes) -> None:
    mode, data, _ = _mode(spec, episodes)
    index = np.array([1, 4])
    g = torch.as_tensor(index)[:, None] + torch.arange(20)
    assert torch.equal(mode._drifted(data.x[g], index, epoch=0), data.x[g])


def _angle_cols(spec) -> list[int | None]:
    """The joint each leading feature column encodes (None: the cos of a periodic joint)."""
    cols: list[int | None] = []
    for j, p in enumerate(spec.periodic):
        cols += [j, None] if p else [j]
    return cols
