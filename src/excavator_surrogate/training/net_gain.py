"""The network joints at validation's speed, where every validation episode agrees.

A machine's speed drifts from day to day (the oil, the weather, the engine), and the
validation episodes of a log taken in sessions are the ones nearest the test in time: the
sessions before it, on its day.  The joints on the static map take validation's speed
(:mod:`.map_fit`, ``[train] map_val_gain``).  A joint a network drives ran at the training
days' mean speed; here its predicted velocity takes validation's too, but only where the
validation episodes say so together (``[train] net_val_gain``).

**The ratio.** For each validation episode and joint, from every second sample ``k`` (after
a warm-up of ``W`` measured samples) the network runs ``n_h`` samples (1 s) on the measured
commands, and its displacement is compared with the measured one by least squares::

    r_e = sum_k  dth_meas(k) dth_net(k) / sum_k dth_net(k)^2,   dth(k) = theta[k + n_h] - theta[k]

(periodic joints wrapped).  Short horizons from measured starts see the speed without the
drift a whole free run piles up.

**The rule** (:func:`network_gains`). A joint is scaled only if

- a network drives it (not on the map: :mod:`.map_fit` scales those);
- validation spans its commands (``[train] choice_min_span``, :mod:`.span`) and is not
  trained on (``train_on_val``);
- there are at least :data:`MIN_EPISODES` validation episodes, and every one's ratio lies
  beyond ``1 +- MIN_SHIFT`` on the same side.

It then takes the ratio pooled over all of them, clipped to
:data:`~.map_fit.GAIN_RANGE`: the network's output normalisation ``y_mean, y_std`` times
``g``, which is exactly ``omega_j <- g omega_j`` (:func:`scaled_outputs`).

Why so strict (``docs/real-history.md``, session 111): a network's ratio on validation is its
error there, not only the machine's speed.  Applied wherever it was measured it gained 3x on
the bucket of a simulated test day 15 % faster than the training days, and cost 4-9 % on the
booms of the continuous and loader logs (one validation segment each; the loader's ratio of
1.10 held in both of its halves and not on the test) and 16 % on a boom whose two validation
sessions both measured 1.04 on a day at the training's mean speed.  Two sessions that each say the same
thing beyond 5 % are a day's speed; one segment of the training's own log is not.
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ..data.episode import Episode
from ..surrogate.angles import wrap_periodic
from ..surrogate.checkpoint import (
    checkpoint_dict,
    read_checkpoint,
    surrogate_from_dict,
    write_checkpoint_dict,
)
from ..surrogate.model import Surrogate
from ..surrogate.rollout import ClosedLoop
from ..surrogate.validation import free_run_error, with_val_scores
from .map_fit import GAIN_RANGE, one_side
from .span import joint_spans

_log = logging.getLogger(__name__)

MIN_EPISODES = 2
"""Validation episodes needed to scale a network joint: one segment cannot tell a day's speed
from the network's error on it."""
MIN_SHIFT = 0.05
"""Every validation episode's ratio must lie beyond ``1 +- MIN_SHIFT``, all on one side (the
networks' own ratios reached 1.04-1.05 on both validation sessions of simulated days at the
training's mean speed)."""
HORIZON_S = 1.0
"""Length of each short run from a measured start [s]."""
STRIDE = 2
"""A short run starts at every ``STRIDE``-th sample."""
CHUNK = 4096
"""Short runs stepped in one batch at most (a long log's starts go in chunks: bounded memory)."""


def displacement_sums(
    sur: Surrogate, ep: Episode, *, n_h: int, stride: int = STRIDE
) -> tuple[np.ndarray, np.ndarray]:
    """``(sum_k dth_meas dth_net, sum_k dth_net^2)``, (n_joint,) each [rad^2], over the
    ``n_h``-sample runs of ``sur`` from every ``stride``-th measured start of ``ep`` (each after
    ``W - 1`` measured samples of warm-up), up to :data:`CHUNK` starts in one batch.

    Args:
        sur: the surrogate; ``ep``: an episode of its spec (``theta: (n_step, n_joint)``
            [rad], ``u: (n_step, n_u)``).
        n_h: samples each run lasts (>= 1).
    """
    w = sur.window
    num, den = np.zeros(sur.spec.n_joint), np.zeros(sur.spec.n_joint)
    starts = np.arange(w - 1, ep.n_step - n_h, stride)
    for at in range(0, len(starts), CHUNK):
        k = starts[at : at + CHUNK]
        loop = ClosedLoop(sur)
        loop.reset_at(ep.theta, ep.u, k)
        for j in range(n_h):
            theta, _ = loop.step(ep.u[k + j])
        d_net = wrap_periodic(theta.double().cpu().numpy() - ep.theta[k], sur.spec.periodic)
        d_meas = wrap_periodic(ep.theta[k + n_h] - ep.theta[k], sur.spec.periodic)
        num += (d_meas * d_net).sum(axis=0)
        den += (d_net * d_net).sum(axis=0)
    return num, den


