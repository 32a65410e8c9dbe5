"""The toolkit every excitation signal is built with: seeds, defaults, end-stop avoidance.

Limit avoidance ("fold"): the plant is, up to its 50 ms delay and a stiff servo lag, an
integrator ``theta' = omega_max * u / u_max``.  :func:`fold_limits` integrates this nominal
model and, whenever the nominal angle would leave ``[theta_min + margin, theta_max - margin]``,
mirrors the joint's command (multiplies it by -1 from then on), so the joint bounces off the
soft limit instead of sitting pinned at the end stop.  Generators are additionally designed
so that folding is rare (angle-sized sinusoids centred in the range).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from ..errors import ConfigError
from ..spec import JointSpec, MachineSpec

RngLike = np.random.Generator | int | None
VelocityMap = Callable[[np.ndarray], np.ndarray]
"""Nominal steady joint velocity [rad/s] of commands ``(n_step, n_joint)`` (element-wise map)."""


def as_rng(rng: RngLike) -> np.random.Generator:
    """A Generator from a Generator, an int seed or None (fresh entropy)."""
    if isinstance(rng, np.random.Generator):
        return rng
    return np.random.default_rng(rng)


def is_limited(j: JointSpec) -> bool:
    """True if the joint has both end stops."""
    return j.theta_min is not None and j.theta_max is not None


def joint_span(j: JointSpec) -> float:
    """Joint range [rad]; 2 pi for unlimited joints."""
    if is_limited(j):
        return float(j.theta_max) - float(j.theta_min)  # type: ignore[arg-type]
    return 2.0 * np.pi


def resolve_defaults(
    spec: MachineSpec,
    theta0: Sequence[float] | np.ndarray | None,
    omega_max: Sequence[float] | np.ndarray | None,
) -> tuple[np.ndarray, np.ndarray | None]:
    """``(theta0, omega_max)`` checked as (n_joint,) arrays; ``theta0`` defaults to mid-range."""
    if theta0 is None:
        theta0 = np.array(
            [0.5 * (j.theta_min + j.theta_max) if is_limited(j) else 0.0 for j in spec.joints]  # type: ignore[operator]
        )
    theta0 = np.asarray(theta0, dtype=np.float64)
    if theta0.shape != (spec.n_joint,):
        raise ConfigError(f"theta0 must have shape ({spec.n_joint},), got {theta0.shape}")
    if omega_max is not None:
        omega_max = np.asarray(omega_max, dtype=np.float64)
        if omega_max.shape != (spec.n_joint,) or np.any(omega_max <= 0):
            raise ConfigError(
                f"omega_max must be {spec.n_joint} positive speeds [rad/s], got {omega_max}"
            )
    return theta0, omega_max


def nominal_speed(spec: MachineSpec, omega_max: np.ndarray | None) -> np.ndarray:
    """(n_joint,) rad/s per command unit of the nominal integrator model."""
    if omega_max is None:
        # No plant information: assume full range in 5 s, only used to size signals.
        return np.array([joint_span(j) / 5.0 / j.u_max for j in spec.joints])
    return omega_max / np.array([j.u_max for j in spec.joints])


def clip_commands(u: np.ndarray, spec: MachineSpec) -> np.ndarray:
    """Clip ``u: (n_step, n_joint)`` into each joint's ``[u_min, u_max]``."""
    lo = np.array([j.u_min for j in spec.joints])
    hi = np.array([j.u_max for j in spec.joints])
    return np.clip(u, lo, hi)


