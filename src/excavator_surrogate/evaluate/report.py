"""Markdown tables in the paper's layout (Table II: Type | Joint | RMSE | MAE | R^2)."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

from ..spec import MachineSpec

PAPER_TABLE_II: dict[str, dict[str, tuple[float, float, float]]] = {
    "omega": {
        "swing": (0.0074, 0.0052, 0.9940),
        "boom": (0.0219, 0.0083, 0.7726),
        "arm": (0.0087, 0.0051, 0.8965),
        "bucket": (0.0122, 0.0059, 0.9424),
    },
    "theta": {
        "swing": (0.0380, 0.0303, 0.9967),
        "boom": (0.0179, 0.0138, 0.9927),
        "arm": (0.0280, 0.0249, 0.9809),
        "bucket": (0.0585, 0.0436, 0.9854),
    },
}
"""Paper Table II (Stage I, MuJoCo, 1800-step step test): (RMSE, MAE, R^2) per joint."""

PAPER_TABLE_III: dict[str, dict[str, dict[str, tuple[float, float, float]]]] = {
    "noload": {
        "omega": {
            "swing": (0.0481, 0.0302, 0.9755),
            "boom": (0.0342, 0.0164, 0.8487),
            "arm": (0.0941, 0.0466, 0.8841),
            "bucket": (0.1528, 0.0559, 0.5828),
        },
        "theta": {
            "swing": (0.1822, 0.1553, 0.9989),
            "boom": (0.0691, 0.0496, 0.9286),
            "arm": (0.1053, 0.0733, 0.9737),
            "bucket": (0.1200, 0.0984, 0.9706),
        },
    },
    "compound": {
        "omega": {
            "swing": (0.0249, 0.0175, 0.9750),
            "boom": (0.0259, 0.0171, 0.7920),
            "arm": (0.0269, 0.0185, 0.8734),
            "bucket": (0.0753, 0.0516, 0.8815),
        },
        "theta": {
            "swing": (0.1451, 0.1120, 0.9774),
            "boom": (0.0763, 0.0654, 0.8210),
            "arm": (0.1469, 0.1251, 0.7309),
            "bucket": (0.3395, 0.3101, 0.8667),
        },
    },
}
"""Paper Table III (Stage II, real excavator): (RMSE, MAE, R^2) per condition and joint."""

_TYPE = {"omega": "Angular velocity ω [rad/s]", "theta": "Angle trajectory θ [rad]"}
_TYPE_MIXED = {"omega": "Velocity ω", "theta": "Position θ"}
"""Type labels of a machine with linear joints: each joint row then names its own unit."""


def format_value(v: float | None, f: float = 1.0) -> str:
    """``v`` times the unit factor ``f`` to 4 decimals, or a dash for a missing value."""
    return "—" if v is None else f"{v * f:.4f}"


def row_label(spec: MachineSpec | None, key: str, joint: str) -> tuple[str, float]:
    """The joint cell and the RMSE/MAE factor of one row: ``Boom`` and 1 for revolute-only
    machines (the Type column gives rad), ``Boom [mm]`` and 1000 for a linear joint in mm."""
    if spec is None or not spec.any_linear or joint not in spec.names:
        return joint.capitalize(), 1.0
    j = spec.joints[spec.names.index(joint)]
    unit = j.rate_unit if key == "omega" else j.display_unit
    return f"{joint.capitalize()} [{unit}]", j.display_factor


def _type_label(spec: MachineSpec | None, key: str) -> str:
    return _TYPE_MIXED[key] if spec is not None and spec.any_linear else _TYPE[key]


def paper_applies(names: tuple[str, ...] | list[str]) -> bool:
    """True when the joints are the paper's four (swing, boom, arm, bucket)."""
    return list(names) == list(PAPER_TABLE_II["omega"])


def markdown_table(
    metrics: Mapping[str, Any], *, paper: bool = False, spec: MachineSpec | None = None
) -> str:
    """One model's metrics as the paper's table; with ``paper`` adds Table II columns.

    Args:
        metrics: ``{"omega": {joint: {rmse, mae, r2}}, "theta": {...}}`` in stored units
            (rad, m for a linear joint).
        paper: add the paper's values for joints it reports (swing, boom, arm, bucket).
        spec: the machine; with linear joints every row names its joint's unit and RMSE/MAE
            are printed in it (e.g. mm).
    """
    head = "| Type | Joint | RMSE | MAE | R² |"
    rule = "|---|---|---:|---:|---:|"
    if paper:
        head += " Paper RMSE | Paper MAE | Paper R² |"
        rule += "---:|---:|---:|"
    lines = [head, rule]
    for key in ("omega", "theta"):
        for i, (joint, m) in enumerate(metrics[key].items()):
            typ = _type_label(spec, key) if i == 0 else ""
            label, f = row_label(spec, key, joint)
            row = f"| {typ} | {label} | {format_value(m['rmse'], f)} | {format_value(m['mae'], f)} | {format_value(m['r2'])} |"
            if paper:
                p = PAPER_TABLE_II[key].get(joint)
                row += (
                    (" " + " | ".join(format_value(x) for x in p) + " |") if p else " — | — | — |"
                )
            lines.append(row)
    return "\n".join(lines) + "\n"


