"""Checks that stop a training early with one line instead of finishing with a useless model.

- :func:`check_excitation` (before the first epoch): a joint whose angle or command never
  moves in the training split cannot be learned; a dataset where no joint moves has nothing to
  learn at all (it used to train with rc 0 and report an R^2 of -4.8e11).
- :func:`check_finite` (after every epoch): weights that became NaN/inf stay so, since the NaN
  rule (:mod:`.parallel`) skips only steps whose loss or gradient is not finite; a finite
  gradient of a huge learning rate can still overflow the weights (``lr = 1e308``).
"""

from __future__ import annotations

import logging
from typing import Any

import numpy as np
import torch
from torch import nn

from ..data.dataset import Dataset
from ..errors import ConfigError, DataError

_log = logging.getLogger(__name__)

STILL = 1e-9
"""A signal whose range (max - min) within each episode of the training split is at most this,
times ``max(1, max |value|)``, never moves (rad for angles, the command's units)."""


def _still(x: np.ndarray) -> np.ndarray:
    """Per-column: True where ``x`` (n_sample, n_col) never moves (NaN ignored)."""
    with np.errstate(invalid="ignore"):
        lo, hi = np.nanmin(x, axis=0), np.nanmax(x, axis=0)
        scale = np.maximum(1.0, np.maximum(np.abs(lo), np.abs(hi)))
        return ~((hi - lo) > STILL * scale)


def check_excitation(dataset: Dataset, *, split: str = "train") -> list[str]:
    """Refuse a training split in which no joint moves; warn (one line per joint) about a joint
    whose angle or command never moves.

    Returns:
        The warnings logged (one per still joint), empty when every joint is excited.

    Raises:
        DataError: no joint's angle and command move anywhere in ``split``.
    """
    eps = dataset.split(split)
    if not eps:
        return []  # the training loop names a missing split
    spec = dataset.spec
    n = spec.n_joint
    # still in every episode (levels that differ between episodes are no motion either)
    theta_still = np.logical_and.reduce([_still(np.asarray(e.theta, np.float64)) for e in eps])
    u_still = np.logical_and.reduce([_still(np.asarray(e.u, np.float64)[:, :n]) for e in eps])
    if bool(np.all(theta_still & u_still)):
        raise DataError(
            dataset.root,
            f"no joint's angle or command ever moves in the '{split}' split "
            f"({', '.join(spec.names)} are constant): there is no excitation to learn from",
            fix="record or simulate episodes where the joints are commanded to move",
        )
    warnings = []
    for j, name in enumerate(spec.names):
        what = [w for w, still in (("angle", theta_still[j]), ("command", u_still[j])) if still]
        if what:
            warnings.append(
                f"no excitation: joint '{name}' {' and '.join(what)} never moves in the "
                f"'{split}' split; the surrogate cannot learn that joint (its R² will be undefined)"
            )
    for w in warnings:
        _log.warning(w)
    return warnings


def check_finite(net: nn.Module, *, epoch: int, lr: float | None = None) -> None:
    """Stop when any weight of ``net`` is NaN or inf (call after every epoch, before saving).

    Args:
        net: the trained network (a DDP wrapper works too).
        epoch: the epoch just finished (0-based, for the message).
        lr: the configured learning rate (for the message).

    Raises:
        ConfigError: one line naming the first non-finite parameter and what to do.
    """
    bad = _first_non_finite(net)
    if bad is None:
        return
    hint = f" (lr = {lr:g} is too large?)" if lr is not None else ""
    raise ConfigError(
        f"[train] the weights became non-finite at epoch {epoch} ({bad}){hint}: lower train.lr"
    )


def _first_non_finite(net: Any) -> str | None:
    with torch.no_grad():
        for name, p in net.named_parameters():
            if not bool(torch.isfinite(p).all()):
                return name
    return None
