"""``exsur train DATASET`` without a preset: a training recipe chosen from the data.

Real logs are not the simulator's long multisine episodes.  They are many short runs (a step
from rest that ends against an end stop after 100-2000 samples), on a machine whose limits
nobody wrote down, at whatever rate the user resampled to.  :func:`auto_config` reads the
dataset's sizes, rate and episode lengths and returns a complete :class:`TrainConfig` plus a
list of one-line reasons (logged and recorded in ``config.toml``).

The recipe, and the measurement behind each choice, is documented in ``docs/real.md``:

- the paper's network (2 x 128 LSTM, FC-ReLU-linear head, window W = 30 samples; W shrinks
  for data whose episodes are too short for it);
- ``stateful`` teacher-forced training on sub-sequences after a burn-in of W recorded
  samples (on the real logs it beat free-run feedback and the windowed one-step loss, and
  costs about one recurrent step per sample); the sub-sequence length follows the episode
  lengths so that no short run is dropped;
- a wall-time budget (the cosine learning-rate schedule ends with it) and an exponential
  moving average of the weights, so the selected checkpoint does not depend on one lucky
  epoch; selection by the whole-episode validation free run;
- a seed ensemble of ``members`` networks trained side by side, one per core;
- the envelope (end stops and speed bounds) from the spec, else from the training data.

Every field can still be overridden: ``auto_config(ds, overrides={"members": 1})``, or on
the command line ``exsur train DATA --members 1``.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from ..config import from_dict, to_dict
from ..data.dataset import Dataset
from ..devices import usable_cpus
from ..errors import DataError
from .config import TrainConfig

TRAIN_BUDGET_S = 540.0
"""Wall time of the whole training (every member) on the reference 2-core machine [s]."""
WINDOW = 30
"""The paper's window W [samples] (also the warm-up of every free run)."""
MIN_WINDOW = 8
"""Smallest window the recipe shrinks to for very short episodes [samples]."""
MAX_SEQ_LEN = 150
"""Longest training sub-sequence including the burn-in [samples]."""
EPOCHS = 40
"""Epochs of the cosine schedule (the wall-time budget ends it earlier on a slow machine)."""
MEMBERS = 4
"""Seed-ensemble members on a machine with 2 or more CPUs (half as many on one CPU)."""


def auto_config(
    dataset: Dataset,
    *,
    overrides: Mapping[str, Any] | None = None,
    cpus: int | None = None,
    budget_s: float = TRAIN_BUDGET_S,
) -> tuple[TrainConfig, list[str]]:
    """The training recipe for ``dataset`` (see the module docstring).

    Args:
        dataset: the training data (``train`` split required; ``val`` used for selection).
        overrides: ``[train]`` fields that replace the recipe's choices (strictly checked).
        cpus: CPUs to plan for (default: those this process may use).
        budget_s: wall time of the whole training, all members [s].

    Returns:
        The config and one reason per choice, e.g. ``"window 30: the paper's W"``.

    Raises:
        DataError: no training episode.
    """
    lengths = np.array([e.n_step for e in dataset.train])
    if lengths.size == 0:
        raise DataError(dataset.root, "has no training episodes", fix="import or simulate some")
    cpus = cpus or usable_cpus()
    why: list[str] = []
    short = int(lengths.min())
    window = WINDOW
    if short < 3 * WINDOW:
        window = max(MIN_WINDOW, short // 3)
        why.append(f"window {window}: the shortest runs hold {short} samples (paper: 30)")
    else:
        why.append(f"window {window}: the paper's W")
    seq_len = int(min(MAX_SEQ_LEN, short - 1))
    seq_len = max(seq_len, window + 10)
    n_drop = int((lengths < seq_len + 1).sum())
    why.append(
        f"stateful, teacher-forced, sub-sequences of {seq_len} samples incl. a {window}-sample "
        f"burn-in: the episodes hold {lengths.min()}-{lengths.max()} samples"
        + (f" ({n_drop} shorter ones are left out)" if n_drop else " (none is left out)")
    )
    members = MEMBERS if cpus >= 2 else MEMBERS // 2
    workers = min(members, cpus)
    per_member = budget_s * workers / members
    why.append(
        f"seed ensemble of {members} member(s), {workers} in parallel, {per_member:.0f} s each "
        f"({budget_s:.0f} s of training in all on {cpus} CPU(s))"
    )
    why.append("envelope: end stops and speed bounds from the spec, else from the training data")
    cfg = TrainConfig(
        window=window,
        hidden=128,
        layers=2,
        head_hidden=128,
        mode="stateful",
        feedback="teacher",
        seq_len=seq_len,
        burn_in=window,
        tbptt=10,
        seq_batch=16,
        lr=1e-3,
        lr_schedule="cosine",
        min_lr=1e-5,
        epochs=EPOCHS,
        patience=EPOCHS,
        ema_decay=0.999,
        members=members,
        member_workers=workers,
        max_train_seconds=per_member,
        end_stops=True,
    )
    if overrides:
        merged = {**to_dict(cfg), **dict(overrides)}
        cfg = from_dict(TrainConfig, merged, where="[train]")
        why.append("overridden: " + ", ".join(f"{k} = {v!r}" for k, v in overrides.items()))
    return cfg, why


def recipe_table(why: list[str]) -> dict[str, Any]:
    """The ``[recipe]`` table of ``config.toml``: ``{"name": "auto", "why": [...]}``."""
    return {"name": "auto", "why": list(why)}
