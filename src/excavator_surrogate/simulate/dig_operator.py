"""The closed-loop ``dig_cycle`` operator: :class:`DigOperator` and its :class:`DigCycleParams`.

Unlike the open-loop signals (:mod:`.signals`), it reads the plant state every control step,
so it is run step by step against the plant by :func:`~.generate.simulate_episode`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from ..errors import ConfigError
from ..spec import MachineSpec
from .commands import RngLike, as_rng


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
