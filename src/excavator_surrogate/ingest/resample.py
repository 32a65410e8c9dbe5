"""Resampling irregular logs onto a uniform grid, anti-aliased.

Data convention (see :mod:`excavator_surrogate.data.episode`): sample ``k`` at ``t_k`` holds

- ``theta[k]``: the angle at ``t_k``;
- ``u[k]``: the command applied during ``[t_k, t_{k+1})``;
- ``omega[k]``: the mean velocity over ``[t_{k-1}, t_k]``, so
  ``omega[k] = (theta[k] - theta[k-1]) / dt`` exactly for derived velocities.

Choices:

- **Angles** (periodic ones unwrapped first) are interpolated linearly onto a fine uniform
  grid at ``factor * rate_out`` (``factor = ceil(rate_in / rate_out)``, so the fine grid is
  at least as fast as the log), low-pass filtered with a zero-phase Butterworth filter
  (order 8, forward-backward, cutoff ``lowpass * rate_out / 2``) and decimated by
  ``factor``.  Zero phase: the angles are not delayed.  When the log is not faster than
  the target, angles are only interpolated.
- **Commands** are **averaged**: ``u[k]`` is the exact mean of the logged command, held
  from each log sample to the next (zero-order hold, as a valve sees it), over
  ``[t_k, t_{k+1})``.  Constant commands stay exact; a switch inside an interval gives
  the duty-weighted mean, which is what an integrating hydraulic actuator responds to.
  The box average also suppresses the log's fast command chatter.
- **Measured velocities** are integrated (trapezoid) to a pseudo-angle, which is resampled
  exactly like the angles and differenced, so ``omega[k]`` is the filtered mean velocity
  over ``[t_{k-1}, t_k]``: the same linear operator as the angles, consistent by
  construction.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

FILTER_ORDER = 8
"""Butterworth order of the anti-alias filter (applied forward and backward)."""


def decimation_factor(rate_in_hz: float, rate_out_hz: float) -> int:
    """Integer factor of the fine grid: ``ceil(rate_in / rate_out)`` (2 % tolerance), at least 1."""
    return max(1, math.ceil(rate_in_hz / rate_out_hz - 0.02))


def antialias_sos(rate_out_hz: float, factor: int, *, lowpass: float = 0.8) -> np.ndarray | None:
    """Second-order sections of the anti-alias low-pass for a fine grid at ``factor * rate_out``.

    Returns None when no filter is needed (``factor == 1`` or ``lowpass == 0``).
    """
    if factor <= 1 or lowpass <= 0:
        return None
    from scipy.signal import butter

    fs = factor * rate_out_hz
    return np.asarray(butter(FILTER_ORDER, lowpass * rate_out_hz / 2.0, fs=fs, output="sos"))


def resample_smooth(
    t_in: np.ndarray,
    x_in: np.ndarray,
    *,
    t0: float,
    n_out: int,
    rate_hz: float,
    factor: int,
    sos: np.ndarray | None,
    t_end: float | None = None,
) -> np.ndarray:
    """Anti-aliased resampling of continuous signals (angles) onto ``t0 + k / rate_hz``.

    Args:
        t_in: (m,) increasing log times [s].
        x_in: (m,) or (m, c) values at ``t_in``.
        t0: first output time [s]; ``t_in[0] <= t0``.
        n_out: number of output samples; ``t0 + (n_out - 1) / rate_hz <= t_in[-1]``.
        rate_hz: output rate [Hz].
        factor: fine-grid factor (:func:`decimation_factor`).
        sos: filter from :func:`antialias_sos`, or None (interpolation only).
        t_end: last time the fine grid may reach (default ``t_in[-1]``); data past the
            last output sample reduces filter edge effects.

    Returns:
        (n_out,) or (n_out, c) values.
    """
    x = np.asarray(x_in, dtype=np.float64)
    one_d = x.ndim == 1
    if one_d:
        x = x[:, None]
    dt_fine = 1.0 / (rate_hz * factor)
    t_end = float(t_in[-1]) if t_end is None else min(float(t_end), float(t_in[-1]))
    n_fine = max((n_out - 1) * factor + 1, math.floor((t_end - t0) / dt_fine + 1e-9) + 1)
    t_fine = t0 + dt_fine * np.arange(n_fine)
    fine = np.empty((n_fine, x.shape[1]))
    for c in range(x.shape[1]):
        fine[:, c] = np.interp(t_fine, t_in, x[:, c])
    if sos is not None and n_fine > 3:
        from scipy.signal import sosfiltfilt

        # odd extension of ~order cutoff periods each side: settles the filter's transient
        padlen = min(n_fine - 2, 2 * FILTER_ORDER * factor)
        fine = sosfiltfilt(sos, fine, axis=0, padlen=max(padlen, 0))
    out = fine[: (n_out - 1) * factor + 1 : factor]
    return out[:, 0] if one_d else out


def _held(t_in: np.ndarray, t: Any) -> Any:
    """The row of increasing log times ``t_in`` whose value holds at each time ``t``: the last
    one at or before it, row 0 before ``t_in[0]`` (the first value is held backwards)."""
    return np.clip(np.searchsorted(t_in, t, side="right") - 1, 0, len(t_in) - 1)


def interval_mean(t_in: np.ndarray, x_in: np.ndarray, t_edges: np.ndarray) -> np.ndarray:
    """Mean of a zero-order-hold signal over each interval ``[t_edges[k], t_edges[k+1])``.

    The logged value ``x_in[i]`` is held from ``t_in[i]`` until ``t_in[i+1]`` (the last one
    onwards; before ``t_in[0]`` the first value is held backwards).

    Args:
        t_in: (m,) increasing log times [s].
        x_in: (m,) or (m, c) values.
        t_edges: (n + 1,) increasing interval edges [s].

    Returns:
        (n,) or (n, c) interval means.
    """
    t_in = np.asarray(t_in, dtype=np.float64)
    x = np.asarray(x_in, dtype=np.float64)
    one_d = x.ndim == 1
    if one_d:
        x = x[:, None]
    # cumulative integral of the held signal at each log time, relative to t_in[0]
    seg = np.diff(t_in)[:, None] * x[:-1]
    cum = np.vstack([np.zeros((1, x.shape[1])), np.cumsum(seg, axis=0)])
    idx = _held(t_in, t_edges)
    integral = cum[idx] + x[idx] * (t_edges - t_in[idx])[:, None]
    out = np.diff(integral, axis=0) / np.diff(t_edges)[:, None]
    return out[:, 0] if one_d else out


def span_rows(t: np.ndarray, a: float, b: float) -> slice:
    """The rows of increasing times ``t`` [s] a span ``[a, b]`` reads: from the last one at
    or before ``a`` (its value holds at ``a``) to the first one at or after ``b``."""
    i0 = int(_held(t, a))
    i1 = min(int(np.searchsorted(t, b, side="left")), t.shape[0] - 1)
    return slice(i0, i1 + 1)


def hold(t_in: np.ndarray, x_in: np.ndarray, t: np.ndarray) -> np.ndarray:
    """A zero-order-hold signal's values at times ``t``, held as :func:`interval_mean` holds
    it: ``x_in[i]`` from ``t_in[i]`` until ``t_in[i+1]``, the first value before ``t_in[0]``.

    Args:
        t_in: (m,) increasing log times [s].
        x_in: (m,) values.
        t: (n,) times [s].

    Returns:
        (n,) the held values.
    """
    return np.asarray(x_in)[_held(t_in, t)]


def cumulative_trapezoid(t: np.ndarray, v: np.ndarray) -> np.ndarray:
    """(m,) running integral of ``v`` over ``t`` (trapezoid rule), starting at 0."""
    inc = 0.5 * (v[1:] + v[:-1]) * np.diff(t)
    return np.concatenate([[0.0], np.cumsum(inc)])
