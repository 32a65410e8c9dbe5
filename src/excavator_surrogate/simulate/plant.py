"""The Stage I MuJoCo excavator plant: commands in, joint angles and velocities out.

Sampling convention (the surrogate relies on it), with ``T_s = 1 / rate_hz`` and
``t_k = k T_s``:

- ``theta[k]``: joint angle at ``t_k`` [rad]; periodic joints (swing) are unwrapped.
- ``u[k]``: command applied during ``[t_k, t_{k+1})`` (the last command of a sequence is
  therefore never applied).
- ``omega[k] = (theta[k] - theta[k-1]) / T_s``: mean joint velocity over the preceding
  interval ``[t_{k-1}, t_k]`` [rad/s]; ``omega[0]`` is the instantaneous velocity at ``t_0``
  (zero after :meth:`MujocoExcavator.reset`).  With MuJoCo's (semi-)implicit Euler, this equals
  the mean of ``qvel`` over the interval's physics steps.

Two paths produce identical numbers: :meth:`MujocoExcavator.step` (Python loop, the
reference, supports a :class:`~.hooks.ForceHook`) and :meth:`MujocoExcavator.rollout`
(``mujoco.rollout``, multi-threaded, chunked in time to bound memory).
"""

from __future__ import annotations

from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

import mujoco
import numpy as np
from mujoco import rollout as mj_rollout

from ..errors import ConfigError
from ..spec import EXCAVATOR, MachineSpec
from .hooks import CommandTransform, ForceHook, ZeroOrderHold

_FULL = mujoco.mjtState.mjSTATE_FULLPHYSICS.value
_CTRL = mujoco.mjtState.mjSTATE_CTRL.value


def default_xml() -> Path:
    """Path of the packaged MJCF (``simulate/assets/excavator.xml``)."""
    return Path(
        str(resources.files("excavator_surrogate") / "simulate" / "assets" / "excavator.xml")
    )


@dataclass(frozen=True)
class PlantConfig:
    """Options of :class:`MujocoExcavator`."""

    xml: str = ""
    """MJCF file of the machine; empty = the packaged SY750H-like excavator."""
    rate_hz: float = 20.0
    """Control/sample rate [Hz]; 1/rate_hz must be a whole number of MJCF timesteps."""
    delay_s: float = 0.05
    """Actuation delay [s] (MJCF actuator ``delay``); at most nsample x timestep of the MJCF."""
    n_threads: int = 1
    """Threads used by the batched :meth:`MujocoExcavator.rollout` (1 = calling thread)."""
    chunk_mb: float = 64.0
    """Memory budget [MB] of one batched rollout chunk (state buffer), bounds peak memory."""
    force_min: tuple[float, ...] = ()
    """Per-joint lower actuator torque limits [N m] (e.g. relief valves); empty = none, or
    the command transform's ``force_limits()`` if it has one."""
    force_max: tuple[float, ...] = ()
    """Per-joint upper actuator torque limits [N m]; empty = none (see ``force_min``)."""


def _state_offsets(model: mujoco.MjModel) -> dict[str, int]:
    """Offsets of the components of an ``mjSTATE_FULLPHYSICS`` vector (ordered by bit)."""
    offsets: dict[str, int] = {}
    pos = 0
    for name in ("TIME", "QPOS", "QVEL", "ACT", "HISTORY"):
        bit = getattr(mujoco.mjtState, f"mjSTATE_{name}").value
        offsets[name] = pos
        pos += mujoco.mj_stateSize(model, bit)
    return offsets


def rate_fits(rate_hz: float, timestep: float) -> bool:
    """Whether the sample period ``1 / rate_hz`` is a whole number (>= 1) of physics steps of
    ``timestep`` [s] (as :class:`MujocoExcavator` requires)."""
    ratio = 1.0 / rate_hz / timestep
    return round(ratio) >= 1 and abs(ratio - round(ratio)) <= 1e-6


