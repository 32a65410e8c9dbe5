"""Linear joints in the import: strokes in m / cm / mm, their velocities, limits and checks."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from excavator_surrogate.data import load_dataset
from excavator_surrogate.errors import ConfigError, DataError
from excavator_surrogate.ingest import import_logs, parse_mapping
from excavator_surrogate.ingest.units import to_si

RATE = 50.0


def _mapping(
    boom: str = 'position = { column = "boom_mm", unit = "mm" }',
    extra: str = "",
) -> dict:
    import tomllib

    text = f"""
[machine]
name = "stroke-rig"
rate_hz = 20
[time]
column = "t"
[split]
by = "fraction"
fractions = [1.0, 0.0, 0.0]
[[joints]]
name = "boom"
{boom}
{extra}
command = {{ column = "u_boom", unit = "physical", range = [-1, 1] }}
[[joints]]
name = "swing"
periodic = true
angle = {{ column = "swing_deg", unit = "deg" }}
command = {{ column = "u_swing", unit = "physical", range = [-1, 1] }}
"""
    return tomllib.loads(text)


def _log(path: Path, *, seconds: float = 30.0, seed: int = 0, stroke0_mm: float = 500.0) -> Path:
    """A stroke that integrates its command (0.2 m/s at full command) and a swing in deg."""
    rng = np.random.default_rng(seed)
    n = int(seconds * RATE)
    t = np.arange(n) / RATE
    u = np.clip(np.repeat(rng.uniform(-1, 1, n // 50 + 1), 50)[:n], -1, 1)
    stroke_mm = stroke0_mm + 1e3 * np.cumsum(0.2 * u) / RATE
    swing_deg = np.cumsum(30.0 * u[::-1]) / RATE
    rate_mm_s = np.gradient(stroke_mm, t)
    body = np.column_stack([t, stroke_mm, rate_mm_s, u, swing_deg, u[::-1]])
    np.savetxt(
        path,
        body,
        delimiter=",",
        header="t,boom_mm,boom_rate,u_boom,swing_deg,u_swing",
        comments="",
        fmt="%.6f",
    )
    return path


def test_position_table_makes_a_linear_joint_in_si(tmp_path: Path) -> None:
    m = parse_mapping(_mapping(extra="limits = [0, 4000]"))
    spec = m.spec()
    boom = spec.joints[0]
    assert (boom.kind, boom.unit) == ("linear", "mm")
    assert (boom.theta_min, boom.theta_max) == pytest.approx((0.0, 4.0))  # mm -> m
    assert spec.joints[1].kind == "revolute" and spec.joints[1].unit == "rad"
    log = _log(tmp_path / "run.csv")
    import_logs([log], m, out=tmp_path / "ds", quiet=True)
    ds = load_dataset(tmp_path / "ds")
    assert ds.spec.joints[0].unit == "mm"  # the Parquet metadata and the manifest keep it
    ep = ds.split("train")[0]
    assert ep.spec.joints[0].kind == "linear"
    raw = np.loadtxt(log, delimiter=",", skiprows=1)
    # stored in m: the resampled stroke lies inside the log's range (mm / 1000)
    lo, hi = raw[:, 1].min() / 1e3, raw[:, 1].max() / 1e3
    assert lo - 1e-3 <= ep.theta[:, 0].min() and ep.theta[:, 0].max() <= hi + 1e-3
    assert np.ptp(ep.theta[:, 0]) > 0.5 * (hi - lo)


def test_angle_table_with_a_length_unit_is_the_same(tmp_path: Path) -> None:
    a = parse_mapping(_mapping('angle = { column = "boom_mm", unit = "mm" }')).spec()
    b = parse_mapping(_mapping()).spec()
    assert a.joints == b.joints


def test_a_long_stroke_in_m_is_not_taken_for_degrees_or_wrapped(tmp_path: Path) -> None:
    """A 'rad' angle beyond ±2π is refused as degrees; a stroke of 7 m in m is a stroke."""
    log = _log(tmp_path / "run.csv", stroke0_mm=7000.0)
    text = log.read_text().splitlines()
    m = parse_mapping(_mapping('position = { column = "boom_mm", unit = "mm" }'))
    import_logs([log], m, out=tmp_path / "ds", quiet=True)
    ep = load_dataset(tmp_path / "ds").split("train")[0]
    assert ep.theta[:, 0].min() > 6.0  # kept above 2π: not wrapped, not rescaled
    # the same numbers declared in m (values / 1000): still a stroke above 2π
    lines = [text[0]] + [
        ",".join([c if k != 1 else f"{float(c) / 1e3:.6f}" for k, c in enumerate(r.split(","))])
        for r in text[1:]
    ]
    (tmp_path / "m.csv").write_text("\n".join(lines) + "\n")
    m2 = parse_mapping(_mapping('position = { column = "boom_mm", unit = "m" }'))
    import_logs([tmp_path / "m.csv"], m2, out=tmp_path / "ds2", quiet=True)
    ep2 = load_dataset(tmp_path / "ds2").split("train")[0]
    tol = 1e-5  # the CSV's 6 decimals of m
    assert np.allclose(ep2.theta[:, 0], ep.theta[:, 0], atol=tol)


def test_measured_velocity_in_mm_s(tmp_path: Path) -> None:
    vel = 'velocity = { column = "boom_rate", unit = "mm/s" }'
    m = parse_mapping(_mapping(extra=vel))
    import_logs([_log(tmp_path / "run.csv")], m, out=tmp_path / "ds", quiet=True)
    ep = load_dataset(tmp_path / "ds").split("train")[0]
    assert np.abs(ep.omega[:, 0]).max() == pytest.approx(0.2, rel=0.1)  # m/s


def test_velocity_in_the_wrong_length_unit_is_found(tmp_path: Path) -> None:
    """A mm/s column declared as m/s is 1000x the stroke's rate of change."""
    m = parse_mapping(_mapping(extra='velocity = { column = "boom_rate", unit = "m/s" }'))
    with pytest.raises(DataError) as e:
        import_logs([_log(tmp_path / "run.csv")], m, out=tmp_path / "ds", quiet=True)
    msg = str(e.value)
    assert "length unit looks wrong" in msg and "boom" in msg and "deg" not in msg


