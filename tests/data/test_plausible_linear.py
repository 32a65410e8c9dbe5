"""The episode contract's plausibility bounds print a linear joint's values in its unit."""

from __future__ import annotations

import numpy as np
import pytest

from excavator_surrogate.data.plausible import check_plausible
from excavator_surrogate.errors import DataError
from excavator_surrogate.spec import JointSpec, MachineSpec

SPEC = MachineSpec((JointSpec("boom", kind="linear", unit="mm"), JointSpec("arm")))
COLS = {"theta": ["theta_boom", "theta_arm"], "omega": ["omega_boom", "omega_arm"]}


def _arrays(boom: np.ndarray) -> dict:
    arm = np.linspace(0.0, 1.0, boom.shape[0])
    return {"theta": np.column_stack([boom, arm]), "omega": np.zeros((boom.shape[0], 2))}


def test_a_legitimate_stroke_passes() -> None:
    boom = np.linspace(0.1, 2.4, 200)  # m: a 2.3 m stroke
    check_plausible(SPEC, _arrays(boom), COLS, where="ep.parquet")


def test_an_impossible_stroke_names_mm_not_rad() -> None:
    boom = np.full(200, 1.0)
    boom[50] = 80.0  # m: beyond the 2π x 10 m bound
    with pytest.raises(DataError) as e:
        check_plausible(SPEC, _arrays(boom), COLS, where="ep.parquet")
    msg = str(e.value)
    assert "joint 'boom': stroke 80000 mm is impossible" in msg, msg
    assert "theta_boom" in msg and "rad" not in msg and "turn" not in msg


def test_an_impossible_stroke_speed_names_mm_per_s() -> None:
    a = _arrays(np.linspace(0.1, 1.0, 200))
    a["omega"][7, 0] = 5000.0  # m/s
    with pytest.raises(DataError) as e:
        check_plausible(SPEC, a, COLS, where="ep.parquet")
    msg = str(e.value)
    assert "velocity 5e+06 mm/s is impossible" in msg and "rad" not in msg, msg
