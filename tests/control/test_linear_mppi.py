"""MPPI on a surrogate of a stroke-sensing machine: positions in m, limits kept."""

from __future__ import annotations

import numpy as np

from excavator_surrogate.control.mppi import MPPI, MPPIConfig
from excavator_surrogate.control.predict import SurrogatePredictor
from excavator_surrogate.spec import JointSpec, MachineSpec
from tests.helpers.surrogates import tiny_surrogate

LO, HI = 0.9, 1.6
"""Stroke limits of both cylinders [m] (shown in mm)."""
SPEC = MachineSpec(
    (
        JointSpec("swing", periodic=True, omega_max=0.8),
        JointSpec("boom", kind="linear", unit="mm", theta_min=LO, theta_max=HI, omega_max=0.2),
        JointSpec("arm", kind="linear", unit="mm", theta_min=LO, theta_max=HI, omega_max=0.2),
    )
)


def test_mppi_plans_in_metres_and_its_rollouts_keep_the_stroke_limits() -> None:
    sur = tiny_surrogate(SPEC, end_stops=True, drive=2.0)
    pred = SurrogatePredictor(sur, n_batch=32)
    theta0 = np.array([0.0, 1.0, 1.5])
    pred.reset(theta0)
    # every candidate, even full commands held for 40 steps, stays inside the strokes
    u = np.random.default_rng(0).uniform(-1000, 1000, size=(32, 40, 3))
    theta = pred.predict(u)
    assert theta.shape == (32, 40, 3)
    assert np.isfinite(theta).all()
    assert theta[..., 1:].min() >= LO - 1e-6 and theta[..., 1:].max() <= HI + 1e-6
    # the planner's reference is in the same SI unit: a stroke target of 1.2 m
    mppi = MPPI(pred, MPPIConfig(n_sample=32, n_horizon=8, replan=2, seed=1))
    mppi.reset(theta0)
    ref = np.repeat(np.array([[0.0, 1.2, 1.2]]), 8, axis=0)
    for k in range(6):
        cmd = mppi.act(k, ref)
        assert cmd.shape == (3,) and np.all(np.abs(cmd) <= 1000)
        mppi.observe(cmd, theta0)
