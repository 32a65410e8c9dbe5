"""What the training data covered, and a per-step flag when a free run leaves it.

A surrogate answers every command sequence with the same confidence, also one the training
logs never contained.  :class:`CoverageRecord` is a compact record of the training data,
stored in the checkpoint (``metrics["coverage"]``):

- per channel (every command column ``u_<joint>`` / ``u_<input>``, every ``theta_<joint>``
  and ``omega_<joint>``): the 0.5 % and 99.5 % quantiles, widened by ``margin`` times their
  distance on each side (a box that ignores the rarest samples, e.g. spikes);
- per joint: a coarse ``n_bin x n_bin`` occupancy grid of (angle, command) inside that box.
  The box alone says "this command level was seen"; the grid adds "at this angle": a full
  boom-up command near the upper stop is a different regime than at mid-stroke.

:func:`ood_flags` flags step ``k`` of joint ``j`` when ``u_j[k]``, ``theta_j[k]`` or
``omega_j[k]`` is outside its box or the (``theta_j``, ``u_j``) cell and its neighbours held no
training sample (:func:`seen_cells`); an exogenous input outside its box flags every joint.  Size: ``4 n_channel + n_joint n_bin^2``
numbers (a few hundred), plain data in the checkpoint.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..data.episode import Episode
from ..errors import CheckpointError, DataError
from ..spec import MachineSpec
from .angles import omega_target, wrap_angle

QUANTILES = (0.005, 0.995)
"""The quantiles that bound each channel's box."""