def comparison_table(
    by_model: Mapping[str, Mapping[str, Any]], *, spec: MachineSpec | None = None
) -> str:
    """Several models side by side: Type | Joint | then RMSE / R² per model (``spec``: as
    in :func:`markdown_table`)."""
    models = list(by_model)
    head = "| Type | Joint | " + " | ".join(f"{m} RMSE | {m} MAE | {m} R²" for m in models) + " |"
    rule = "|---|---|" + "---:|---:|---:|" * len(models)
    lines = [head, rule]
    first = by_model[models[0]]
    for key in ("omega", "theta"):
        for i, joint in enumerate(first[key]):
            label, f = row_label(spec, key, joint)
            cells = []
            for m in models:
                v = by_model[m][key].get(joint, {"rmse": None, "mae": None, "r2": None})
                cells += [
                    format_value(v["rmse"], f),
                    format_value(v["mae"], f),
                    format_value(v["r2"]),
                ]
            typ = _type_label(spec, key) if i == 0 else ""
            lines.append(f"| {typ} | {label} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


IN_SAMPLE_NOTE = (
    "In-sample: the model trained on the '{split}' split it is scored on, so these scores do "
    "not measure how it does on runs it has not seen; score a held-out test split for that"
)
"""The note over an evaluation of the split the model trained on (``run.in_sample``)."""


def report_markdown(
    by_model: Mapping[str, Mapping[str, Any]],
    *,
    primary: str,
    run: Mapping[str, Any] | None = None,
    paper: bool = True,
    spec: MachineSpec | None = None,
    linkage: Mapping[str, Mapping[str, Any]] | None = None,
) -> str:
    """The ``table.md`` text: run summary, the primary model in the paper's layout, then a
    comparison; ``spec`` prints linear joints in their own unit, ``linkage`` (joint ->
    ``{rmse, mae, r2}`` in rad, :func:`~.cbe.linkage_metrics`) adds their angles through the
    linkage."""
    names = list(by_model[primary]["omega"])
    # the paper's joints are angles: a machine that senses strokes is not its machine
    show_paper = paper and paper_applies(names) and not (spec is not None and spec.any_linear)
    parts = ["# Closed-loop behavioural equivalence (CBE)", ""]
    if run:
        keys = (
            "checkpoint",
            "dataset",
            "split",
            "reference",
            "mode",
            "n_episode",
            "n_step_scored",
            "warmup",
        )
        parts += [f"- {k}: {run[k]}" for k in keys if k in run]
        parts.append("")
        if run.get("in_sample"):
            parts += [f"**{IN_SAMPLE_NOTE.format(split=run.get('split'))}**", ""]
    parts += [
        f"## {primary}" + (" (paper Table II alongside)" if show_paper else ""),
        "",
        markdown_table(by_model[primary], paper=show_paper, spec=spec),
    ]
    if linkage:
        parts += [linkage_markdown(linkage)]
    if len(by_model) > 1:
        parts += [
            "## Comparison",
            "",
            comparison_table(by_model, spec=spec),
            against_others(by_model, primary=primary, units=linear_units(spec)),
            "",
        ]
    return "\n".join(parts)


def against_others(
    by_model: Mapping[str, Mapping[str, Any]],
    *,
    primary: str,
    units: Mapping[str, tuple[float, str]] | None = None,
) -> str:
    """One line: per other model of the table, on how many joints ``primary``'s free-run
    angle (position) RMSE is lower, and each joint where it is not, both RMSEs in degrees, or
    for a joint in ``units`` (joint -> (factor, unit): a linear joint's stored m times factor
    is its unit) in its own unit; e.g. ``lower than ARX on 4 of 4 joints; lower than
    Structured on 3 of 4 (not the arm: 27.2° against 5.86°)``.  Empty without other models."""
    own = by_model[primary]["theta"]
    units = units or {}

    def shown(joint: str, v: float | None) -> str:  # 3 significant digits: 0.520°, 30.0°, 123 mm
        if v is None:
            return "no finite error"
        f, unit = units.get(joint, (math.degrees(1.0), "°"))
        x = v * f
        text = f"{x:.0f}" if abs(x) >= 1000 else f"{x:#.3g}".rstrip(".")  # 1234 mm, not 1.23e+03
        return text + ("" if unit == "°" else " ") + unit

    def lower(a: float | None, b: float | None) -> bool:  # None: a diverged (NaN) free run
        return a is not None and (b is None or a < b)

    parts = []
    for label, m in by_model.items():
        if label == primary:
            continue
        pairs = [
            (joint, own[joint]["rmse"], v["rmse"])
            for joint, v in m["theta"].items()
            if joint in own
        ]
        if not pairs:
            continue
        lost = [(j, a, b) for j, a, b in pairs if not lower(a, b)]
        text = f"lower than {label} on {len(pairs) - len(lost)} of {len(pairs)} joints"
        if lost:
            text += (
                " (not "
                + ", ".join(f"the {j}: {shown(j, a)} against {shown(j, b)}" for j, a, b in lost)
                + ")"
            )
        parts.append(text)
    if not parts:
        return ""
    what = "position" if units else "angle"
    return f"**Free-run {what} RMSE of {primary}:** " + "; ".join(parts) + "."


def linear_units(spec: MachineSpec | None) -> dict[str, tuple[float, str]]:
    """Joint -> (factor, unit) of each linear joint of ``spec``: its stored m times factor is
    its mapping's unit (:func:`against_others`' ``units``)."""
    if spec is None:
        return {}
    return {j.name: (j.display_factor, j.display_unit) for j in spec.joints if j.linear}


EPISODES_TOP = 3
"""Episodes listed per joint under *Where the error is*."""


def episodes_markdown(
    episodes: Sequence[Mapping[str, Any]],
    *,
    spec: MachineSpec | None = None,
    figures: Sequence[str] = (),
    top: int = EPISODES_TOP,
) -> str:
    """*Where the error is*: per joint, the ``top`` episodes holding the largest shares of its
    pooled squared angle error, each with its own RMSE (``run.episodes`` of ``metrics.json``
    with :func:`~.metrics.episode_errors`' fields), and the episode figures written; empty
    for one episode (the table above is that episode)."""
    if len(episodes) < 2 or "theta_share" not in episodes[0]:
        return ""
    names = list(episodes[0]["theta_share"])
    lines = [
        "## Where the error is",
        "",
        f"The {min(top, len(episodes))} episodes holding most of each joint's squared angle "
        "error (share of the pooled sum; the joint's RMSE above is the square root of that "
        "sum over its samples):",
        "",
        "| Joint | Episode | its RMSE"
        + ("" if spec is not None and spec.any_linear else " [rad]")
        + " | share |",
        "|---|---|---:|---:|",
    ]
    for name in names:
        label, f = row_label(spec, "theta", name)
        ranked = sorted(
            (e for e in episodes if e["theta_share"].get(name) is not None),
            key=lambda e: -e["theta_share"][name],
        )[:top]
        for i, e in enumerate(ranked):
            lines.append(
                f"| {label if i == 0 else ''} | {e['name']} | {format_value(e['theta_rmse'][name], f)} "
                f"| {100 * e['theta_share'][name]:.0f} % |"
            )
    lines.append("")
    if len(figures) == 1:
        lines += [f"Figure: `{figures[0]}` (the first episode).", ""]
    elif figures:
        lines += [
            "Figures: " + ", ".join(f"`{x}`" for x in figures) + " (the first episode, then "
            "those holding the largest share of any joint's error).",
            "",
        ]
    return "\n".join(lines) + "\n"


def linkage_markdown(linkage: Mapping[str, Mapping[str, Any]]) -> str:
    """The linear joints' angles through their linkage: one row per joint, in rad (as the
    revolute joints' rows)."""
    lines = [
        "Joint angles through the linkage (the strokes turned into angles):",
        "",
        "| Joint | angle RMSE [rad] | angle MAE [rad] | angle R² |",
        "|---|---:|---:|---:|",
    ]
    for joint, m in linkage.items():
        lines.append(
            f"| {joint.capitalize()} | {format_value(m['rmse'])} | {format_value(m['mae'])} | {format_value(m['r2'])} |"
        )
    far = {joint: m for joint, m in linkage.items() if m.get("unreachable")}
    if far:
        lines.append("")
    for joint, m in far.items():
        lines.append(
            f"{joint.capitalize()}: no angle: {m['unreachable']} of {m['samples']} strokes "
            "(free run or reference) lie beyond what its linkage's triangle can reach; check "
            "its a, b and l0 against the position's unit."
        )
    return "\n".join(lines) + "\n"
