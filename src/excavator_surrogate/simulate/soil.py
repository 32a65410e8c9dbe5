"""Compound operation: soil resistance at the bucket tip and a payload that fills and spills.

:class:`SoilHook` is a :class:`~.hooks.ForceHook` (Python-loop path only).  Before every
physics step it

- applies a **cutting resistance** at the bucket tooth tip while the tip is below the ground
  plane ``z < ground_z``: a force opposing the tip velocity ``v`` whose magnitude grows with
  the depth ``d = ground_z - z_tip`` (a Zelenin/McKyes-style "specific cutting resistance"
  ``k`` times the cut cross-section ``w d``) and with speed::

      F = -min(F_max, k w d (1 + c_v |v|)) * f_up * v / sqrt(|v|^2 + v_s^2)

  ``f_up`` (< 1 when the tip moves up) weakens the resistance when pulling out; the smooth
  sign ``v / sqrt(|v|^2 + v_s^2)`` keeps the explicitly applied force stable at 2 ms steps.
  The force is mapped to joint torques with the tip Jacobian: ``qfrc_applied = J_tip^T F``.
- **fills the bucket** with the swept soil volume ``dV = eta w d |v| dt`` (up to
  ``capacity_m3``) while below ground, and **spills** it (``dV = -V dt / spill_tau_s``) above
  ground once the tooth line points forward of ``spill_cos`` (bucket curled out: dumping).
  The payload ``rho V`` is added to the bucket body as a uniform box at ``payload_pos``:
  ``model.body_mass``, ``body_ipos``, ``body_iquat``, ``body_inertia`` change at run time.

``mj_setConst`` is **not** needed after changing the bucket's mass: MuJoCo computes the mass
matrix and bias forces from ``body_mass``/``body_inertia`` at every step (verified against a
recompiled model: identical dynamics to 1e-19 rad after 1 s); only ``body_subtreemass`` and
hence ``data.subtree_com`` go stale, which no part of this plant uses.  ``mj_setConst`` would
even reset ``data.qpos`` to ``qpos0``.  :meth:`SoilHook.reset` restores the empty bucket.

The hook's matrix maths (the tip velocity ``J qvel``, the torques ``J^T F``, the inertia
tensor and its principal axes) uses MuJoCo's own routines (``mju_mulMatVec``,
``mju_mulMatTVec``, ``mju_mulMatMatT``, ``mju_eig3``), not NumPy's ``@`` and ``linalg``.
NumPy hands those to OpenBLAS, which picks its kernels by CPU (AVX-512 ones on an Intel or a
Zen 4 CPU, AVX2 ones on a Zen 5), and they round differently. The closed-loop digging
operator grew that last bit into another log on another computer; MuJoCo's routines are the
same code everywhere.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np

from ..errors import ConfigError


@dataclass(frozen=True)
class SoilConfig:
    """Soil and payload model of the compound scenario (TOML ``[simulate.soil]``)."""

    enabled: bool = False
    """Apply soil forces and payload (requires the Python-loop simulation path)."""
    ground_z: float = 0.0
    """Height of the ground plane [m] (the MJCF's tracks stand on z = 0)."""
    tip_site: str = "tip"
    """MJCF site at the bucket tooth tip."""
    bucket_body: str = "bucket"
    """MJCF body that carries the payload."""
    base_body: str = "upper"
    """MJCF body whose x axis is the machine's forward direction (spill test)."""
    resistance: bool = True
    """Apply the cutting resistance below ground."""
    cutting_resistance_pa: float = 1.5e5
    """Specific cutting resistance k [N/m^2] (medium soil / clay, 0.05-0.3 MPa)."""
    bucket_width_m: float = 1.9
    """Cutting width w [m] (4.5 m^3 bucket of a 75 t class excavator)."""
    speed_factor: float = 0.5
    """Rate effect c_v [s/m]: resistance grows by c_v |v| (inertial soil forces)."""
    up_factor: float = 0.3
    """Fraction of the resistance when the tip moves straight up (pulling out)."""
    smooth_speed: float = 0.5
    """Smoothing speed v_s of the force direction [m/s] (stability of the explicit force)."""
    max_force_n: float = 6.0e5
    """Cap of the resistance magnitude [N]."""
    payload: bool = True
    """Fill and spill a payload in the bucket."""
    density_kg_m3: float = 1700.0
    """Density of the loose soil in the bucket [kg/m^3]."""
    capacity_m3: float = 4.5
    """Heaped bucket capacity [m^3]."""
    fill_efficiency: float = 0.5
    """Fraction eta of the swept volume w d |v| dt that enters the bucket."""
    spill_cos: float = 0.2
    """Spill when cos(angle between the tooth line and the machine's forward axis) exceeds this."""
    spill_tau_s: float = 0.5
    """Time constant of spilling [s]."""
    payload_pos: tuple[float, float, float] = (0.9, 0.0, 0.3)
    """Payload centre in the bucket body frame [m]."""
    payload_half_m: tuple[float, float, float] = (0.7, 0.85, 0.35)
    """Half sizes of the payload box (for its inertia) [m]."""
    update_kg: float = 50.0
    """Re-write the bucket's inertial parameters when the payload changed by more than this [kg]."""

    def __post_init__(self) -> None:
        for name in (
            "cutting_resistance_pa",
            "bucket_width_m",
            "speed_factor",
            "max_force_n",
            "density_kg_m3",
            "capacity_m3",
            "fill_efficiency",
            "update_kg",
        ):
            if not getattr(self, name) >= 0:
                raise ConfigError(f"soil.{name} must be >= 0, got {getattr(self, name)}")
        for name in ("smooth_speed", "spill_tau_s"):
            if not getattr(self, name) > 0:
                raise ConfigError(f"soil.{name} must be > 0, got {getattr(self, name)}")
        if not 0 <= self.up_factor <= 1:
            raise ConfigError(f"soil.up_factor must be in [0, 1], got {self.up_factor}")


def _box_inertia(mass: float, half: np.ndarray) -> np.ndarray:
    """3x3 inertia tensor of a uniform box about its centre."""
    a2 = (2.0 * half) ** 2
    return mass / 12.0 * np.diag([a2[1] + a2[2], a2[0] + a2[2], a2[0] + a2[1]])


def _shift(mass: float, d: np.ndarray) -> np.ndarray:
    """Parallel-axis term ``m (|d|^2 E - d d^T)``."""
    return mass * (mujoco.mju_dot3(d, d) * np.eye(3) - np.outer(d, d))


class SoilHook:
    """:class:`~.hooks.ForceHook`: soil resistance below ground, payload fill and spill.

    Attributes (updated every physics step, for logging):
        depth: tip depth below ground [m] (negative above ground).
        volume: soil in the bucket [m^3]; ``payload_kg = density * volume``.
        force: (3,) resistance applied at the tip [N].
        stats: counters: ``below_ground_s``, ``dug_m3``, ``dumped_m3``, ``n_dump``,
            ``max_payload_kg``.
    """

    def __init__(self, config: SoilConfig | None = None) -> None:
        self.config = config or SoilConfig()
        self._model_id: int | None = None
        self.depth = 0.0
        self.volume = 0.0
        self.force = np.zeros(3)
        self.stats: dict[str, float] = {}

    # ------------------------------------------------------------------ setup
    def _bind(self, model: mujoco.MjModel) -> None:
        c = self.config
        self._tip = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, c.tip_site)
        self._bucket = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, c.bucket_body)
        self._base = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, c.base_body)
        if min(self._tip, self._bucket, self._base) < 0:
            raise ConfigError(
                f"soil: the MJCF needs site '{c.tip_site}' and bodies '{c.bucket_body}', "
                f"'{c.base_body}'"
            )
        b = self._bucket
        self._m0 = float(model.body_mass[b])
        self._ipos0 = model.body_ipos[b].copy()
        self._iquat0 = model.body_iquat[b].copy()
        self._inertia0 = model.body_inertia[b].copy()
        rot = np.empty(9)
        mujoco.mju_quat2Mat(rot, self._iquat0)
        r = rot.reshape(3, 3)
        # I0 = R diag(I) R^T: the body-frame inertia tensor about ipos0
        self._I0 = np.empty((3, 3))
        mujoco.mju_mulMatMatT(self._I0, r * self._inertia0, r)
        self._jacp = np.zeros((3, model.nv))
        self._v = np.zeros(3)
        self._f = np.zeros(3)
        self._model_id = id(model)

    def reset(self, model: mujoco.MjModel, data: mujoco.MjData) -> None:
        """Empty the bucket (restore its inertial parameters) and clear the forces."""
        del data
        if self._model_id != id(model):
            self._bind(model)
        self._set_payload(model, 0.0)
        self.volume = 0.0
        self.depth = 0.0
        self.force = np.zeros(3)
        self._applied = False
        self.stats = {
            "below_ground_s": 0.0,
            "dug_m3": 0.0,
            "dumped_m3": 0.0,
            "n_dump": 0,
            "max_payload_kg": 0.0,
        }
        self._loaded = False
        self._volume_seen = 0.0

    @property
    def payload_kg(self) -> float:
        """Current payload mass [kg]."""
        return self.config.density_kg_m3 * self.volume

    def _set_payload(self, model: mujoco.MjModel, mass: float) -> None:
        """Write bucket mass, COM, principal inertia and frame for a payload of ``mass`` kg."""
        b = self._bucket
        self._mass_set = mass
        if mass <= 0:
            model.body_mass[b] = self._m0
            model.body_ipos[b] = self._ipos0
            model.body_iquat[b] = self._iquat0
            model.body_inertia[b] = self._inertia0
            return
        cp = np.asarray(self.config.payload_pos, dtype=np.float64)
        total = self._m0 + mass
        com = (self._m0 * self._ipos0 + mass * cp) / total
        inertia = (
            self._I0
            + _shift(self._m0, self._ipos0 - com)
            + _box_inertia(mass, np.asarray(self.config.payload_half_m, dtype=np.float64))
            + _shift(mass, cp - com)
        )
        # inertia = V diag(val) V^T, V the rotation of the principal frame (as quat)
        val, vec, quat = np.empty(3), np.empty(9), np.empty(4)
        mujoco.mju_eig3(val, vec, quat, inertia.reshape(-1))
        model.body_mass[b] = total
        model.body_ipos[b] = com
        model.body_iquat[b] = quat
        model.body_inertia[b] = val

    # ------------------------------------------------------------------ per step
    def __call__(self, model: mujoco.MjModel, data: mujoco.MjData) -> None:
        """Apply soil forces and update the payload for the coming physics step."""
        if self._model_id != id(model):
            self.reset(model, data)
        c = self.config
        self.depth = depth = c.ground_z - float(data.site_xpos[self._tip, 2])
        if depth <= 0 and self.volume == 0.0 and not self._applied:
            return  # above ground, empty bucket: nothing to do
        h = model.opt.timestep
        if depth > 0:
            self.stats["below_ground_s"] += h
            jac = self._jacp
            mujoco.mj_jacSite(model, data, jac, None, self._tip)
            # v = J qvel: the tip velocity [m/s]
            mujoco.mju_mulMatVec(self._v, jac, data.qvel)
            vx, vy, vz = self._v.tolist()
            speed = math.sqrt(vx * vx + vy * vy + vz * vz)
            if c.resistance:
                mag = min(
                    c.max_force_n,
                    c.cutting_resistance_pa
                    * c.bucket_width_m
                    * depth
                    * (1.0 + c.speed_factor * speed),
                )
                up = min(max(vz / (speed + 1e-9), 0.0), 1.0)
                mag *= 1.0 - (1.0 - c.up_factor) * up
                scale = -mag / math.sqrt(speed * speed + c.smooth_speed * c.smooth_speed)
                self._f[0], self._f[1], self._f[2] = scale * vx, scale * vy, scale * vz
                self.force = self._f
                # qfrc_applied = J^T F
                mujoco.mju_mulMatTVec(data.qfrc_applied, jac, self._f)
                self._applied = True
            if c.payload and self.volume < c.capacity_m3:
                dv = c.fill_efficiency * c.bucket_width_m * depth * speed * h
                dv = min(dv, c.capacity_m3 - self.volume)
                self.volume += dv
                self.stats["dug_m3"] += dv
        else:
            if self._applied:
                data.qfrc_applied[:] = 0.0
                self.force = np.zeros(3)
                self._f = np.zeros(3)
                self._applied = False
            if self.volume > 0:
                # cos of the angle between the tooth line (tip site x axis) and the machine's
                # forward axis (base body x axis); matrices are row-major 3x3
                sx, bx = data.site_xmat[self._tip], data.xmat[self._base]
                cos = float(sx[0] * bx[0] + sx[3] * bx[3] + sx[6] * bx[6])
                if cos > c.spill_cos:
                    dv = self.volume * min(1.0, h / c.spill_tau_s)
                    if self.volume - dv < 0.01 * c.capacity_m3:  # the last 1 % falls out at once
                        dv = self.volume
                    self.volume -= dv
                    self.stats["dumped_m3"] += dv
        if self.volume == self._volume_seen:
            return
        self._volume_seen = self.volume
        mass = c.density_kg_m3 * self.volume
        if mass > self.stats["max_payload_kg"]:
            self.stats["max_payload_kg"] = mass
        if mass > 0.5 * c.density_kg_m3 * c.capacity_m3:
            self._loaded = True
        elif self._loaded and mass < 0.1 * c.density_kg_m3 * c.capacity_m3:
            self._loaded = False
            self.stats["n_dump"] += 1
        if c.payload and (
            abs(mass - self._mass_set) > c.update_kg or (mass == 0.0) != (self._mass_set == 0.0)
        ):
            self._set_payload(model, mass)


class ChainHook:
    """Calls several :class:`~.hooks.ForceHook` objects in order (and their ``reset``)."""

    def __init__(self, *hooks: Any) -> None:
        self.hooks = tuple(h for h in hooks if h is not None)

    def reset(self, model: mujoco.MjModel, data: mujoco.MjData) -> None:
        """Reset every hook that has a ``reset``."""
        for h in self.hooks:
            if hasattr(h, "reset"):
                h.reset(model, data)

    def __call__(self, model: mujoco.MjModel, data: mujoco.MjData) -> None:
        """Call every hook."""
        for h in self.hooks:
            h(model, data)
