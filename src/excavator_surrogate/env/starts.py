"""Where an episode starts: a pose at rest, or a recorded history.

:func:`check_theta0` validates a start pose at rest (``options["theta0"]``), for both
environments.  Angles are in rad and a linear joint's stroke in m, as stored; the messages
give a stroke, its distance beyond a stop and its jumps in the joint's printed unit (mm ...).

``reset(options={"history": {"theta": theta, "u": u}})`` warms the surrogate up on the
machine's own samples: ``theta`` (n_hist, n_joint) [rad] are ``theta[0..n_hist-1]`` and
``u`` (n_hist - 1, n_u) [command units] the commands ``u[0..n_hist-2]`` between them (the
joints', then any exogenous inputs', as in the dataset).  The episode then starts at
``theta[n_hist-1]`` with ``ω = wrap(theta[n_hist-1] - theta[n_hist-2]) / T_s``, the
observation's definition of ω, and stepping the recorded commands ``u[n_hist-1:]``
continues the free run ``exsur evaluate`` makes with ``warmup = n_hist``
(:class:`~excavator_surrogate.surrogate.rollout.ClosedLoop`).  A controller can so start
mid-cycle, from states the machine was really in, under load.

Only the surrogate can start this way: a log does not hold the plant's hidden state (servo
setpoints, the actuator's delay line, the hydraulic transform's memory), so
``ExcavatorMujoco-v0`` refuses it with one line.

:class:`RecordedStarts` (the surrogate envs' ``recorded_starts=``) draws such histories at
random from a dataset's logs, for the resets that give neither a pose nor a history.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from ..data.episode import Episode
from ..errors import ConfigError
from ..spec import JointSpec, MachineSpec
from ..surrogate.angles import joint_limits, wrap_periodic

THETA0_SLACK = 0.02
"""A given start pose may lie this fraction of a joint's range beyond its end stop: it starts
at the stop, and a warning says so (a pose read off a log at a stop, plus sensor noise, or
a model whose stops are its training data's range).  Farther out is an error."""


def _sig(x: float) -> str:
    """``x`` to 4 significant digits, without an exponent below 1e6 (``40000``, ``968.3``)."""
    return f"{float(f'{x:.4g}'):.6g}"


def shown(j: JointSpec, x: float) -> str:
    """A start value of joint ``j`` as the env takes it, ``0.5 rad`` or ``2 m``; a stroke
    printed in cm or mm names that too (``2 m (2000 mm)``)."""
    if not j.linear:
        return f"{x:.4g} rad"
    if j.display_factor == 1.0:
        return f"{x:.4g} m"
    return f"{x:.4g} m ({_sig(x * j.display_factor)} {j.display_unit})"


def distance(j: JointSpec, d: float) -> str:
    """How far ``d`` [rad or m] a value of joint ``j`` lies beyond a stop: in deg for an angle,
    in the joint's printed unit for a stroke (``968.3 mm``)."""
    if not j.linear:
        return f"{math.degrees(d):.3g} deg"
    return f"{_sig(d * j.display_factor)} {j.display_unit}"


def overshoot(spec: MachineSpec, beyond: np.ndarray) -> str:
    """The largest of ``beyond`` (..., n_joint) [rad or m], how far start values were put back
    at their stops: the angles' largest in deg (``1.05 deg``), each stroke's in its unit with
    its name (``18.3 mm (boom)``), joined by commas; joints not moved are left out."""
    worst = np.abs(beyond).reshape(-1, spec.n_joint).max(axis=0)
    angles = [w for j, w in zip(spec.joints, worst) if not j.linear and w > 0]
    parts = [f"{math.degrees(max(angles)):.3g} deg"] if angles else []
    parts += [
        f"{distance(j, w)} ({j.name})" for j, w in zip(spec.joints, worst) if j.linear and w > 0
    ]
    return ", ".join(parts)


def check_theta0(spec: MachineSpec, theta0: Any, *, where: str, warn: bool = True) -> np.ndarray:
    """Validate a start pose: (n_joint,) finite, limited joints inside their limits.

    A limited joint up to :data:`THETA0_SLACK` of its range beyond a limit starts at that
    limit, with one warning naming the joint and the distance (``warn=False``: no warning,
    the caller says it); farther out raises.

    Returns:
        The pose (n_joint,) [rad], float64, clipped into the limits.
    """
    try:
        th = np.asarray(theta0, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):  # text, ragged lists, None entries
        th = np.full(0, np.nan)
    if th.shape != (spec.n_joint,) or not np.isfinite(th).all():
        what = "angles in rad" if not spec.any_linear else "values (angles in rad, strokes in m)"
        raise ConfigError(
            f"{where}: theta0 must be {spec.n_joint} finite {what} for joints "
            f"{list(spec.names)}, got {theta0!r:.200}"
        )
    th = th.copy()
    for k, (j, lo, hi) in enumerate(zip(spec.joints, *joint_limits(spec))):
        # lo, hi = -inf, +inf for a periodic joint or an open limit: never beyond
        span = hi - lo
        slack = THETA0_SLACK * span if math.isfinite(span) else 0.0
        beyond = max(lo - th[k], th[k] - hi)
        if beyond <= 1e-9:
            continue
        if beyond > slack + 1e-9:
            raise ConfigError(
                f"{where}: theta0[{k}] ({j.name}) = {shown(j, th[k])} is outside the joint "
                f"limits {_limits(j)} by {distance(j, beyond)}, more than "
                f"{THETA0_SLACK:.0%} of the range: give a start pose inside them"
            )
        stop = lo if th[k] < lo else hi
        if warn:
            gym.logger.warn(
                f"{where}: theta0[{k}] ({j.name}) = {shown(j, th[k])} is "
                f"{distance(j, beyond)} beyond its end stop {shown(j, stop)}: it starts at the "
                "stop"
            )
        th[k] = stop
    return th


def _limits(j: JointSpec) -> str:
    """Joint ``j``'s limits as the messages print them: ``[lo, hi]`` in rad for an angle (as
    stored), in the printed unit for a stroke (``[250.7, 2031.7] mm``)."""
    if not j.linear:
        return f"[{j.theta_min}, {j.theta_max}]"
    f = j.display_factor
    lo, hi = (None if v is None else f"{v * f:.6g}" for v in (j.theta_min, j.theta_max))
    return f"[{lo}, {hi}] {j.display_unit}"


def _array(value: Any, *, what: str, where: str) -> np.ndarray:
    try:
        return np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):  # text, ragged lists, None entries
        raise ConfigError(f"{where}: history['{what}'] must be an array of numbers") from None


