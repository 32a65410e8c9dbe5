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

A periodic joint's angle is fitted and checked on one turn, ``c_j + wrap(theta_j - c_j)``
round the circular mean ``c_j`` of its training angles (``turn_centre``), so the same pose on
any turn is one sample and every training sample lands in the cell it was counted in
(:func:`on_box_turn`).
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
    turn_centre: np.ndarray | None = None
    """(n_joint,) centre ``c_j`` [rad] of the turn each periodic joint's angles were fitted on
    (``c_j +- pi``; 0 on the other joints); None in a record written before it (its periodic
    angles are checked round the box's middle, and only when outside the box)."""

    @property
    def n_bin(self) -> int:
        """Occupancy grid bins per axis."""
        return int(self.grid.shape[1])

    def to_dict(self) -> dict[str, Any]:
        """Plain data for the checkpoint."""
        out: dict[str, Any] = {
            "channels": list(self.channels),
            "lo": [float(v) for v in self.lo],
            "hi": [float(v) for v in self.hi],
            "grid": self.grid.astype(int).tolist(),
            "n_sample": int(self.n_sample),
            "margin": float(self.margin),
            "quantiles": list(QUANTILES),
        }
        if self.turn_centre is not None:
            out["turn_centre"] = [float(v) for v in self.turn_centre]
        return out

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
                turn_centre=(
                    None
                    if d.get("turn_centre") is None
                    else np.asarray(d["turn_centre"], dtype=np.float64)
                ),
            )
        except (KeyError, TypeError, ValueError) as e:
            raise CheckpointError(f"malformed coverage record ({e}); calibrate again") from e
        n = len(rec.channels)
        if rec.lo.shape != (n,) or rec.hi.shape != (n,) or rec.grid.ndim != 3:
            raise CheckpointError("malformed coverage record (sizes disagree); calibrate again")
        if rec.turn_centre is not None and rec.turn_centre.shape != (rec.grid.shape[0],):
            raise CheckpointError(
                "malformed coverage record (turn_centre size disagrees); calibrate again"
            )
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
    n_joint = spec.n_joint
    it = spec.n_u + np.arange(n_joint)
    per = np.flatnonzero(spec.periodic)
    centre = np.zeros(n_joint)
    if per.size:
        # c_j = atan2(mean sin theta_j, mean cos theta_j), the circular mean of the training angles
        centre[per] = np.arctan2(np.sin(x[:, it[per]]).mean(0), np.cos(x[:, it[per]]).mean(0))
    # periodic angles on one turn round their mean (what on_box_turn does at check time)
    x[:, it] = on_turn(x[:, it], spec, centre)
    q_lo, q_hi = np.quantile(x, QUANTILES, axis=0)
    span = q_hi - q_lo
    lo, hi = q_lo - margin * span, q_hi + margin * span
    grid = np.zeros((n_joint, n_bin, n_bin), dtype=np.int64)
    iu = np.arange(n_joint)
    cell, inside = _cells(x[:, it], x[:, iu], lo[it], hi[it], lo[iu], hi[iu], n_bin)
    for j in range(n_joint):
        c = cell[inside[:, j], j]
        np.add.at(grid[j], (c[:, 0], c[:, 1]), 1)
    return CoverageRecord(channel_names(spec), lo, hi, grid, int(x.shape[0]), margin, centre)


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


def turn_centres(rec: CoverageRecord, spec: MachineSpec) -> tuple[np.ndarray, bool]:
    """The turn a periodic joint's angle is checked on: ``(centre, every)`` with ``centre``
    (n_joint,) [rad] and ``every`` whether every angle is moved to it.

    A record with ``turn_centre`` gives its fit centre ``c_j`` and True (the check takes each
    angle where the fit took it); an older record gives its box's middle
    ``m_j = (lo_j + hi_j) / 2`` and False (only an angle outside its box moves: such a box
    may span more than a turn).
    """
    if rec.turn_centre is not None:
        return np.asarray(rec.turn_centre, dtype=np.float64), True
    it = spec.n_u + np.arange(spec.n_joint)
    return 0.5 * (rec.lo[it] + rec.hi[it]), False


def on_turn(theta: np.ndarray, spec: MachineSpec, centre: np.ndarray) -> np.ndarray:
    """``theta`` (..., n_joint) [rad] with each periodic joint's angle moved by whole turns to
    ``[c_j - pi, c_j + pi)`` (``centre``: (n_joint,) [rad]); other joints stay::

        theta_j <- c_j + wrap(theta_j - c_j)
    """
    per = np.asarray(spec.periodic, dtype=bool)
    return np.where(per, centre + wrap_angle(theta - centre), theta)


def on_box_turn(rec: CoverageRecord, spec: MachineSpec, theta: np.ndarray) -> np.ndarray:
    """``theta`` (..., n_joint) [rad] with each periodic joint's angle moved by whole turns to
    the turn the record was fitted on (:func:`turn_centres`): the network reads it as
    sin/cos, so the same pose on another turn is the same input, and a training sample falls
    in the box and grid cell it was counted in (with the box's middle an angle in the box's
    margin beyond ``c_j +- pi`` stayed, while the fit had counted it a turn away: 9.8 % of a
    training swing flagged)::

        theta_j <- c_j + wrap(theta_j - c_j)    (record with turn_centre)
        theta_j <- m_j + wrap(theta_j - m_j)    where theta_j is outside [lo_j, hi_j] (older)
    """
    theta = np.asarray(theta, dtype=np.float64)
    if not any(spec.periodic):
        return theta
    centre, every = turn_centres(rec, spec)
    if every:
        return on_turn(theta, spec, centre)
    it = spec.n_u + np.arange(spec.n_joint)
    out = (theta < rec.lo[it]) | (theta > rec.hi[it])
    return np.where(out, on_turn(theta, spec, centre), theta)


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
