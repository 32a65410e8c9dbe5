"""Excitation signals: command sequences ``u: (n_step, n_joint)`` for simulated episodes.

Every generator has the signature::

    fn(rng, n_step, spec, *, theta0=None, omega_max=None, limit_margin=0.05, params=None)
        -> u: (n_step, n_joint), commands within each joint's [u_min, u_max]

- ``rng``: a :class:`numpy.random.Generator` or an int seed.
- ``theta0``: (n_joint,) initial angles [rad] (default mid-range).
- ``omega_max``: (n_joint,) joint speed [rad/s] reached at full command (``u_max``); the
  generators use it to size angle excursions and to keep joints away from their end stops.
  ``None`` disables limit avoidance (the plant still clamps at its limits).
- ``params``: the signal's parameter dataclass (defaults if ``None``).

Limit avoidance ("fold"): the plant is, up to its 50 ms delay and a stiff servo lag, an
integrator ``theta' = omega_max * u / u_max``.  :func:`fold_limits` integrates this nominal
model and, whenever the nominal angle would leave ``[theta_min + margin, theta_max - margin]``,
mirrors the joint's command (multiplies it by -1 from then on), so the joint bounces off the
soft limit instead of sitting pinned at the end stop.  Generators are additionally designed
so that folding is rare (angle-sized sinusoids centred in the range).

Kinds (:data:`SIGNALS`): ``multisine`` (paper training), ``steps`` (paper test: hold-and-step
with random amplitudes and durations incl. zero periods), ``chirp``, ``prbs`` (random binary
steps), ``work_cycle`` (operator-like dig / lift / swing / dump / return, open loop).
Closed-loop kind (:data:`CLOSED_LOOP`): ``dig_cycle`` (:class:`DigOperator`, reads the plant
state every step; compound operation with soil contact).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, ClassVar

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


# ---------------------------------------------------------------------------- parameters
@dataclass(frozen=True)
class MultisineParams:
    """Sum of sinusoids per joint, sized in angle space (paper training signal)."""

    n_component: int = 4
    """Sinusoids per joint."""
    spread: float = 4.0
    """Frequencies are log-uniform in [f_c / spread, f_c * spread] around the joint's natural
    frequency f_c = peak speed / (2 pi angle amplitude)."""
    f_min: float = 0.01
    """Lowest allowed frequency [Hz]."""
    f_max: float = 1.0
    """Highest allowed frequency [Hz]."""
    excursion: float = 0.85
    """Largest peak-to-peak nominal angle excursion as a fraction of the joint range (swing: of 2 pi)."""
    level_min: float = 0.3
    """Smallest peak |u| as a fraction of u_max (drawn per joint and episode)."""
    level_max: float = 1.0
    """Largest peak |u| as a fraction of u_max."""
    p_idle: float = 0.05
    """Probability that a joint stays idle (u = 0) for the whole episode."""
    tries: int = 50
    """Phase draws tried to fit the oscillation inside the soft range before folding."""


@dataclass(frozen=True)
class StepParams:
    """Hold-and-step sequences, independent per joint (paper test signal)."""

    hold_min: float = 1.0
    """Shortest hold [s]."""
    hold_max: float = 6.0
    """Longest hold [s]."""
    p_zero: float = 0.3
    """Probability that a hold is a zero-command period."""
    level_min: float = 0.15
    """Smallest non-zero |u| as a fraction of u_max."""
    level_max: float = 1.0
    """Largest |u| as a fraction of u_max."""


@dataclass(frozen=True)
class ChirpParams:
    """Logarithmic frequency sweep with constant nominal angle amplitude."""

    f_start: float = 0.02
    """Sweep start frequency [Hz] (joints sweep up or down at random)."""
    f_end: float = 1.0
    """Sweep end frequency [Hz]."""
    excursion: float = 0.6
    """Peak-to-peak nominal angle excursion as a fraction of the joint range (swing: of 2 pi)."""
    level_max: float = 1.0
    """Command clip as a fraction of u_max (high frequencies are clipped to this)."""


@dataclass(frozen=True)
class PrbsParams:
    """Random binary (+a / -a) steps with random switching times."""

    hold_min: float = 0.3
    """Shortest time between switches [s]."""
    hold_mean: float = 1.5
    """Mean time between switches [s]."""
    level_min: float = 0.3
    """Smallest amplitude a as a fraction of u_max (drawn per joint and episode)."""
    level_max: float = 1.0
    """Largest amplitude a as a fraction of u_max."""


@dataclass(frozen=True)
class WorkCycleParams:
    """Operator-like truck-loading cycles: dig, lift, swing, dump, return (4-joint excavators)."""

    swing_min_deg: float = 45.0
    """Smallest dump swing angle [deg]."""
    swing_max_deg: float = 150.0
    """Largest dump swing angle [deg]."""
    tau: float = 0.3
    """Joystick ramp time constant [s] (first-order smoothing of the phase commands)."""
    pause_max: float = 1.5
    """Longest pause between phases [s]."""


@dataclass(frozen=True)
class DigCycleParams:
    """Closed-loop operator: dig into the ground, lift, swing, dump, return (4-joint excavators)."""

    depth_min: float = 0.3
    """Smallest target cutting depth [m] below ground."""
    depth_max: float = 1.0
    """Largest target cutting depth [m]."""
    swing_min_deg: float = 45.0
    """Smallest swing between digging and dumping [deg]."""
    swing_max_deg: float = 150.0
    """Largest swing between digging and dumping [deg]."""
    dig_spread_deg: float = 20.0
    """Digging direction varies by up to +- this around the episode's first one [deg]."""
    p_switch_side: float = 0.2
    """Probability per cycle that the dump (truck) side switches."""
    level_min: float = 0.5
    """Smallest joystick level of a phase (fraction of u_max)."""
    level_max: float = 1.0
    """Largest joystick level of a phase."""
    tau_min: float = 0.1
    """Shortest joystick ramp time constant [s] (drawn per episode)."""
    tau_max: float = 0.35
    """Longest joystick ramp time constant [s]."""
    pause_max: float = 0.8
    """Longest pause (zero command) between phases [s]."""
    swing_brake_rad: float = 1.2
    """Swing error [rad] below which the swing command is reduced (braking the slow swing)."""
    swing_decel: float = 0.25
    """Swing deceleration [rad/s^2] the operator expects when releasing the lever."""
    reaction_s: float = 0.3
    """Operator's allowance for delays when releasing the swing lever [s]."""
    min_press: float = 0.35
    """Smallest lever deflection while a joint is still off target (beyond the dead zones)."""
    clearance: float = 0.3
    """Tip height [m] above ground the operator keeps outside digging (raises the boom first)."""


