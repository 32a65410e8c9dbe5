"""The ``report.md`` of ``exsur run``, built from sections.

Each section is a function ``(metrics, ctx) -> lines`` that returns nothing when the run has
no such result; :data:`SECTIONS` lists them in report order, so a new result is one function
and one entry.  ``metrics`` is the run's ``metrics.json`` content; paths in it are relative
to the report folder.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ..spec import LINEAR_UNITS
from .data_card import notes_lines, reach_lines, splits_lines
from .horizon import horizon_markdown
from .metrics import worst_defined_r2, worst_r2_text
from .report import PAPER_TABLE_III, against_others
from .uncertainty import UNCERTAINTY_HEADING, uncertainty_markdown


@dataclass(frozen=True)
class ReportContext:
    """What the sections need besides ``metrics.json``."""

    name: str
    """The preset's name."""
    spec_names: tuple[str, ...]
    """Joint names in order."""
    table_md: str
    """The CBE table (``table.md``)."""
    paper_table: str = "none"
    """Which of the paper's tables to show: ``II``, ``III-noload``, ``III-compound``, ``none``."""
    learning_curves: tuple[str, ...] = ()
    """The trained models' ``learning_curve.png`` files, relative to the run folder."""
    data: Mapping[str, Any] | None = None
    """The trained-on dataset's card (:func:`.data_card.describe_dataset`); None: no section."""
    horizon_figure: bool = False
    """Whether the run folder holds ``horizon.png`` (the prediction-horizon figure)."""
    datasets: tuple[str, ...] = ()
    """The dataset folders the run wrote (``data``, ``data_clean``), relative to the run
    folder; none when it trained on the user's ``--data`` without cleaning."""


def _fmt(v: Any, f: float = 1.0) -> str:
    return "n/a" if v is None else f"{v * f:.4f}"


def _unit(metrics: Mapping[str, Any], joint: str) -> tuple[float, str]:
    """``(factor, unit)`` a joint's stored values print in: ``(1, "rad")``, or for a linear
    joint its mapping's unit (``run.units`` of ``metrics.json``, e.g. ``(1000, "mm")``)."""
    u = (metrics.get("run", {}).get("units") or {}).get(joint, {}).get("display", "rad")
    return LINEAR_UNITS.get(u, 1.0), u


def _linear_units(
    metrics: Mapping[str, Any], joints: Iterable[str]
) -> dict[str, tuple[float, str]]:
    """Joint -> ``(factor, unit)`` (:func:`_unit`) of each linear joint of ``joints``: the
    run report's twin of :func:`.report.linear_units`, read from ``metrics.json``."""
    return {j: u for j in joints if (u := _unit(metrics, j))[1] != "rad"}


def _summary(metrics: Mapping[str, Any], ctx: ReportContext) -> list[str]:
    """Title, worst-joint R², the split scored, timings and the figure."""
    run = metrics.get("run", {})
    lines = [f"# exsur run: preset `{ctx.name}`", ""]
    what = "position" if run.get("units") else "angle"  # strokes of linear joints too
    lines += [
        f"Closed-loop free run on the {run.get('split', 'test')} split "
        f"({run.get('n_step_scored', '?')} scored steps, "
        f"reference: {run.get('reference', '?')}): **worst-joint {what} R² "
        f"{worst_r2_text(metrics, 'theta')}, worst-joint ω R² {worst_r2_text(metrics, 'omega')}**.",
        "",
        *([_no_test(run), ""] if run.get("split", "test") != "test" else []),
        *([against, ""] if (against := _against(metrics)) else []),
        "Timings [s]: " + ", ".join(f"{k} {v}" for k, v in run.get("timings_s", {}).items()),
        "",
        "![closed-loop comparison](cbe.png)",
        "",
    ]
    return lines


def _against(metrics: Mapping[str, Any]) -> str:
    """The surrogate's angle RMSE against each model of the comparison (the baselines), one
    line (:func:`.report.against_others`), or ""."""
    others = metrics.get("compare") or {}
    if not others:
        return ""
    return against_others(
        {"the surrogate": metrics, **others},
        primary="the surrogate",
        units=_linear_units(metrics, metrics["theta"]),
    )


def _no_test(run: Mapping[str, Any]) -> str:
    """What the summary's scores are worth without a test split: optimistic where the scored
    split selected the checkpoint, in-sample where the model also trained on it."""
    split = run.get("split")
    if run.get("in_sample"):
        return (
            f"**No test split: scored on the '{split}' split, which the networks also trained "
            "on, so these numbers are in-sample**: they do not say how the model does on runs "
            "it has not seen. Hold runs out as a test split (the mapping's `[split]` table, "
            "`test = [...]`) to measure that."
        )
    return (
        f"No test split: scored on the '{split}' split, which also selected the checkpoint, so "
        "these numbers are optimistic."
    )