def fold_limits(
    u: np.ndarray,
    spec: MachineSpec,
    *,
    theta0: np.ndarray,
    omega_max: np.ndarray | None,
    limit_margin: float = 0.05,
    lookahead: float = 0.5,
    velocity_map: VelocityMap | None = None,
) -> np.ndarray:
    """Mirror each limited joint's command whenever its nominal angle would leave the soft range.

    The nominal angle integrates ``omega_max * u / u_max``.  The command's sign is flipped
    (for the rest of the episode, until the next flip) when, with the current sign, the
    nominal angle would leave ``[min + margin, max - margin]`` within the next ``lookahead``
    seconds of the command sequence, and in any case before it leaves the band.  If the
    command value changed less than ``lookahead`` seconds before a flip, the flip is moved
    back to that change, so a step that would run into a limit is usually reversed from its
    start.  The rewind reaches only the last change of the *raw* command, once per run: a
    flip due shortly before the next raw change, or a second flip in one run, stays where it
    falls, and the output can hold pulses as short as one sample (docs/plant.md, Known
    limitations; left so that simulated datasets stay as they are).

    Args:
        u: (n_step, n_joint) commands.
        spec: machine spec (limits, command ranges, ``dt``).
        theta0: (n_joint,) initial angles [rad].
        omega_max: (n_joint,) speed at ``u_max`` [rad/s]; ``None`` returns ``u`` unchanged.
        limit_margin: distance kept from each end stop [rad].
        lookahead: horizon [s] of the early reversal and shortest folded pulse.
        velocity_map: nominal velocity of a command for a nonlinear plant (e.g. the
            hydraulic static map with dead zones and direction-dependent speeds); the
            nominal angle then integrates ``velocity_map(u)`` instead of the linear model.

    Returns:
        (n_step, n_joint) commands whose nominal angle stays in ``[min + margin, max - margin]``
        (a joint starting outside that band is only allowed to move back into it).
    """
    if omega_max is None:
        return u
    if velocity_map is not None:
        return _fold_mapped(
            u,
            spec,
            theta0=theta0,
            velocity_map=velocity_map,
            limit_margin=limit_margin,
            lookahead=lookahead,
        )
    raw = np.asarray(u, dtype=np.float64)
    u = raw.copy()
    n_step = u.shape[0]
    gain = nominal_speed(spec, omega_max) * spec.dt
    n_look = max(1, round(lookahead / spec.dt))
    for k, j in enumerate(spec.joints):
        if not is_limited(j):
            continue
        lo = float(j.theta_min) + limit_margin  # type: ignore[arg-type]
        hi = float(j.theta_max) - limit_margin  # type: ignore[arg-type]
        col = raw[:, k]
        out = u[:, k]
        # future excursions of the raw command: max/min over m in (i, i + n_look] of S[m] - S[i]
        csum = np.concatenate([[0.0], np.cumsum(col), np.zeros(n_look)])
        csum[n_step + 1 :] = csum[n_step]
        win = np.lib.stride_tricks.sliding_window_view(csum[1:], n_look)[:n_step]
        up = (win.max(axis=1) - csum[:n_step]) * gain[k]
        down = (win.min(axis=1) - csum[:n_step]) * gain[k]
        th = float(theta0[k])
        sign = 1.0
        run_start, th_run, rewound = 0, th, -1
        i = 0
        while i < n_step:
            if i > 0 and col[i] != col[i - 1] and i != run_start:
                run_start, th_run = i, th
            rise, fall = (up[i], down[i]) if sign > 0 else (-down[i], -up[i])
            leaves = th + rise > hi or th + fall < lo
            flip = leaves and th - fall <= hi and th - rise >= lo  # mirrored future fits
            c = sign * col[i]
            nxt = th + gain[k] * c
            overflow = (c > 0 and nxt > hi) or (c < 0 and nxt < lo)
            if (flip or overflow) and run_start < i < run_start + n_look and rewound != run_start:
                sign, th, rewound, i = (
                    -sign,
                    th_run,
                    run_start,
                    run_start,
                )  # flip from the run start
                continue
            if flip or overflow:
                sign = -sign
                c = -c
                nxt = th + gain[k] * c
                if (c > 0 and nxt > hi) or (c < 0 and nxt < lo):  # cannot move either way: hold
                    c, nxt = 0.0, th
            out[i] = c
            th = nxt
            i += 1
    return clip_commands(u, spec)


@dataclass(frozen=True)
class NominalModel:
    """Nominal joint model of a non-ideal plant, used to keep excitation off the end stops.

    Callable like a :data:`VelocityMap`; pass it as ``velocity_map``.
    """

    velocity: VelocityMap
    """Steady joint velocity [rad/s] of commands ``(n_step, n_joint)`` (element-wise map)."""
    accel_max: tuple[float, ...] | None = None
    """Per-joint largest rate of change of the velocity [rad/s^2] (None: unlimited)."""

    def __call__(self, u: np.ndarray) -> np.ndarray:
        """Steady velocity of ``u``."""
        return self.velocity(u)


