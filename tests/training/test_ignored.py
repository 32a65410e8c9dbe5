"""Ignored exogenous inputs: trained without their columns, stored with them (training/ignored.py)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch

from excavator_surrogate.data import Dataset
from excavator_surrogate.errors import CheckpointError
from excavator_surrogate.spec import EXCAVATOR, InputSpec
from excavator_surrogate.surrogate.features import Normalization
from excavator_surrogate.surrogate.model import Surrogate, build_net
from excavator_surrogate.surrogate.rollout import rollout
from excavator_surrogate.surrogate.series import with_lag_columns
from excavator_surrogate.training.ignored import narrowed, widened, without_inputs
from tests.helpers.surrogates import tiny_surrogate
from tests.helpers.training import tiny_dataset

WIDE = replace(
    EXCAVATOR,
    inputs=(InputSpec("throttle", u_min=0.0, u_max=100.0), InputSpec("gear", u_min=-1, u_max=1)),
)
LIKE = Normalization.from_arrays(  # a network using the inputs: their columns' statistics
    x_mean=np.r_[np.zeros(WIDE.n_feature - 2), 0.3, -0.1],
    x_std=np.r_[np.ones(WIDE.n_feature - 2), 2.0, 0.5],
    y_mean=np.zeros(WIDE.n_joint),
    y_std=np.ones(WIDE.n_joint),
    spec=WIDE,
)


def _delayed(sur: Surrogate) -> Surrogate:
    """``sur`` (with a speed prior) reading its commands 1, 0, 2 and 1 samples back: the
    prior's columns are then the delayed-command features, after the inputs' place."""
    state = dict(sur.net.state_dict())
    norm = with_lag_columns(sur.norm, state, (1, 0, 2, 1))
    state["prior.cols"] = norm.lag_start + torch.arange(sur.spec.n_joint)
    mcfg = replace(sur.model_cfg, n_feature=norm.n_feature)
    net = build_net(mcfg).eval()
    net.load_state_dict(state)
    return replace(sur, net=net, norm=norm, model_cfg=mcfg)


VARIANTS = {
    "stateful": lambda: tiny_surrogate(seed=1),
    "play-velocity": lambda: tiny_surrogate(seed=2, play=(0.05, 0.2), omega_in=True),
    "prior": lambda: tiny_surrogate(seed=3, prior=True, end_stops=True),
    "delayed-prior": lambda: _delayed(tiny_surrogate(seed=4, prior=True)),
    "arx": lambda: tiny_surrogate(seed=5, mode="windowed", cell="arx"),
}


def _commands(n_step: int = 60) -> tuple[np.ndarray, np.ndarray]:
    """Angles (1, n_step, 4) and commands with both inputs (1, n_step, 6)."""
    rng = np.random.default_rng(0)
    u = np.concatenate(
        [
            rng.uniform(-800, 800, (1, n_step, 4)),
            rng.uniform(0, 100, (1, n_step, 1)),
            rng.choice([-1.0, 1.0], (1, n_step, 1)),
        ],
        -1,
    )
    theta = np.cumsum(rng.normal(0, 0.01, (1, n_step, 4)), 1)
    return theta, u


@pytest.mark.parametrize("variant", VARIANTS)
def test_widened_runs_as_the_network_without_inputs_and_narrowed_undoes_it(variant) -> None:
    sur = VARIANTS[variant]()
    wide = widened(sur, spec=WIDE, like=LIKE)
    assert wide.spec.u_names == WIDE.u_names and wide.norm.n_feature == sur.norm.n_feature + 2
    cols = WIDE.input_features
    assert torch.equal(wide.norm.x_std[cols], LIKE.x_std[cols])
    assert torch.equal(wide.norm.u_scale, LIKE.u_scale)
    assert wide.model_cfg.n_feature == sur.model_cfg.n_feature + 2
    theta, u = _commands()
    th_wide, om_wide = rollout(wide.eval(), theta, u)
    th, om = rollout(sur, theta, u[..., :4])  # the inputs change nothing
    np.testing.assert_allclose(th_wide, th, atol=1e-5)
    np.testing.assert_allclose(om_wide, om, atol=1e-5)
    back = narrowed(wide, where="x.pt")
    assert back.spec == sur.spec and back.model_cfg == sur.model_cfg
    for name, w in sur.net.state_dict().items():
        assert torch.equal(back.net.state_dict()[name], w), name
    for name, t in sur.norm.state_dict().items():
        assert torch.equal(back.norm.state_dict()[name], t), name


def test_narrowed_refuses_a_network_that_reads_its_inputs() -> None:
    wide = widened(tiny_surrogate(seed=1), spec=WIDE, like=LIKE)
    with torch.no_grad():
        wide.net.rnn.weight_ih_l0[0, WIDE.input_features.start] = 0.1
    with pytest.raises(CheckpointError, match=r"^run/last\.pt: the network reads its exogenous"):
        narrowed(wide, where="run/last.pt")


def test_without_inputs_keeps_the_joints_arrays() -> None:
    ds = tiny_dataset(2, n_train=2, n_step=50)
    spec = replace(ds.spec, inputs=WIDE.inputs)
    wide = Dataset(spec=spec, root=ds.root)
    for split, eps in ds.episodes.items():
        wide.episodes[split] = [
            e.replace(spec=spec, u=np.concatenate([e.u, np.ones((e.n_step, 2))], 1)) for e in eps
        ]
    narrow = without_inputs(wide)
    assert narrow.spec == ds.spec and narrow.spec.n_input == 0
    for split, eps in wide.episodes.items():
        assert len(eps) == len(narrow.episodes[split]) > 0 or not eps
        for a, b in zip(eps, narrow.episodes[split]):
            assert b.spec == narrow.spec and np.array_equal(b.u, a.u[:, :2])
            assert b.theta is a.theta
