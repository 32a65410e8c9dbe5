"""Consistency-aware adaptive Kalman filtering (paper Sec. IV, Algorithm 1) and better variants.

Every filter runs independently per joint ("lane") and is vectorised over lanes: arrays are
time-major ``(n_step, n_lane)`` with ``n_lane = n_batch * n_joint``, the loop runs over time
only, and the 2x2 / 3x3 matrix algebra is written out in closed form per element (the
equation is the comment above each block, filterpy style); the kernels are in :mod:`.filters`,
this module validates the input, picks the engine and the method, and shapes the result.

Methods (``CleanConfig.method``):

``paper``
    Algorithm 1 as published: state ``s = [theta, omega]``, constant-velocity model
    ``A = [[1, Ts], [0, 1]]``, ``Q = diag(Q_theta, Q_omega)``, angle-only measurement
    ``H = [1, 0]``; R switches between ``R_trust`` and ``R_untrust`` by the jump and
    consistency tests.  The gyro is used only by the consistency test.
``gyro``
    The gyro as a control input with its bias as a state: ``s = [theta, b]``,
    ``theta_t = theta_{t-1} + Ts (omega_meas_t - b_{t-1})``, ``b_t = b_{t-1}``, i.e.
    ``A = [[1, -Ts], [0, 1]]``, ``B u = [Ts omega_meas_t, 0]``, ``H = [1, 0]``, same
    adaptive R.  Gyro white noise enters as angle process noise ``Ts^2 r_gyro``.
``gyro3``
    The gyro as a second measurement with a bias state: ``s = [theta, omega, b]``,
    ``z = [theta_meas, omega_meas]``, ``H = [[1, 0, 0], [0, 1, 1]]``,
    ``R = diag(R_t, r_gyro)``; the model follows the data convention
    ``theta_t = theta_{t-1} + Ts omega_t`` (``Q`` has the matching off-diagonal term).
    The two rows are applied as sequential scalar updates (exact for diagonal R), the gyro
    first, so the angle tests see a prior that already contains this sample's gyro reading.
``rts``
    Offline: the ``gyro`` forward filter followed by a Rauch-Tung-Striebel smoother (means
    only; trusted flags come from the forward pass).

Detection (our reading of Algorithm 1, see docs/cleaning.md).  With
``G_t = Ts * sum_{j=1..t} omega_meas_j`` (integrated gyro, ``G_0 = 0``):

- jump test: ``delta_t = |theta_t - theta_{t-1}|`` (``jump_ref="raw"``, the paper) or
  ``|theta_t - theta_prior_t|`` (``jump_ref="prior"``, the innovation); jump if
  ``delta_t > tau_jump``.
- consistency test: the angle reconstructed by integrating the gyro from the fused estimate
  ``i`` steps back is ``theta_intg_t(i) = theta_hat_{t-i} + G_t - G_{t-i}``.
  ``cons_mode="anchors"``: ``eps_t = RMS_{i=1..w}(theta_t - theta_intg_t(i))`` (the current
  sample against ``w`` gyro reconstructions); ``cons_mode="samples"`` (literal RMS over the
  last ``w`` raw samples): ``eps_t = RMS_{k=t-w+1..t}(theta_k - theta_hat_{t-w} - G_k + G_{t-w})``.
  Consistent if ``eps_t < tau_cons``.  Near the start the window shrinks to what exists.
- ``c_t = (not jump) and consistent``.  Lock-out guard: a sample that would make the run
  of untrusted samples longer than ``max_untrusted_s`` is filtered as untrusted, then the
  angle is re-anchored at it (``theta_hat = z_t``, ``P_theta = R_trust``, angle
  cross-covariances 0) and ``c_t = 1`` (else a filter that drifted during a long fault
  could reject correct data forever).

Output angular velocity is the backward difference of the fused angle,
``omega_hat_t = (theta_hat_t - theta_hat_{t-1}) / Ts`` (paper eq.), row 0 copies row 1.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from ..errors import ConfigError, DataError
from .config import CleanConfig
from .filters import forward2, forward3, rts2

LOOP_MAX_LANES = 8
"""``engine="auto"`` uses the plain per-sample loop up to this many lanes (batch x joints):
below ~15 lanes numpy's per-call overhead makes the vectorised loop slower than plain Python.
Both give bit-identical results."""


@dataclass
class FusionResult:
    """Output of :func:`fuse`; arrays have the input's shape ((n_batch,) n_step, n_joint)."""

    theta: np.ndarray
    """Fused angle theta_hat [rad]."""
    omega: np.ndarray
    """Backward difference of theta_hat [rad/s] (row 0 copies row 1)."""
    trusted: np.ndarray
    """Consistency flag c_t (bool); row 0 is always True."""
    bias: np.ndarray | None = None
    """Estimated gyro bias [rad/s] (gyro, gyro3, rts), else None."""


