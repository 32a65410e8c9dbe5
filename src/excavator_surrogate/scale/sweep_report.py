"""The report of a sweep: ``sweep.md``, ``sweep.png``, ``sweep.json`` and ``best.pt``, written
from every trial of the study so far (:func:`write_report`), and the :class:`SweepResult`
that :func:`~.sweep.run_sweep` returns."""

from __future__ import annotations

import logging
import math
import shutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import optuna  # an optional dependency: imported only once a sweep has checked it is there

from ..io_utils import atomic_path, write_json, write_text

_log = logging.getLogger(__name__)


@dataclass
class SweepResult:
    """What a sweep worker leaves behind (all trials of the study, not only its own)."""

    study_name: str
    storage: str
    n_complete: int
    n_pruned: int
    n_fail: int
    best_value: float | None
    """Best validation free-run error of the study (None: no trial completed)."""
    best_params: dict[str, Any] = field(default_factory=dict)
    best_trial: int | None = None
    best_checkpoint: Path | None = None
    """``DIR/best.pt`` if the best trial's checkpoint could be copied, else None."""
    table: Path | None = None
    plot: Path | None = None


def _rows(study: optuna.Study) -> list[dict[str, Any]]:
    rows = []
    for t in study.get_trials(deepcopy=False):
        if t.state not in (optuna.trial.TrialState.COMPLETE, optuna.trial.TrialState.PRUNED):
            continue
        inter = dict(sorted(t.intermediate_values.items()))
        value = t.value if t.state == optuna.trial.TrialState.COMPLETE else None
        rows.append(
            {
                "trial": t.number,
                "state": t.state.name.lower(),
                "value": value,
                "best_seen": min(inter.values()) if inter else None,
                "params": dict(t.params),
                "curve": [[int(k), float(v)] for k, v in inter.items()],
                "epochs_run": t.user_attrs.get("epochs_run", len(inter)),
                "budget_cut": t.user_attrs.get("budget_cut"),  # None: not recorded
                "seconds": t.user_attrs.get("seconds"),
                "checkpoint": t.user_attrs.get("checkpoint"),
                "host": t.user_attrs.get("host"),
                "train": t.user_attrs.get("train"),
            }
        )
    return rows


def _markdown(rows: list[dict[str, Any]], *, study: str, counts: dict[str, int], top: int) -> str:
    done = sorted((r for r in rows if r["value"] is not None), key=lambda r: r["value"])[:top]
    keys: list[str] = []
    for r in done:
        keys += [k for k in r["params"] if k not in keys]
    head = ["rank", "trial", "val_error", "epochs", "time [s]", *keys]
    lines = [
        f"# Sweep `{study}`",
        "",
        f"{counts['complete']} complete, {counts['pruned']} pruned, {counts['fail']} failed trials; "
        "val_error = mean over joints of free-run RMSE(θ) / std(θ) on the validation split "
        "(lower is better).",
        "",
        "| " + " | ".join(head) + " |",
        "|" + "|".join("---" for _ in head) + "|",
    ]
    for rank, r in enumerate(done, 1):
        cells = [
            str(rank),
            str(r["trial"]),
            f"{r['value']:.4g}",
            f"{r['epochs_run']}{' (cut)' if r['budget_cut'] else ''}",
            "" if r["seconds"] is None else f"{r['seconds']:.1f}",
        ]
        for k in keys:
            v = r["params"].get(k, "")
            cells.append(f"{v:.3g}" if isinstance(v, float) else str(v))
        lines.append("| " + " | ".join(cells) + " |")
    if not done:
        lines.append("| – | no completed trial yet | | | |")
    cut = [str(r["trial"]) for r in done if r["budget_cut"]]
    if cut:
        lines += [
            "",
            f"**Warning: the wall-time cap (--trial-seconds) cut trial(s) {', '.join(cut)} "
            "short** (epochs marked cut): their val_error depends on the computer's speed and "
            "load, and they rank against trials that ran their planned epochs.",
        ]
    return "\n".join(lines) + "\n"


