"""Learning curves of a training folder: the training loss and the validation free-run error per
epoch, one line per network (a single network, or every member of an ensemble, of each input
way or kind), with the epoch each network selected (its ``best.pt``) marked (``exsur train``
writes it as ``learning_curve.png`` next to ``best.pt``)."""

from __future__ import annotations

import csv
import math
import tomllib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import DataError
from .png import png_path, save_png

NEEDED = ("epoch", "train_loss", "val_error")
"""The columns of an epoch log (``log.csv`` of one network) the figure reads."""


@dataclass(frozen=True)
class Curve:
    """One network's epoch log."""

    label: str
    """Its folder relative to the training folder (``network`` for the folder itself)."""
    epoch: np.ndarray
    """(n_epoch,) epoch numbers."""
    train_loss: np.ndarray
    """(n_epoch,) mean training loss (NaN where not logged)."""
    val_error: np.ndarray
    """(n_epoch,) validation free-run error (NaN where not logged)."""
    selected: float | None = None
    """The epoch the network's ``best.pt`` holds: the last one its log marks ``best`` (the
    selection may smooth the error, average weights or start late, so it need not be the
    lowest point of the curve); None when the log has no ``best`` column or marks none."""
    free_from: int | None = None
    """First epoch of the free-run loss after teacher-forced ones (its ``config.toml``:
    ``feedback = "free"``, ``teacher_epochs > 0``), where the training loss jumps; else None."""


def _free_from(config: Path) -> int | None:
    """The first free-run epoch a network's ``config.toml`` plans after teacher-forced ones."""
    try:
        train = tomllib.loads(config.read_text(encoding="utf-8")).get("train", {})
    except (OSError, tomllib.TOMLDecodeError):
        return None
    teacher = train.get("teacher_epochs", 0)
    if train.get("feedback") == "free" and isinstance(teacher, int) and teacher > 0:
        return teacher
    return None


def _number(text: str | None) -> float:
    try:
        return float(text) if text not in (None, "") else math.nan
    except ValueError:
        return math.nan


def read_curves(folder: str | Path) -> list[Curve]:
    """Every epoch log under ``folder`` (``log.csv`` files with :data:`NEEDED` columns; an
    ensemble's own ``log.csv``, one row per member, has no ``train_loss`` and is skipped), in
    path order."""
    folder = Path(folder)
    curves = []
    for path in sorted(folder.rglob("log.csv")):
        with path.open(newline="") as f:
            rows = list(csv.DictReader(f))
        if not rows or not all(c in rows[0] for c in NEEDED):
            continue
        rel = path.parent.relative_to(folder).as_posix()
        marked = [_number(r["epoch"]) for r in rows if str(r.get("best", "")).strip() == "1"]
        curves.append(
            Curve(
                label="network" if rel == "." else rel,
                epoch=np.array([_number(r["epoch"]) for r in rows]),
                train_loss=np.array([_number(r["train_loss"]) for r in rows]),
                val_error=np.array([_number(r["val_error"]) for r in rows]),
                selected=marked[-1] if marked else None,
                free_from=_free_from(path.parent / "config.toml"),
            )
        )
    return curves


def plot_learning_curves(folder: str | Path, *, out: str | Path, dpi: int = 110) -> Path:
    """Draw the learning curves of the training folder ``folder`` to the PNG ``out`` (written
    atomically) and return its path.

    Left: training loss per epoch (a dashed line where it turns from teacher-forced to free
    run); right: validation free-run error per epoch (the error training selects by), both on
    a log scale; a dot marks the epoch each network selected (:attr:`Curve.selected`; the
    lowest validation error where the log does not say).

    Raises:
        DataError: ``folder`` holds no epoch log.
        ConfigError: ``out`` does not end in ``.png``.
    """
    from matplotlib.figure import Figure  # no pyplot: backend-independent, thread-safe

    out = png_path(out)
    curves = read_curves(folder)
    if not curves:
        raise DataError(
            folder,
            "no epoch log (log.csv with epoch, train_loss, val_error): not a training folder",
        )
    fig = Figure(figsize=(11.0, 4.2), layout="constrained")
    ax_loss, ax_val = fig.subplots(1, 2, sharex=True)
    for i, c in enumerate(curves):
        color = f"C{i % 10}"
        ax_loss.plot(c.epoch, c.train_loss, lw=1.0, color=color, label=c.label)
        ax_val.plot(c.epoch, c.val_error, lw=1.0, color=color, label=c.label)
        k = _selected_row(c)
        if k is not None:
            ax_val.plot(c.epoch[k], c.val_error[k], "o", ms=5, color=color)
    starts = {c.free_from for c in curves} - {None}
    for k in sorted(starts):  # the loss changes meaning there: teacher-forced, then free run
        ax_loss.axvline(k - 0.5, color="0.4", lw=0.8, ls="--")
        ax_loss.annotate(
            "free-run loss from here",
            (k - 0.5, 1.0),
            xycoords=("data", "axes fraction"),
            xytext=(3, -10),
            textcoords="offset points",
            fontsize=7,
            color="0.3",
        )
    for ax, what in ((ax_loss, "training loss"), (ax_val, "validation free-run error")):
        ax.set_yscale("log")
        ax.set_xlabel("epoch")
        ax.set_ylabel(what)
        ax.grid(True, which="both", lw=0.3, alpha=0.5)
    ax_val.set_title("dot: the epoch each network's best.pt holds", fontsize=9)
    if len(curves) <= 12:
        ax_loss.legend(fontsize=7, loc="upper right")
    fig.suptitle(f"learning curves: {Path(folder).name} ({len(curves)} network(s))")
    return save_png(fig, out, dpi=dpi)


def _selected_row(c: Curve) -> int | None:
    """The row of the dot: the selected epoch's, else the lowest validation error's (None: no
    finite error to mark)."""
    if c.selected is not None:
        rows = np.flatnonzero(c.epoch == c.selected)
        if rows.size and np.isfinite(c.val_error[rows[-1]]):
            return int(rows[-1])
    if np.isfinite(c.val_error).any():
        return int(np.nanargmin(c.val_error))
    return None
