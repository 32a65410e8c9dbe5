"""The CBE tables print each linear joint in its own unit (mm ...), revolute ones as before."""

from __future__ import annotations

import pytest

from excavator_surrogate.evaluate.report import markdown_table, report_markdown
from excavator_surrogate.spec import EXCAVATOR, JointSpec, MachineSpec

STROKES = MachineSpec(
    (
        JointSpec("swing", periodic=True),
        JointSpec("boom", kind="linear", unit="mm"),
        JointSpec("arm", kind="linear", unit="cm"),
        JointSpec("bucket", kind="linear", unit="m"),
    )
)


def _metrics(names: tuple[str, ...]) -> dict:
    one = {"rmse": 0.0125, "mae": 0.01, "r2": 0.95}
    return {"omega": {n: dict(one) for n in names}, "theta": {n: dict(one) for n in names}}


def _row(text: str, label: str) -> list[str]:
    line = next(ln for ln in text.splitlines() if f"| {label} |" in ln)
    return [c.strip() for c in line.strip("|").split("|")]


def test_linear_rows_name_their_unit_and_scale_rmse() -> None:
    text = markdown_table(_metrics(STROKES.names), spec=STROKES)
    assert _row(text, "Boom [mm]")[2:5] == ["12.5000", "10.0000", "0.9500"]  # m -> mm, R² as is
    assert _row(text, "Arm [cm]")[2:4] == ["1.2500", "1.0000"]
    assert _row(text, "Bucket [m/s]")[2] == "0.0125"
    assert _row(text, "Swing [rad]")[2] == "0.0125"
    assert "Angle trajectory θ [rad]" not in text and "deg" not in text


def test_revolute_machines_print_as_before() -> None:
    m = _metrics(EXCAVATOR.names)
    assert markdown_table(m, spec=EXCAVATOR) == markdown_table(m)
    assert "Angle trajectory θ [rad]" in markdown_table(m)


def test_the_paper_is_not_shown_for_a_stroke_machine() -> None:
    """Same joint names as the paper's machine, but strokes: its Table II does not apply."""
    m = _metrics(STROKES.names)
    assert "Paper RMSE" in report_markdown({"LSTM": m}, primary="LSTM")
    assert "Paper RMSE" not in report_markdown({"LSTM": m}, primary="LSTM", spec=STROKES)


def test_linkage_angles_are_listed() -> None:
    m = _metrics(STROKES.names)
    link = {"boom": {"rmse": 0.02, "mae": 0.015, "r2": 0.99}}
    text = report_markdown({"LSTM": m, "ARX": m}, primary="LSTM", spec=STROKES, linkage=link)
    assert _row(text, "Boom")[1:4] == ["0.0200", "0.0150", "0.9900"]
    assert "angle RMSE [rad]" in text
    # the comparison table scales too
    comp = text.split("## Comparison")[1]
    assert _row(comp, "Boom [mm]")[2] == "12.5000" and _row(comp, "Boom [mm]")[5] == "12.5000"


@pytest.mark.parametrize("unit", ["mm", "cm", "m"])
def test_factor_matches_the_unit(unit: str) -> None:
    spec = MachineSpec((JointSpec("boom", kind="linear", unit=unit),))
    text = markdown_table(_metrics(spec.names), spec=spec)
    expect = {"mm": "12.5000", "cm": "1.2500", "m": "0.0125"}[unit]
    assert _row(text, f"Boom [{unit}]")[2] == expect


def _run_metrics(units: dict | None) -> dict:
    m = _metrics(STROKES.names)
    m["run"] = {"split": "test", "n_step_scored": 10, "reference": "true"}
    if units is not None:
        m["run"]["units"] = units
    m["cleaning"] = {
        n: {"rmse_raw": 0.002, "rmse_fused": 0.001, "rmse_ratio": 0.5} for n in STROKES.names
    }
    return m


def test_run_report_prints_linear_joints_in_their_unit() -> None:
    from excavator_surrogate.evaluate.run_report import ReportContext, render_run_report

    ctx = ReportContext(name="x", spec_names=STROKES.names, table_md="", paper_table="III-compound")
    units = {
        j.name: {"theta": "m" if j.linear else "rad", "display": j.unit} for j in STROKES.joints
    }
    text = render_run_report(_run_metrics(units), ctx)
    assert "| boom [mm] | 2.0000 | 1.0000 | 0.5000 |" in text
    assert "| swing [rad] | 0.0020 | 0.0010 |" in text
    assert "worst-joint position R²" in text and "Table III" not in text
    before = render_run_report(_run_metrics(None), ctx)  # a revolute machine: as before
    assert "raw angle RMSE [rad]" in before and "| boom | 0.0020 |" in before
    assert "worst-joint angle R²" in before and "Table III" in before


def test_the_run_reports_other_tables_name_their_units_and_undefined_r2() -> None:
    """Table III and the cleaning effect printed RMSE and MAE without a unit; the ensemble
    table printed a worst R² of -inf for a joint whose R² is undefined."""
    from excavator_surrogate.evaluate.run_report import ReportContext, render_run_report

    ctx = ReportContext(name="x", spec_names=STROKES.names, table_md="", paper_table="III-compound")
    m = _run_metrics(None)
    still = _metrics(STROKES.names)
    still["omega"]["bucket"]["r2"] = None
    m["ensemble_members"] = {"ensemble": still}
    m["cleaning_effect"] = {"trained on cleaned": _metrics(STROKES.names)}
    m["cleaning_effect"]["trained on raw"] = _metrics(STROKES.names)
    text = render_run_report(m, ctx)
    assert "| ω [rad/s] | swing | 0.0125 / " in text and "| θ [rad] | bucket | 0.0125 / " in text
    assert "| θ RMSE cleaned [rad] | θ RMSE raw [rad] |" in text
    assert "| ensemble | 0.9500 | 0.9500 | 0.9500 | 0.9500 | 0.9500 | 0.9500 (bucket: —) |" in text
    assert "-inf" not in text
    units = {
        j.name: {"theta": "m" if j.linear else "rad", "display": j.unit} for j in STROKES.joints
    }
    m["run"]["units"] = units
    text = render_run_report(m, ctx)
    assert "| boom [mm] | 0.9500 | 0.9500 | 12.5000 | 12.5000 |" in text
