"""The ensemble of two kinds, joint by joint (training/composite.py), against the networks'
own outputs."""

from __future__ import annotations

import numpy as np
import pytest

from excavator_surrogate.errors import ConfigError
from excavator_surrogate.surrogate.ensemble import merge
from excavator_surrogate.training.composite import composite, in_prior_form
from tests.surrogate.test_structured import _episode
from tests.training.test_kinds import _omega, _plain_net, _prior_net


def test_a_plain_network_in_prior_form_keeps_its_output() -> None:
    plain, prior = _plain_net(0), _prior_net(1, exact=(True, False))
    form = in_prior_form(plain, prior)
    assert form.norm.lags == prior.norm.lags == (3, 5) and form.net.prior is not None
    assert float(form.net.prior.k_pos.abs().sum()) == 0.0
    ep = _episode(9)
    np.testing.assert_allclose(_omega(form, ep), _omega(plain, ep), atol=1e-5)


def test_a_composite_takes_each_joint_from_its_member() -> None:
    """joint_weights (0/1 per joint): joint 0 from the map-correcting network, joint 1 from
    the plain one, on the same input rows; and the composite ensemble of four plain and two
    map-correcting networks is the plain ones' mean on one joint, the others' on the other."""
    ep = _episode(9)
    plains = [_plain_net(s) for s in (0, 1, 2, 3)]
    priors = [_prior_net(s + 10, exact=(False, False)) for s in (0, 1)]
    pair = merge([in_prior_form(plains[0], priors[0]), priors[0]], joint_weights=[[0, 1], [1, 0]])
    assert "composite" in pair.metrics and "ensemble" not in pair.metrics
    om = _omega(pair, ep)
    np.testing.assert_allclose(om[:, 0], _omega(priors[0], ep)[:, 0], atol=1e-5)
    np.testing.assert_allclose(om[:, 1], _omega(plains[0], ep)[:, 1], atol=1e-5)
    both = composite(plains, priors, [True, False])
    assert "ensemble" in both.metrics and both.metrics["ensemble"]["n_member"] == 2
    want = np.stack(
        [
            np.mean([_omega(b, ep)[:, 0] for b in priors], axis=0),
            np.mean([_omega(a, ep)[:, 1] for a in plains], axis=0),
        ],
        axis=1,
    )
    np.testing.assert_allclose(_omega(both, ep), want, atol=1e-5)
    with pytest.raises(ValueError, match="do not divide"):
        composite(plains[:3], priors, [True, False])
    with pytest.raises(ConfigError, match="joint_weights"):
        merge([plains[0], plains[1]], joint_weights=[[0.5, 1.0], [0.2, 0.0]])


def test_a_composite_with_twins_takes_each_joints_plain_share_from_its_way() -> None:
    """With the plain side as pairs (the inputs on some joints, :mod:`.variants`): joint j
    is a_j times the map-correcting networks' mean plus 1 - a_j times the mean of the twins
    (where they take joint j) or of the plain networks, against the plain loop over the
    networks; a network left with no weight is not in the model."""
    ep = _episode(9)
    plains = [_plain_net(s) for s in (0, 1)]
    twins = [_plain_net(s) for s in (20, 21)]
    priors = [_prior_net(s + 10, exact=(False, False)) for s in (0, 1)]
    om = {k: [_omega(n, ep) for n in nets] for k, nets in (("p", plains), ("t", twins))}
    om["b"] = [_omega(n, ep) for n in priors]

    def mean(k: str, j: int) -> np.ndarray:
        return np.mean([o[:, j] for o in om[k]], axis=0)

    for a in ([0.5, 0.0], [0.0, 1.0], [0.5, 0.5], [0.0, 0.0]):
        got = _omega(composite(plains, priors, a, twins=twins, twin_joints=[True, False]), ep)
        want = np.stack(
            [
                a[0] * mean("b", 0) + (1 - a[0]) * mean("t", 0),
                a[1] * mean("b", 1) + (1 - a[1]) * mean("p", 1),
            ],
            axis=1,
        )
        np.testing.assert_allclose(got, want, atol=1e-5, err_msg=f"a = {a}")
    # joint 0 on the map-correcting networks: the twins (joint 0 only) carry no weight
    model = composite(plains, priors, [1.0, 0.0], twins=twins, twin_joints=[True, False])
    one = sum(n.model_cfg.hidden for n in (plains[0], priors[0]))
    assert model.model_cfg.hidden == len(priors) * one
    with pytest.raises(ValueError, match="pair up"):
        composite(plains, priors, [0.5, 0.0], twins=twins[:1], twin_joints=[True, False])
    with pytest.raises(ValueError, match="one flag per joint"):
        composite(plains, priors, [0.5, 0.0], twins=twins, twin_joints=[True])


def test_a_composite_blends_both_kinds_by_its_weights() -> None:
    """Weight 1/2 on a joint: the mean of the map-correcting ensemble and the plain one; a
    weight outside [0, 1] is refused."""
    ep = _episode(9)
    plains = [_plain_net(s) for s in (0, 1, 2, 3)]
    priors = [_prior_net(s + 10, exact=(False, False)) for s in (0, 1)]
    both = composite(plains, priors, [0.5, 0.0])
    plain = np.mean([_omega(a, ep) for a in plains], axis=0)
    prior = np.mean([_omega(b, ep) for b in priors], axis=0)
    want = np.stack([0.5 * plain[:, 0] + 0.5 * prior[:, 0], plain[:, 1]], axis=1)
    np.testing.assert_allclose(_omega(both, ep), want, atol=1e-5)
    with pytest.raises(ValueError, match=r"not in \[0, 1\]"):
        composite(plains, priors, [1.5, 0.0])
