"""Excitation signals: shapes, ranges, determinism, limit avoidance."""

from __future__ import annotations

import numpy as np
import pytest

from excavator_surrogate.errors import ConfigError
from excavator_surrogate.simulate import excitation as ex
from excavator_surrogate.simulate.plant import MujocoExcavator
from excavator_surrogate.spec import EXCAVATOR, JointSpec, MachineSpec

OMEGA_MAX = np.array([0.68, 0.45, 0.55, 1.0])
THETA0 = np.array([1.0, -0.6, 2.5, 0.0])  # near the boom's lower and the arm's upper limit


@pytest.mark.parametrize("kind", sorted(ex.SIGNALS))
def test_signal_shape_range_and_determinism(kind: str) -> None:
    n = 1200
    u = ex.generate(kind, 7, n, EXCAVATOR, theta0=THETA0, omega_max=OMEGA_MAX)
    assert u.shape == (n, EXCAVATOR.n_joint) and np.all(np.isfinite(u))
    assert np.all(np.abs(u) <= 1000.0)
    assert np.any(u != 0.0)
    np.testing.assert_array_equal(
        u,
        ex.generate(
            kind, np.random.default_rng(7), n, EXCAVATOR, theta0=THETA0, omega_max=OMEGA_MAX
        ),
    )
    assert not np.array_equal(
        u, ex.generate(kind, 8, n, EXCAVATOR, theta0=THETA0, omega_max=OMEGA_MAX)
    )
    # nominal integrated angle stays inside the soft range
    ang = THETA0 + np.cumsum(u, axis=0) * OMEGA_MAX / 1000.0 * EXCAVATOR.dt
    for k, j in enumerate(EXCAVATOR.joints):
        if j.theta_min is not None:
            assert ang[:, k].min() >= j.theta_min + 0.05 - 1e-9
            assert ang[:, k].max() <= j.theta_max - 0.05 + 1e-9


def test_steps_have_holds_and_zero_periods() -> None:
    u = ex.steps(0, 1800, EXCAVATOR, theta0=THETA0, omega_max=OMEGA_MAX)
    changes = np.count_nonzero(np.diff(u, axis=0), axis=0)
    assert np.all(changes < 1800 // 10)  # piecewise constant
    assert np.mean(u == 0.0) > 0.1  # zero periods


def test_simulated_excitation_avoids_end_stops() -> None:
    plant = MujocoExcavator()
    u = ex.generate("steps", 3, 1800, EXCAVATOR, theta0=THETA0, omega_max=plant.omega_max)
    theta = plant.rollout(u[None], theta0=THETA0[None])["theta"][0]
    for k, j in enumerate(EXCAVATOR.joints):
        if j.theta_min is not None:
            assert theta[:, k].min() > j.theta_min + 0.02 and theta[:, k].max() < j.theta_max - 0.02


def test_fold_reverses_command_at_soft_limit() -> None:
    spec = MachineSpec(joints=(JointSpec("a", theta_min=0.0, theta_max=1.0),))
    u = np.full((400, 1), 1000.0)  # 1 rad/s for 20 s
    out = ex.fold_limits(
        u, spec, theta0=np.array([0.5]), omega_max=np.array([1.0]), limit_margin=0.1
    )
    assert set(np.unique(out)) == {-1000.0, 1000.0}
    ang = 0.5 + np.cumsum(out[:, 0]) / 1000.0 * spec.dt
    assert ang.min() >= 0.1 - 1e-9 and ang.max() <= 0.9 + 1e-9


def test_generic_spec_without_four_joints() -> None:
    spec = MachineSpec(
        joints=(JointSpec("turn", periodic=True), JointSpec("lift", theta_min=-1, theta_max=1))
    )
    for kind in ("multisine", "steps", "chirp", "prbs"):
        u = ex.generate(kind, 0, 300, spec, omega_max=np.array([0.5, 0.5]))
        assert u.shape == (300, 2)
    with pytest.raises(ConfigError):
        ex.generate("work_cycle", 0, 300, spec)
    with pytest.raises(ConfigError):
        ex.generate("nope", 0, 300, spec)


def test_fold_makes_no_short_pulses() -> None:
    """From this start pose, a step that would run into a limit is reversed from its start,
    not after a few samples.  Not a guarantee for every pose: from random poses the fold can
    leave reversals as short as one sample (docs/plant.md, Known limitations)."""
    for seed in range(5):
        u = ex.steps(seed, 1800, EXCAVATOR, theta0=THETA0, omega_max=OMEGA_MAX)
        for k in range(1, EXCAVATOR.n_joint):
            s = np.sign(u[:, k])
            edges = np.flatnonzero(np.diff(s)) + 1
            runs = np.diff(np.concatenate([[0], edges, [len(s)]]))
            starts = np.concatenate([[0], edges])
            assert np.all((runs >= 10) | (s[starts] == 0) | (starts + runs == len(s)))


def test_signals_are_declared_once_in_the_registry() -> None:
    import dataclasses
    import pickle

    from excavator_surrogate.config import from_dict
    from excavator_surrogate.simulate.signals import REGISTRY

    cfg = ex.ExcitationConfig()
    assert [f.name for f in dataclasses.fields(cfg)] == list(REGISTRY)
    assert set(ex.SIGNALS) | set(ex.CLOSED_LOOP) == set(REGISTRY)
    assert not set(ex.SIGNALS) & set(ex.CLOSED_LOOP)
    for name, kind in REGISTRY.items():
        assert getattr(cfg, name) == kind.params()
    assert pickle.loads(pickle.dumps(cfg)) == cfg  # travels to simulation worker processes
    assert from_dict(ex.ExcitationConfig, {"chirp": {"f_end": 0.5}}).chirp.f_end == 0.5
    with pytest.raises(ConfigError, match="unknown key"):
        from_dict(ex.ExcitationConfig, {"nope": {}})