def test_out_of_limits_prints_the_mapping_unit(tmp_path: Path) -> None:
    m = parse_mapping(_mapping(extra="limits = [0, 600]"))
    with pytest.raises(DataError) as e:
        import_logs([_log(tmp_path / "run.csv")], m, out=tmp_path / "ds", quiet=True)
    msg = str(e.value)
    assert "outside the declared limits [0 mm, 600 mm]" in msg, msg
    assert " rad" not in msg and "deg" not in msg


@pytest.mark.parametrize(
    ("boom", "extra", "msgs"),
    [
        (
            'position = { column = "boom_mm", unit = "inch" }',
            "",
            ["joint 'boom'", "must be one of ['deg', 'rad', 'm', 'cm', 'mm']", "'inch'"],
        ),
        (
            'position = { column = "boom_mm", unit = "mm" }',
            "periodic = true",
            ["joint 'boom'", "cannot be periodic"],
        ),
        (
            'position = { column = "boom_mm", unit = "mm" }',
            'velocity = { column = "boom_rate", unit = "deg/s" }',
            ["joint 'boom'", "does not fit the position's unit 'mm'", "mm/s"],
        ),
        (
            'angle = { column = "boom_mm", unit = "deg" }',
            "linkage = { a = 1, b = 2 }",
            ["joint 'boom'", "only for a linear joint"],
        ),
        (
            'position = { column = "boom_mm", unit = "mm" }',
            "linkage = { a = 1 }",
            ["joint 'boom'", "linkage needs a and b"],
        ),
        (
            'position = { column = "boom_mm", unit = "mm" }\nangle = { column = "x", unit = "deg" }',
            "",
            ["joint 'boom'", "either angle or position"],
        ),
        (  # the geometry in m beside a position in mm: it reaches none of the limits
            'position = { column = "boom_mm", unit = "mm" }\nlimits = [250.7, 2031.7]',
            "linkage = { a = 1.25, b = 3.4, l0 = 2.05, phi = 65.89 }",
            [
                "m.toml: joint 'boom': the linkage reaches strokes 0.1 .. 2.6 mm only (its "
                "length |a - b| .. a + b, less l0), not the limits 250.7 .. 2031.7 mm: its a, b "
                "and l0 look like m; give them in mm, the position's unit"
            ],
        ),
        (  # the right unit, but a triangle too short for the upper limit
            'position = { column = "boom_mm", unit = "mm" }\nlimits = [250.7, 2031.7]',
            "linkage = { a = 1250, b = 3400, l0 = 3000, phi = 65.89 }",
            [
                "reaches strokes -850 .. 1650 mm only",
                "not the limits 250.7 .. 2031.7 mm: check a, b and l0 (in mm, the position's",
            ],
        ),
    ],
)
def test_mapping_refusals_are_one_line(boom: str, extra: str, msgs: list[str]) -> None:
    with pytest.raises(ConfigError) as e:
        parse_mapping(_mapping(boom, extra), path="m.toml")
    text = str(e.value)
    assert "\n" not in text and text.startswith("m.toml")
    for msg in msgs:
        assert msg in text, text