def _paper_table_iii(metrics: Mapping[str, Any], ctx: ReportContext) -> list[str]:
    """The paper's Table III next to ours (Stage II presets of the 4-joint excavator)."""
    lines: list[str] = []
    paper_key = {"III-noload": "noload", "III-compound": "compound"}.get(ctx.paper_table)
    strokes = bool(metrics.get("run", {}).get("units"))  # the paper's machine senses angles
    if paper_key and set(ctx.spec_names) == {"swing", "boom", "arm", "bucket"} and not strokes:
        ref = PAPER_TABLE_III[paper_key]
        lines += [
            f"## Against the paper's Table III ({paper_key})",
            "",
            "| Type | Joint | RMSE (ours / paper) | MAE (ours / paper) | R² (ours / paper) |",
            "|---|---|---|---|---|",
        ]
        for typ, label in (("omega", "ω [rad/s]"), ("theta", "θ [rad]")):
            for j in ctx.spec_names:
                m = metrics[typ][j]
                p = ref[typ][j]
                lines.append(
                    f"| {label} | {j} | {_fmt(m['rmse'])} / {p[0]:.4f} | {_fmt(m['mae'])} / {p[1]:.4f} "
                    f"| {_fmt(m['r2'])} / {p[2]:.4f} |"
                )
        lines.append("")
    return lines


def _cleaning(metrics: Mapping[str, Any], ctx: ReportContext) -> list[str]:
    """Kalman cleaning against the ground truth."""
    lines: list[str] = []
    if metrics.get("cleaning"):
        mixed = bool(metrics.get("run", {}).get("units"))  # linear joints: units per row
        unit = "" if mixed else " [rad]"
        lines += [
            "## Cleaning (adaptive Kalman filter) against the ground truth",
            "",
            f"| Joint | raw angle RMSE{unit} | fused angle RMSE{unit} | ratio | jump precision | jump recall |",
            "|---|---|---|---|---|---|",
        ]
        for j, c in metrics["cleaning"].items():
            if not isinstance(c, dict):
                continue
            f, u = _unit(metrics, j)
            lines.append(
                f"| {j}{f' [{u}]' if mixed else ''} | {_fmt(c.get('rmse_raw'), f)} "
                f"| {_fmt(c.get('rmse_fused'), f)} | {_fmt(c.get('rmse_ratio'))} "
                f"| {_fmt(c.get('jump_precision'))} | {_fmt(c.get('jump_recall'))} |"
            )
        lines += [""] + [f"![fusion {j}](fusion_{j}.png)" for j in ctx.spec_names] + [""]
    return lines


def _against_cleaned(metrics: Mapping[str, Any], ctx: ReportContext) -> list[str]:
    """The surrogate scored against the truth and against the cleaned data."""
    th = metrics["theta"]
    om = metrics["omega"]
    lines: list[str] = []
    if "against_cleaned" in metrics:
        lines += [
            "## Surrogate CBE: against the truth vs against the cleaned data",
            "",
            "| Joint | θ R² (truth) | θ R² (cleaned) | ω R² (truth) | ω R² (cleaned) |",
            "|---|---|---|---|---|",
        ]
        ac = metrics["against_cleaned"]
        for j in ctx.spec_names:
            lines.append(
                f"| {j} | {_fmt(th[j]['r2'])} | {_fmt(ac['theta'][j]['r2'])} | {_fmt(om[j]['r2'])} "
                f"| {_fmt(ac['omega'][j]['r2'])} |"
            )
        lines.append("")
    return lines


def _cleaning_effect(metrics: Mapping[str, Any], ctx: ReportContext) -> list[str]:
    """The same LSTM trained on cleaned vs raw data."""
    lines: list[str] = []
    if "cleaning_effect" in metrics:
        ce = metrics["cleaning_effect"]
        mixed = bool(metrics.get("run", {}).get("units"))  # linear joints: units per row
        unit = "" if mixed else " [rad]"
        lines += [
            "## Effect of cleaning: the same LSTM trained on cleaned vs raw data (scored against the truth)",
            "",
            f"| Joint | θ R² cleaned | θ R² raw | θ RMSE cleaned{unit} | θ RMSE raw{unit} "
            "| ω R² cleaned | ω R² raw |",
            "|---|---|---|---|---|---|---|",
        ]
        c, r = ce["trained on cleaned"], ce["trained on raw"]
        for j in ctx.spec_names:
            f, u = _unit(metrics, j)
            lines.append(
                f"| {j}{f' [{u}]' if mixed else ''} | {_fmt(c['theta'][j]['r2'])} "
                f"| {_fmt(r['theta'][j]['r2'])} | {_fmt(c['theta'][j]['rmse'], f)} "
                f"| {_fmt(r['theta'][j]['rmse'], f)} | {_fmt(c['omega'][j]['r2'])} "
                f"| {_fmt(r['omega'][j]['r2'])} |"
            )
        lines.append("")
    return lines


