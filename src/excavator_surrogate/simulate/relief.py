"""No wind-up at relief: :class:`ReliefAntiWindup`, the force hook of the hydraulic stand-in.

A relief valve is an actuator force limit (MJCF ``forcerange``,
:meth:`~.hydraulics.HydraulicTransform.force_limits`).  A flow-controlled servo that hits it
would keep integrating its setpoint and lunge once the load goes; this hook holds the setpoint
at the limit, as the excess flow of a real cylinder goes over the relief valve to tank.  It
reads the plant's state, so it runs in the Python loop only (docs/hydraulics.md).
"""

from __future__ import annotations

import mujoco
import numpy as np

from ..errors import ConfigError
from ..spec import EXCAVATOR, MachineSpec


class ReliefAntiWindup:
    """:class:`~.hooks.ForceHook` that keeps force-limited servos from winding up.

    The MJCF servos integrate the velocity demand into a position setpoint ``act``.  When the
    actuator force hits its ``forcerange`` (relief valve open), the setpoint would keep
    running ahead of the stalled joint and the joint would lunge forward once the load goes
    away.  Before every physics step this hook clamps ``act`` so that the coming step's
    unclamped servo force ``kp (act + h c - gear q) - kv gear qdot`` (``c``: the delayed
    control MuJoCo will read, ``actearly``) stays inside the force range: the lost flow is
    gone, as with a real relief valve.  Python-loop path only (``mujoco.rollout`` cannot call
    it); it changes nothing while no force limit is reached.

    Args:
        spec: joints (names of the MJCF joints and actuators).
    """

    def __init__(self, *, spec: MachineSpec = EXCAVATOR) -> None:
        self.spec = spec
        self._ready = False

    def reset(self, model: mujoco.MjModel, data: mujoco.MjData) -> None:
        """Look up actuators, gains and force ranges of ``model``."""
        del data
        act = np.array(
            [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_ACTUATOR, n) for n in self.spec.names]
        )
        jnt = np.array(
            [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, n) for n in self.spec.names]
        )
        if np.any(act < 0) or np.any(jnt < 0):
            raise ConfigError(
                f"ReliefAntiWindup: the MJCF lacks joints/actuators {list(self.spec.names)}"
            )
        lim = model.actuator_forcelimited[act].astype(bool)
        self._rows = [
            (
                int(a),
                int(model.actuator_actadr[a]),
                int(model.jnt_qposadr[j]),
                int(model.jnt_dofadr[j]),
                float(model.actuator_gear[a, 0]),
                float(model.actuator_gainprm[a, 0]),
                float(-model.actuator_biasprm[a, 2]),
                float(model.actuator_forcerange[a, 0]),
                float(model.actuator_forcerange[a, 1]),
                float(model.actuator_delay[a]),
            )
            for a, j in zip(act[lim], jnt[lim])
        ]
        self._buf = np.zeros(1)
        self._ready = True

    def __call__(self, model: mujoco.MjModel, data: mujoco.MjData) -> None:
        """Clamp the servo setpoints of force-limited actuators (before ``mj_step``)."""
        if not self._ready:
            self.reset(model, data)
        h = model.opt.timestep
        force, act, qpos, qvel = data.actuator_force, data.act, data.qpos, data.qvel
        for i, aadr, qadr, vadr, gear, kp, kv, lo, hi, delay in self._rows:
            f = force[i]
            # Wind-up only builds up while the force is at its limit: skip unless the last
            # step's force came within 5 % of a limit.
            if 0.95 * lo < f < 0.95 * hi:
                continue
            # With actearly the coming step's force uses act + h * c, with c the (delayed)
            # control MuJoCo reads from the history buffer; one step of the stiff servo's
            # setpoint is worth MN m, so it must be included.
            c = mujoco.mj_readCtrl(model, data, i, data.time - delay, self._buf, 0)[0]
            length = gear * qpos[qadr] - h * c
            damp = kv * gear * qvel[vadr]
            a = act[aadr]
            a_hi = length + (hi + damp) / kp
            a_lo = length + (lo + damp) / kp
            if a > a_hi:
                act[aadr] = a_hi
            elif a < a_lo:
                act[aadr] = a_lo
