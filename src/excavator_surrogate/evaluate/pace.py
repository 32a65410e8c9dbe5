"""How fast this computer trained a model, against the plan's reference machine and the cap.

The plan (``training/plan.py``) fixes the epochs from the data's sizes at a reference
machine's speed, and the wall-time cap only stops a computer that is much slower or busier
(``exsur train --dry-run`` prints the headroom before a run).  After the run, each network's
``log.csv`` holds what happened: the wall time of every epoch's training steps
(``epoch_s``), the reference machine's time for the same steps (``ref_epoch_s``; NaN where
the cost model does not cover the config) and the wall time since the start (``time_s``).
:func:`training_pace` sums them over every network beside a checkpoint, so a report can say
how this computer, as loaded during the run, compared with the reference and how much of the
cap it used: how much slower or busier the same run could have been and still trained every
planned epoch.  Nothing here goes into ``best.pt`` (it reads the clock's record).
"""

from __future__ import annotations

import csv
import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

LOGS = ("log.csv", "member_*/log.csv", "*/member_*/log.csv")
"""Where a training writes its networks' logs in its folder: a single network's, an
ensemble's members', and the members of each group (the kinds' ``plain/``, ``prior/``)."""


def training_pace(model_dir: str | Path) -> dict[str, Any] | None:
    """The training time of every network of the model in ``model_dir`` (each ``log.csv``
    of :data:`LOGS` with an ``epoch_s`` column; other runs' folders inside it are not read).

    Returns:
        ``None`` without such logs, else ``{"networks", "epochs", "timed_epochs", "train_s",
        "reference_train_s", "pace", "longest_s", "per_network"}``: the training steps' wall
        time [s] summed over networks and their timed epochs (a run resumed from a
        ``best.pt`` carries its earlier epochs without times), the reference machine's for the same
        steps [s] (NaN if any network's is unknown), their ratio (``pace``: 1.3 means 30 %
        slower than the reference), the longest network's wall time from start to last
        epoch [s], and per network its log (relative to ``model_dir``), epochs and times.
    """
    root = Path(model_dir)
    nets = []
    for log in sorted({p for pattern in LOGS for p in root.glob(pattern)}):
        try:
            with open(log, newline="") as f:
                rows = list(csv.DictReader(f))
        except (OSError, csv.Error, UnicodeDecodeError):
            continue  # a log that cannot be read tells nothing about time
        if not rows or "epoch_s" not in rows[0]:
            continue  # an ensemble's summary of its members, not a network's epochs
        # a run resumed from a best.pt carries its earlier epochs without times
        timed = [r for r in rows if math.isfinite(_num(r.get("epoch_s")))]
        nets.append(
            {
                "log": log.relative_to(root).as_posix(),
                "epochs": len(rows),
                "timed_epochs": len(timed),
                "train_s": round(sum(_num(r.get("epoch_s")) for r in timed), 1),
                "reference_train_s": round(sum(_num(r.get("ref_epoch_s")) for r in timed), 1),
                "wall_s": round(_num(rows[-1].get("time_s")), 1),
            }
        )
    if not nets:
        return None
    train_s = sum(n["train_s"] for n in nets)
    ref_s = sum(n["reference_train_s"] for n in nets)
    return {
        "networks": len(nets),
        "epochs": sum(n["epochs"] for n in nets),
        "timed_epochs": sum(n["timed_epochs"] for n in nets),
        "train_s": round(train_s, 1),
        "reference_train_s": round(ref_s, 1),
        "pace": round(train_s / ref_s, 3) if ref_s > 0 else math.nan,
        "longest_s": max(n["wall_s"] for n in nets),
        "per_network": nets,
    }


def pace_markdown(pace: Mapping[str, Any] | None, training: Mapping[str, Any] | None) -> str:
    """One paragraph on :func:`training_pace` against the cap of ``training`` (the ``best.pt``
    metrics' ``training`` record); empty without either."""
    if not pace or not training:
        return ""
    members = list(training.get("members") or [training])
    cap = max((float(m.get("max_train_seconds") or 0.0) for m in members), default=0.0)
    cut = any(bool(m.get("budget_cut")) for m in members)
    text = (
        f"\nTime on this computer: {pace['networks']} network(s), {pace['epochs']} epochs in all; "
        f"their training steps took {pace['train_s']:.0f} s"
    )
    timed = pace.get("timed_epochs", pace["epochs"])
    if timed < pace["epochs"]:
        text += f" (the {timed} timed ones: a run resumed from a best.pt carries no earlier times)"
    ratio = pace.get("pace")  # NaN, or None once through JSON: no reference time
    if isinstance(ratio, int | float) and math.isfinite(ratio):
        text += (
            f", {ratio:.2f}x the reference machine's {pace['reference_train_s']:.0f} s "
            "(the time the plan is sized by)"
        )
    longest = float(pace.get("longest_s") or 0.0)
    text += f". The longest network ran {_seconds(longest)} s"
    if cap > 0 and cut:
        text += f" and its {_seconds(cap)}-s cap cut it.\n"
    elif cap > 0 and longest > 0:
        text += (
            f" of its {_seconds(cap)}-s cap ({100 * longest / cap:.0f} %): a run up to "
            f"{cap / longest:.2f}x slower (a slower computer, or more load on this one) still "
            "trains every planned epoch.\n"
        )
    else:
        text += " (no wall-time cap).\n"
    return text


def _num(v: Any) -> float:
    """A CSV cell as a number (an empty or missing cell: NaN)."""
    try:
        return float(v)
    except (TypeError, ValueError):
        return math.nan


def _seconds(s: float) -> str:
    """``s`` seconds as the summary prints them: whole seconds from 10 s on (``76``), two
    significant digits below (``0.3``, ``2.5``): a sub-second cap is not "0 s"."""
    return f"{s:.0f}" if s >= 10 else f"{s:.2g}"
