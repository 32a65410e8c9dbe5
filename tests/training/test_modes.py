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
