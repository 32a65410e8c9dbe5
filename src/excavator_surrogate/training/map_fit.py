"""The static map a joint follows: its end stops, and what happens to it after the choice.

:mod:`.map_joints` chooses the joints that follow the static valve map, fitted on the
training split (:func:`~..surrogate.structured.fit_prior`), each stopping at the training
data's angle range (:func:`map_end_stops`).  After the choice the map can change twice:

- **refitted** on the training and validation splits together (``[train]
  map_refit_share``; :func:`refit_map`, where validation holds that share of the training's
  samples: off in the recipe);
- **its gains scaled to validation's speed** (``[train] map_val_gain``, the recipe's since
  session 109; :func:`scale_gains`).  A machine's speed drifts: the oil warms up over a log,
  one day runs faster than the last.  Validation is the data nearest the test in time (the
  log's next stretch, the sessions before the test's), so every joint on the map takes the
  map's gains scaled by validation's least-squares speed ratio
  (:func:`~..surrogate.structured.speed_ratio`), clipped to :data:`GAIN_RANGE`::

      k_pos, k_neg <- g k_pos, g k_neg,   g = clip(sum_t w s / sum_t s^2, 0.8, 1.25)

  over the validation episodes (``s`` the map's speed of the delayed command, ``w`` the
  measured one), where several episodes each measure it on the same side of 1 (since
  session 111), and where one episode, a log's next stretch, measures it faster (since
  session 112: within a log the oil only warms).  The dead zones and delays stay the
  training's; so do the other joints.

Either way the map joints' validation scores are then in-sample.

Evidence for the gains (``docs/real-history.md``, session 109; ``bench/real.py``, medians of
three seeds, angle RMSE on the test and on the more test data): the continuous log's swing
9.70 -> 8.74 and 35.71 -> 35.26 deg, its bucket 3.44 -> 3.20 and 14.90 -> 14.65 (the
10-minute loader's bucket alike), the 7-minute loader's bucket 13.92 -> 12.42 and 16.78 ->
14.68; on the sessions log, whose sessions each draw their own oil temperature, the swing and
the arm gain 0.3-0.5 % on the test and lose 0.6 % and 5 % on the 12 more sessions.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from ..data.episode import Episode
from ..surrogate.angles import joint_limits, omega_target
from ..surrogate.structured import fit_prior, joint_fit, speed_ratio, training_range_spec

GAIN_RANGE = (0.8, 1.25)
"""The least and the largest scale a map joint's gains take from validation."""


def map_end_stops(train: Sequence[Episode]) -> tuple[Any, Any]:
    """The end stops ``(lo, hi)``, (n_joint,) each [rad], of a joint on the static map: those
    the training episodes' spec declares, else the training data's angle range (+-inf on a
    periodic joint), the structured baseline's (:func:`.structured.training_range_spec`)."""
    return joint_limits(training_range_spec(train[0].spec, train))


def refit_map(
    pick: Sequence[int],
    train: Sequence[Episode],
    val: Sequence[Episode],
    *,
    max_delay: int,
    end_stops: bool,
) -> tuple[dict[str, Any], tuple[Any, Any] | None]:
    """The static map fitted again on the training and validation episodes together, after the
    choice was made on validation with the map of the training split: ``(fit, stops)``.

    Args:
        pick: (n_joint,) each joint's variant of the choice: 0 the map with delays up to
            ``max_delay`` [samples], 1 the map without delays.
        end_stops: the end stops come from both splits (:func:`map_end_stops`); else None
            (the network's).
    """
    both = [*train, *val]
    spec = both[0].spec
    fits = [fit_prior(both, spec, max_delay=max_delay)]
    if any(pick):
        fits.append(fit_prior(both, spec))
    fit = {k: [fits[v][k][j] for j, v in enumerate(pick)] for k in fits[0]}
    return fit, (map_end_stops(both) if end_stops else None)


def refit_due(train: Sequence[Episode], val: Sequence[Episode], *, share: float) -> float | None:
    """Validation's samples over the training's, if a map refit is due (``share > 0`` and
    validation holds at least ``share`` times the training's samples), else None."""
    n_train = sum(e.n_step for e in train)
    ratio = sum(e.n_step for e in val) / max(n_train, 1)
    return ratio if share > 0 and ratio >= share else None


def _say_refit(record: dict[str, Any]) -> None:
    """Add the refit (:func:`refit_map`) to ``record``'s ``why``, if there was one."""
    if "refit" in record:
        record["why"] += (
            f"; the map then refitted on training + validation (validation holds "
            f"{record['refit']['val_share']:.0%} of the training's samples; its validation "
            "scores are in-sample on the map joints)"
        )