def test_linkage_is_converted_to_si() -> None:
    m = parse_mapping(_mapping(extra="linkage = { a = 1200, b = 3400, l0 = 2000, phi = 60 }"))
    link = m.spec().joints[0].linkage
    assert link is not None
    assert (link.a, link.b, link.l0) == pytest.approx((1.2, 3.4, 2.0))
    assert link.phi == pytest.approx(np.pi / 3)


@pytest.mark.parametrize(
    ("linkage", "says"),
    [
        (  # lengths in m, read in mm: 0.05 .. 1.05 mm, no stroke of the log (85.7 .. 912 mm)
            "linkage = { a = 0.5, b = 1.5, l0 = 0.95 }",
            "joint 'boom', 1500 of 1500 samples: the linkage reaches strokes 0.05 .. 1.05 mm "
            "only (its length |a - b| .. a + b, less l0), not the log's strokes 85.6998 .. "
            "912.225 mm: its a, b and l0 look like m; give them in mm, the position's unit",
        ),
        (  # 100 .. 1100 mm: the log's shortest strokes are beyond it
            "linkage = { a = 500, b = 1500, l0 = 900 }",
            "the linkage reaches strokes 100 .. 1100 mm only (its length |a - b| .. a + b, less "
            "l0), not the log's strokes 85.6998 .. 912.225 mm: check a, b and l0 (in mm, the",
        ),
    ],
)
def test_strokes_beyond_the_linkage_are_refused(tmp_path: Path, linkage: str, says: str) -> None:
    """Without limits, the log's strokes are what the triangle must reach: one line naming
    the file, the column, the first row beyond it and the likely unit slip (the import had
    passed, and evaluate scored every stroke's clipped angle a perfect 0.0000)."""
    m = parse_mapping(_mapping(extra=linkage), path="m.toml")
    log = _log(tmp_path / "run.csv")
    with pytest.raises(DataError) as e:
        import_logs([log], m, out=tmp_path / "ds", quiet=True)
    msg = str(e.value)
    assert "\n" not in msg and msg.startswith(f"{log}, column 'boom_mm', row "), msg
    assert says in msg, msg
    assert "(the linkage of joint 'boom' is in m.toml; docs/import.md, Linear joints)" in msg
    assert not (tmp_path / "ds").exists()
    # a triangle that reaches every stroke imports
    fits = parse_mapping(_mapping(extra="linkage = { a = 500, b = 1500, l0 = 950 }"))
    import_logs([log], fits, out=tmp_path / "ok", quiet=True)
    assert load_dataset(tmp_path / "ok").spec.joints[0].linkage == fits.spec().joints[0].linkage


def test_si_factors() -> None:
    assert [to_si(u) for u in ("m", "cm", "mm", "rad", "m/s", "mm/s")] == pytest.approx(
        [1.0, 0.01, 0.001, 1.0, 1.0, 0.001]
    )
    assert to_si("deg") == pytest.approx(np.pi / 180)
    assert to_si(None) == 1.0  # no unit: already SI