def _ensemble_members(metrics: Mapping[str, Any], ctx: ReportContext) -> list[str]:
    """The seed ensemble's members vs the merged network."""
    run = metrics.get("run", {})
    lines: list[str] = []
    if "ensemble_members" in metrics:
        em = metrics["ensemble_members"]
        lines += [
            "## Seed ensemble: the merged network vs its members "
            f"(scored against the {'truth' if run.get('reference') == 'true' else 'measured data'})",
            "",
            "| Model | "
            + " | ".join(f"θ R² {j}" for j in ctx.spec_names)
            + " | worst θ R² | worst ω R² |",
            "|---|" + "---|" * (len(ctx.spec_names) + 2),
        ]
        for label, m in em.items():
            lines.append(
                f"| {label} | "
                + " | ".join(_fmt(m["theta"][j]["r2"]) for j in ctx.spec_names)
                + f" | {_worst_cell(m, 'theta')} | {_worst_cell(m, 'omega')} |"
            )
        lines.append("")
    return lines


def _worst_cell(m: Mapping[str, Any], key: str) -> str:
    """The worst defined R² of ``m[key]`` for a table cell, the joints without one named
    (``"0.9310 (bucket: —)"``), as the headline's :func:`.metrics.worst_r2_text` does."""
    worst, bad = worst_defined_r2(m, key)
    return (_fmt(worst) if worst is not None else "—") + (f" ({', '.join(bad)}: —)" if bad else "")


def _uncertainty(metrics: Mapping[str, Any], ctx: ReportContext) -> list[str]:
    """The ensemble's bands (coverage, width) and the share of steps flagged out of distribution."""
    unc = metrics.get("uncertainty")
    if not unc:
        return []
    units = _linear_units(metrics, ctx.spec_names)
    return uncertainty_markdown(unc, ctx.spec_names, units=units).splitlines()


def _cbe_table(metrics: Mapping[str, Any], ctx: ReportContext) -> list[str]:
    """The CBE table (paper layout, baselines).  ``table.md`` ends with the uncertainty
    section too; the report has that as its own section (:func:`_uncertainty`), so it is cut
    here, not shown twice."""
    table = ctx.table_md.replace("# Closed-loop behavioural equivalence (CBE)", "")
    table = table.split(UNCERTAINTY_HEADING)[0]
    return ["## CBE table", "", table.strip(), ""]


def _horizon(metrics: Mapping[str, Any], ctx: ReportContext) -> list[str]:
    """The angle error n seconds after measured starts, against holding still, and its figure."""
    result = metrics.get("horizon")
    if not result or not result.get("n_start"):
        return []
    table = horizon_markdown(result).splitlines()
    figure = ["", "![prediction horizon](horizon.png)"] if ctx.horizon_figure else []
    return [*table, *figure, ""]


def _learning_curves(metrics: Mapping[str, Any], ctx: ReportContext) -> list[str]:
    """Each trained model's training loss and validation error per epoch."""
    if not ctx.learning_curves:
        return []
    lines = ["## Learning curves", ""]
    for path in ctx.learning_curves:
        lines += [f"![learning curves of {path.rsplit('/', 1)[0]}]({path})", ""]
    return lines


def _data(metrics: Mapping[str, Any], ctx: ReportContext) -> list[str]:
    """The splits the model trained, selected and was scored on, and the notes on them."""
    if not ctx.data:
        return []
    card = ctx.data
    lines = ["## Data", ""]
    if card["warnings"]:
        lines += [*notes_lines(card), ""]
    lines += [*splits_lines(card), *reach_lines(card), ""]
    where = Path(card["path"])
    out = metrics.get("run", {}).get("out")
    if out and not where.is_absolute():
        where = Path(out) / where
    lines += [f"Per joint and split (positions, speeds, commands): `exsur info {where}`.", ""]
    return lines


def _files(metrics: Mapping[str, Any], ctx: ReportContext) -> list[str]:
    """What the folder holds (a dataset folder only when the run wrote it)."""
    folders = "".join(f", `{d}/`" for d in ctx.datasets)
    return [
        "Files: `metrics.json`, `table.md`, `config.toml`, `model/best.pt` (load with "
        f"`excavator_surrogate.surrogate.load_checkpoint`){folders}.",
        "",
    ]


Section = Callable[[Mapping[str, Any], ReportContext], list[str]]

SECTIONS: tuple[Section, ...] = (
    _summary,
    _paper_table_iii,
    _cleaning,
    _against_cleaned,
    _cleaning_effect,
    _ensemble_members,
    _uncertainty,
    _cbe_table,
    _horizon,
    _data,
    _learning_curves,
    _files,
)
"""The report's sections, in order."""


def render_run_report(metrics: Mapping[str, Any], ctx: ReportContext) -> str:
    """The human-readable ``report.md`` of a run: every section of :data:`SECTIONS`."""
    return "\n".join(line for section in SECTIONS for line in section(metrics, ctx))