@dataclass(frozen=True)
class ExcitationConfig:
    """Parameters of every signal kind (TOML table ``[simulate.excitation.<kind>]``)."""

    multisine: MultisineParams = field(default_factory=MultisineParams)
    """Parameters of ``multisine``."""
    steps: StepParams = field(default_factory=StepParams)
    """Parameters of ``steps``."""
    chirp: ChirpParams = field(default_factory=ChirpParams)
    """Parameters of ``chirp``."""
    prbs: PrbsParams = field(default_factory=PrbsParams)
    """Parameters of ``prbs``."""
    work_cycle: WorkCycleParams = field(default_factory=WorkCycleParams)
    """Parameters of ``work_cycle``."""
    dig_cycle: DigCycleParams = field(default_factory=DigCycleParams)
    """Parameters of the closed-loop ``dig_cycle`` operator."""


# ---------------------------------------------------------------------------- helpers
def _limited(j: JointSpec) -> bool:
    return j.theta_min is not None and j.theta_max is not None


def _span(j: JointSpec) -> float:
    """Joint range [rad]; 2 pi for unlimited joints."""
    if _limited(j):
        return float(j.theta_max) - float(j.theta_min)  # type: ignore[arg-type]
    return 2.0 * np.pi


def _defaults(
    spec: MachineSpec,
    theta0: Sequence[float] | np.ndarray | None,
    omega_max: Sequence[float] | np.ndarray | None,
) -> tuple[np.ndarray, np.ndarray | None]:
    if theta0 is None:
        theta0 = np.array(
            [0.5 * (j.theta_min + j.theta_max) if _limited(j) else 0.0 for j in spec.joints]  # type: ignore[operator]
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


def _nominal_speed(spec: MachineSpec, omega_max: np.ndarray | None) -> np.ndarray:
    """(n_joint,) rad/s per command unit of the nominal integrator model."""
    if omega_max is None:
        # No plant information: assume full range in 5 s, only used to size signals.
        return np.array([_span(j) / 5.0 / j.u_max for j in spec.joints])
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
    back to that change, so folding never creates pulses shorter than ``lookahead``
    (a step that would run into a limit is reversed from its start instead).

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
    gain = _nominal_speed(spec, omega_max) * spec.dt
    n_look = max(1, round(lookahead / spec.dt))
    for k, j in enumerate(spec.joints):
        if not _limited(j):
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
        if not _limited(j):
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


def _hold_sequence(
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


# ---------------------------------------------------------------------------- signals
def multisine(
    rng: RngLike,
    n_step: int,
    spec: MachineSpec,
    *,
    theta0: Sequence[float] | np.ndarray | None = None,
    omega_max: Sequence[float] | np.ndarray | None = None,
    limit_margin: float = 0.05,
    params: MultisineParams | None = None,
    velocity_map: VelocityMap | None = None,
) -> np.ndarray:
    """Sum of sinusoids per joint whose integrated (nominal) angle stays inside the range.

    Per joint: a peak command level and an angle amplitude are drawn; frequencies are spread
    around the frequency at which a sinusoid of that amplitude reaches that speed; the
    command ``sum_i a_i cos(2 pi f_i t + phi_i)`` is scaled to the peak level, shrunk if its
    nominal angle ``theta0 + cumsum(u) * speed * T_s`` exceeds the soft range, and the phases
    are redrawn (``tries`` times) until that angle fits; :func:`fold_limits` handles the rest.
    Returns ``u: (n_step, n_joint)``.
    """
    rng = as_rng(rng)
    p = params or MultisineParams()
    theta0_, omega_max_ = _defaults(spec, theta0, omega_max)
    speed = _nominal_speed(spec, omega_max_)
    t = np.arange(n_step) * spec.dt
    u = np.zeros((n_step, spec.n_joint))
    for k, j in enumerate(spec.joints):
        level = rng.uniform(p.level_min, p.level_max) * j.u_max
        idle = rng.uniform() < p.p_idle
        amp = 0.5 * p.excursion * _span(j) * rng.uniform(0.5, 1.0)  # angle amplitude [rad]
        f_c = level * speed[k] / (2 * np.pi * amp)
        f = np.clip(
            f_c * np.exp(rng.uniform(-np.log(p.spread), np.log(p.spread), p.n_component)),
            p.f_min,
            p.f_max,
        )
        w = rng.uniform(0.2, 1.0, p.n_component)
        a = w / w.sum() * amp * 2 * np.pi * f  # angular-velocity amplitudes [rad/s]
        if _limited(j):
            lo = float(j.theta_min) + limit_margin  # type: ignore[arg-type]
            hi = float(j.theta_max) - limit_margin  # type: ignore[arg-type]
        else:
            lo, hi = -np.inf, np.inf
        best, best_err = None, np.inf
        for _ in range(max(1, p.tries)):
            phi = rng.uniform(0, 2 * np.pi, p.n_component)
            cmd = (a * np.cos(2 * np.pi * f * t[:, None] + phi)).sum(axis=1) / speed[k]
            peak = np.max(np.abs(cmd)) if n_step else 0.0
            if peak > 0:
                cmd *= level / peak
            ang = theta0_[k] + np.concatenate([[0.0], np.cumsum(cmd[:-1])]) * speed[k] * spec.dt
            width = ang.max() - ang.min()
            if np.isfinite(hi - lo) and width > 0.98 * (hi - lo):  # shrink to fit the range
                cmd *= 0.98 * (hi - lo) / width
                ang = theta0_[k] + (ang - theta0_[k]) * 0.98 * (hi - lo) / width
            err = max(0.0, ang.max() - hi) + max(0.0, lo - ang.min())
            if err < best_err:
                best, best_err = cmd, err
            if err == 0.0:
                break
        u[:, k] = 0.0 if idle or best is None else best
    u = clip_commands(u, spec)
    return fold_limits(
        u,
        spec,
        theta0=theta0_,
        omega_max=omega_max_,
        limit_margin=limit_margin,
        velocity_map=velocity_map,
    )


def steps(
    rng: RngLike,
    n_step: int,
    spec: MachineSpec,
    *,
    theta0: Sequence[float] | np.ndarray | None = None,
    omega_max: Sequence[float] | np.ndarray | None = None,
    limit_margin: float = 0.05,
    params: StepParams | None = None,
    velocity_map: VelocityMap | None = None,
) -> np.ndarray:
    """Hold-and-step commands, independent per joint: random hold durations, random signed
    amplitudes, and zero-command periods.  Returns ``u: (n_step, n_joint)``."""
    rng = as_rng(rng)
    p = params or StepParams()
    theta0_, omega_max_ = _defaults(spec, theta0, omega_max)
    u = np.zeros((n_step, spec.n_joint))
    for k, j in enumerate(spec.joints):
        for a, b in _hold_sequence(rng, n_step, spec.dt, p.hold_min, p.hold_max):
            if rng.uniform() < p.p_zero:
                continue
            mag = rng.uniform(p.level_min, p.level_max)
            u[a:b, k] = (j.u_max if rng.uniform() < 0.5 else j.u_min) * mag
    u = clip_commands(u, spec)
    return fold_limits(
        u,
        spec,
        theta0=theta0_,
        omega_max=omega_max_,
        limit_margin=limit_margin,
        velocity_map=velocity_map,
    )


def chirp(
    rng: RngLike,
    n_step: int,
    spec: MachineSpec,
    *,
    theta0: Sequence[float] | np.ndarray | None = None,
    omega_max: Sequence[float] | np.ndarray | None = None,
    limit_margin: float = 0.05,
    params: ChirpParams | None = None,
    velocity_map: VelocityMap | None = None,
) -> np.ndarray:
    """Logarithmic sweep per joint with constant nominal angle amplitude (command amplitude
    grows with frequency, clipped at ``level_max``).  Returns ``u: (n_step, n_joint)``."""
    rng = as_rng(rng)
    p = params or ChirpParams()
    theta0_, omega_max_ = _defaults(spec, theta0, omega_max)
    speed = _nominal_speed(spec, omega_max_)
    duration = max(n_step * spec.dt, spec.dt)
    t = np.arange(n_step) * spec.dt
    u = np.zeros((n_step, spec.n_joint))
    for k, j in enumerate(spec.joints):
        f0, f1 = (p.f_start, p.f_end) if rng.uniform() < 0.5 else (p.f_end, p.f_start)
        rate = np.log(f1 / f0) / duration
        f = f0 * np.exp(rate * t)
        phase = 2 * np.pi * f0 * np.expm1(rate * t) / rate if rate != 0 else 2 * np.pi * f0 * t
        amp = 0.5 * p.excursion * _span(j)
        if _limited(j):  # start phase so that the oscillation is centred in the range
            mid = 0.5 * (float(j.theta_min) + float(j.theta_max))  # type: ignore[arg-type]
            s = np.clip((theta0_[k] - mid) / amp, -1.0, 1.0)
            phi = np.arcsin(s) if rng.uniform() < 0.5 else np.pi - np.arcsin(s)
        else:
            phi = rng.uniform(0, 2 * np.pi)
        cmd = amp * 2 * np.pi * f * np.cos(phase + phi) / speed[k]
        u[:, k] = np.clip(cmd, -p.level_max * j.u_max, p.level_max * j.u_max)
    u = clip_commands(u, spec)
    return fold_limits(
        u,
        spec,
        theta0=theta0_,
        omega_max=omega_max_,
        limit_margin=limit_margin,
        velocity_map=velocity_map,
    )


def prbs(
    rng: RngLike,
    n_step: int,
    spec: MachineSpec,
    *,
    theta0: Sequence[float] | np.ndarray | None = None,
    omega_max: Sequence[float] | np.ndarray | None = None,
    limit_margin: float = 0.05,
    params: PrbsParams | None = None,
    velocity_map: VelocityMap | None = None,
) -> np.ndarray:
    """Random binary steps ``+a / -a`` per joint, hold times ``hold_min + Exp(hold_mean -
    hold_min)``, amplitude ``a`` drawn per joint.  Returns ``u: (n_step, n_joint)``."""
    rng = as_rng(rng)
    p = params or PrbsParams()
    theta0_, omega_max_ = _defaults(spec, theta0, omega_max)
    u = np.zeros((n_step, spec.n_joint))
    for k, j in enumerate(spec.joints):
        a = rng.uniform(p.level_min, p.level_max) * j.u_max
        sign = 1.0 if rng.uniform() < 0.5 else -1.0
        i = 0
        while i < n_step:
            hold = p.hold_min + rng.exponential(max(p.hold_mean - p.hold_min, 1e-9))
            n = max(1, round(hold / spec.dt))
            u[i : i + n, k] = sign * a
            sign = -sign
            i += n
    u = clip_commands(u, spec)
    return fold_limits(
        u,
        spec,
        theta0=theta0_,
        omega_max=omega_max_,
        limit_margin=limit_margin,
        velocity_map=velocity_map,
    )


def work_cycle(
    rng: RngLike,
    n_step: int,
    spec: MachineSpec,
    *,
    theta0: Sequence[float] | np.ndarray | None = None,
    omega_max: Sequence[float] | np.ndarray | None = None,
    limit_margin: float = 0.05,
    params: WorkCycleParams | None = None,
    velocity_map: VelocityMap | None = None,
) -> np.ndarray:
    """Operator-like truck-loading cycles with overlapping (compound) joint motions.

    Needs joints named ``swing``, ``boom``, ``arm``, ``bucket``; other joints stay idle.
    Each cycle: dig (arm in, bucket curl, boom trims), lift (boom up), swing to a random dump
    angle (boom still rising), dump (bucket open, arm out), return (swing back, boom down,
    arm out), separated by random pauses.  Phase commands are smoothed by a first-order
    joystick ramp ``tau``.  Positive commands: swing left, boom up, arm in, bucket curl.
    Returns ``u: (n_step, n_joint)``.
    """
    rng = as_rng(rng)
    p = params or WorkCycleParams()
    theta0_, omega_max_ = _defaults(spec, theta0, omega_max)
    col = {n: i for i, n in enumerate(spec.names)}
    missing = {"swing", "boom", "arm", "bucket"} - set(col)
    if missing:
        raise ConfigError(
            f"signal 'work_cycle' needs joints swing, boom, arm, bucket; missing {sorted(missing)}"
        )
    speed = _nominal_speed(spec, omega_max_)
    dt = spec.dt
    umax = {n: spec.joints[col[n]].u_max for n in col}
    raw = np.zeros((n_step, spec.n_joint))
    i = 0

    def put(name: str, start: float, dur: float, level: float) -> None:
        a = i + round(start / dt)
        b = min(n_step, a + max(1, round(dur / dt)))
        if a < n_step:
            raw[a:b, col[name]] = level * umax[name]

    while i < n_step:
        # dig
        d = rng.uniform(3.0, 6.0)
        put("arm", 0.0, d, rng.uniform(0.5, 1.0))
        put("bucket", 0.3 * d, 0.7 * d, rng.uniform(0.4, 1.0))
        put("boom", 0.0, 0.4 * d, -rng.uniform(0.0, 0.4))
        put("boom", 0.6 * d, 0.4 * d, rng.uniform(0.0, 0.4))
        t = d
        # lift (+ start of swing for compound motion)
        d = rng.uniform(1.5, 3.0)
        put("boom", t, d, rng.uniform(0.6, 1.0))
        put("bucket", t, 0.3 * d, rng.uniform(0.0, 0.3))
        t += d
        # swing to dump (boom still rising)
        angle = np.deg2rad(rng.uniform(p.swing_min_deg, p.swing_max_deg))
        lvl = rng.uniform(0.6, 1.0)
        direction = 1.0 if rng.uniform() < 0.5 else -1.0
        d_sw = angle / (lvl * umax["swing"] * speed[col["swing"]])
        put("swing", t - 0.3 * d, d_sw, direction * lvl)
        put("boom", t, 0.5 * d_sw, rng.uniform(0.2, 0.6))
        t += d_sw - 0.3 * d
        # dump
        d = rng.uniform(1.5, 3.0)
        put("bucket", t, d, -rng.uniform(0.6, 1.0))
        put("arm", t, d, -rng.uniform(0.3, 0.8))
        t += d + rng.uniform(0.0, p.pause_max)
        # return (swing back, boom down, arm out for the next dig)
        lvl_back = rng.uniform(0.6, 1.0)
        d_back = angle / (lvl_back * umax["swing"] * speed[col["swing"]])
        put("swing", t, d_back, -direction * lvl_back)
        put("boom", t, 0.8 * d_back, -rng.uniform(0.4, 0.9))
        put("arm", t, 0.8 * d_back, -rng.uniform(0.3, 0.7))
        t += d_back + rng.uniform(0.0, p.pause_max)
        i += max(1, round(t / dt))
    # first-order joystick ramp: y[k] = y[k-1] + alpha (x[k] - y[k-1])
    alpha = 1.0 - np.exp(-dt / max(p.tau, 1e-9))
    u = np.empty_like(raw)
    y = np.zeros(spec.n_joint)
    for k in range(n_step):
        y = y + alpha * (raw[k] - y)
        u[k] = y
    u = clip_commands(u, spec)
    return fold_limits(
        u,
        spec,
        theta0=theta0_,
        omega_max=omega_max_,
        limit_margin=limit_margin,
        velocity_map=velocity_map,
    )


class DigOperator:
    """Closed-loop operator script for compound operation: dig, lift + swing, dump, return.

    At every control step it reads the true joint angles and the bucket-tip position and
    returns joystick commands, so it really digs into the ground (keeping a target depth
    with the boom while crowding the arm, backing off when the arm stalls) and dumps at a
    varied swing angle.  Phases (each ends when its targets are reached or on a timeout,
    followed by a random pause):

    ``approach`` (swing to the digging direction, boom/arm/bucket to a random pre-dig pose)
    -> ``penetrate`` (boom down until the tip is ``depth`` below ground) -> ``drag`` (arm in,
    boom holds the depth, bucket curls in the second half; stops when the arm is in, the
    bucket is full or time is up) -> ``curl`` (bucket in, boom breaks out) -> ``lift_swing``
    (boom up, swing +-45-150 deg to the dump side) -> ``dump`` (bucket out, arm out) ->
    ``approach`` of the next cycle.

    Commands are proportional to the remaining joint error (saturated at a random phase
    level), smoothed by a first-order joystick ramp.  Needs joints named ``swing``, ``boom``,
    ``arm``, ``bucket``; other joints stay idle.  Positive commands: swing left, boom up,
    arm in, bucket curl.

    Args:
        spec: machine spec.
        rng: random generator (the operator's only source of randomness).
        params: operator parameters.
        ground_z: ground height [m].
    """

    PHASES = ("approach", "penetrate", "drag", "curl", "lift_swing", "dump")

    def __init__(
        self,
        spec: MachineSpec,
        *,
        rng: RngLike,
        params: DigCycleParams | None = None,
        ground_z: float = 0.0,
    ) -> None:
        col = {n: i for i, n in enumerate(spec.names)}
        missing = {"swing", "boom", "arm", "bucket"} - set(col)
        if missing:
            raise ConfigError(
                f"signal 'dig_cycle' needs joints swing, boom, arm, bucket; missing {sorted(missing)}"
            )
        self.spec = spec
        self.rng = as_rng(rng)
        self.p = params or DigCycleParams()
        self.ground_z = float(ground_z)
        self.col = col
        self.dt = spec.dt
        self.lo = np.array([-np.inf if j.theta_min is None else j.theta_min for j in spec.joints])
        self.hi = np.array([np.inf if j.theta_max is None else j.theta_max for j in spec.joints])
        self.u_max = np.array([j.u_max for j in spec.joints])
        self.u_min = np.array([j.u_min for j in spec.joints])

    # ------------------------------------------------------------------ helpers
    def _clip_target(self, name: str, value: float, margin: float = 0.08) -> float:
        k = self.col[name]
        return float(np.clip(value, self.lo[k] + margin, self.hi[k] - margin))

    def _level(self) -> float:
        return float(self.rng.uniform(self.p.level_min, self.p.level_max))

    TOL: ClassVar[dict[str, float]] = {"swing": 0.12, "boom": 0.08, "arm": 0.1, "bucket": 0.12}
    """Joint tolerances [rad] at which a target counts as reached (lever released)."""
    BAND: ClassVar[dict[str, float]] = {"boom": 0.25, "arm": 0.3, "bucket": 0.4}
    """Errors [rad] below which the lever is eased off proportionally."""

    def _press(self, name: str, err: float, omega: float, level: float) -> float:
        """Joystick fraction for a joint error ``err`` [rad] at velocity ``omega`` [rad/s].

        Operators push the lever (never into the valve dead zone: at least ``min_press``) and
        release it inside the tolerance.  The slow, heavy swing is released early enough to
        coast to the target: when its braking distance ``omega^2 / (2 decel) + |omega| t_r``
        covers the remaining error.
        """
        p = self.p
        if abs(err) <= self.TOL[name]:
            return 0.0
        sign = 1.0 if err > 0 else -1.0
        if name == "swing":
            coasting = omega * sign > 0
            brake = omega * omega / (2.0 * p.swing_decel) + abs(omega) * p.reaction_s
            if coasting and abs(err) <= brake:
                return 0.0
            return sign * max(min(level, abs(err) / p.swing_brake_rad), p.min_press)
        return sign * max(min(level, abs(err) / self.BAND[name]), p.min_press)

    def _start(self, phase: str) -> None:
        r, p = self.rng, self.p
        self.phase, self.t_phase = phase, 0.0
        self.pause = float(r.uniform(0.0, p.pause_max))
        self.levels = {n: self._level() for n in ("swing", "boom", "arm", "bucket")}
        if phase == "approach":
            spread = np.deg2rad(p.dig_spread_deg)
            self.psi_dig = self.psi_dig0 + float(r.uniform(-spread, spread))
            self.targets = {
                "swing": self.psi_dig,
                "boom": self._clip_target("boom", r.uniform(0.0, 0.35)),
                "arm": self._clip_target("arm", r.uniform(0.7, 1.2)),
                "bucket": self._clip_target("bucket", r.uniform(-0.3, 0.4)),
            }
            self.timeout = 14.0
        elif phase == "penetrate":
            self.depth = float(r.uniform(p.depth_min, p.depth_max))
            self.arm_assist = float(r.uniform(0.0, 0.35))
            self.timeout = 6.0
        elif phase == "drag":
            self.arm_end = self._clip_target("arm", r.uniform(1.9, 2.45))
            self.curl_level = float(r.uniform(0.2, 0.6))
            self.z_target = self.ground_z - self.depth
            self.stall_s = 0.0
            self.timeout = 12.0
        elif phase == "curl":
            self.targets = {"bucket": self._clip_target("bucket", r.uniform(1.9, 2.4))}
            self.breakout = float(r.uniform(0.2, 0.5))
            self.timeout = 5.0
        elif phase == "lift_swing":
            if r.uniform() < p.p_switch_side:
                self.side = -self.side
            delta = np.deg2rad(r.uniform(p.swing_min_deg, p.swing_max_deg))
            self.targets = {
                "swing": self.psi_dig + self.side * delta,
                "boom": self._clip_target("boom", r.uniform(0.35, 0.75)),
                "arm": self._clip_target("arm", r.uniform(1.3, 2.0)),
                "bucket": self._clip_target("bucket", r.uniform(1.9, 2.4)),
            }
            self.swing_after = float(r.uniform(0.3, 1.5))
            self.timeout = 20.0
        elif phase == "dump":
            self.targets = {
                "bucket": self._clip_target("bucket", r.uniform(-0.5, 0.1)),
                "arm": self._clip_target("arm", r.uniform(0.9, 1.5)),
                "boom": self.targets.get("boom", 0.5),  # keep the lift height
            }
            self.timeout = 6.0

    def reset(self, theta0: np.ndarray) -> None:
        """Start an episode at ``theta0: (n_joint,)`` [rad]."""
        r = self.rng
        self.theta0 = np.asarray(theta0, dtype=np.float64)
        self.tau = float(r.uniform(self.p.tau_min, self.p.tau_max))
        self.alpha = 1.0 - np.exp(-self.dt / self.tau)
        self.psi_dig0 = float(self.theta0[self.col["swing"]] + r.uniform(-0.5, 0.5))
        self.side = 1.0 if r.uniform() < 0.5 else -1.0
        self.depth = float(r.uniform(self.p.depth_min, self.p.depth_max))
        self.y = np.zeros(self.spec.n_joint)
        self.cycles = 0
        self.phase_log: list[tuple[int, str]] = []
        self.k = 0
        self._start("approach")
        self.phase_log.append((0, "approach"))

    # ------------------------------------------------------------------ step
    def __call__(
        self,
        theta: np.ndarray,
        omega: np.ndarray,
        *,
        tip: np.ndarray,
        payload_fraction: float = 0.0,
    ) -> np.ndarray:
        """Joystick command ``u: (n_joint,)`` for the current true state.

        Args:
            theta: (n_joint,) joint angles [rad] (swing unwrapped).
            omega: (n_joint,) joint velocities [rad/s].
            tip: (3,) bucket-tip position in the world [m].
            payload_fraction: bucket fill in [0, 1].
        """
        c, dt = self.col, self.dt
        th = {n: float(theta[c[n]]) for n in ("swing", "boom", "arm", "bucket")}
        frac = dict.fromkeys(th, 0.0)
        lv = self.levels
        done = False
        self.t_phase += dt
        if self.pause > 0:
            self.pause -= dt
        elif self.phase in ("approach", "lift_swing", "curl", "dump"):
            low = float(tip[2]) < self.ground_z + self.p.clearance
            if low and self.phase in ("approach", "dump") and "boom" in self.targets:
                # bucket too low: raise the boom target (ratchet, never lowered again in this
                # phase) instead of dragging the bucket through the soil
                self.targets["boom"] = max(
                    self.targets["boom"], self._clip_target("boom", th["boom"] + 0.15)
                )
            reached = True
            for n, target in self.targets.items():
                if n == "swing" and self.phase == "lift_swing" and self.t_phase < self.swing_after:
                    reached = False
                    continue
                err = target - th[n]
                frac[n] = self._press(n, err, float(omega[c[n]]), lv[n])
                if abs(err) > self.TOL[n]:
                    reached = False
            if self.phase == "curl":
                frac["boom"] = self.breakout
            elif low and self.phase in ("approach", "dump"):
                frac["arm"] = 0.0  # hold the arm until the bucket is clear
                reached = False
            done = reached
        elif self.phase == "penetrate":
            frac["boom"] = -lv["boom"] * 0.8
            frac["arm"] = self.arm_assist
            depth = self.ground_z - float(tip[2])
            done = depth >= self.depth or th["boom"] < self.lo[c["boom"]] + 0.1
        elif self.phase == "drag":
            frac["arm"] = lv["arm"]
            frac["boom"] = float(np.clip(1.5 * (self.z_target - float(tip[2])), -0.6, 0.8))
            progress = (th["arm"] - self.targets_arm_start) / max(
                self.arm_end - self.targets_arm_start, 1e-3
            )
            if progress > 0.4:
                frac["bucket"] = self.curl_level
            if abs(float(omega[c["arm"]])) < 0.03:
                self.stall_s += dt
                if self.stall_s > 1.0:  # stalled: dig shallower
                    self.z_target += 0.15
                    self.stall_s = 0.0
            else:
                self.stall_s = 0.0
            done = th["arm"] >= self.arm_end or payload_fraction >= 0.95
        if done or self.t_phase > self.timeout:
            nxt = self.PHASES[(self.PHASES.index(self.phase) + 1) % len(self.PHASES)]
            if nxt == "approach":
                self.cycles += 1
            if nxt == "drag":
                self.targets_arm_start = th["arm"]
            self._start(nxt)
            self.phase_log.append((self.k + 1, nxt))
        self.k += 1
        raw = np.zeros(self.spec.n_joint)
        for n, f in frac.items():
            raw[c[n]] = f * (self.u_max[c[n]] if f >= 0 else -self.u_min[c[n]])
        self.y = self.y + self.alpha * (raw - self.y)
        return np.clip(self.y, self.u_min, self.u_max)


CLOSED_LOOP: tuple[str, ...] = ("dig_cycle",)
"""Closed-loop signal kinds: run step by step against the plant (:class:`DigOperator`)."""

Signal = Callable[..., np.ndarray]

SIGNALS: dict[str, Signal] = {
    "multisine": multisine,
    "steps": steps,
    "chirp": chirp,
    "prbs": prbs,
    "work_cycle": work_cycle,
}
"""Signal kinds by name."""


def generate(
    kind: str,
    rng: RngLike,
    n_step: int,
    spec: MachineSpec,
    *,
    theta0: Sequence[float] | np.ndarray | None = None,
    omega_max: Sequence[float] | np.ndarray | None = None,
    limit_margin: float = 0.05,
    config: ExcitationConfig | None = None,
    velocity_map: VelocityMap | None = None,
) -> np.ndarray:
    """Generate ``u: (n_step, n_joint)`` of signal ``kind`` with its parameters from ``config``.

    ``velocity_map`` (optional) is the plant's nominal command -> velocity map used to keep
    the joints off their end stops (see :func:`fold_limits`); default: linear in ``omega_max``.
    Closed-loop kinds (:data:`CLOSED_LOOP`) need the plant and are run by
    :func:`~.generate.simulate_episode`.
    """
    if kind in CLOSED_LOOP:
        raise ConfigError(
            f"signal '{kind}' is a closed-loop operator script: it needs the plant's state "
            "(use simulate_dataset / DigOperator), not an open-loop command sequence"
        )
    if kind not in SIGNALS:
        raise ConfigError(f"unknown signal kind '{kind}': choose one of {', '.join(SIGNALS)}")
    if n_step < 1:
        raise ConfigError(f"n_step must be >= 1, got {n_step}")
    cfg = config or ExcitationConfig()
    params: Any = getattr(cfg, kind)
    return SIGNALS[kind](
        rng,
        n_step,
        spec,
        theta0=theta0,
        omega_max=omega_max,
        limit_margin=limit_margin,
        params=params,
        velocity_map=velocity_map,
    )