def check_history(
    spec: MachineSpec,
    history: Any,
    *,
    where: str,
    n_envs: int | None = None,
    omega_max: float | None = None,
    warn: bool = True,
) -> tuple[np.ndarray, np.ndarray]:
    """Validate ``options["history"]``.

    Args:
        spec: the machine (joints, command and input ranges, rate).
        history: a mapping with ``theta`` (n_hist, n_joint) [rad] and ``u`` (n_hist - 1,
            n_u) [command units]; with ``n_envs``, also one per env: (n_envs, n_hist,
            n_joint) and (n_envs, n_hist - 1, n_u).
        where: prefix of the error message (the env and the call).
        n_envs: the vector env's size (None: a single env).
        omega_max: the fastest a joint may move between two samples [rad/s] (the divergence
            guard's; None: unchecked): a faster step is a jump in the log, refused.
        warn: warn when a last angle is put at a stop (False: silently, for recorded starts).

    Returns:
        ``(theta, u)``, (n_hist, n_joint) and (n_hist - 1, n_u), or with ``n_envs`` (n_envs,
        n_hist, n_joint) and (n_envs, n_hist - 1, n_u), float64 (one history for every env:
        checked once, returned as read-only broadcasts).  The last angle of each history
        passes :func:`check_theta0` (a limited joint up to 2 % of its range beyond a stop is
        put at the stop; farther out raises).

    Raises:
        ConfigError: one line naming the entry, the sample and the joint or command.
    """
    if not isinstance(history, Mapping) or set(history) != {"theta", "u"}:
        got = sorted(history) if isinstance(history, Mapping) else type(history).__name__
        raise ConfigError(
            f"{where}: options['history'] must be a dict with 'theta' (n_hist, n_joint) [rad] "
            f"and 'u' (n_hist-1, n_u) [command units], got {got}"
        )
    theta = _array(history["theta"], what="theta", where=where)
    u = _array(history["u"], what="u", where=where)
    n_joint, n_u = spec.n_joint, spec.n_u
    batched = n_envs is not None and (theta.ndim == 3 or u.ndim == 3)
    if batched and theta.ndim == 2:  # one angle history, per-env commands
        theta = np.broadcast_to(theta, (n_envs, *theta.shape))
    # one history for every env is checked once, and broadcast at the end
    lead = (n_envs,) if batched else ()
    shape_ok = (
        theta.ndim == len(lead) + 2
        and theta.shape[: len(lead)] == lead
        and theta.shape[-1] == n_joint
        and theta.shape[-2] >= 2
        and u.shape == (*lead, theta.shape[-2] - 1, n_u)
    )
    if not shape_ok:
        per_env = f" (or with a first axis of {n_envs} envs)" if n_envs is not None else ""
        raise ConfigError(
            f"{where}: options['history'] needs 'theta' (n_hist >= 2, {n_joint}) [rad] and "
            f"'u' (n_hist - 1, {n_u}) [command units]{per_env}, got {theta.shape} and {u.shape}"
        )
    for name, a in (("theta", theta), ("u", u)):
        bad = np.argwhere(~np.isfinite(a))
        if bad.size:
            raise ConfigError(f"{where}: history['{name}']{[int(i) for i in bad[0]]} is not finite")
    lo = np.array([s.u_min for s in spec.u_specs])
    hi = np.array([s.u_max for s in spec.u_specs])
    out = np.argwhere((u < lo) | (u > hi))
    if out.size:
        at = tuple(int(i) for i in out[0])
        col = spec.u_specs[at[-1]]
        raise ConfigError(
            f"{where}: history['u']{list(at)} ({col.name}) = {u[at]:.6g} is outside its range "
            f"[{col.u_min:g}, {col.u_max:g}]: give the commands in the machine's command units, "
            "clipped into the range"
        )
    if omega_max is not None:
        speed = np.abs(velocities(spec, theta))  # (..., n_hist - 1, n_joint)
        fast = np.argwhere(speed > omega_max)
        if fast.size:
            at = tuple(int(i) for i in fast[0])
            env = f" env {at[0]}" if len(at) == 3 else ""
            j = spec.joints[at[-1]]
            # the guard's bound is one number in stored units: rad/s, or m/s for a stroke
            fast_at, bound = f"{speed[at]:.3g} rad/s", f"{omega_max:g}"
            if j.linear:
                f = j.display_factor
                fast_at = f"{_sig(speed[at] * f)} {j.rate_unit}"
                bound = f"{omega_max:g} m/s"
                if f != 1.0:
                    bound += f" = {_sig(omega_max * f)} {j.rate_unit}"
            raise ConfigError(
                f"{where}{env}: history['theta'] of {j.name} jumps between samples "
                f"{at[-2]} and {at[-2] + 1} ({fast_at}, beyond the guard's omega_max {bound}): a "
                "jump in the log; clean it (exsur clean) or start from a stretch without one"
            )
    theta = np.array(theta, dtype=np.float64)  # a writable copy (broadcasts are read-only)
    u = np.array(u, dtype=np.float64)
    rows = theta.reshape(-1, *theta.shape[-2:])
    clipped, moved = [], np.zeros((len(rows), n_joint))
    for i, th in enumerate(rows):
        who = f"{where} env {i}" if batched else where
        last = check_theta0(spec, th[-1], where=f"{who} history['theta'][-1]", warn=False)
        if not np.array_equal(last, th[-1]):
            clipped.append(i)
            moved[i] = last - th[-1]
        th[-1] = last
    if warn and clipped:  # one warning for all of them
        if n_envs is not None:  # one history for all: each env's is clipped alike
            n, first = (len(clipped), clipped[0]) if batched else (n_envs, 0)
            whose = f"the histories of {n} env(s) (first: env {first}) end"
        else:
            whose = "the history ends"
        gym.logger.warn(
            f"{where}: {whose} up to {overshoot(spec, moved)} beyond an end stop: it starts at "
            "the stop"
        )
    if n_envs is not None and not batched:
        theta = np.broadcast_to(theta, (n_envs, *theta.shape))
        u = np.broadcast_to(u, (n_envs, *u.shape))
    return theta, u


