"""Model selection: validate the epoch's candidates by free run, keep the best epoch.

After every epoch the candidates (the raw weights, and the weight average with ``ema_decay``)
are rolled out in closed loop on the validation episodes on the main rank, side by side in
one batched run (:func:`~excavator_surrogate.surrogate.validation.free_run_errors`); the
better one competes for ``best.pt``.  The result is broadcast, so every rank keeps the same
bookkeeping.  When the validation split is short (one or two segments), the recipe makes the
competition sound: only epochs after ``select_after`` of the plan compete, each scored with
its recent neighbours (:func:`selection_score`).  When validation spans too little of the
commands to vouch for the others (one command level), the selected epoch's weights are
averaged with the last epoch's (``average_last``, :func:`averaged`).  The epochs before them are not validated at all
(:func:`first_validated`), except the few whose errors the first competitors' scores read:
on a continuous log the validation free run costs several times the epoch's training.  When
the networks train on the validation episodes too (``train_on_val``), only the last epoch
competes: an in-sample score picks no epoch, it only says whether the weight average beats
the raw weights there.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from ..data.episode import Episode
from ..surrogate.model import Surrogate
from ..surrogate.validation import free_run_errors
from .config import TrainConfig
from .parallel import Parallel


def finite_or_inf(x: float) -> float:
    """``x``, or +inf if it is NaN (a diverged candidate never wins)."""
    return x if math.isfinite(x) else math.inf


@dataclass
class Choice:
    """The validated candidates of one epoch and the one picked."""

    vals: dict[str, dict[str, Any]]
    """Free-run scores by candidate label (``raw``, ``ema``)."""
    pick: str
    """Label of the better candidate."""
    chosen: Surrogate
    """The better candidate."""

    @property
    def val(self) -> dict[str, Any]:
        """Scores of the chosen candidate."""
        return self.vals[self.pick]


def choose(
    cands: list[tuple[str, Surrogate]],
    val_eps: list[Episode],
    par: Parallel,
    *,
    max_steps: int | None,
) -> Choice:
    """Validate every candidate (main rank, in one batched free run, broadcast) and pick the
    lowest ``val_error``."""
    labels = [label for label, _ in cands]
    errors = (
        free_run_errors([cand for _, cand in cands], val_eps, max_steps=max_steps)
        if par.is_main
        else None
    )
    vals = dict(zip(labels, par.broadcast(errors), strict=True))
    pick = min(vals, key=lambda k: finite_or_inf(vals[k]["val_error"]))
    return Choice(vals=vals, pick=pick, chosen=dict(cands)[pick])


def is_better(val_error: float, best: float, *, min_delta: float) -> bool:
    """A validation error that counts as an improvement over ``best``."""
    return val_error < best * (1.0 - min_delta)


def first_eligible(epochs: int, select_after: float, *, last_only: bool = False) -> int:
    """First epoch that may compete for ``best.pt``: ``floor(select_after * epochs)``, or the
    last planned one with ``last_only`` (validation is trained on: it can pick nothing)."""
    if last_only:
        return max(0, epochs - 1)
    return math.floor(select_after * epochs)


def first_validated(
    epochs: int, select_after: float, *, smooth: int, plateau: bool, last_only: bool = False
) -> int:
    """First epoch that is validated: the first that may compete (:func:`first_eligible`)
    less the ``smooth`` before it whose errors its score reads (:func:`selection_score`), so
    skipping the others changes no score; 0 for the ``plateau`` schedule, which steps on
    every epoch's validation error."""
    if plateau:
        return 0
    return max(0, first_eligible(epochs, select_after, last_only=last_only) - smooth)


def validation_start(cfg: TrainConfig) -> int:
    """:func:`first_validated` of the training ``cfg`` plans (its epochs, selection rule,
    schedule and whether validation is trained on)."""
    return first_validated(
        cfg.epochs,
        cfg.select_after,
        smooth=cfg.select_smooth,
        plateau=cfg.lr_schedule == "plateau",
        last_only=cfg.train_on_val,
    )


def not_validated(cands: list[tuple[str, Surrogate]], n_joint: int) -> Choice:
    """The :class:`Choice` of an epoch before :func:`first_validated`: every score NaN, the
    raw weights picked (it competes for nothing)."""
    nan = [math.nan] * n_joint
    vals = {
        label: {"val_error": math.nan, "theta_rmse": nan, "theta_r2": nan, "omega_rmse": nan}
        for label, _ in cands
    }
    return Choice(vals=vals, pick=cands[0][0], chosen=cands[0][1])


def selection_score(recent: list[float], *, smooth: int) -> float:
    """Score of the latest epoch from the validation errors of the epochs so far, oldest
    first (``recent[-1]`` is the latest): its own error, or with ``smooth > 0`` the larger of
    it and the median of the last ``smooth + 1`` (a diverged epoch counts as +inf).

    On one short validation segment the error of neighbouring epochs jumps by more than the
    real differences between them; the minimum over many epochs then picks a lucky draw.  The
    median asks the whole recent stretch to be good, and the maximum that the saved weights
    themselves are.
    """
    own = finite_or_inf(recent[-1])
    if smooth <= 0:
        return own
    window = [finite_or_inf(v) for v in recent[-(smooth + 1) :]]
    return max(own, float(np.median(window)))


def averaged(best: Surrogate, last: Surrogate) -> Surrogate:
    """A copy of ``best`` whose network weights are the mean of ``best``'s and ``last``'s,
    parameter by parameter (two epochs of one run: the same architecture and features).

        w = (w_best + w_last) / 2

    Validation at one command level picks the epoch that suits that level; the last epoch
    fits the training's levels.  On h1-dev with a duty held out of training (60 or 80; the
    validation runs at 50) the average beat the selected epoch on every joint of every seed,
    where the last epoch alone lost 1.5-2x at duty 60 (docs/real-history.md)."""
    out = copy.deepcopy(best)
    with torch.no_grad():
        for p, q in zip(out.net.parameters(), last.net.parameters(), strict=True):
            p.add_(q).mul_(0.5)
    return out