def _plot(path: Path, rows: list[dict[str, Any]], *, top: int, study: str) -> None:
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    fig, (ax0, ax1) = plt.subplots(1, 2, figsize=(11, 4.2), constrained_layout=True)
    done = [r for r in rows if r["value"] is not None]
    pruned = [r for r in rows if r["value"] is None and r["best_seen"] is not None]
    if done:
        ax0.scatter([r["trial"] for r in done], [r["value"] for r in done], s=18, label="complete")
    if pruned:
        ax0.scatter(
            [r["trial"] for r in pruned],
            [r["best_seen"] for r in pruned],
            marker="x",
            s=18,
            color="0.6",
            label="pruned (best epoch)",
        )
    if done:
        order = sorted(done, key=lambda r: r["trial"])
        best, xs, ys = math.inf, [], []
        for r in order:
            best = min(best, r["value"])
            xs.append(r["trial"])
            ys.append(best)
        ax0.step(xs, ys, where="post", color="C3", label="best so far")
    ax0.set_xlabel("trial")
    ax0.set_ylabel("validation free-run error")
    ax0.set_yscale("log")
    ax0.set_title(f"study '{study}'")
    if done or pruned:  # a study of failed trials only has nothing to label
        ax0.legend(fontsize=8)
    for k, r in enumerate(sorted(done, key=lambda r: r["value"])[:top]):
        if r["curve"]:
            e, v = zip(*r["curve"])
            ax1.plot(e, v, marker=".", label=f"#{r['trial']} ({r['value']:.3g})", color=f"C{k}")
    from matplotlib.ticker import MaxNLocator

    for ax in (ax0, ax1):
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    ax1.set_xlabel("epoch")
    ax1.set_ylabel("validation free-run error")
    ax1.set_yscale("log")
    ax1.set_title(f"best {min(top, len(done))} trials")
    if done:
        ax1.legend(fontsize=8)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)


def write_report(
    study: optuna.Study, *, out: str | Path, storage: str, top: int = 5
) -> SweepResult:
    """Write ``sweep.md``, ``sweep.png``, ``sweep.json`` and ``best.pt`` for the whole study.

    ``storage``: the study's storage URL as it may be shown (its password already hidden).
    """
    out = Path(out)
    states = [t.state for t in study.get_trials(deepcopy=False)]
    counts = {
        "complete": sum(s == optuna.trial.TrialState.COMPLETE for s in states),
        "pruned": sum(s == optuna.trial.TrialState.PRUNED for s in states),
        "fail": sum(s == optuna.trial.TrialState.FAIL for s in states),
    }
    rows = _rows(study)
    res = SweepResult(
        study_name=study.study_name,
        storage=storage,
        n_complete=counts["complete"],
        n_pruned=counts["pruned"],
        n_fail=counts["fail"],
        best_value=None,
    )
    if counts["complete"]:
        bt = study.best_trial
        res.best_value, res.best_params, res.best_trial = (
            float(bt.value),
            dict(bt.params),
            bt.number,
        )
        src = bt.user_attrs.get("checkpoint")
        if src and Path(src).is_file():
            with atomic_path(out / "best.pt") as tmp:
                shutil.copyfile(src, tmp)
            res.best_checkpoint = out / "best.pt"
        else:
            _log.info(
                f"best trial {bt.number} ran on {bt.user_attrs.get('host', '?')}; its checkpoint "
                f"{src} is not reachable from here: copy it by hand"
            )
    res.table = out / "sweep.md"
    write_text(res.table, _markdown(rows, study=study.study_name, counts=counts, top=top))
    res.plot = out / "sweep.png"
    _plot(res.plot, rows, top=top, study=study.study_name)
    write_json(
        out / "sweep.json",
        {
            "study": study.study_name,
            "storage": storage,
            **counts,
            "best": {"trial": res.best_trial, "value": res.best_value, "params": res.best_params},
            "trials": rows,
        },
    )
    _log.info(
        f"sweep: {counts['complete']} complete / {counts['pruned']} pruned / {counts['fail']} failed; "
        + (
            f"best trial {res.best_trial}: val_error {res.best_value:.4g}"
            if res.best_value is not None
            else "no completed trial"
        )
    )
    return res