def backward_difference(theta: np.ndarray, dt: float, *, axis: int = 0) -> np.ndarray:
    """``(theta_t - theta_{t-1}) / dt`` along ``axis``; the first sample copies the second (0 if only one)."""
    theta = np.moveaxis(np.asarray(theta, dtype=np.float64), axis, 0)
    om = np.zeros_like(theta)
    if theta.shape[0] > 1:
        om[1:] = (theta[1:] - theta[:-1]) / dt
        om[0] = om[1]
    return np.moveaxis(om, 0, axis)


def fuse(
    theta: np.ndarray,
    omega: np.ndarray,
    *,
    dt: float,
    config: CleanConfig | None = None,
    n_valid: np.ndarray | None = None,
    engine: Literal["auto", "vector", "loop"] = "auto",
) -> FusionResult:
    """Fuse measured angles and gyro velocities with the configured filter.

    Args:
        theta: (n_batch, n_step, n_joint) or (n_step, n_joint) measured angles [rad]
            (periodic joints must already be unwrapped).
        omega: same shape, measured (gyro) angular velocities [rad/s].
        dt: sample period Ts [s].
        config: filter parameters (default :class:`CleanConfig`).
        n_valid: optional (n_batch,) number of valid leading samples per batch row (rows
            padded to a common length); padded samples are ignored and their outputs are
            meaningless.
        engine: ``vector`` (numpy over lanes, loop over time), ``loop`` (plain Python per
            sample and joint, :mod:`.reference`) or ``auto`` (``loop`` for at most
            :data:`LOOP_MAX_LANES` lanes).  Results are bit-identical.

    Returns:
        :class:`FusionResult` with the input's shape.
    """
    cfg = config or CleanConfig()
    theta = np.asarray(theta, dtype=np.float64)
    omega = np.asarray(omega, dtype=np.float64)
    squeeze = theta.ndim == 2
    if squeeze:
        theta, omega = theta[None], omega[None]
    if theta.ndim != 3 or theta.shape != omega.shape:
        raise DataError(
            None,
            f"theta {theta.shape} and omega {omega.shape} must both be (n_batch, n_step, n_joint)",
        )
    if not dt > 0:
        raise ConfigError(f"clean: dt must be positive, got {dt}")
    n_batch, n_step, n_joint = theta.shape
    if n_step == 0:
        raise DataError(None, "cannot filter an empty sequence (n_step = 0)")
    nv = (
        np.full(n_batch, n_step, dtype=np.int64)
        if n_valid is None
        else np.asarray(n_valid, np.int64)
    )
    if nv.shape != (n_batch,) or (nv < 1).any() or (nv > n_step).any():
        raise DataError(
            None, f"n_valid must be (n_batch,) = ({n_batch},) with values in [1, {n_step}]"
        )
    # time-major lanes: (n_step, n_batch * n_joint)
    z = np.ascontiguousarray(theta.transpose(1, 0, 2).reshape(n_step, n_batch * n_joint))
    g = np.ascontiguousarray(omega.transpose(1, 0, 2).reshape(n_step, n_batch * n_joint))
    lane_nv = np.repeat(nv, n_joint)
    if (lane_nv < n_step).any():  # padded tails: finite, inert values
        pad = np.arange(n_step)[:, None] >= lane_nv[None, :]
        z = np.where(pad, z[lane_nv - 1, np.arange(z.shape[1])][None, :], z)
        g = np.where(pad, 0.0, g)
    bad = ~(np.isfinite(z) & np.isfinite(g))
    if bad.any():
        k, lane = (int(x) for x in np.argwhere(bad)[0])
        raise DataError(
            None,
            f"non-finite angle or velocity at batch {lane // n_joint}, joint {lane % n_joint}",
            row=k,
            fix="fill or drop gaps before cleaning",
        )

    n_lane = n_batch * n_joint
    if engine not in ("auto", "vector", "loop"):
        raise ConfigError(f"clean: engine must be 'auto', 'vector' or 'loop', got {engine!r}")
    if engine == "loop" or (engine == "auto" and n_lane <= LOOP_MAX_LANES):
        return _fuse_loop(z, g, nv, n_joint=n_joint, dt=dt, config=cfg, squeeze=squeeze)

    bias = None
    if cfg.method == "paper":
        out = forward2(z, g, dt=dt, config=cfg, model="cv")
        th = out["theta"]
    elif cfg.method == "gyro":
        out = forward2(z, g, dt=dt, config=cfg, model="gyro")
        th, bias = out["theta"], out["x1"]
    elif cfg.method == "gyro3":
        out = forward3(z, g, dt=dt, config=cfg)
        th, bias = out["theta"], out["bias"]
    else:  # rts
        out = forward2(z, g, dt=dt, config=cfg, model="gyro", store=True)
        th, bias = rts2(out, g, dt=dt, config=cfg, model="gyro", n_valid=lane_nv)

    def back(a: np.ndarray) -> np.ndarray:
        r = a.reshape(n_step, n_batch, n_joint).transpose(1, 0, 2)
        return r[0] if squeeze else r

    theta_hat = np.ascontiguousarray(back(th))
    return FusionResult(
        theta=theta_hat,
        omega=backward_difference(theta_hat, dt, axis=-2),
        trusted=np.ascontiguousarray(back(out["trusted"])),
        bias=None if bias is None else np.ascontiguousarray(back(bias)),
    )