def warn_short_history(n_hist: int, window: int, *, where: str) -> None:
    """A warning when a history is shorter than the model's window ``W``: the warm-up is then
    padded with its first sample, unlike the one ``exsur evaluate`` validated."""
    if n_hist < window:
        gym.logger.warn(
            f"{where}: options['history'] has {n_hist} samples, fewer than the model's window "
            f"W = {window}: its warm-up is padded with the first sample; give {window} samples "
            "for the warm-up the model was validated with"
        )


def velocities(spec: MachineSpec, theta: np.ndarray) -> np.ndarray:
    """``wrap(theta[k] - theta[k-1]) / T_s`` [rad/s] along a history (..., n_hist, n_joint)
    [rad] -> (..., n_hist - 1, n_joint), ``wrap`` on periodic joints: the observation's ω."""
    d = theta[..., 1:, :] - theta[..., :-1, :]
    return wrap_periodic(d, spec.periodic) / spec.dt


def last_velocity(spec: MachineSpec, theta: np.ndarray) -> np.ndarray:
    """The last of :func:`velocities`: the ω a history (..., n_hist, n_joint) [rad] ends
    with [rad/s]."""
    return velocities(spec, theta[..., -2:, :])[..., 0, :]


class RecordedStarts:
    """Random starts at recorded moments of a machine's logs, for resets without a pose.

    Each draw picks one of the episodes' moments ``k`` uniformly over all of them (every
    sample with ``window - 1`` samples before it whose angles a start pose may take:
    :func:`check_theta0`) and returns the history that ends there,
    ``theta[k - window + 1 .. k]`` and ``u[k - window + 1 .. k - 1]``: an RL policy or a
    controller then trains and is tested from the states the machine was really in (moving,
    loaded, at the poses operators use), not only from rest.

    Args:
        source: a dataset folder (its ``split`` is read) or the episodes themselves.
        spec: the surrogate's machine; episodes of another machine or rate are refused.
        window: samples of each history (the surrogate's ``W``).
        split: the split of a dataset folder (default ``train``: the states the model knows).
    """

    def __init__(
        self,
        source: str | Path | Sequence[Episode],
        *,
        spec: MachineSpec,
        window: int,
        split: str = "train",
    ) -> None:
        if isinstance(source, str | Path):
            from ..data.dataset import load_dataset

            episodes: Sequence[Episode] = load_dataset(source, splits=(split,)).split(split)
            where = f"{source} ({split} split)"
        else:
            episodes, where = list(source), "recorded_starts"
        self.window = max(2, int(window))
        for ep in episodes:
            diff = spec.mismatch(ep.spec)
            if diff is not None:
                raise ConfigError(
                    f"{where}: episode '{ep.name}' is of another machine than the surrogate "
                    f"({diff}, surrogate vs episode): start from logs of the machine it models"
                )
        # a moment whose angle lies beyond a joint's stop by more than a start pose may (a
        # test split's run past the training's range) is not drawn: the reset would refuse it
        lo, hi = joint_limits(spec)
        span = np.where(np.isfinite(hi - lo), hi - lo, 0.0)
        lo, hi = lo - THETA0_SLACK * span, hi + THETA0_SLACK * span
        self.episodes: list[Episode] = []
        self._moments: list[np.ndarray] = []
        """Per kept episode, the samples ``k`` a draw may end at."""
        for ep in episodes:
            inside = ((ep.theta >= lo) & (ep.theta <= hi)).all(axis=1)
            k = np.flatnonzero(inside[self.window - 1 :]) + self.window - 1
            if len(k):
                self.episodes.append(ep)
                self._moments.append(k)
        if not self._moments:
            raise ConfigError(
                f"{where}: no episode has the {self.window} samples a recorded start needs, "
                "ending inside the joint limits"
            )
        self._cum = np.cumsum([len(k) for k in self._moments])
        """Running count of the moments, per episode (a draw's index falls into one)."""

    @property
    def n_moment(self) -> int:
        """How many moments a draw picks from."""
        return int(self._cum[-1])

    def draw(self, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """One history: ``theta`` (window, n_joint) [rad] and ``u`` (window - 1, n_u)."""
        r = int(rng.integers(self.n_moment))
        e = int(np.searchsorted(self._cum, r, side="right"))
        k = int(self._moments[e][r - (int(self._cum[e - 1]) if e else 0)])  # the moment
        ep = self.episodes[e]
        lo = k - self.window + 1
        return np.array(ep.theta[lo : k + 1], dtype=np.float64), np.array(ep.u[lo:k], np.float64)
