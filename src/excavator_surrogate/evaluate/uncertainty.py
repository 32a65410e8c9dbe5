"""The uncertainty part of a CBE evaluation: band coverage and width, out-of-distribution share.

``metrics.json`` gets ``"uncertainty"``::

    {"available": bool, "notes": [...], "levels": [0.5, 0.9],
     "theta": {"<joint>": {"coverage_50", "width_50", "coverage_90", "width_90", "spread"}},
     "omega": {...},
     "ood": {"<joint>": share of flagged steps, "any": share} | null}

Coverage is the share of scored steps whose reference lies inside the band (a calibrated
band covers about its level); width is the mean full width [rad, rad/s].  A single network
has ``available: false`` and a note: it has no uncertainty to report.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any, Literal

import numpy as np

from ..data.episode import Episode
from ..surrogate.bands import EpisodePrediction, band_scores, predict_episodes
from ..surrogate.coverage import ood_flags
from ..surrogate.ensemble import member_head, n_member
from ..surrogate.model import Surrogate
from ..surrogate.rollout import EpisodeRollout
from ..surrogate.uncertainty import NO_MEMBERS, UncertainPrediction, stored_coverage
from .report import format_value


def uncertainty_runs(
    sur: Surrogate,
    episodes: Sequence[Episode],
    runs: Sequence[EpisodeRollout],
    *,
    reference: Literal["measured", "true"] = "measured",
    max_steps: int | None = None,
) -> list[EpisodePrediction]:
    """Spread, bands and flags of ``sur`` on ``episodes``.

    ``runs`` are ``sur``'s ordinary free runs of the same episodes: a single network (or an
    ensemble without member outputs) reuses them for the flags instead of running again.
    """
    if member_head(sur) is not None:
        return predict_episodes(sur, episodes, reference=reference, max_steps=max_steps)
    cov = stored_coverage(sur)
    out = []
    for r, ep in zip(runs, episodes):
        n = len(r.time)
        pred = UncertainPrediction(r.theta_hat[None], r.omega_hat[None], r.warmup)
        pred.notes = [
            NO_MEMBERS
            if n_member(sur) < 2
            else "ensemble merged by an older exsur: no member outputs (merge it again)"
        ]
        if cov is None:
            pred.notes.append("no training coverage record: no out-of-distribution flags")
        else:
            pred.ood = ood_flags(cov, sur.spec, pred.theta, pred.omega, ep.u[None, :n])
        pred.theta, pred.omega = pred.theta[0], pred.omega[0]
        pred.ood = None if pred.ood is None else pred.ood[0]
        out.append(EpisodePrediction(r.name, r.time, pred, r.theta_ref, r.omega_ref))
    return out


def uncertainty_metrics(sur: Surrogate, preds: Sequence[EpisodePrediction]) -> dict[str, Any]:
    """The ``"uncertainty"`` entry of ``metrics.json`` (see the module docstring)."""
    return band_scores(preds, sur.spec.names, [j.periodic for j in sur.spec.joints])


def _pct(v: float | None) -> str:
    return "—" if v is None else f"{100 * v:.0f} %"


def _share(v: float) -> str:
    """A share of steps as a percentage whose zero means none: a few flagged steps of a
    long run read "0.3 %" or "< 0.1 %", not "0 %" beside the figure's red marks."""
    if v <= 0 or v >= 0.01:
        return _pct(v)
    return "< 0.1 %" if v < 0.001 else f"{100 * v:.1f} %"


SHORTFALL = 0.10
"""A band is called too narrow on a scored split where its coverage falls more than this
below its level (a 90 % band covering under 80 %): beyond what one split's scatter of a
calibrated band (about ±0.07 on 12 runs of the stand-in, docs/design.md) explains."""


def undercovered(unc: Mapping[str, Any], names: Sequence[str]) -> list[tuple[str, str, int, float]]:
    """The bands that covered too little of the scored steps: ``(quantity, joint, level in
    %, coverage)`` for every band whose coverage is more than :data:`SHORTFALL` below its
    level (``quantity``: ``theta`` or ``omega``)."""
    out = []
    for q in ("theta", "omega"):
        for n in names:
            for lv in unc.get("levels") or []:
                cov = (unc.get(q) or {}).get(n, {}).get(f"coverage_{round(100 * lv)}")
                if cov is not None and cov < lv - SHORTFALL:
                    out.append((q, n, round(100 * lv), float(cov)))
    return out