class MujocoExcavator:
    """A MuJoCo machine driven by joint commands at the control rate.

    Args:
        config: plant options.
        spec: joints (names must match MJCF joints and actuators), command ranges, rate.
        command_transform: control-rate commands -> physics-rate actuator demands
            (default :class:`~.hooks.ZeroOrderHold`, the ideal Stage I plant).
        force_hook: called before every physics step in the Python loop (default none);
            its optional ``reset(model, data)`` runs at :meth:`reset` before the pose is set.

    Attributes:
        model, data: the MuJoCo model and the Python-loop data.
        substeps: physics steps per control step (25 for 2 ms / 20 Hz).
        omega_max: (n_joint,) joint velocity [rad/s] demanded by command ``u_max``.
    """

    def __init__(
        self,
        config: PlantConfig | None = None,
        *,
        spec: MachineSpec = EXCAVATOR,
        command_transform: CommandTransform | None = None,
        force_hook: ForceHook | None = None,
    ) -> None:
        self.config = config = config or PlantConfig()
        if not abs(spec.rate_hz - config.rate_hz) <= 1e-9:  # NaN too: with_rate refuses it
            spec = spec.with_rate(config.rate_hz)
        self.spec = spec
        xml = Path(config.xml) if config.xml else default_xml()
        if not xml.is_file():
            raise ConfigError(
                f"{xml}: MJCF file not found (leave 'xml' empty for the packaged excavator)"
            )
        try:
            self.model = mujoco.MjModel.from_xml_path(str(xml))
        except ValueError as e:
            raise ConfigError(f"{xml}: MuJoCo cannot load the model ({e})") from e
        m = self.model
        self.data = mujoco.MjData(m)
        self.dt = 1.0 / config.rate_hz
        self.substeps = round(self.dt / m.opt.timestep)
        if not rate_fits(config.rate_hz, m.opt.timestep):
            raise ConfigError(
                f"{xml}: rate_hz = {config.rate_hz:g} Hz samples every {self.dt:g} s, not a "
                f"whole number of the MJCF's {m.opt.timestep:g} s timesteps; use rate_hz = "
                f"{1.0 / m.opt.timestep:g} Hz / n, or change the MJCF timestep"
            )
        self._jnt = np.array([self._named(mujoco.mjtObj.mjOBJ_JOINT, n, xml) for n in spec.names])
        self._act = np.array(
            [self._named(mujoco.mjtObj.mjOBJ_ACTUATOR, n, xml) for n in spec.names]
        )
        self._qadr = m.jnt_qposadr[self._jnt].copy()
        self._vadr = m.jnt_dofadr[self._jnt].copy()
        if np.any(m.actuator_dyntype[self._act] != mujoco.mjtDyn.mjDYN_INTEGRATOR):
            raise ConfigError(f"{xml}: every joint actuator must be an integrated-velocity servo")
        self._aadr = m.actuator_actadr[self._act].copy()
        self._set_delay(config.delay_s, xml)
        self.gear = m.actuator_gear[self._act, 0].copy()
        u_max = np.array([j.u_max for j in spec.joints])
        self.omega_max = u_max / self.gear
        self._offsets = _state_offsets(m)
        self.n_state = mujoco.mj_stateSize(m, _FULL)
        self.transform: CommandTransform = command_transform or ZeroOrderHold()
        self.force_hook = force_hook
        self._set_force_limits(xml)
        self._pool: mj_rollout.Rollout | None = None
        self._pool_data: list[mujoco.MjData] = []
        self._theta = np.zeros(spec.n_joint)
        self._scratch = mujoco.MjData(m)

    # ------------------------------------------------------------------ setup helpers
    def _named(self, obj: mujoco.mjtObj, name: str, xml: Path) -> int:
        i = mujoco.mj_name2id(self.model, obj, name)
        if i < 0:
            kind = "joint" if obj == mujoco.mjtObj.mjOBJ_JOINT else "actuator"
            raise ConfigError(
                f"{xml}: no {kind} named '{name}' (the spec's joints are {list(self.spec.names)})"
            )
        return int(i)

    def _set_delay(self, delay_s: float, xml: Path) -> None:
        m = self.model
        if delay_s < 0:
            raise ConfigError(f"delay_s must be >= 0, got {delay_s}")
        # the longest delay every actuator's ctrl history ring buffer can hold [s]
        cap = float(m.actuator_history[self._act, 0].min()) * m.opt.timestep
        for name, a in zip(self.spec.names, self._act):
            nsample = int(m.actuator_history[a, 0])
            if delay_s > 0 and delay_s > nsample * m.opt.timestep + 1e-12:
                what = "delay_s (simulate.delay_s, PlantConfig.delay_s)"
                if not self.config.xml:
                    raise ConfigError(
                        f"{what} = {delay_s:g} s exceeds the packaged excavator's {cap:g} s "
                        f"delay buffer (joint '{name}'); use 0 <= delay_s <= {cap:g}, add dead "
                        f'time with plant = "hydraulic" and hydraulics.delay_s, or copy the '
                        f"MJCF, raise its actuators' nsample and set simulate.xml to the copy"
                    )
                raise ConfigError(
                    f"{xml}: {what} = {delay_s:g} s exceeds the ctrl history of joint '{name}' "
                    f"({nsample} samples x {m.opt.timestep:g} s); use 0 <= delay_s <= {cap:g}, "
                    f"or raise that actuator's nsample in the MJCF"
                )
            # Read the history just after (t - delay): robust to floating-point time rounding
            # with zero-order hold, so the delay is exactly delay_s rounded up to the timestep.
            m.actuator_delay[a] = max(0.0, delay_s - 0.05 * m.opt.timestep) if delay_s > 0 else 0.0

    def _set_force_limits(self, xml: Path) -> None:
        """Actuator torque limits from the config, else from the command transform (relief)."""
        cfg, n = self.config, self.spec.n_joint
        limits: tuple[Any, Any] | None = None
        if cfg.force_min or cfg.force_max:
            lo = (
                np.asarray(cfg.force_min, dtype=np.float64)
                if cfg.force_min
                else np.full(n, -np.inf)
            )
            hi = (
                np.asarray(cfg.force_max, dtype=np.float64) if cfg.force_max else np.full(n, np.inf)
            )
            limits = (lo, hi)
        elif callable(getattr(self.transform, "force_limits", None)):
            limits = self.transform.force_limits()  # type: ignore[attr-defined]
        if limits is None:
            return
        lo, hi = (np.asarray(x, dtype=np.float64).reshape(-1) for x in limits)
        if (
            lo.shape != (n,)
            or hi.shape != (n,)
            or np.any(lo >= hi)
            or np.any(lo > 0)
            or np.any(hi < 0)
        ):
            raise ConfigError(
                f"{xml}: force limits need {n} values each with force_min <= 0 <= force_max, "
                f"got {lo.tolist()} / {hi.tolist()}"
            )
        m = self.model
        big = 1e30  # one-sided limits: MuJoCo needs finite ranges
        m.actuator_forcelimited[self._act] = 1
        m.actuator_forcerange[self._act, 0] = np.maximum(lo, -big) / self.gear
        m.actuator_forcerange[self._act, 1] = np.minimum(hi, big) / self.gear

    # ------------------------------------------------------------------ state
    @property
    def n_joint(self) -> int:
        """Number of joints."""
        return self.spec.n_joint

    def default_pose(self) -> np.ndarray:
        """(n_joint,) mid-range angles (0 for unlimited joints) [rad]."""
        out = np.zeros(self.n_joint)
        for k, j in enumerate(self.spec.joints):
            if j.theta_min is not None and j.theta_max is not None:
                out[k] = 0.5 * (j.theta_min + j.theta_max)
        return out

    def _check_theta0(self, theta0: np.ndarray) -> None:
        for k, j in enumerate(self.spec.joints):
            lo = -np.inf if j.theta_min is None else j.theta_min
            hi = np.inf if j.theta_max is None else j.theta_max
            bad = (theta0[..., k] < lo - 1e-9) | (theta0[..., k] > hi + 1e-9)
            if np.any(bad):
                raise ConfigError(
                    f"initial angle of joint '{j.name}' outside its range [{lo:g}, {hi:g}] rad: "
                    f"{np.asarray(theta0[..., k])[bad].ravel()[0]:.4g}"
                )

    def _settle(self, data: mujoco.MjData, theta0: np.ndarray) -> None:
        """Reset ``data`` to rest at ``theta0`` with zero ctrl history and the servo setpoints
        pre-loaded against gravity, so the machine starts in exact static equilibrium.

        Except at an end stop: a joint at its limit gets a preload beyond ``actrange``, which
        MuJoCo clamps, so it settles by up to 0.45 mrad (docs/plant.md, Known limitations)."""
        m = self.model
        mujoco.mj_resetData(m, data)
        data.qpos[self._qadr] = theta0
        mujoco.mj_forward(m, data)
        tau = data.qfrc_bias[self._vadr]  # gravity (qvel = 0), N m
        kp = m.actuator_gainprm[self._act, 0]
        data.act[self._aadr] = self.gear * theta0 + tau / (self.gear * kp)
        mujoco.mj_forward(m, data)

    def site_position(self, theta: np.ndarray, site: str = "tip") -> np.ndarray:
        """(3,) world position [m] of the MJCF site ``site`` at joint angles ``theta: (n_joint,)``
        (kinematics only; the simulation state is not touched)."""
        i = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_SITE, site)
        if i < 0:
            raise ConfigError(f"the MJCF has no site named '{site}'")
        d = self._scratch
        d.qpos[self._qadr] = np.asarray(theta, dtype=np.float64)
        mujoco.mj_kinematics(self.model, d)
        return d.site_xpos[i].copy()

    def initial_state(self, theta0: np.ndarray) -> np.ndarray:
        """Full physics state ``(n_batch, n_state)`` at rest at ``theta0: (n_batch, n_joint)`` [rad]."""
        theta0 = np.atleast_2d(np.asarray(theta0, dtype=np.float64))
        self._check_theta0(theta0)
        out = np.empty((theta0.shape[0], self.n_state))
        for b in range(theta0.shape[0]):
            self._settle(self._scratch, theta0[b])
            mujoco.mj_getState(self.model, self._scratch, out[b], _FULL)
        return out

    # ------------------------------------------------------------------ Python loop
    def reset(self, *, theta0: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Start an episode at rest at ``theta0: (n_joint,)`` [rad] (default mid-range).

        Returns:
            ``(theta, omega)``, each ``(n_joint,)``: sample 0 (omega is zero).
        """
        theta0 = self.default_pose() if theta0 is None else np.asarray(theta0, dtype=np.float64)
        if theta0.shape != (self.n_joint,):
            raise ConfigError(f"theta0 must have shape ({self.n_joint},), got {theta0.shape}")
        self._check_theta0(theta0)
        # The hook's reset runs first, so that it can restore model parameters (e.g. remove a
        # payload) before the servos are pre-loaded for static equilibrium at theta0.
        if self.force_hook is not None and hasattr(self.force_hook, "reset"):
            self.force_hook.reset(self.model, self.data)  # type: ignore[attr-defined]
        self._settle(self.data, theta0)
        self.transform.reset(n_batch=1, substeps=self.substeps, timestep=self.model.opt.timestep)
        self._theta = self.data.qpos[self._qadr].copy()
        return self._theta.copy(), self.data.qvel[self._vadr].copy()

    def step(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Apply ``u: (n_joint,)`` (command units) for one control period ``T_s``.

        Returns:
            ``(theta, omega)``, each ``(n_joint,)``: the next sample, with omega the mean
            velocity over the period [rad/s].

        Raises:
            ConfigError: ``u`` of another shape, or NaN/Inf in it (naming the joint); the
                plant and the transform's state are left untouched.
        """
        m, d = self.model, self.data
        u = np.asarray(u, dtype=np.float64)
        if u.shape != (self.n_joint,):
            raise ConfigError(f"u must have shape ({self.n_joint},), got {u.shape}")
        # before the transform: a NaN would poison its state (e.g. the hysteresis) for good
        self._check_finite(u)
        u = u.reshape(1, 1, self.n_joint)
        demand = self.transform(u)[0]  # (substeps, n_joint)
        if self.force_hook is None and np.all(demand == demand[0]):
            d.ctrl[self._act] = demand[0]
            mujoco.mj_step(m, d, nstep=self.substeps)
        else:
            for s in range(self.substeps):
                d.ctrl[self._act] = demand[s]
                if self.force_hook is not None:
                    self.force_hook(m, d)
                mujoco.mj_step(m, d)
        theta = d.qpos[self._qadr].copy()
        omega = (theta - self._theta) / self.dt
        self._theta = theta
        return theta.copy(), omega

    def simulate(self, u: np.ndarray, *, theta0: np.ndarray) -> dict[str, np.ndarray]:
        """Python-loop reference with the same interface as :meth:`rollout`.

        Args:
            u: (n_batch, n_step, n_joint) commands in [-1000, 1000]; u[:, -1] is never applied.
            theta0: (n_batch, n_joint) initial angles [rad].

        Returns:
            ``{"theta", "omega"}``, each (n_batch, n_step, n_joint).
        """
        u, theta0 = self._check_batch(u, theta0)
        n_batch, n_step, _ = u.shape
        theta = np.empty_like(u)
        omega = np.empty_like(u)
        for b in range(n_batch):
            theta[b, 0], omega[b, 0] = self.reset(theta0=theta0[b])
            for k in range(n_step - 1):
                theta[b, k + 1], omega[b, k + 1] = self.step(u[b, k])
        return {"theta": theta, "omega": omega}

    # ------------------------------------------------------------------ batched
    def _check_batch(self, u: np.ndarray, theta0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        u = np.asarray(u, dtype=np.float64)
        theta0 = np.asarray(theta0, dtype=np.float64)
        if u.ndim != 3 or u.shape[2] != self.n_joint or u.shape[1] < 1:
            raise ConfigError(
                f"u must have shape (n_batch, n_step >= 1, {self.n_joint}), got {u.shape}"
            )
        if theta0.shape != (u.shape[0], self.n_joint):
            raise ConfigError(
                f"theta0 must have shape ({u.shape[0]}, {self.n_joint}), got {theta0.shape}"
            )
        self._check_finite(u)
        return u, theta0

    def _check_finite(self, u: np.ndarray) -> None:
        """Refuse NaN/Inf in ``u: (..., n_joint)`` in one line naming the first bad joint."""
        bad = ~np.isfinite(u)
        if np.any(bad):
            k = int(np.flatnonzero(bad.reshape(-1, self.n_joint).any(axis=0))[0])
            value = u[..., k][bad[..., k]].ravel()[0]
            raise ConfigError(
                f"u contains non-finite commands: joint '{self.spec.names[k]}' got {value}; "
                f"commands must be finite numbers in [-u_max, u_max]"
            )

    def _ensure_pool(self) -> None:
        n = max(1, int(self.config.n_threads))
        if self._pool is None:
            self._pool = mj_rollout.Rollout(nthread=n if n > 1 else 0)
            self._pool_data = [mujoco.MjData(self.model) for _ in range(n)]

    def close(self) -> None:
        """Stop the rollout thread pool (also done at garbage collection)."""
        if self._pool is not None:
            self._pool.close()
            self._pool = None
            self._pool_data = []

    def __enter__(self) -> MujocoExcavator:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def __del__(self) -> None:  # pragma: no cover - best effort
        try:
            self.close()
        except Exception:
            pass

    def rollout(self, u: np.ndarray, *, theta0: np.ndarray) -> dict[str, np.ndarray]:
        """Simulate a batch of episodes with ``mujoco.rollout`` (``config.n_threads`` threads).

        Identical to :meth:`simulate` (same numbers); requires no force hook.

        Args:
            u: (n_batch, n_step, n_joint) commands in [-1000, 1000] at the control rate;
                u[:, k] acts during [t_k, t_{k+1}); u[:, -1] is never applied.
            theta0: (n_batch, n_joint) initial angles [rad]; every episode starts at rest.

        Returns:
            ``{"theta", "omega"}``, each (n_batch, n_step, n_joint) [rad], [rad/s].
        """
        if self.force_hook is not None:
            raise ConfigError(
                "the batched rollout cannot apply a force hook; use simulate()/step()"
            )
        u, theta0 = self._check_batch(u, theta0)
        state = self.initial_state(theta0)
        self.transform.reset(
            n_batch=u.shape[0], substeps=self.substeps, timestep=self.model.opt.timestep
        )
        return self._rollout(state, u)

    def physics_state(self) -> np.ndarray:
        """The Python-loop data's full physics state ``(n_state,)`` (time, qpos, qvel, act and
        the actuator delay history): with the transform's state, all a rollout continues from."""
        out = np.empty(self.n_state)
        mujoco.mj_getState(self.model, self.data, out, _FULL)
        return out

    def rollout_from(self, state: np.ndarray, u: np.ndarray) -> dict[str, np.ndarray]:
        """Continue a batch of episodes from full physics states with ``mujoco.rollout``.

        Unlike :meth:`rollout`, the command transform is NOT reset: it must already hold the
        ``n_batch`` command histories that belong to ``state`` (e.g. a tiled copy of another
        plant's transform, see :meth:`~.hydraulics.HydraulicTransform.tiled`).

        Args:
            state: (n_batch, n_state) full physics states (:meth:`physics_state`).
            u: (n_batch, n_step, n_joint) commands; u[:, k] acts during [t_k, t_{k+1});
                u[:, -1] is never applied.

        Returns:
            ``{"theta", "omega"}``, each (n_batch, n_step, n_joint) [rad], [rad/s]; sample 0
            is the state's angle and instantaneous velocity.
        """
        if self.force_hook is not None:
            raise ConfigError(
                "the batched rollout cannot apply a force hook; use simulate()/step()"
            )
        state = np.asarray(state, dtype=np.float64)
        u = np.asarray(u, dtype=np.float64)
        if state.ndim != 2 or state.shape[1] != self.n_state:
            raise ConfigError(f"state must have shape (n_batch, {self.n_state}), got {state.shape}")
        if u.ndim != 3 or u.shape[0] != state.shape[0] or u.shape[2] != self.n_joint:
            raise ConfigError(
                f"u must have shape ({state.shape[0]}, n_step, {self.n_joint}), got {u.shape}"
            )
        self._check_finite(u)
        return self._rollout(np.ascontiguousarray(state), u)

    def _rollout(self, state: np.ndarray, u: np.ndarray) -> dict[str, np.ndarray]:
        """``mujoco.rollout`` from ``state: (n_batch, n_state)`` with the transform as it is."""
        m = self.model
        n_batch, n_step, n_joint = u.shape
        sub = self.substeps
        theta = np.empty_like(u)
        omega = np.empty_like(u)
        q, v = self._offsets["QPOS"], self._offsets["QVEL"]
        theta[:, 0] = state[:, q + self._qadr]
        omega[:, 0] = state[:, v + self._vadr]
        if n_step == 1:
            return {"theta": theta, "omega": omega}
        self._ensure_pool()
        bytes_per_step = n_batch * sub * (self.n_state + m.nu) * 8
        chunk = max(1, min(n_step - 1, int(self.config.chunk_mb * 2**20 // bytes_per_step)))
        n_thread = max(1, int(self.config.n_threads))
        prev = theta[:, 0].copy()
        ctrl_buf = np.zeros((n_batch, chunk * sub, m.nu))
        state_buf = np.empty((n_batch, chunk * sub, self.n_state))  # reused: no page faults
        k0 = 0
        while k0 < n_step - 1:
            k1 = min(n_step - 1, k0 + chunk)
            n = (k1 - k0) * sub
            demand = self.transform(u[:, k0:k1])
            if demand.shape != (n_batch, n, n_joint):
                raise ConfigError(
                    f"command transform returned shape {demand.shape}, expected {(n_batch, n, n_joint)}"
                )
            if n == ctrl_buf.shape[1]:
                ctrl, out = ctrl_buf, state_buf
            else:  # last, shorter chunk
                ctrl = np.zeros((n_batch, n, m.nu))
                out = np.empty((n_batch, n, self.n_state))
            ctrl[:, :, self._act] = demand
            assert self._pool is not None
            out, _ = self._pool.rollout(
                m, self._pool_data[:n_thread], state, ctrl, control_spec=_CTRL, nstep=n, state=out
            )
            th = out[:, sub - 1 :: sub, q + self._qadr]  # (n_batch, k1 - k0, n_joint)
            theta[:, k0 + 1 : k1 + 1] = th
            omega[:, k0 + 1 : k1 + 1] = (
                th - np.concatenate([prev[:, None], th[:, :-1]], axis=1)
            ) / self.dt
            prev = th[:, -1].copy()
            state = np.ascontiguousarray(out[:, -1])
            k0 = k1
        return {"theta": theta, "omega": omega}