def _fuse_loop(
    z: np.ndarray,
    g: np.ndarray,
    nv: np.ndarray,
    *,
    n_joint: int,
    dt: float,
    config: CleanConfig,
    squeeze: bool,
) -> FusionResult:
    """:func:`fuse` with the plain-loop engine on time-major lanes (padding repeats the last row)."""
    from .reference import reference_fuse

    n_step = z.shape[0]
    n_batch = nv.shape[0]
    theta = np.empty((n_batch, n_step, n_joint))
    trusted = np.ones((n_batch, n_step, n_joint), dtype=bool)
    bias = None if config.method == "paper" else np.empty((n_batch, n_step, n_joint))
    for b in range(n_batch):
        n = int(nv[b])
        lanes = slice(b * n_joint, (b + 1) * n_joint)
        r = reference_fuse(z[:n, lanes], g[:n, lanes], dt=dt, config=config)
        theta[b, :n], theta[b, n:] = r["theta"], r["theta"][-1]
        trusted[b, :n] = r["trusted"]
        if bias is not None:
            bias[b, :n], bias[b, n:] = r["bias"], r["bias"][-1]
    if squeeze:
        theta, trusted = theta[0], trusted[0]
        bias = None if bias is None else bias[0]
    return FusionResult(
        theta=theta,
        omega=backward_difference(theta, dt, axis=-2),
        trusted=trusted,
        bias=bias,
    )
