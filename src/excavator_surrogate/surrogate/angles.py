"""Joint angles and speeds: the training target, the machine's envelope and the closed loop's
integration step.

Data convention (the same as :mod:`.features`): sample ``k`` holds ``theta[k]`` (angle at
``t_k``) and ``omega[k]`` (mean velocity over ``[t_{k-1}, t_k]``).  The training target is the
backward difference of the angle, ``omega_tgt[k] = wrap(theta[k] - theta[k-1]) / T_s`` (``wrap``
only for periodic joints), so integrating it, ``theta[k+1] = theta[k] + T_s * omega_tgt[k+1]``,
reproduces the angles exactly.  Every closed loop (free run, envs, engine, ONNX, training's
free-run mode) takes that step through :func:`integrate` (or its NumPy twin), which also
applies the end stops and speed bounds of :func:`envelope`.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from ..spec import MachineSpec


def wrap_angle(d: np.ndarray) -> np.ndarray:
    """Wrap angle differences to ``[-pi, pi)`` [rad]."""
    return (np.asarray(d) + math.pi) % (2.0 * math.pi) - math.pi


def wrap_periodic(d: np.ndarray, periodic: np.ndarray | tuple[bool, ...]) -> np.ndarray:
    """``d`` (..., n_joint) with the periodic joints' entries wrapped to ``[-pi, pi)`` [rad]
    (``periodic``: (n_joint,) flags, e.g. ``spec.periodic``): the shorter way round."""
    return np.where(np.asarray(periodic, dtype=bool), wrap_angle(d), d)


def omega_target(theta: np.ndarray, spec: MachineSpec) -> np.ndarray:
    """Training target: backward difference of the angle.

    Args:
        theta: (n_step, n_joint) angles [rad]; periodic joints may be wrapped or unwrapped.
        spec: the machine (``periodic`` flags, ``dt``).

    Returns:
        (n_step, n_joint) ``omega_tgt`` [rad/s]; row ``k >= 1`` is
        ``wrap(theta[k] - theta[k-1]) / T_s``; row 0 is NaN (no previous sample; never a target).
    """
    theta = np.asarray(theta, dtype=np.float64)
    d = np.diff(theta, axis=0)
    per = np.asarray(spec.periodic, dtype=bool)
    if per.any():
        d[:, per] = wrap_angle(d[:, per])
    out = np.full_like(theta, np.nan)
    out[1:] = d / spec.dt
    return out


def joint_limits(spec: MachineSpec) -> tuple[np.ndarray, np.ndarray]:
    """Mechanical end stops ``(lo, hi)``, each ``(n_joint,)`` [rad]; ``-inf`` / ``+inf`` for
    periodic joints and for limits the spec leaves open (``None``)."""
    lo = [
        -math.inf if j.periodic or j.theta_min is None else float(j.theta_min) for j in spec.joints
    ]
    hi = [
        math.inf if j.periodic or j.theta_max is None else float(j.theta_max) for j in spec.joints
    ]
    return np.array(lo), np.array(hi)


def speed_limits(spec: MachineSpec) -> np.ndarray:
    """Largest angular speed per joint ``(n_joint,)`` [rad/s]; ``+inf`` where the spec has none."""
    return np.array([math.inf if j.omega_max is None else float(j.omega_max) for j in spec.joints])


def envelope(spec: MachineSpec) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The machine's physical envelope ``(lo, hi, omega_max)``, each ``(n_joint,)``: end stops
    [rad] (:func:`joint_limits`) and speed bounds [rad/s] (:func:`speed_limits`)."""
    lo, hi = joint_limits(spec)
    return lo, hi, speed_limits(spec)