def episode_ratios(
    sur: Surrogate, episodes: Sequence[Episode], *, n_h: int, stride: int = STRIDE
) -> tuple[np.ndarray, np.ndarray]:
    """``(per_episode, pooled)``: the measured-over-predicted displacement ratio
    (:func:`displacement_sums`) of each episode, (n_episode, n_joint), and over all of them
    together, (n_joint,); NaN where the network predicts no motion."""
    sums = [displacement_sums(sur, ep, n_h=n_h, stride=stride) for ep in episodes]
    num = np.array([s[0] for s in sums]).reshape(len(sums), sur.spec.n_joint)
    den = np.array([s[1] for s in sums]).reshape(len(sums), sur.spec.n_joint)
    with np.errstate(invalid="ignore", divide="ignore"):
        per = np.where(den > 0, num / den, np.nan)
        pooled = np.where(den.sum(0) > 0, num.sum(0) / den.sum(0), np.nan)
    return per, pooled


def network_gains(
    per_episode: np.ndarray, pooled: np.ndarray, eligible: Sequence[bool]
) -> list[float]:
    """Per joint, the scale of a network joint's velocity (the module's rule): the pooled
    ratio clipped to :data:`~.map_fit.GAIN_RANGE` on an ``eligible`` joint where at least
    :data:`MIN_EPISODES` episodes each measured a ratio beyond ``1 +- MIN_SHIFT`` on one
    side, else 1.0.

    Args:
        per_episode: (n_episode, n_joint) ratios (:func:`episode_ratios`).
        pooled: (n_joint,) the ratio over all episodes.
        eligible: (n_joint,) the joints a network drives, with validation spanning them.
    """
    per = np.asarray(per_episode, dtype=float)
    out = []
    for j, ok in enumerate(eligible):
        agree = len(per) >= MIN_EPISODES and one_side(per[:, j], shift=MIN_SHIFT)
        out.append(float(np.clip(pooled[j], *GAIN_RANGE)) if ok and agree else 1.0)
    return out


def scaled_outputs(sur: Surrogate, gains: Sequence[float]) -> Surrogate:
    """A copy of ``sur`` whose predicted velocity of joint ``j`` is ``gains[j]`` times
    ``sur``'s: the output normalisation's ``y_mean`` and ``y_std`` scaled (a speed prior keeps
    its own copy of the old ones, so ``s(u) + y_std head`` scales whole).

    Raises:
        ValueError: the network reads its previous velocity (``omega_in``), standardised with
            the same ``y_mean, y_std``: scaling them would change its inputs too.
    """
    norm = sur.norm
    if norm.omega_in:
        raise ValueError("scaled_outputs: the network reads its velocity (omega_in)")
    g = torch.as_tensor(list(gains), dtype=norm.y_std.dtype, device=norm.y_std.device)
    out = dataclasses.replace(sur)
    out.norm = dataclasses.replace(norm, y_mean=norm.y_mean * g, y_std=norm.y_std * g)
    return out


