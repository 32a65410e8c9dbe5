"""Linear joints in the machine spec: fields, refusals, serialisation, linkage."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from excavator_surrogate.errors import ConfigError
from excavator_surrogate.spec import EXCAVATOR, JointSpec, Linkage, MachineSpec


def _stroke_spec() -> MachineSpec:
    return MachineSpec(
        joints=(
            JointSpec("swing", periodic=True),
            JointSpec(
                "boom",
                kind="linear",
                unit="mm",
                theta_min=0.1,
                theta_max=1.9,
                linkage=Linkage(a=1.2, b=3.4, phi=1.1, l0=2.0),
            ),
            JointSpec("arm", kind="linear", unit="cm"),
        ),
        rate_hz=20.0,
    )


def test_linear_spec_round_trips_through_json() -> None:
    spec = _stroke_spec()
    back = MachineSpec.from_dict(json.loads(json.dumps(spec.to_dict())))
    assert back == spec
    assert back.joints[1].linkage == spec.joints[1].linkage
    assert [j.display_unit for j in back.joints] == ["rad", "mm", "cm"]
    assert [j.display_factor for j in back.joints] == [1.0, 1000.0, 100.0]
    assert back.joints[1].rate_unit == "mm/s"


def test_revolute_dict_is_unchanged_and_old_dicts_load() -> None:
    """Specs written before linear joints (no kind/unit keys) load as revolute joints, and a
    revolute spec writes the same keys as before (checkpoints and episodes compare equal)."""
    d = EXCAVATOR.to_dict()
    keys = set(d["joints"][0])
    assert not keys & {"kind", "unit", "linkage"}
    back = MachineSpec.from_dict(d)
    assert back == EXCAVATOR
    assert all(j.kind == "revolute" and j.unit == "rad" for j in back.joints)


@pytest.mark.parametrize(
    ("kw", "msg"),
    [
        ({"kind": "linear", "unit": "mm", "periodic": True}, "cannot be periodic"),
        ({"kind": "linear", "unit": "inch"}, "use one of m, cm, mm"),
        ({"kind": "revolute", "unit": "mm"}, 'kind = "linear"'),
        ({"kind": "prismatic", "unit": "m"}, "use revolute or linear"),
        ({"linkage": Linkage(a=1.0, b=2.0)}, "only a linear joint has a linkage"),
    ],
)
def test_bad_kinds_are_refused_in_one_line(kw: dict, msg: str) -> None:
    with pytest.raises(ConfigError) as e:
        JointSpec("boom", **kw)
    assert msg in str(e.value) and "boom" in str(e.value) and "\n" not in str(e.value)


def test_mismatch_names_the_kind() -> None:
    a = MachineSpec((JointSpec("boom"),))
    b = MachineSpec((JointSpec("boom", kind="linear", unit="mm"),))
    assert a.mismatch(b) == "joint 'boom' revolute vs linear"
    # the display unit is only how it prints: mm and cm data fit the same model
    c = MachineSpec((JointSpec("boom", kind="linear", unit="cm"),))
    assert b.mismatch(c) is None


def test_linkage_stroke_and_angle_are_inverse() -> None:
    link = Linkage(a=1.25, b=3.4, phi=1.15, l0=2.05)
    theta = np.linspace(-0.75, 0.85, 50)
    s = link.stroke(theta)
    assert np.all(np.diff(s) > 0)  # monotonic over the joint's range
    assert np.allclose(link.angle(s), theta, atol=1e-9)
    # the law of cosines by hand at one point
    t = 0.3
    expect = math.sqrt(1.25**2 + 3.4**2 - 2 * 1.25 * 3.4 * math.cos(t + 1.15)) - 2.05
    assert link.stroke(t) == pytest.approx(expect, rel=1e-12)


def test_linkage_reach_and_misfit() -> None:
    """The triangle reaches lengths |a - b| .. a + b; strokes beyond them are named with the
    likely unit slip of a, b and l0 only when those are out of all proportion."""
    link = Linkage(a=1.25, b=3.4, phi=1.15, l0=2.05)
    assert link.reach == pytest.approx((0.1, 2.6))
    assert link.reachable([0.1, 1.0, 2.6, 2.61, 0.09]).tolist() == [True, True, True, False, False]
    assert link.misfit(0.25, 2.03, "mm") is None
    in_mm = Linkage(a=1.25e-3, b=3.4e-3, phi=1.15, l0=2.05e-3)  # 1.25 read as mm, meant m
    assert in_mm.misfit(0.25, 2.03, "mm", what="the limits") == (
        "the linkage reaches strokes 0.1 .. 2.6 mm only (its length |a - b| .. a + b, less "
        "l0), not the limits 250 .. 2030 mm: its a, b and l0 look like m; give them in mm, "
        "the position's unit"
    )
    in_m = Linkage(a=1250.0, b=3400.0, phi=1.15, l0=2050.0)  # 1250 read as m, meant mm
    assert "its a, b and l0 look like mm; give them in m" in str(in_m.misfit(0.25, 2.03, "m"))
    short = Linkage(a=1.25, b=3.4, phi=1.15, l0=3.0)  # in proportion: no unit to blame
    assert str(short.misfit(0.25, 2.03, "cm")).endswith(
        "not strokes 25 .. 203 cm: check a, b and l0 (in cm, the position's unit)"
    )


@pytest.mark.parametrize(
    "kw", [{"a": 0.0, "b": 1.0}, {"a": 1.0, "b": math.nan}, {"a": 1, "b": 1, "l0": -1}]
)
def test_bad_linkage_is_refused(kw: dict) -> None:
    with pytest.raises(ConfigError, match="linkage"):
        Linkage(**kw)