def _undercovered_note(unc: Mapping[str, Any], short: Sequence[tuple[str, str, int, float]]) -> str:
    """One paragraph naming the joints :func:`undercovered` found, with every band's coverage
    there, and what to make of them."""
    sym = {"theta": "θ", "omega": "ω"}
    tags = [f"{round(100 * lv)}" for lv in unc["levels"]]
    seen = dict.fromkeys((q, n) for q, n, _, _ in short)  # each (quantity, joint) once, in order
    parts = [
        f"{sym[q]} {n} " + " / ".join(_pct(unc[q][n][f"coverage_{t}"]) for t in tags)
        for q, n in seen
    ]
    return (
        "**The bands were too narrow on these runs** (coverage of the "
        + " / ".join(f"{t} %" for t in tags)
        + " bands): "
        + ", ".join(parts)
        + ". They were calibrated on other runs, and here the model's error outgrew its "
        "members' disagreement: do not take them as limits on runs like these (`exsur "
        "calibrate CKPT DATASET` fits them again on data that holds such runs)."
    )


UNCERTAINTY_HEADING = "## Uncertainty and out-of-distribution"
"""The heading of :func:`uncertainty_markdown`'s section (``table.md`` and ``report.md``)."""


def uncertainty_markdown(
    unc: Mapping[str, Any],
    names: Sequence[str],
    *,
    units: Mapping[str, tuple[float, str]] | None = None,
) -> str:
    """Markdown lines: per joint the bands' coverage and width and the flagged share.

    ``units``: joint -> ``(factor, unit)`` of each linear joint (its stored m times factor is
    its mapping's unit, :func:`.report.linear_units`): its widths print in that unit and its
    row names it, as the CBE table's do; other joints' in rad and rad/s."""
    units = units or {}
    lines = [UNCERTAINTY_HEADING, ""]
    for note in unc.get("notes") or []:
        lines.append(f"Note: {note}.")
    if unc.get("notes"):
        lines.append("")
    if unc.get("available"):
        tags = [f"{round(100 * lv)}" for lv in unc["levels"]]
        head = ["Type", "Joint"]
        for t in tags:
            head += [f"{t} % band coverage", f"{t} % width"]
        lines += ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
        for q, sym, rad in (("theta", "θ", "rad"), ("omega", "ω", "rad/s")):
            for n in names:
                d = unc[q][n]
                f, unit = units.get(n, (1.0, ""))
                per_s = "/s" if q == "omega" else ""
                cells = [sym, f"{n} [{unit}{per_s}]"] if unit else [f"{sym} [{rad}]", n]
                for t in tags:
                    cells += [_pct(d[f"coverage_{t}"]), format_value(d[f"width_{t}"], f)]
                lines.append("| " + " | ".join(cells) + " |")
        lines.append("")
        short = undercovered(unc, names)
        if short:
            lines += [_undercovered_note(unc, short), ""]
    ood = unc.get("ood")
    if ood is not None:
        lines += [
            "Steps flagged out of distribution (outside the training data's range, or an "
            "angle/command pair it never came near): "
            + ", ".join(f"{n} {_share(ood[n])}" for n in names)
            + f"; any joint {_share(ood['any'])}.",
            "",
        ]
    return "\n".join(lines) + "\n"


def figure_bands(
    pred: UncertainPrediction,
) -> tuple[dict[float, tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] | None, Any]:
    """``(bands, ood)`` of one episode for :func:`~excavator_surrogate.plotting.cbe.plot_cbe`:
    level -> (omega_lo, omega_hi, theta_lo, theta_hi), and the (n_step,) any-joint flag."""
    bands = None
    if pred.bands is not None:
        bands = {
            lv: (*d["omega"], *d["theta"])  # type: ignore[misc]
            for lv, d in pred.bands.items()
        }
    return bands, (None if pred.ood is None else pred.ood.any(-1))