def choose_network_gains(
    sur: Surrogate,
    val: Sequence[Episode],
    *,
    on_map: Sequence[bool],
    spanned: Sequence[bool] | None,
    trained_on_val: bool,
    max_steps: int | None = None,
) -> tuple[Surrogate | None, dict[str, Any]]:
    """The module's rule on ``sur`` (the run's final model): ``(scaled, record)``, ``scaled``
    None where no joint changes, else with its own validation free-run scores in its metrics
    (``val_error``, ``val``: in-sample on the scaled joints).  ``record``: ``joints`` and
    ``gain`` (the scaled ones), ``ratios`` (per validation episode, per joint), ``pooled``,
    ``why``.

    Args:
        val: the validation episodes; ``on_map``: (n_joint,) the joints on the static map;
        spanned: (n_joint,) the joints whose commands validation spans (None: all).
        trained_on_val: the networks trained on ``val`` (then nothing is scaled).
        max_steps: the validation free run's steps per episode (``[train] val_steps``).
    """
    names = list(sur.spec.names)
    n_h = max(1, round(HORIZON_S * sur.spec.rate_hz))
    record: dict[str, Any] = {"names": names, "joints": [], "gain": []}
    if trained_on_val or sur.norm.omega_in or len(val) < MIN_EPISODES:
        record["why"] = "the network joints keep the training's speed: " + (
            "the networks trained on the validation episodes"
            if trained_on_val
            else "the networks read their own velocity"
            if sur.norm.omega_in
            else f"{len(val)} validation episode(s), fewer than {MIN_EPISODES} to agree on a speed"
        )
        return None, record
    per, pooled = episode_ratios(sur, val, n_h=n_h)
    spans = [True] * len(names) if spanned is None else [bool(s) for s in spanned]
    eligible = [not m and s for m, s in zip(on_map, spans)]
    gains = network_gains(per, pooled, eligible)
    record["ratios"] = np.round(per, 4).tolist()
    record["pooled"] = np.round(pooled, 4).tolist()
    changed = [j for j, g in enumerate(gains) if g != 1.0]
    record["joints"] = [names[j] for j in changed]
    record["gain"] = [gains[j] for j in changed]
    measured = ", ".join(
        f"{n} {' / '.join(f'{r:.3f}' for r in per[:, j])}"
        for j, n in enumerate(names)
        if eligible[j]
    )
    rule = (
        f"every one of {len(val)} validation episodes' 1-s displacement ratio beyond "
        f"1 +- {MIN_SHIFT:g} on one side"
    )
    if not changed:
        record["why"] = (
            "the network joints keep the training's speed: no joint a network drives has "
            + rule
            + (f" ({measured})" if measured else "")
        )
        return None, record
    each = ", ".join(f"{names[j]} x{gains[j]:.3f}" for j in changed)
    record["why"] = (
        f"the network joints' speeds scaled to validation's ({each}): {rule} (validation is the "
        f"data nearest the test in time; {measured}); their validation scores are in-sample"
    )
    scaled = scaled_outputs(sur, gains)  # sur's metrics, then its own validation scores
    return with_val_scores(scaled, free_run_error(scaled, list(val), max_steps=max_steps)), record


def after_map_choice(
    sur: Surrogate,
    train: Sequence[Episode],
    val: Sequence[Episode],
    *,
    map_record: Mapping[str, Any] | None,
    min_span: float,
    trained_on_val: bool,
    max_steps: int | None = None,
) -> tuple[Surrogate | None, dict[str, Any]]:
    """:func:`choose_network_gains` on a run's model after its static map choice, whose
    record (``map_record``, None without one) names the map joints; validation's span is
    measured only where the rule can act.

    Args:
        train, val: the run's training and validation episodes (the span is measured on them).
        min_span: ``[train] choice_min_span``; ``trained_on_val``: ``[train] train_on_val``;
        max_steps: ``[train] val_steps`` (None: whole episodes).
    """
    chosen = set((map_record or {}).get("chosen") or [])
    can_act = not trained_on_val and len(val) >= MIN_EPISODES  # else no span is needed
    spanned = joint_spans(train, val, sur.spec, min_span=min_span)[1] if can_act else None
    return choose_network_gains(
        sur,
        val,
        on_map=[n in chosen for n in sur.spec.names],
        spanned=spanned,
        trained_on_val=trained_on_val,
        max_steps=max_steps,
    )


def apply_network_gains(
    best: str | Path,
    train: Sequence[Episode],
    val: Sequence[Episode],
    *,
    min_span: float,
    trained_on_val: bool,
    max_steps: int | None = None,
) -> dict[str, Any]:
    """:func:`after_map_choice` on the checkpoint ``best``: rewrites it atomically with the
    scaled model, if any joint changes, and records the rule's outcome either way in
    ``metrics.training.net_val_gain``.  Returns the record (the arguments: as
    :func:`after_map_choice`'s)."""
    path = Path(best)
    ckpt = read_checkpoint(path)
    sur = surrogate_from_dict(ckpt, where=str(path))
    metrics = dict(ckpt.get("metrics") or {})
    training = dict(metrics.get("training") or {})
    new, record = after_map_choice(
        sur,
        train,
        val,
        map_record=training.get("static_map"),
        min_span=min_span,
        trained_on_val=trained_on_val,
        max_steps=max_steps,
    )
    if new is not None:
        ckpt = checkpoint_dict(new, history=ckpt.get("history"))  # no resuming into it
        metrics = dict(ckpt.get("metrics") or {})
    training["net_val_gain"] = record
    metrics["training"] = training
    ckpt["metrics"] = metrics
    write_checkpoint_dict(path, ckpt)
    _log.info(f"{path}: {record['why']}")
    return record