def _fold_mapped(
    u: np.ndarray,
    spec: MachineSpec,
    *,
    theta0: np.ndarray,
    velocity_map: VelocityMap,
    limit_margin: float,
    lookahead: float,
) -> np.ndarray:
    """:func:`fold_limits` for a nonlinear, direction-dependent nominal model.

    Same algorithm; the nominal velocity is ``velocity_map(+-u)`` (command as given or
    mirrored) instead of ``omega_max * (+-u) / u_max``, approached at the rate
    ``velocity_map.accel_max`` if given (:class:`NominalModel`), and the distance needed to
    stop, ``v |v| / (2 a)``, is added before testing the limits.
    """
    raw = np.asarray(u, dtype=np.float64)
    u = raw.copy()
    n_step = u.shape[0]
    dt = spec.dt
    vel_pos = np.asarray(velocity_map(raw), dtype=np.float64)  # sign +1 [rad/s]
    vel_neg = np.asarray(velocity_map(-raw), dtype=np.float64)  # mirrored
    accel_max = getattr(velocity_map, "accel_max", None)
    accel = (
        np.full(spec.n_joint, np.inf)
        if accel_max is None
        else np.asarray(accel_max, dtype=np.float64).reshape(spec.n_joint)
    )
    n_look = max(1, round(lookahead / dt))

    def excursions(inc: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        csum = np.concatenate([[0.0], np.cumsum(inc), np.zeros(n_look)])
        csum[n_step + 1 :] = csum[n_step]
        win = np.lib.stride_tricks.sliding_window_view(csum[1:], n_look)[:n_step]
        return win.max(axis=1) - csum[:n_step], win.min(axis=1) - csum[:n_step]

    for k, j in enumerate(spec.joints):
        if not is_limited(j):
            continue
        lo = float(j.theta_min) + limit_margin  # type: ignore[arg-type]
        hi = float(j.theta_max) - limit_margin  # type: ignore[arg-type]
        col = raw[:, k]
        out = u[:, k]
        ex = {1.0: excursions(vel_pos[:, k] * dt), -1.0: excursions(vel_neg[:, k] * dt)}
        vels = {1.0: vel_pos[:, k], -1.0: vel_neg[:, k]}
        a_k = float(accel[k])
        dv = a_k * dt  # largest velocity change per step

        if np.isfinite(a_k):

            def stop(v: float, a_k: float = a_k) -> float:
                return v * abs(v) / (2.0 * a_k)

            def advance(v: float, target: float, dv: float = dv) -> float:
                return v + min(max(target - v, -dv), dv)

        else:

            def stop(v: float, a_k: float = a_k) -> float:
                return 0.0

            def advance(v: float, target: float, dv: float = dv) -> float:
                return target

        def over(v: float, nxt: float, lo: float = lo, hi: float = hi) -> bool:
            end = nxt + stop(v)
            return (v > 0 and end > hi) or (v < 0 and end < lo)

        th = float(theta0[k])
        v = 0.0
        sign = 1.0
        run_start, th_run, v_run, rewound = 0, th, v, -1
        i = 0
        while i < n_step:
            if i > 0 and col[i] != col[i - 1] and i != run_start:
                run_start, th_run, v_run = i, th, v
            rise, fall = ex[sign][0][i], ex[sign][1][i]
            m_rise, m_fall = ex[-sign][0][i], ex[-sign][1][i]
            th_stop = th + stop(v)
            leaves = th + rise > hi or th + fall < lo
            flip = leaves and th_stop + m_rise <= hi and th_stop + m_fall >= lo  # mirrored fits
            c = sign * col[i]
            v_new = advance(v, vels[sign][i])
            nxt = th + v_new * dt
            overflow = over(v_new, nxt)
            if (flip or overflow) and run_start < i < run_start + n_look and rewound != run_start:
                sign, th, v, rewound, i = -sign, th_run, v_run, run_start, run_start
                continue
            if flip or overflow:
                sign = -sign
                c = -c
                v_new = advance(v, vels[sign][i])
                nxt = th + v_new * dt
                if over(v_new, nxt):  # cannot move either way: release
                    c = 0.0
                    v_new = advance(v, 0.0)
                    nxt = th + v_new * dt
            out[i] = c
            th, v = nxt, v_new
            i += 1
    return clip_commands(u, spec)


def hold_sequence(
    rng: np.random.Generator, n_step: int, dt: float, hold_min: float, hold_max: float
) -> list[tuple[int, int]]:
    """Random ``(start, stop)`` segments covering ``[0, n_step)``, durations uniform [s]."""
    segs = []
    i = 0
    while i < n_step:
        n = max(1, round(rng.uniform(hold_min, hold_max) / dt))
        segs.append((i, min(n_step, i + n)))
        i += n
    return segs
