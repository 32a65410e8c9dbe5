"""Excitation signals: command sequences ``u: (n_step, n_joint)`` for simulated episodes.

Every signal is declared here, once: a parameter dataclass (the TOML table
``[simulate.excitation.<kind>]``), an open-loop generator (or a closed-loop operator) and one
entry in :data:`REGISTRY`.  :class:`~.excitation.ExcitationConfig`, ``SIGNALS``, ``CLOSED_LOOP``
and the ``[simulate] *_signals`` checks are all derived from the registry, so adding a signal
touches this module only.

Every generator has the signature::

    fn(rng, n_step, spec, *, theta0=None, omega_max=None, limit_margin=0.05, params=None,
       velocity_map=None) -> u: (n_step, n_joint), commands within each joint's [u_min, u_max]

- ``rng``: a :class:`numpy.random.Generator` or an int seed.
- ``theta0``: (n_joint,) initial angles [rad] (default mid-range).
- ``omega_max``: (n_joint,) joint speed [rad/s] reached at full command (``u_max``); the
  generators use it to size angle excursions and to keep joints away from their end stops
  (:func:`~.commands.fold_limits`).  ``None`` disables limit avoidance.
- ``params``: the signal's parameter dataclass (defaults if ``None``).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from ..errors import ConfigError
from ..spec import MachineSpec
from .commands import (
    RngLike,
    VelocityMap,
    as_rng,
    clip_commands,
    fold_limits,
    hold_sequence,
    is_limited,
    joint_span,
    nominal_speed,
    resolve_defaults,
)
from .dig_operator import DigCycleParams
from .session import SessionParams


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
    theta0_, omega_max_ = resolve_defaults(spec, theta0, omega_max)
    speed = nominal_speed(spec, omega_max_)
    t = np.arange(n_step) * spec.dt
    u = np.zeros((n_step, spec.n_joint))
    for k, j in enumerate(spec.joints):
        level = rng.uniform(p.level_min, p.level_max) * j.u_max
        idle = rng.uniform() < p.p_idle
        amp = 0.5 * p.excursion * joint_span(j) * rng.uniform(0.5, 1.0)  # angle amplitude [rad]
        f_c = level * speed[k] / (2 * np.pi * amp)
        f = np.clip(
            f_c * np.exp(rng.uniform(-np.log(p.spread), np.log(p.spread), p.n_component)),
            p.f_min,
            p.f_max,
        )
        w = rng.uniform(0.2, 1.0, p.n_component)
        a = w / w.sum() * amp * 2 * np.pi * f  # angular-velocity amplitudes [rad/s]
        if is_limited(j):
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
    theta0_, omega_max_ = resolve_defaults(spec, theta0, omega_max)
    u = np.zeros((n_step, spec.n_joint))
    for k, j in enumerate(spec.joints):
        for a, b in hold_sequence(rng, n_step, spec.dt, p.hold_min, p.hold_max):
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
    theta0_, omega_max_ = resolve_defaults(spec, theta0, omega_max)
    speed = nominal_speed(spec, omega_max_)
    duration = max(n_step * spec.dt, spec.dt)
    t = np.arange(n_step) * spec.dt
    u = np.zeros((n_step, spec.n_joint))
    for k, j in enumerate(spec.joints):
        f0, f1 = (p.f_start, p.f_end) if rng.uniform() < 0.5 else (p.f_end, p.f_start)
        rate = np.log(f1 / f0) / duration
        f = f0 * np.exp(rate * t)
        phase = 2 * np.pi * f0 * np.expm1(rate * t) / rate if rate != 0 else 2 * np.pi * f0 * t
        amp = 0.5 * p.excursion * joint_span(j)
        if is_limited(j):  # start phase so that the oscillation is centred in the range
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
    theta0_, omega_max_ = resolve_defaults(spec, theta0, omega_max)
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
    theta0_, omega_max_ = resolve_defaults(spec, theta0, omega_max)
    col = {n: i for i, n in enumerate(spec.names)}
    missing = {"swing", "boom", "arm", "bucket"} - set(col)
    if missing:
        raise ConfigError(
            f"signal 'work_cycle' needs joints swing, boom, arm, bucket; missing {sorted(missing)}"
        )
    speed = nominal_speed(spec, omega_max_)
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


Signal = Callable[..., np.ndarray]
"""An open-loop generator (see the module docstring)."""


@dataclass(frozen=True)
class SignalKind:
    """One registered signal kind."""

    params: type
    """Its parameter dataclass (TOML table ``[simulate.excitation.<kind>]``)."""
    generate: Signal | None
    """The open-loop generator; None for a closed-loop operator run against the plant."""
    doc: str
    """One line for the docs and ``exsur config show``."""


REGISTRY: dict[str, SignalKind] = {
    "multisine": SignalKind(MultisineParams, multisine, "sum of sinusoids (paper training)"),
    "steps": SignalKind(
        StepParams, steps, "hold-and-step, random amplitudes and durations (paper test)"
    ),
    "chirp": SignalKind(ChirpParams, chirp, "frequency sweep"),
    "prbs": SignalKind(PrbsParams, prbs, "random binary steps"),
    "work_cycle": SignalKind(
        WorkCycleParams, work_cycle, "open-loop operator: dig / lift / swing / dump / return"
    ),
    "dig_cycle": SignalKind(
        DigCycleParams, None, "closed-loop digging operator (DigOperator, compound operation)"
    ),
    "dig_session": SignalKind(
        SessionParams,
        None,
        "closed-loop operator shift: digging cycles, free moves, pauses, throttle (SessionOperator)",
    ),
}
"""Every signal kind by name, in the order of ``[simulate.excitation]``."""