@dataclass(frozen=True)
class CoverageRecord:
    """The training data's envelope: per-channel boxes and per-joint (theta, u) occupancy."""

    channels: tuple[str, ...]
    """Channel names: ``u_<joint>``..., ``u_<input>``..., ``theta_<joint>``..., ``omega_<joint>``...."""
    lo: np.ndarray
    """(n_channel,) lower box edge (quantile 0.5 % minus the margin) [channel units]."""
    hi: np.ndarray
    """(n_channel,) upper box edge (quantile 99.5 % plus the margin) [channel units]."""
    grid: np.ndarray
    """(n_joint, n_bin, n_bin) int, training samples per (theta_j bin, u_j bin) inside the box."""
    n_sample: int
    """Training samples the record was built from."""
    margin: float = 0.05
    """Box widening on each side, as a fraction of the quantile range."""

    @property
    def n_bin(self) -> int:
        """Occupancy grid bins per axis."""
        return int(self.grid.shape[1])

    def to_dict(self) -> dict[str, Any]:
        """Plain data for the checkpoint."""
        return {
            "channels": list(self.channels),
            "lo": [float(v) for v in self.lo],
            "hi": [float(v) for v in self.hi],
            "grid": self.grid.astype(int).tolist(),
            "n_sample": int(self.n_sample),
            "margin": float(self.margin),
            "quantiles": list(QUANTILES),
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> CoverageRecord:
        """Inverse of :meth:`to_dict` (:class:`CheckpointError` on a malformed record)."""
        try:
            rec = cls(
                channels=tuple(str(c) for c in d["channels"]),
                lo=np.asarray(d["lo"], dtype=np.float64),
                hi=np.asarray(d["hi"], dtype=np.float64),
                grid=np.asarray(d["grid"], dtype=np.int64),
                n_sample=int(d["n_sample"]),
                margin=float(d.get("margin", 0.05)),
            )
        except (KeyError, TypeError, ValueError) as e:
            raise CheckpointError(f"malformed coverage record ({e}); calibrate again") from e
        n = len(rec.channels)
        if rec.lo.shape != (n,) or rec.hi.shape != (n,) or rec.grid.ndim != 3:
            raise CheckpointError("malformed coverage record (sizes disagree); calibrate again")
        return rec


def channel_names(spec: MachineSpec) -> tuple[str, ...]:
    """The record's channels for ``spec``: commands (joints, then inputs), angles, velocities."""
    return (
        *(f"u_{n}" for n in spec.names),
        *(f"u_{i.name}" for i in spec.inputs),
        *(f"theta_{n}" for n in spec.names),
        *(f"omega_{n}" for n in spec.names),
    )


def _stack(
    theta: np.ndarray, omega: np.ndarray, u: np.ndarray
) -> np.ndarray:  # (..., n_channel) in channel order
    return np.concatenate([u, theta, omega], axis=-1)


def fit_coverage(
    episodes: Sequence[Episode], spec: MachineSpec, *, n_bin: int = 10, margin: float = 0.05
) -> CoverageRecord:
    """Build the record of what ``episodes`` (the training split) covered.

    Args:
        episodes: training episodes (measured ``theta`` [rad], ``u``); omega is the backward
            difference of theta, the training target.
        spec: the machine.
        n_bin: occupancy grid bins per axis.
        margin: box widening on each side, as a fraction of the quantile range.

    Raises:
        DataError: no episodes.
    """
    if not episodes:
        raise DataError(None, "no training episodes to record coverage from", fix="check the split")
    rows = [_stack(ep.theta, omega_target(ep.theta, spec), ep.u)[1:] for ep in episodes]
    x = np.concatenate(rows)  # (n_sample, n_channel); row 0 of each episode has no velocity
    per = spec.n_u + np.flatnonzero(spec.periodic)  # periodic angles: one turn round their mean
    if per.size:
        c = np.arctan2(np.sin(x[:, per]).mean(0), np.cos(x[:, per]).mean(0))
        x[:, per] = c + wrap_angle(x[:, per] - c)
    q_lo, q_hi = np.quantile(x, QUANTILES, axis=0)
    span = q_hi - q_lo
    lo, hi = q_lo - margin * span, q_hi + margin * span
    n_joint = spec.n_joint
    grid = np.zeros((n_joint, n_bin, n_bin), dtype=np.int64)
    iu, it = np.arange(n_joint), spec.n_u + np.arange(n_joint)
    cell, inside = _cells(x[:, it], x[:, iu], lo[it], hi[it], lo[iu], hi[iu], n_bin)
    for j in range(n_joint):
        c = cell[inside[:, j], j]
        np.add.at(grid[j], (c[:, 0], c[:, 1]), 1)
    return CoverageRecord(channel_names(spec), lo, hi, grid, int(x.shape[0]), margin)


def _cells(
    theta: np.ndarray,
    u: np.ndarray,
    t_lo: np.ndarray,
    t_hi: np.ndarray,
    u_lo: np.ndarray,
    u_hi: np.ndarray,
    n_bin: int,
) -> tuple[np.ndarray, np.ndarray]:
    """Grid cell ``(..., n_joint, 2)`` (theta bin, u bin) of each sample and whether it lies in
    the box ``(..., n_joint)``."""
    inside = (theta >= t_lo) & (theta <= t_hi) & (u >= u_lo) & (u <= u_hi)
    with np.errstate(invalid="ignore", divide="ignore"):
        bt = np.floor((theta - t_lo) / np.maximum(t_hi - t_lo, 1e-12) * n_bin)
        bu = np.floor((u - u_lo) / np.maximum(u_hi - u_lo, 1e-12) * n_bin)
    bt = np.clip(np.nan_to_num(bt), 0, n_bin - 1).astype(np.int64)
    bu = np.clip(np.nan_to_num(bu), 0, n_bin - 1).astype(np.int64)
    return np.stack([bt, bu], axis=-1), inside


def ood_flags(
    rec: CoverageRecord,
    spec: MachineSpec,
    theta: np.ndarray,
    omega: np.ndarray,
    u: np.ndarray,
) -> np.ndarray:
    """Per-step, per-joint out-of-distribution flags of a free run.

    Args:
        rec: the training data's record.
        spec: the machine (joints and inputs in the record's order).
        theta: (..., n_step, n_joint) the run's angles [rad] (its own prediction).
        omega: (..., n_step, n_joint) its velocities [rad/s] (NaN during the warm-up: not
            checked).
        u: (..., n_step, n_u) the commands driving it.

    Returns:
        (..., n_step, n_joint) bool: step ``k`` of joint ``j`` is outside what training covered
        (``.any(-1)`` is the any-joint flag).
    """
    if rec.channels != channel_names(spec):
        raise CheckpointError(
            f"coverage record channels {list(rec.channels)} do not match the machine; calibrate again"
        )
    n_joint, n_u = spec.n_joint, spec.n_u
    theta = on_box_turn(rec, spec, np.asarray(theta, dtype=np.float64))
    x = _stack(theta, omega, u)
    finite = np.isfinite(x)
    out = finite & ((x < rec.lo) | (x > rec.hi))  # (..., n_step, n_channel)
    iu, it, iw = np.arange(n_joint), n_u + np.arange(n_joint), n_u + n_joint + np.arange(n_joint)
    flag = out[..., iu] | out[..., it] | out[..., iw]
    if n_u > n_joint:  # an exogenous input outside its box: every joint is off its data
        flag |= out[..., n_joint:n_u].any(-1, keepdims=True)
    cell, inside = _cells(
        x[..., it], x[..., iu], rec.lo[it], rec.hi[it], rec.lo[iu], rec.hi[iu], rec.n_bin
    )
    seen = seen_cells(rec.grid)[np.arange(n_joint), cell[..., 0], cell[..., 1]]
    return flag | (inside & ~seen)


def box_centres(rec: CoverageRecord, spec: MachineSpec) -> np.ndarray:
    """(n_joint,) the middle of each joint's angle box [rad] (the turn a periodic joint's
    angle is checked on)."""
    it = spec.n_u + np.arange(spec.n_joint)
    return 0.5 * (rec.lo[it] + rec.hi[it])


def on_box_turn(rec: CoverageRecord, spec: MachineSpec, theta: np.ndarray) -> np.ndarray:
    """``theta`` (..., n_joint) [rad] with each periodic joint's angle outside its box moved by
    whole turns to within half a turn of the box's middle ``m_j``: the network reads it as
    sin/cos, so the same pose on another turn is the same input (it had been flagged on one
    turn and not on the other).  An angle inside its box stays (a box of an unwrapped
    record may span more than a turn)::

        theta_j <- m_j + wrap(theta_j - m_j)    where theta_j is outside [lo_j, hi_j]
    """
    per = np.asarray(spec.periodic, dtype=bool)
    if not per.any():
        return theta
    it = spec.n_u + np.arange(spec.n_joint)
    m = box_centres(rec, spec)
    out = per & ((theta < rec.lo[it]) | (theta > rec.hi[it]))
    return np.where(out, m + wrap_angle(theta - m), theta)


def seen_cells(grid: np.ndarray) -> np.ndarray:
    """(n_joint, n_bin, n_bin) bool: the cell or one of its 8 neighbours held a training
    sample.  A finite training set leaves holes between the paths it took; one cell of
    tolerance keeps the flag for regions the data never came near."""
    occ = np.pad(grid > 0, ((0, 0), (1, 1), (1, 1)))
    n = grid.shape[1]
    out = np.zeros(grid.shape, dtype=bool)
    for a in range(3):
        for b in range(3):
            out |= occ[:, a : a + n, b : b + n]
    return out
