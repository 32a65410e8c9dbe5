"""The training coverage record of a periodic joint: one wrap rule for the fit and the check."""

from __future__ import annotations

import itertools

import numpy as np
import torch

from excavator_surrogate.data import Episode
from excavator_surrogate.env.uncertainty import OodFlags
from excavator_surrogate.errors import CheckpointError
from excavator_surrogate.spec import MachineSpec
from excavator_surrogate.surrogate.angles import omega_target, wrap_angle
from excavator_surrogate.surrogate.coverage import (
    CoverageRecord,
    fit_coverage,
    on_box_turn,
    ood_flags,
)
from excavator_surrogate.surrogate.synthetic import synthetic_spec

POSES = (-1.0, 2.5, 5.8)
"""Swing rests [rad]: 6.8 rad from first to last, more than a turn."""


def _swings(spec: MachineSpec) -> list[Episode]:
    """The swing rests at each of :data:`POSES` (command 0) and moves between them at a
    command of +-500, there and back, logged unwrapped; the way there again logged wrapped to
    [-pi, pi).  The other joint follows a slow sine."""
    eps = []
    for name, poses, cmd in (("there", POSES, 500.0), ("back", POSES[::-1], -500.0)):
        sw, u0 = [np.full(80, poses[0])], [np.zeros(80)]
        for a, b in itertools.pairwise(poses):
            sw += [np.linspace(a, b, 200)[1:], np.full(80, b)]
            u0 += [np.full(199, cmd), np.zeros(80)]
        t = np.arange(sum(len(s) for s in sw)) * spec.dt
        theta = np.stack([np.concatenate(sw), 0.5 * np.sin(0.7 * t)], axis=1)
        u = np.stack([np.concatenate(u0), 300 * np.cos(0.7 * t)], axis=1)
        eps.append(Episode(spec=spec, time=t, u=u, theta=theta, omega=0 * theta, name=name))
    wrapped = eps[0].theta.copy()
    wrapped[:, 0] = wrap_angle(wrapped[:, 0])
    eps.append(Episode(spec=spec, time=eps[0].time, u=eps[0].u, theta=wrapped, omega=0 * wrapped))
    return eps


def _flags(rec: CoverageRecord, spec: MachineSpec, ep: Episode) -> tuple[np.ndarray, np.ndarray]:
    """(n_step - 1, n_joint) flags of ``ep``'s samples 1.. from ``ood_flags`` and the torch twin."""
    om = omega_target(ep.theta, spec)
    want = ood_flags(rec, spec, ep.theta, om, ep.u)[1:]
    box = OodFlags(rec, spec, dtype=torch.float64)
    t = lambda a: torch.as_tensor(a[1:])  # noqa: E731
    got = box(t(ep.theta), t(ep.u), t(om)).numpy()
    return want, got


def test_every_training_sample_of_a_swing_over_a_turn_is_in_distribution():
    """The record moved each periodic angle to ``c +- pi`` round its circular mean ``c``, the
    check only an angle outside the box (5 % wider than that), round the box's middle: a rest
    at 2.5 rad, in the margin beyond ``c + pi`` = 2.26, was counted a turn away (-3.78) and
    checked where it was, so 12.6 % of the training samples were flagged by their own record.
    Now the record keeps ``c`` and the check turns every angle round it, in NumPy and in torch
    (the engine's and the ONNX graph's flags)."""
    spec = synthetic_spec(2)
    eps = _swings(spec)
    assert np.ptp(eps[0].theta[:, 0]) > 2 * np.pi
    rec = fit_coverage(eps, spec)
    sw = np.concatenate([ep.theta[1:, 0] for ep in eps])
    c = np.arctan2(np.sin(sw).mean(), np.cos(sw).mean())  # the swing's circular mean
    assert rec.hi[spec.n_u] > POSES[1] > c + np.pi  # the rest lies in the box's margin
    for ep in eps:
        want, got = _flags(rec, spec, ep)
        assert not want.any(), f"{ep.name}: {want.mean(0)} of its samples flagged"
        np.testing.assert_array_equal(got, want)
    # the swing's rest on other turns is in distribution too; a rest never made is not
    poses = np.array([[2.5, 0.0], [2.5 - 2 * np.pi, 0.0], [2.5 + 4 * np.pi, 0.0], [0.5, 0.0]])
    cmd = np.array([[0.0, 300.0]] * 4)
    flags = ood_flags(rec, spec, poses, np.zeros_like(poses), cmd)[:, 0]
    assert flags.tolist() == [False, False, False, True]


def test_a_record_without_turn_centre_loads_and_checks_as_before():
    """A record written before ``turn_centre``: it loads, round-trips without the field and
    keeps the old check (an angle inside the box stays where it is, one outside turns round
    the box's middle), so its flags do not change under it; the torch twin agrees."""
    spec = synthetic_spec(2)
    eps = _swings(spec)
    new = fit_coverage(eps, spec)
    d = new.to_dict()
    assert len(d["turn_centre"]) == spec.n_joint
    back = CoverageRecord.from_dict(d)
    assert back.turn_centre is not None
    np.testing.assert_array_equal(back.turn_centre, new.turn_centre)
    del d["turn_centre"]
    old = CoverageRecord.from_dict(d)
    assert old.turn_centre is None and "turn_centre" not in old.to_dict()
    it = spec.n_u
    lo, hi, m = old.lo[it], old.hi[it], 0.5 * (old.lo[it] + old.hi[it])
    theta = np.array([[2.5, 0.0], [lo - 0.1, 0.0], [hi + 0.1, 0.0]])
    turned = on_box_turn(old, spec, theta)[:, 0]
    np.testing.assert_allclose(
        turned, [2.5, m + wrap_angle(lo - 0.1 - m), m + wrap_angle(hi + 0.1 - m)]
    )
    want, got = _flags(old, spec, eps[0])
    np.testing.assert_array_equal(got, want)
    assert want[:, 0].any()  # the old rule's flags, unchanged (the rest at 2.5 rad)
    d["turn_centre"] = [0.0]
    try:
        CoverageRecord.from_dict(d)
    except CheckpointError as e:
        assert "turn_centre" in str(e) and "calibrate again" in str(e)
    else:
        raise AssertionError("a turn_centre of the wrong size was accepted")
