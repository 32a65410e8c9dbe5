"""The scores and summaries of ``bench/real.py``: free-run errors in each joint's shown unit,
the tables it prints, the JSON's per-shape summary, and what a recipe run's logs and model
say about its training and its choices."""

from __future__ import annotations

import csv
import math
import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from excavator_surrogate.data import Episode
from excavator_surrogate.evaluate.cbe import evaluate_models

sys.path.insert(0, str(Path(__file__).parent))
from real_cases import as_spec


def shown(spec) -> tuple[np.ndarray, list[str]]:
    """Per joint: stored value x factor = shown value, and the shown unit (deg for an angle in
    rad, the mapping's ``m`` / ``cm`` / ``mm`` for a stroke stored in m)."""
    factors = [j.display_factor if j.linear else math.degrees(1.0) for j in spec.joints]
    return np.array(factors), [j.display_unit if j.linear else "deg" for j in spec.joints]


def score(sur, episodes) -> dict[str, list[float]]:
    """Free-run position RMSE and R^2 per joint, pooled over ``episodes`` after the warm-up,
    in each joint's shown unit (:func:`shown`: deg for an angle, the mapping's unit for a
    stroke)."""
    metrics, runs = evaluate_models({"m": sur}, episodes)
    th = metrics["m"]["theta"]
    lo = np.min([r.theta_hat[r.warmup :].min(axis=0) for r in runs["m"]], axis=0)
    hi = np.max([r.theta_hat[r.warmup :].max(axis=0) for r in runs["m"]], axis=0)
    return {
        "rmse": [f * th[j]["rmse"] for f, j in zip(shown(sur.spec)[0], sur.spec.names)],
        "r2": [th[j]["r2"] for j in sur.spec.names],
        "theta_min": (shown(sur.spec)[0] * lo).tolist(),
        "theta_max": (shown(sur.spec)[0] * hi).tolist(),
    }


def scored_more(sur, more: Sequence[Episode], spec) -> dict:
    """``{"more": {"rmse", "r2"}}``: :func:`score` on ``more`` (as a dataset of ``spec``, the
    one ``sur`` trained on, holds them), or ``{}`` without more test data."""
    if not more:
        return {}
    got = score(sur, as_spec(more, spec))
    return {"more": {"rmse": got["rmse"], "r2": got["r2"]}}


BASELINES = (
    ("plain_lstm", "plain 2x128 LSTM, one-step loss"),
    ("arx", "linear ARX, clipped to the training range"),
    ("structured", "structured (dead zone, gain, delay, end stops)"),
)
"""The baselines' goal names and row labels: the recipe's median must beat each on every joint."""


def print_table(title: str, head: str, rows: dict[str, dict], median, n_seeds: int) -> None:
    """One markdown table of ``rows`` (label -> ``rmse``, ``r2`` and maybe ``train_s``) and the
    recipe's median; with a ``train_s`` column when the rows carry it."""
    train = any("train_s" in r for r in rows.values())
    print()
    print(title)
    print(f"| model | {head} |" + (" train [s] |" if train else ""))
    print("|---|" + "---|" * (len(median) + train))
    for label, r in rows.items():
        row = " | ".join(f"{e:.2f} ({q:.3f})" for e, q in zip(r["rmse"], r["r2"]))
        print(f"| {label} | {row} |" + (f" {r.get('train_s', '-')} |" if train else ""))
    print(f"| default recipe, median of {n_seeds} | {cells(median)} |" + (" |" if train else ""))


def cells(values) -> str:
    """``values`` as a table row's cells, two decimals."""
    return " | ".join(f"{v:.2f}" for v in values)


def beats_every_joint(median, rows: dict[str, dict]) -> dict[str, bool | None]:
    """Per baseline (:data:`BASELINES`): the median below its RMSE on every joint (None: the
    baseline did not run)."""
    return {
        name: None if label not in rows else bool(np.all(median < np.array(rows[label]["rmse"])))
        for name, label in BASELINES
    }


def summary(median, rows: dict[str, dict]) -> dict:
    """The JSON's ``median_over`` (the median over each baseline's RMSE, per joint) and
    ``models`` (every row's RMSE and R^2, rounded)."""
    return {
        "median_over": {
            k: [round(float(a / b), 3) for a, b in zip(median, rows[k]["rmse"])]
            for k in rows
            if not k.startswith("default recipe")
        },
        "models": {
            k: {
                "rmse": [round(v, 3) for v in r["rmse"]],
                "r2": [round(v, 4) for v in r["r2"]],
            }
            for k, r in rows.items()
        },
    }


def training_log(out: Path) -> dict:
    """What the training logs of a recipe run say: per member, epochs run, the epoch of the
    lowest validation error (the selected one unless the recipe smooths its selection), the
    validation error at the first, that and the last epoch, and the worst joint's validation
    angle R^2 there (against the test's: how optimistic the selection is); the first is the
    first validated epoch."""
    members = []
    logs = sorted(out.rglob("member_*/log.csv")) or sorted(out.rglob("log.csv"))
    for path in logs:
        with path.open() as f:
            every = list(csv.DictReader(f))
        # epochs before select_after are not validated (their val_error is nan)
        rows = [r for r in every if math.isfinite(float(r.get("val_error") or "nan"))]
        if not rows:
            continue
        err = [float(r["val_error"]) for r in rows]
        best = int(np.argmin(err))
        members.append(
            {
                "epochs_run": len(every),
                "lowest_val_epoch": int(rows[best]["epoch"]) + 1,
                "val_first_best_last": [round(err[0], 4), round(err[best], 4), round(err[-1], 4)],
                "val_theta_r2_min_at_best": round(
                    float(rows[best].get("val_theta_r2_min", "nan")), 4
                ),
            }
        )
    return {"members": members}


def choices(sur) -> dict:
    """What the trained model chose on validation, beside the validation free run's position
    RMSE per joint in the shown unit (to set against the scored split's): the joints on the
    static map, those driven by the map-correcting networks (and of those, the ones driven by
    the even blend of both kinds), whether the inputs are used and by which joints."""
    metrics = sur.metrics or {}
    facts = metrics.get("training") or {}
    val = (metrics.get("val") or {}).get("theta_rmse")
    out: dict = {
        "val_rmse": None
        if val is None
        else [round(float(v), 3) for v in shown(sur.spec)[0] * np.asarray(val)]
    }
    for key, field in (
        ("static_map", "chosen"),
        ("kinds", "chosen"),
        ("kinds", "blended"),
        ("exogenous", "kept"),
        ("exogenous", "joints"),
    ):
        record = facts.get(key)
        if isinstance(record, dict) and field in record:
            out[f"{key}_{field}"] = record[field]
    return out