def one_side(ratios: Sequence[float], *, shift: float = 0.0) -> bool:
    """Whether every ratio lies above ``1 + shift``, or every one below ``1 - shift`` (none
    NaN): validation episodes that each find the machine off the same way."""
    r = np.asarray(ratios, dtype=float)
    return bool(np.all(r > 1.0 + shift) or np.all(r < 1.0 - shift))


def validation_gains(
    fit: Mapping[str, Any], val: Sequence[Episode], on_map: Sequence[bool]
) -> list[float]:
    """Per joint, the scale of its map's gains: validation's speed ratio clipped to
    :data:`GAIN_RANGE` on a joint ``on_map``, 1.0 on the others.  With several validation
    episodes, only where each one's own ratio is above 1, or each one's below: episodes that
    disagree measure the map's error at their operating points, not the day's speed (the
    README's arm3 example, whose plant has no drift: the bucket's four validation runs
    measured 0.68-1.01, pooled 0.88, and the scale took its test R^2 from 0.947 to 0.894).
    With one validation episode (a log's next stretch), only where it is faster: a machine's
    oil warms over a log and does not cool while it works, so a next stretch slower than the
    training is the map's error at its operating points (on 7-minute logs of six machines
    the bench's rules were not set on, three of the four joints it slowed, x0.93-0.98, lost
    6-21 % on the test and the continuation, and the fourth, x0.99, moved 0.2 %; session
    112).

    Args:
        fit: the map (:func:`~..surrogate.structured.fit_prior`'s lists: ``delay``,
            ``a_pos``, ``a_neg``, ``k_pos``, ``k_neg``).
        val: the validation episodes.
        on_map: (n_joint,) the joints that follow the map.
    """
    spec = val[0].spec
    omegas = [omega_target(e.theta, spec) for e in val]
    out = []
    for j, on in enumerate(on_map):
        if not on:
            out.append(1.0)
            continue
        jf = joint_fit(fit, j)
        u, w = [e.u[:, j] for e in val], [om[:, j] for om in omegas]
        # several episodes: each must find the machine off the same way
        if len(val) > 1 and not one_side([speed_ratio(jf, [a], [b]) for a, b in zip(u, w)]):
            out.append(1.0)
            continue
        g = float(np.clip(speed_ratio(jf, u, w), *GAIN_RANGE))
        out.append(max(g, 1.0) if len(val) == 1 else g)  # one stretch: only warmer
    return out


def scale_gains(
    fit: Mapping[str, Any], val: Sequence[Episode], on_map: Sequence[bool], *, record: dict
) -> dict[str, Any]:
    """``fit`` with the map joints' gains scaled by :func:`validation_gains`, which
    ``record["val_gain"]`` keeps (``{"joints": [...], "gain": [...]}``, the joints on the map
    and their scales); ``fit`` itself where no joint is on the map."""
    if not any(on_map) or not val:
        return dict(fit)
    gains = validation_gains(fit, val, on_map)
    names = record["names"]
    record["val_gain"] = {
        "joints": [n for n, on in zip(names, on_map) if on],
        "gain": [g for g, on in zip(gains, on_map) if on],
        "episodes": len(val),
    }
    return {
        **fit,
        "k_pos": [k * g for k, g in zip(fit["k_pos"], gains)],
        "k_neg": [k * g for k, g in zip(fit["k_neg"], gains)],
    }


def _say_gain(record: dict[str, Any]) -> None:
    """Add the validation gains (:func:`scale_gains`) to ``record``'s ``why``, if any."""
    got = record.get("val_gain")
    if not got:
        return
    kept = (
        "its validation episodes disagreeing on the side"
        if got["episodes"] > 1
        else "one validation stretch not faster than the training (a machine warms over a log)"
    )
    each = ", ".join(
        f"{n} x{g:.3f}" if g != 1.0 else f"{n} x1, {kept}"
        for n, g in zip(got["joints"], got["gain"])
    )
    record["why"] += (
        f"; the map joints' speeds then scaled to validation's ({each}: validation is the "
        "data nearest the test in time; their validation scores are in-sample)"
    )


def say_changes(record: dict[str, Any]) -> None:
    """Add what changed the map after the choice (a refit, validation's speed) to
    ``record``'s ``why``."""
    _say_refit(record)
    _say_gain(record)
