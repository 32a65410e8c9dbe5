"""Stage II stand-in: a hydraulic excavator as a command transform plus relief force limits.

:class:`HydraulicTransform` implements :class:`~.hooks.CommandTransform`: it maps joystick
commands at the control rate to physics-rate velocity demands of the MJCF's flow-controlled
servos.  Every effect below is switchable (:class:`HydraulicConfig`) and is a function of the
command history only, so the batched ``mujoco.rollout`` path can use it.  Signal chain per
joint ``j`` (``x = u / u_max`` for ``u >= 0``, ``u / |u_min|`` for ``u < 0``)::

    x --play (hysteresis)--> s --dead zone, progressive curve, asymmetric gain--> q
      --drift (oil temperature), the day's slow-down--> --flow sharing (one pump)-->
      --acceleration limit--> --transport delay--> --first-order valve lag--> y;
      ctrl = y * u_max  (y<0: y*|u_min|)

The play, the static map, the drift and the flow sharing act on the piecewise-constant
command (control rate); the acceleration limit, delay and lag at the physics rate.  All
stages are time-invariant except the drift, so the delay commutes with them; the order
only matters for the nonlinear stages and is documented in docs/hydraulics.md.

State-dependent effects cannot be a function of the command history:

- **Relief valves** are actuator force limits (MJCF ``forcerange``), see
  :meth:`HydraulicTransform.force_limits`; :class:`~.plant.MujocoExcavator` applies them.
  A loaded joint then slows or stalls.
- **No wind-up at relief** (:class:`~.relief.ReliefAntiWindup`, a :class:`~.hooks.ForceHook`,
  Python loop only): the integrating servo's setpoint is held at the force limit, as the excess
  flow of a real cylinder goes over the relief valve to tank instead of being "remembered".

Parameter sources are listed in docs/hydraulics.md; most are typical literature/brochure
values for a 70-80 t excavator or engineering estimates (said so there).
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, fields
from functools import partial
from typing import Any

import numpy as np
from scipy.signal import lfilter

from ..errors import ConfigError
from ..spec import EXCAVATOR, MachineSpec

PerJoint = float | tuple[float, ...]
"""A scalar applied to every joint, or one value per joint (spec order)."""

EFFECTS = (
    "hysteresis",
    "dead_zone",
    "gain_curve",
    "asymmetry",
    "drift",
    "flow_sharing",
    "accel_limit",
    "transport_delay",
    "valve_lag",
    "relief",
)
"""Names of the on/off switches of :class:`HydraulicConfig`, in signal-chain order."""


@dataclass(frozen=True)
class HydraulicConfig:
    """Hydraulic effects (each switchable) and their parameters; per-joint tuples in spec order.

    Defaults describe a 70-80 t class excavator (swing, boom, arm, bucket); see
    docs/hydraulics.md for equations and sources.  TOML table ``[simulate.hydraulics]``.
    """

    hysteresis: bool = True
    """Spool hysteresis: play (backlash) operator of half-width ``play`` on the command."""
    dead_zone: bool = True
    """Spool overlap: no flow while ``|s|`` is below ``dead_zone_pos`` / ``dead_zone_neg``."""
    gain_curve: bool = True
    """Progressive metering curve ``q = r ** curve_exponent`` (fine control at small strokes)."""
    asymmetry: bool = True
    """Direction-dependent full-stroke speed ``gain_pos`` / ``gain_neg`` (cylinder area ratio)."""
    drift: bool = False
    """Slow speed drift over an episode (oil warming up): ``1 - drift_amplitude exp(-t / drift_tau_s)``."""
    flow_sharing: bool = True
    """One pump: flows are scaled down together when their sum exceeds ``pump_max_lpm``."""
    accel_limit: bool = True
    """Rate limit of the flow demand (pressure-limited acceleration of the heavy links)."""
    transport_delay: bool = True
    """Extra dead time ``delay_s`` (pilot lines, CAN, pump response) on top of the MJCF delay."""
    valve_lag: bool = True
    """First-order valve/spool lag with time constant ``lag_s``."""
    relief: bool = True
    """Relief valves: actuator torque limits ``relief_pos_nm`` / ``relief_neg_nm`` (MJCF forcerange)."""

    play: PerJoint = 0.03
    """Half-width b of the play operator [fraction of full stroke] (hysteresis 2b = 6 %)."""
    dead_zone_pos: PerJoint = (0.15, 0.18, 0.14, 0.12)
    """Dead zone for positive commands [fraction of u_max] (swing left, boom up, arm in, curl)."""
    dead_zone_neg: PerJoint = (0.15, 0.12, 0.16, 0.14)
    """Dead zone for negative commands [fraction of |u_min|]."""
    curve_exponent: PerJoint = (1.5, 1.6, 1.6, 1.4)
    """Exponent gamma of the metering curve (1 = linear, 2 = quadratic)."""
    gain_pos: PerJoint = (1.0, 0.8, 0.85, 0.85)
    """Full-stroke speed for positive commands as a fraction of the MJCF omega_max."""
    gain_neg: PerJoint = (1.0, 1.0, 1.0, 1.0)
    """Full-stroke speed for negative commands as a fraction of the MJCF omega_max."""
    drift_amplitude: float = 0.1
    """Speed deficit of cold oil at t = 0 (dataset generation draws it per episode in [0, this])."""
    drift_tau_s: float = 600.0
    """Warm-up time constant of the drift [s]."""
    day_slowdown: float = 0.0
    """Speed deficit of the day: every valve's speed times ``1 - day_slowdown`` (ambient
    temperature, oil grade, pump wear; dataset generation with ``simulate.days`` draws it per
    day in [0, this])."""
    flow_full_lpm: PerJoint = (350.0, 700.0, 700.0, 450.0)
    """Pump flow a joint draws at full speed [L/min]."""
    pump_max_lpm: float = 1000.0
    """Largest total pump flow [L/min] shared by all joints."""
    accel_max: PerJoint = (0.35, 3.0, 5.0, 8.0)
    """Largest rate of change of the flow demand [full speed per s] (1/accel_max = time to full speed)."""
    delay_s: float = 0.05
    """Transport delay [s] added by the transform (rounded to physics steps)."""
    lag_s: PerJoint = (0.10, 0.08, 0.06, 0.05)
    """Valve lag time constant [s] (exact zero-order-hold discretisation)."""
    relief_pos_nm: PerJoint = (7.5e5, 2.2e6, 1.5e6, 7.2e5)
    """Largest joint torque in the positive direction [N m] (relief pressure x area x lever)."""
    relief_neg_nm: PerJoint = (7.5e5, 1.2e6, 0.8e6, 4.0e5)
    """Largest joint torque in the negative direction [N m] (rod side: smaller area)."""

    def __post_init__(self) -> None:
        if not self.pump_max_lpm > 0:
            raise ConfigError(f"hydraulics.pump_max_lpm must be > 0, got {self.pump_max_lpm}")
        if not self.drift_tau_s > 0:
            raise ConfigError(f"hydraulics.drift_tau_s must be > 0, got {self.drift_tau_s}")
        if not 0 <= self.drift_amplitude < 1:
            raise ConfigError(
                f"hydraulics.drift_amplitude must be in [0, 1), got {self.drift_amplitude}"
            )
        if not 0 <= self.day_slowdown < 1:
            raise ConfigError(f"hydraulics.day_slowdown must be in [0, 1), got {self.day_slowdown}")
        if self.delay_s < 0:
            raise ConfigError(f"hydraulics.delay_s must be >= 0, got {self.delay_s}")

    @classmethod
    def ideal(cls, **on: bool) -> HydraulicConfig:
        """All effects off (the transform is then the ideal zero-order hold), except those
        switched on by keyword, e.g. ``HydraulicConfig.ideal(dead_zone=True)``."""
        bad = sorted(set(on) - set(EFFECTS))
        if bad:
            raise ConfigError(f"unknown hydraulic effect(s) {bad}; choose from {list(EFFECTS)}")
        return cls(**{e: bool(on.get(e, False)) for e in EFFECTS})


def _per_joint(value: PerJoint, n_joint: int, name: str, *, lo: float, hi: float) -> np.ndarray:
    arr = np.asarray(value, dtype=np.float64).reshape(-1)
    if arr.size == 1:
        arr = np.full(n_joint, float(arr[0]))
    elif arr.size != n_joint:
        raise ConfigError(
            f"hydraulics.{name}: got {arr.size} values for {n_joint} joints; "
            "give one value or one per joint"
        )
    if np.any(~np.isfinite(arr)) or np.any(arr < lo) or np.any(arr > hi):
        raise ConfigError(
            f"hydraulics.{name}: values must be in [{lo:g}, {hi:g}], got {arr.tolist()}"
        )
    return arr


@dataclass(frozen=True)
class _Params:
    """Per-joint parameter arrays (n_joint,) resolved for a spec, effects folded in."""

    u_pos: np.ndarray
    u_neg: np.ndarray
    play: np.ndarray
    dz_pos: np.ndarray
    dz_neg: np.ndarray
    gamma: np.ndarray
    g_pos: np.ndarray
    g_neg: np.ndarray
    flow: np.ndarray
    accel: np.ndarray
    lag: np.ndarray


def resolve(config: HydraulicConfig, spec: MachineSpec) -> _Params:
    """Per-joint parameter arrays of ``config`` for ``spec``; disabled effects become neutral."""
    n = spec.n_joint
    u_pos = np.array([j.u_max for j in spec.joints], dtype=np.float64)
    u_neg = np.array([-j.u_min for j in spec.joints], dtype=np.float64)
    if np.any(u_pos <= 0) or np.any(u_neg <= 0):
        raise ConfigError(
            "hydraulics: every joint's command range must contain 0 (u_min < 0 < u_max)"
        )
    c = config

    def pj(name: str, lo: float, hi: float, on: bool, neutral: float) -> np.ndarray:
        arr = _per_joint(getattr(c, name), n, name, lo=lo, hi=hi)
        return arr if on else np.full(n, neutral)

    return _Params(
        u_pos=u_pos,
        u_neg=u_neg,
        play=pj("play", 0.0, 0.49, c.hysteresis, 0.0),
        dz_pos=pj("dead_zone_pos", 0.0, 0.9, c.dead_zone, 0.0),
        dz_neg=pj("dead_zone_neg", 0.0, 0.9, c.dead_zone, 0.0),
        gamma=pj("curve_exponent", 0.2, 5.0, c.gain_curve, 1.0),
        g_pos=pj("gain_pos", 0.0, 1.0, c.asymmetry, 1.0),
        g_neg=pj("gain_neg", 0.0, 1.0, c.asymmetry, 1.0),
        flow=pj("flow_full_lpm", 0.0, np.inf, c.flow_sharing, 0.0),
        accel=pj("accel_max", 1e-6, np.inf, c.accel_limit, np.inf),
        lag=pj("lag_s", 0.0, np.inf, c.valve_lag, 0.0),
    )


try:  # lfilter's own kernel without its argument checks (10 us per call saved per joint)
    from scipy.signal._sigtools import _linear_filter as _lfilter_kernel
except ImportError:  # pragma: no cover - other scipy layouts
    _lfilter_kernel = None


def _first_order(a: float, x: np.ndarray, zi: np.ndarray) -> np.ndarray:
    """``y_n = a x_n + (1 - a) y_{n-1}`` along axis 1 of ``x: (n_batch, n)``; ``zi = (1 - a) y_{-1}``
    of shape (n_batch, 1).  Identical arithmetic in every chunking (streaming-consistent)."""
    b_coef = np.array([a])
    a_coef = np.array([1.0, a - 1.0])
    if _lfilter_kernel is not None:
        return _lfilter_kernel(b_coef, a_coef, x, 1, zi)[0]
    return lfilter(b_coef, a_coef, x, axis=1, zi=zi)[0]


def spool_map(s: np.ndarray, p: _Params) -> np.ndarray:
    """Static valve map: spool position ``s`` in [-1, 1] -> normalised flow ``q`` (dead zone,
    progressive curve, asymmetric gain).  Shapes ``(..., n_joint)``."""
    pos = s >= 0
    dz = np.where(pos, p.dz_pos, p.dz_neg)
    r = np.clip((np.abs(s) - dz) / (1.0 - dz), 0.0, 1.0)
    r = np.where(p.gamma == 1.0, r, r**p.gamma)
    return np.where(pos, p.g_pos * r, -p.g_neg * r)


class HydraulicTransform:
    """Hydraulic :class:`~.hooks.CommandTransform`: joystick commands -> servo velocity demands.

    Causal and streaming-consistent (bit-identical output whether the command sequence is
    fed at once or in chunks), vectorised over batch and joints; loops over time run at the
    control rate only.

    Args:
        config: effects and parameters (default :class:`HydraulicConfig`).
        spec: machine spec (joint count, command ranges); per-joint tuples must match it.

    Example::

        plant = MujocoExcavator(PlantConfig(), command_transform=HydraulicTransform())
    """

    def __init__(
        self, config: HydraulicConfig | None = None, *, spec: MachineSpec = EXCAVATOR
    ) -> None:
        self.config = config or HydraulicConfig()
        self.spec = spec
        self.params = resolve(self.config, spec)
        self.reset(n_batch=1, substeps=1, timestep=spec.dt)

    # ------------------------------------------------------------------ plant interface
    def force_limits(self) -> tuple[np.ndarray, np.ndarray] | None:
        """Relief torque limits ``(lo, hi)``, each ``(n_joint,)`` [N m], or None if relief is off.

        :class:`~.plant.MujocoExcavator` applies them as actuator ``forcerange`` unless its
        :class:`~.plant.PlantConfig` sets ``force_min`` / ``force_max`` itself.
        """
        if not self.config.relief:
            return None
        n = self.spec.n_joint
        hi = _per_joint(self.config.relief_pos_nm, n, "relief_pos_nm", lo=0.0, hi=np.inf)
        lo = _per_joint(self.config.relief_neg_nm, n, "relief_neg_nm", lo=0.0, hi=np.inf)
        return -lo, hi

    def nominal_velocity(self, u: np.ndarray, *, omega_max: np.ndarray) -> np.ndarray:
        """Steady-state joint velocity [rad/s] of a constant command ``u: (..., n_joint)``
        for one joint moving alone (static map only: no hysteresis, sharing or drift)."""
        u = np.asarray(u, dtype=np.float64)
        p = self.params
        x = np.where(u >= 0, u / p.u_pos, u / p.u_neg)
        return spool_map(np.clip(x, -1.0, 1.0), p) * np.asarray(omega_max, dtype=np.float64)

    def nominal_model(self, *, omega_max: np.ndarray) -> Any:
        """:class:`~.commands.NominalModel` (static map + acceleration limit) of this plant,
        used by the excitation signals to stay off the end stops."""
        from .commands import NominalModel

        omega_max = np.asarray(omega_max, dtype=np.float64)
        accel = self.params.accel * omega_max
        return NominalModel(
            velocity=partial(_nominal_velocity, self, omega_max),
            accel_max=None if not np.all(np.isfinite(accel)) else tuple(accel.tolist()),
        )

    # ------------------------------------------------------------------ CommandTransform
    def reset(self, *, n_batch: int, substeps: int, timestep: float) -> None:
        """Start ``n_batch`` new episodes at rest (all states zero, cold oil)."""
        n = self.spec.n_joint
        p = self.params
        self.n_batch = int(n_batch)
        self.substeps = int(substeps)
        self.timestep = float(timestep)
        self.dt = self.substeps * self.timestep
        self.k = 0  # control steps processed since reset (drift clock)
        self.pump_scale = 1.0
        """Engine throttle: the pump's largest flow is ``pump_scale * pump_max_lpm`` (set per step
        by a closed-loop operator that changes the throttle, :mod:`.session`)."""
        self._play = np.zeros((n_batch, n))
        self._rate = np.zeros((n_batch, n))
        self.n_delay = (
            round(self.config.delay_s / self.timestep) if self.config.transport_delay else 0
        )
        self._delay = np.zeros((n_batch, self.n_delay, n))
        self._a = np.where(p.lag > 0, -np.expm1(-self.timestep / np.maximum(p.lag, 1e-300)), 1.0)
        self._lag = np.zeros((n_batch, n))
        self._step_max = p.accel * self.timestep  # largest demand change per physics step

    def __call__(self, u: np.ndarray) -> np.ndarray:
        """``u: (n_batch, n_step, n_joint)`` commands -> ``(n_batch, n_step * substeps, n_joint)``
        actuator demands in ctrl (command) units."""
        u = np.asarray(u, dtype=np.float64)
        n_batch, n_step, n_joint = u.shape
        if n_batch != self.n_batch or n_joint != self.spec.n_joint:
            raise ConfigError(
                f"hydraulic transform was reset for ({self.n_batch}, *, {self.spec.n_joint}), "
                f"got commands of shape {u.shape}"
            )
        p, c, sub = self.params, self.config, self.substeps
        x = np.clip(np.where(u >= 0, u / p.u_pos, u / p.u_neg), -1.0, 1.0)
        # 1. hysteresis: play operator, rescaled so that full stroke stays full stroke
        if np.any(p.play > 0):
            s = np.empty_like(x)
            z = self._play
            for k in range(n_step):
                z = np.minimum(np.maximum(z, x[:, k] - p.play), x[:, k] + p.play)
                s[:, k] = z
            self._play = z
            s = s / (1.0 - p.play)
        else:
            s = x
        # 2. static valve map
        q = spool_map(s, p)
        # 3. drift (oil warming up): slow multiplicative speed change; the day's slow-down
        if c.drift and c.drift_amplitude > 0:
            t = (self.k + np.arange(n_step)) * self.dt
            q = q * (1.0 - c.drift_amplitude * np.exp(-t / c.drift_tau_s))[None, :, None]
        if c.day_slowdown > 0:
            q = q * (1.0 - c.day_slowdown)
        # 4. flow sharing: one pump
        if c.flow_sharing:
            aq = np.abs(q)
            demand = aq[..., 0] * p.flow[0]  # (n_batch, n_step) L/min; fixed summation order
            for j in range(1, n_joint):  # (a matmul's order depends on the chunk shape)
                demand = demand + aq[..., j] * p.flow[j]
            pump = c.pump_max_lpm * self.pump_scale
            scale = np.minimum(1.0, pump / np.maximum(demand, 1e-12))
            q = q * scale[:, :, None]
        self.k += n_step
        # 5. acceleration limit at the physics rate, closed form within each control step:
        #    z_i = z_0 + clip(q - z_0, -r i, r i), i = 1..substeps
        i = np.arange(1, sub + 1, dtype=np.float64)[:, None]  # (sub, 1)
        if np.all(np.isfinite(self._step_max)):
            starts = np.empty_like(q)
            z = self._rate
            big = self._step_max * sub
            for k in range(n_step):
                starts[:, k] = z
                z = z + np.clip(q[:, k] - z, -big, big)
            self._rate = z
            ramp = self._step_max * i  # (sub, n_joint)
            y = starts[:, :, None, :] + np.clip(
                (q - starts)[:, :, None, :], -ramp, ramp
            )  # (n_batch, n_step, sub, n_joint)
            y = y.reshape(n_batch, n_step * sub, n_joint)
        else:
            y = np.repeat(q, sub, axis=1)
            if n_step:
                self._rate = q[:, -1].copy()
        # 6. transport delay (physics steps)
        if self.n_delay:
            full = np.concatenate([self._delay, y], axis=1)
            y = full[:, : n_step * sub]
            self._delay = full[:, n_step * sub :].copy()
        # 7. first-order valve lag, exact ZOH discretisation: y_n = y_{n-1} + a (x_n - y_{n-1})
        if np.any(self._a < 1.0) and y.shape[1]:
            yt = np.ascontiguousarray(y.transpose(2, 0, 1))  # (n_joint, n_batch, n)
            for j in range(n_joint):
                a = self._a[j]
                if a < 1.0:
                    zi = ((1.0 - a) * self._lag[:, j])[:, None]
                    yt[j] = _first_order(a, yt[j], zi)
                self._lag[:, j] = yt[j, :, -1]
            y = yt.transpose(1, 2, 0)
        return np.where(y >= 0, y * p.u_pos, y * p.u_neg)

    def tiled(self, n_batch: int) -> HydraulicTransform:
        """A copy that continues this transform's ONE command history in ``n_batch`` parallel
        sequences (what a sampling planner forks from the machine's current state)."""
        if self.n_batch != 1:
            raise ConfigError(
                f"hydraulic transform: only a single-sequence transform can be tiled, this one has {self.n_batch}"
            )
        out = copy.copy(self)
        out.n_batch = int(n_batch)
        for k in ("_play", "_rate", "_delay", "_lag"):
            setattr(out, k, np.repeat(getattr(self, k), n_batch, axis=0))
        return out

    def state_dict(self) -> dict[str, Any]:
        """Copies of the internal states (for debugging and tests)."""
        return {
            "k": self.k,
            "play": self._play.copy(),
            "rate": self._rate.copy(),
            "delay": self._delay.copy(),
            "lag": self._lag.copy(),
        }


def _nominal_velocity(
    transform: HydraulicTransform, omega_max: np.ndarray, u: np.ndarray
) -> np.ndarray:
    return transform.nominal_velocity(u, omega_max=omega_max)


def config_fields() -> list[str]:
    """Names of all :class:`HydraulicConfig` fields (for docs and CLI help)."""
    return [f.name for f in fields(HydraulicConfig)]