def envelope_inward(
    lim: tuple[np.ndarray, ...], *, dtype: torch.dtype, device: torch.device | str | None = None
) -> tuple[torch.Tensor, ...]:
    """The envelope ``lim`` (``(lo, hi[, omega_max])`` float64, as :meth:`Surrogate.limits_np`
    gives it) as ``dtype`` tensors, each bound moved to the inside where the cast rounds it
    outward (float32's nearest 2.65 is 2.6500001): an angle clipped to them reads inside the
    float64 limits, so an env at its own end stop reports no limit violation."""
    out = []
    for k, a in enumerate(lim):
        t = torch.as_tensor(a, dtype=dtype, device=device)
        back = t.double().cpu().numpy()
        outside = back < a if k == 0 else back > a  # lo rounded down; hi, omega_max up
        toward = torch.full_like(t, math.inf if k == 0 else -math.inf)
        t = torch.where(torch.as_tensor(outside, device=t.device), torch.nextafter(t, toward), t)
        out.append(t)
    return tuple(out)


Limits = tuple[torch.Tensor, torch.Tensor] | tuple[torch.Tensor, torch.Tensor, torch.Tensor]
"""``(lo, hi)`` end stops [rad], optionally with ``omega_max`` [rad/s], each (n_joint,)."""


def integrate(
    theta: torch.Tensor,
    omega: torch.Tensor,
    *,
    dt: float,
    limits: Limits | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """One integration step of the closed loop, with optional end stops and speed bounds.

    Args:
        theta: (..., n_joint) angle ``theta[k]`` [rad].
        omega: (..., n_joint) predicted ``omega[k+1]`` [rad/s].
        dt: sample period T_s [s].
        limits: ``(lo, hi)`` or ``(lo, hi, omega_max)``, each (n_joint,) (see :func:`envelope`),
            or None.

    Returns:
        ``theta[k+1]`` [rad] and the velocity the sensors would report, ``omega[k+1]`` [rad/s]:
        the prediction clipped to ``[-omega_max, omega_max]``, except at an end stop, where it
        is what was actually travelled.
    """
    if limits is None:
        # theta[k+1] = theta[k] + T_s * omega[k+1]
        return theta + dt * omega, omega
    lo, hi = limits[0], limits[1]
    if len(limits) == 3:
        # omega[k+1] <- min(max(omega[k+1], -omega_max), omega_max)       (speed bound)
        omega = torch.minimum(torch.maximum(omega, -limits[2]), limits[2])
    # theta[k+1] = theta[k] + T_s * omega[k+1]
    nxt = theta + dt * omega
    # theta[k+1] <- min(max(theta[k+1], theta_min), theta_max)        (end stops)
    stopped = torch.minimum(torch.maximum(nxt, lo), hi)
    hit = stopped != nxt
    # omega[k+1] = (theta[k+1] - theta[k]) / T_s                     (only where a stop was hit)
    omega = torch.where(hit, (stopped - theta) / dt, omega)
    return stopped, omega


def integrate_np(
    theta: np.ndarray,
    omega: np.ndarray,
    *,
    dt: float,
    limits: tuple[np.ndarray, ...] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """NumPy twin of :func:`integrate` (the plain-loop reference uses it)."""
    if limits is None:
        return theta + dt * omega, omega
    if len(limits) == 3:
        omega = np.minimum(np.maximum(omega, -limits[2]), limits[2])
    nxt = theta + dt * omega
    stopped = np.minimum(np.maximum(nxt, limits[0]), limits[1])
    hit = stopped != nxt
    return stopped, np.where(hit, (stopped - theta) / dt, omega)


def omega_in_np(theta: np.ndarray, spec: MachineSpec) -> np.ndarray:
    """The velocity input feature of every sample: :func:`omega_target` with row 0 set to 0
    (an episode starts at rest).  ``theta: (n_step, n_joint)`` [rad] -> ``(n_step, n_joint)``
    [rad/s]."""
    out = omega_target(theta, spec)
    out[:1] = 0.0
    return out


def unwrap_periodic(theta: np.ndarray, spec: MachineSpec) -> np.ndarray:
    """Unwrap periodic joints along the time axis (-2): ``(..., n_step, n_joint)`` [rad]."""
    theta = np.array(theta, dtype=np.float64, copy=True)
    for j, p in enumerate(spec.periodic):
        if p:
            theta[..., j] = np.unwrap(theta[..., j], axis=-1)
    return theta
