"""The physical envelope: speed bounds in every closed loop, end stops and speeds from data."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
import torch

from excavator_surrogate.data import Dataset
from excavator_surrogate.spec import MachineSpec
from excavator_surrogate.surrogate import rollout, rollout_reference
from excavator_surrogate.surrogate.angles import (
    envelope,
    envelope_inward,
    integrate,
    integrate_np,
    omega_target,
    unwrap_periodic,
)
from excavator_surrogate.surrogate.checkpoint import load_checkpoint, save_checkpoint
from excavator_surrogate.surrogate.envelope import fill_envelope
from excavator_surrogate.training import train
from tests.helpers.surrogates import make_surrogate
from tests.helpers.training import tiny_dataset, tiny_train_config


def _bounded(spec: MachineSpec, omega_max: float) -> MachineSpec:
    joints = tuple(dataclasses.replace(j, omega_max=omega_max) for j in spec.joints)
    return dataclasses.replace(spec, joints=joints)


def _open(spec: MachineSpec) -> MachineSpec:
    """``spec`` with every limit and speed bound removed (as most users' mappings are)."""
    joints = tuple(
        dataclasses.replace(j, theta_min=None, theta_max=None, omega_max=None) for j in spec.joints
    )
    return dataclasses.replace(spec, joints=joints)


def test_envelope_inward_never_rounds_a_bound_outward():
    lo = np.array([-math.inf, -0.6, 0.3])
    hi = np.array([math.inf, 0.85, 2.65])
    w = np.array([1.1, math.inf, 0.7])
    got32 = [t.double().numpy() for t in envelope_inward((lo, hi, w), dtype=torch.float32)]
    assert (got32[0] >= lo).all() and (got32[1] <= hi).all() and (got32[2] <= w).all()
    # each finite bound at most one float32 step from the float64 one (the cast, or one inward)
    want = np.array([lo, hi, w])
    fin = np.isfinite(want)
    step = np.abs(np.spacing(want[fin].astype(np.float32)))
    assert (np.abs(np.array(got32)[fin] - want[fin]) <= step).all()
    assert np.isinf(got32[0][0]) and np.isinf(got32[1][0]) and np.isinf(got32[2][1])
    got64 = envelope_inward((lo, hi, w), dtype=torch.float64)
    for a, t in zip((lo, hi, w), got64):
        np.testing.assert_array_equal(t.numpy(), a)  # float64: the bounds themselves


def test_integrate_bounds_the_speed_before_the_stops():
    lo = torch.tensor([-math.inf, -1.0])
    hi = torch.tensor([math.inf, 1.0])
    w = torch.tensor([2.0, 3.0])
    theta = torch.tensor([[0.0, 0.0], [0.0, 0.95]])
    omega = torch.tensor([[5.0, -10.0], [-1.0, 4.0]])
    dt = 0.05
    th, om = integrate(theta, omega, dt=dt, limits=(lo, hi, w))
    # clipped speed is integrated; a stop still reports what was travelled
    torch.testing.assert_close(om[0], torch.tensor([2.0, -3.0]))
    torch.testing.assert_close(th[0], torch.tensor([0.1, -0.15]))
    torch.testing.assert_close(om[1, 0], torch.tensor(-1.0))
    torch.testing.assert_close(th[1, 1], torch.tensor(1.0))
    torch.testing.assert_close(om[1, 1], torch.tensor((1.0 - 0.95) / dt))
    th_n, om_n = integrate_np(
        theta.double().numpy(),
        omega.double().numpy(),
        dt=dt,
        limits=(lo.numpy(), hi.numpy(), w.numpy()),
    )
    np.testing.assert_allclose(th_n, th.double().numpy(), atol=1e-6)
    np.testing.assert_allclose(om_n, om.double().numpy(), atol=1e-4)


@pytest.mark.parametrize("mode", ["windowed", "stateful"])
def test_speed_bound_holds_in_every_path(spec, episodes, mode):
    bound = 0.05
    sur = make_surrogate(
        _bounded(spec, bound), episodes, mode=mode, window=5, end_stops=True, drive=6.0
    )
    assert len(sur.limits_np()) == 3
    n = 50
    theta = np.stack([e.theta[:n] for e in episodes])
    u = np.stack([e.u[:n] for e in episodes])
    th_b, om_b = rollout(sur, theta, u)
    w = sur.window
    assert np.abs(om_b[:, w:]).max() <= bound + 1e-6
    # the same network without the envelope runs faster than the bound
    free = dataclasses.replace(sur, end_stops=False)
    _, om_f = rollout(free, theta, u)
    assert np.abs(om_f[:, w:]).max() > 2 * bound
    for i in range(len(episodes)):
        th_r, om_r = rollout_reference(sur, theta[i], u[i])
        np.testing.assert_allclose(th_b[i], th_r, atol=1e-5)
        np.testing.assert_allclose(om_b[i], om_r, atol=1e-4)


def test_speed_bound_survives_the_checkpoint(spec, episodes, tmp_path: Path):
    sur = make_surrogate(_bounded(spec, 0.3), episodes, end_stops=True)
    back = load_checkpoint(save_checkpoint(tmp_path / "a.pt", sur))
    np.testing.assert_array_equal(envelope(back.spec)[2], np.full(spec.n_joint, 0.3))


def test_fill_envelope_takes_what_the_spec_lacks_from_the_data(spec, episodes):
    declared = spec.joints[-1]
    assert declared.theta_min is not None  # the fixture's last joint is limited
    spec2 = dataclasses.replace(
        spec, joints=(*_open(spec).joints[:-1], dataclasses.replace(declared, omega_max=9.0))
    )
    out, info = fill_envelope(spec2, episodes, limit_margin=0.1, speed_margin=0.5)
    th = np.concatenate([unwrap_periodic(e.theta, spec) for e in episodes])
    om = np.concatenate([omega_target(e.theta, spec)[1:] for e in episodes])
    for k, j in enumerate(out.joints):
        if j.periodic:
            assert j.theta_min is None and j.theta_max is None
            assert info[j.name]["theta_min_source"] == "none"
        elif k == spec.n_joint - 1:
            assert (j.theta_min, j.theta_max) == (declared.theta_min, declared.theta_max)
            assert j.omega_max == 9.0 and info[j.name]["omega_max_source"] == "spec"
        else:
            span = th[:, k].max() - th[:, k].min()
            assert j.theta_min == pytest.approx(th[:, k].min() - 0.1 * span)
            assert j.theta_max == pytest.approx(th[:, k].max() + 0.1 * span)
            assert info[j.name]["theta_max_source"] == "data"
        if k < spec.n_joint - 1:
            assert j.omega_max == pytest.approx(1.5 * np.abs(om[:, k]).max())
    none, _ = fill_envelope(_open(spec), episodes, limit_margin=-1, speed_margin=-1)
    assert none == _open(spec)


def test_training_without_declared_limits_stays_inside_the_observed_range(tmp_path: Path):
    ds = tiny_dataset(3, n_train=2, n_step=200)
    spec = _open(ds.spec)
    open_ds = Dataset(
        spec=spec,
        episodes={s: [e.replace(spec=spec) for e in eps] for s, eps in ds.episodes.items()},
    )
    cfg = tiny_train_config(epochs=1, limit_margin=0.0, speed_margin=0.0)
    sur = load_checkpoint(train(cfg, open_ds, out=tmp_path / "m", show_progress=False))
    lo, hi, w = envelope(sur.spec)
    th = np.concatenate([e.theta for e in open_ds.train])
    lim = ~np.array(spec.periodic)
    assert lim.sum() >= 2 and np.isinf(lo[~lim]).all()
    np.testing.assert_allclose(lo[lim], th.min(axis=0)[lim])
    np.testing.assert_allclose(hi[lim], th.max(axis=0)[lim])
    assert np.isfinite(w).all()
    # a network driven hard into one direction rests on the observed extreme
    with torch.no_grad():
        sur.net.head[-1].bias += 50.0
    ep = open_ds.test[0]
    th_hat, om_hat = rollout(sur, ep.theta[None], ep.u[None])
    assert (th_hat >= lo - 1e-6).all() and (th_hat <= hi + 1e-6).all()
    assert np.isclose(th_hat[0, -1, lim], hi[lim]).all()
    assert np.nanmax(np.abs(om_hat)) <= w.max() + 1e-6
