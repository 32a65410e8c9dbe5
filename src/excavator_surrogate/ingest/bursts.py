"""Impossible angle samples without declared limits: magnitudes and bursts of any length.

The spike screen (:func:`~.outliers.find_spikes`) finds corrupt runs of up to three samples;
the joint limits find longer ones only when the mapping declares limits, and most do not.
:func:`find_impossible` finds the rest from the log itself:

- magnitudes no sensor reads: non-finite values, and angles beyond ``MAX_TURNS`` turns
  for a joint with end stops (``MAX_TURNS_PERIODIC`` for a periodic one; both are the data
  contract's, :mod:`excavator_surrogate.data.plausible`);
- bursts: a jump implying a speed no joint reaches (above :data:`JUMP_SPEED` rad/s and
  :data:`JUMP_FACTOR` times the log's own 99th-percentile speed; a step is taken as at
  least the log's median time step, so two samples stamped 0.2 ms apart by a jittery
  logger do not make one), paired with a jump back to where the joint could plausibly be
  by then.  The samples between are the burst, whatever its length.  A jump without a jump
  back (a burst at the start or the end of the log) marks the shorter side, when that is at
  most half the log.

Legitimate motion, end stops (the joint stops, it does not jump) and a periodic joint's wrap
at ±180° (unwrapped before the rate test) never exceed those speeds.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..data.plausible import MAX_TURNS, MAX_TURNS_PERIODIC

JUMP_SPEED = 10.0
"""A jump is impossible only above this speed [rad/s] ..."""
JUMP_FACTOR = 20.0
"""... and above this multiple of the log's own 99th-percentile speed |Δθ|/Δt (Δt at least
the median step)."""


@dataclass(frozen=True)
class Burst:
    """One run of impossible samples, rows ``start`` to ``stop - 1`` of the input."""

    start: int
    stop: int
    reason: str
    """``magnitude`` (no sensor reads it) or ``jump`` (entered and left at impossible speeds)."""
    speed: float = math.nan
    """For ``jump``: the entry (or exit) speed [rad/s]."""
    scale: float = math.nan
    """For ``jump``: the log's own 99th-percentile speed [rad/s]."""


def find_impossible(
    theta: np.ndarray, t: np.ndarray, *, periodic: bool
) -> tuple[np.ndarray, list[Burst]]:
    """Samples of one angle channel that no joint and no sensor can produce.

    Args:
        theta: (n,) angle [rad] as logged (periodic joints not yet unwrapped).
        t: (n,) strictly increasing sample times [s].
        periodic: the joint has no end stops (its angle is unwrapped before the rate test).

    Returns:
        ``(mask, bursts)``: (n,) bool, True on impossible samples, and the runs in row order.
    """
    n = theta.shape[0]
    bound = 2 * math.pi * (MAX_TURNS_PERIODIC if periodic else MAX_TURNS)
    with np.errstate(invalid="ignore"):
        huge = ~(np.abs(theta) <= bound)  # NaN/inf too
    mask = huge.copy()
    bursts = [Burst(a, b, "magnitude") for a, b in _runs(huge)]
    ok = np.flatnonzero(~huge)
    if ok.size >= 3:
        x = np.unwrap(theta[ok]) if periodic else theta[ok]
        for a, b, speed, scale in _jump_bursts(x, t[ok]):
            rows = ok[a:b]
            mask[rows] = True
            bursts.append(Burst(int(rows[0]), int(rows[-1]) + 1, "jump", speed, scale))
    bursts.sort(key=lambda r: r.start)
    return mask[:n], bursts


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """``(start, stop)`` of each run of True in ``mask``."""
    edges = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    return list(zip(np.flatnonzero(edges == 1).tolist(), np.flatnonzero(edges == -1).tolist()))


def _jump_bursts(x: np.ndarray, t: np.ndarray) -> list[tuple[int, int, float, float]]:
    """``(start, stop, speed, scale)`` of each burst of ``x`` [rad] bounded by impossible jumps."""
    n = x.shape[0]
    dt = np.diff(t)
    # a step shorter than the typical one (a jittered time stamp) does not make a speed
    speed = np.abs(np.diff(x)) / np.maximum(dt, np.median(dt))
    scale = float(np.quantile(speed, 0.99))
    thr = max(JUMP_SPEED, JUMP_FACTOR * scale)
    jumps = (np.flatnonzero(speed > thr) + 1).tolist()  # row s jumped from row s - 1
    out: list[tuple[int, int, float, float]] = []
    i = 0
    while i < len(jumps):
        s = jumps[i]
        v = float(speed[s - 1])
        back = None
        for k in range(i + 1, len(jumps)):
            e = jumps[k]
            if e - s > n // 2:
                break
            # the samples around the burst agree: the joint could have moved between them
            if abs(x[e] - x[s - 1]) <= thr * (t[e] - t[s - 1]):
                back = k
                break
        if back is not None:
            out.append((s, jumps[back], v, scale))
            i = back + 1
            continue
        # no jump back: the shorter side of the jump is the burst (log start or end)
        a, b = (0, s) if s <= n - s else (s, n)
        if b - a <= n // 2:
            out.append((a, b, v, scale))
        i += 1
    return out
