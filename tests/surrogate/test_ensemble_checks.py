"""merge refuses a member with non-finite weights, the same member twice and a member of
another machine; members trained on other data of the machine merge."""

from __future__ import annotations

from dataclasses import replace

import pytest
import torch

from excavator_surrogate.errors import ConfigError
from excavator_surrogate.surrogate.ensemble import merge, non_finite_weight
from tests.helpers.surrogates import make_surrogate


def test_merge_refuses_a_member_with_nan_weights(spec, episodes):
    a = make_surrogate(spec, episodes, seed=0, window=5)
    b = make_surrogate(spec, episodes, seed=1, window=5)
    assert non_finite_weight(b) is None
    with torch.no_grad():
        b.net.head[2].weight[0, 0] = float("nan")
    assert non_finite_weight(b) == "head.2.weight"
    with pytest.raises(
        ConfigError, match=r"member 1 \(.*\) has non-finite weights \(head.2.weight\)"
    ):
        merge([a, b])


def test_merge_refuses_the_same_member_twice(spec, episodes):
    a = make_surrogate(spec, episodes, seed=0, window=5)
    b = make_surrogate(spec, episodes, seed=1, window=5)
    with pytest.raises(ConfigError, match="member 2 .* has the same weights as ensemble member 0"):
        merge([a, b, a])
    assert merge([a, b]).metrics["ensemble"]["n_member"] == 2


def _envelope(spec, *, lo: float, hi: float, omega: float | None, source: str):
    """``spec`` with the end stops and speed bounds training on some data derives."""
    joints = tuple(
        replace(j, omega_max=omega)
        if j.periodic
        else replace(j, theta_min=lo, theta_max=hi, omega_max=omega)
        for j in spec.joints
    )
    return replace(spec, joints=joints, meta={**spec.meta, "data_source": source})


def test_members_trained_on_other_data_of_the_machine_merge(spec, episodes):
    """Members of one machine trained on other data derive other end stops and speed bounds
    from it: ``merge`` compared whole specs and refused them as another "machine spec
    (joints, rate, limits)".  It now compares the machine (``MachineSpec.mismatch``) and
    keeps the widest envelope, and the sources of both."""
    a_spec = _envelope(spec, lo=-1.0, hi=1.1, omega=0.4, source="mujoco-ideal")
    b_spec = _envelope(spec, lo=-1.1, hi=1.0, omega=0.6, source="import")
    a = make_surrogate(a_spec, episodes, seed=0, window=5)
    b = make_surrogate(b_spec, episodes, seed=1, window=5)
    ens = merge([a, b])
    swing, boom = ens.spec.joints[:2]
    assert (boom.theta_min, boom.theta_max, boom.omega_max) == (-1.1, 1.1, 0.6)
    assert (swing.theta_min, swing.theta_max, swing.omega_max) == (None, None, 0.6)
    assert ens.spec.meta["data_source"] == "import+mujoco-ideal"
    assert ens.spec.mismatch(spec) is None
    unbounded = make_surrogate(spec, episodes, seed=2, window=5)  # no speed bound: none
    assert merge([a, unbounded]).spec.joints[1].omega_max is None
    assert merge([a, make_surrogate(a_spec, episodes, seed=3, window=5)]).spec == a_spec
    # another machine: refused, naming what differs
    joints = list(spec.joints)
    joints[1] = replace(joints[1], u_min=-1.0, u_max=1.0)
    other = make_surrogate(replace(spec, joints=tuple(joints)), episodes, seed=4, window=5)
    with pytest.raises(ConfigError) as e:
        merge([a, other])
    assert str(e.value).startswith(
        "ensemble member 1 (lstm) differs from ensemble member 0 (lstm) in its machine "
        f"(joint '{spec.names[1]}' command range [-1000, 1000] vs [-1, 1]); "
    )
