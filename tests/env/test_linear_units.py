"""Linear joints in the envs and the ONNX metadata: bounds in m, units as the mapping gave."""

from __future__ import annotations

import numpy as np
import pytest

from excavator_surrogate.env.base import observation_space
from excavator_surrogate.env.export import units_metadata
from excavator_surrogate.env.safety import GuardConfig
from excavator_surrogate.spec import JointSpec, MachineSpec

SPEC = MachineSpec(
    (
        JointSpec("swing", periodic=True),
        JointSpec("boom", kind="linear", unit="mm", theta_min=0.25, theta_max=2.03),
    )
)


def test_observation_bounds_of_a_stroke_are_its_limits_in_m() -> None:
    box = observation_space(SPEC, guard=GuardConfig(limit_margin=0.1, omega_max=20.0))
    assert box.low[0] == pytest.approx(-np.pi) and box.high[0] == pytest.approx(np.pi)
    # the stroke is stored in m: 0.25 .. 2.03 m, widened by the guard's margin
    assert box.low[1] == pytest.approx(0.15) and box.high[1] == pytest.approx(2.13)


def test_units_metadata() -> None:
    meta = units_metadata(SPEC)
    assert meta["swing"] == {"theta": "rad", "omega": "rad/s", "display": "rad", "factor": "1.0"}
    assert meta["boom"] == {"theta": "m", "omega": "m/s", "display": "mm", "factor": "1000.0"}
