"""The closed-loop ``dig_session`` operator: one long shift of digging, free moves and pauses.

A real machine's log is rarely a clean series of work cycles.  An operator digs a few
cycles, stops, repositions the front, waits for a truck, changes the engine throttle and
digs again somewhere else.  :class:`SessionOperator` scripts that around the
:class:`~.dig_operator.DigOperator`:

- after every completed digging cycle, with probability ``p_break``, a **break**: either an
  idle pause (levers released, ``idle_min_s``-``idle_max_s``) or a spell of **free moves**
  (``free_min_s``-``free_max_s`` of moving the front and the swing to random poses above
  ground, each move proportional to the remaining error, as the digging operator's levers);
- at the start of a break, with probability ``p_throttle``, a new **engine throttle** from
  ``throttle_levels``: the pump's largest flow scales with it (the hydraulic plant's
  ``pump_scale``), so at low throttle fast compound moves slow down;
- after a break, digging resumes in a new direction (a new :meth:`DigOperator.reset`).

The throttle is what a real log records next to the joysticks (engine speed, throttle
setting); with ``SimulateConfig.inputs = ["throttle"]`` it becomes the exogenous input
``u_throttle`` (a fraction of full throttle).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import ConfigError
from ..spec import MachineSpec
from .commands import RngLike, as_rng
from .dig_operator import DigCycleParams, DigOperator


@dataclass(frozen=True)
class SessionParams:
    """Closed-loop operator shift: digging cycles, free moves, idle pauses, throttle changes."""

    p_break: float = 0.5
    """Probability of a break after a digging cycle."""
    p_idle: float = 0.4
    """Probability that a break is an idle pause (else free moves)."""
    idle_min_s: float = 3.0
    """Shortest idle pause [s]."""
    idle_max_s: float = 15.0
    """Longest idle pause [s]."""
    free_min_s: float = 8.0
    """Shortest spell of free moves [s]."""
    free_max_s: float = 30.0
    """Longest spell of free moves [s]."""
    move_timeout_s: float = 8.0
    """Longest single free move before the next target [s]."""
    swing_reach_deg: float = 120.0
    """Free moves swing up to +- this from the current direction [deg]."""
    throttle_levels: tuple[float, ...] = (0.5, 0.75, 1.0)
    """Engine throttle settings [fraction of full] the operator chooses from."""
    p_throttle: float = 0.5
    """Probability that the throttle changes at a break."""
    throttle_start: float = 1.0
    """Engine throttle at the start of the shift [fraction of full]."""

    def __post_init__(self) -> None:
        for name in ("p_break", "p_idle", "p_throttle"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ConfigError(
                    f"dig_session.{name} must be in [0, 1], got {getattr(self, name)}"
                )
        for lo, hi in (("idle_min_s", "idle_max_s"), ("free_min_s", "free_max_s")):
            if not 0.0 <= getattr(self, lo) <= getattr(self, hi):
                raise ConfigError(f"dig_session: need 0 <= {lo} <= {hi}")
        if not self.move_timeout_s > 0:
            raise ConfigError(f"dig_session.move_timeout_s must be > 0, got {self.move_timeout_s}")
        levels = (*self.throttle_levels, self.throttle_start)
        if not self.throttle_levels or not all(0.0 < t <= 1.0 for t in levels):
            raise ConfigError(
                f"dig_session.throttle_levels and throttle_start must be fractions in (0, 1], "
                f"got {list(self.throttle_levels)} and {self.throttle_start}"
            )


class SessionOperator:
    """Closed-loop operator for one long log: :class:`DigOperator` cycles, breaks, throttle.

    The same call interface as :class:`DigOperator` (``reset(theta0)``, then
    ``op(theta, omega, tip=..., payload_fraction=...) -> u: (n_joint,)``), plus
    :attr:`throttle` (the current engine throttle, read by the plant loop every step).

    Args:
        spec: machine spec (joints swing, boom, arm, bucket).
        rng: random generator (the operator's only source of randomness).
        params: session parameters.
        dig: parameters of the digging cycles.
        ground_z: ground height [m].
    """

    def __init__(
        self,
        spec: MachineSpec,
        *,
        rng: RngLike,
        params: SessionParams | None = None,
        dig: DigCycleParams | None = None,
        ground_z: float = 0.0,
    ) -> None:
        self.rng = as_rng(rng)
        self.p = params or SessionParams()
        self.dig = DigOperator(spec, rng=self.rng, params=dig, ground_z=ground_z)
        self.spec = spec
        self.dt = spec.dt
        self.ground_z = float(ground_z)
        self.throttle = float(self.p.throttle_start)
        """Current engine throttle [fraction of full]."""

    # ------------------------------------------------------------------ bookkeeping
    @property
    def cycles(self) -> int:
        """Digging cycles completed in this episode."""
        return self._cycles + self.dig.cycles

    def reset(self, theta0: np.ndarray) -> None:
        """Start an episode at ``theta0: (n_joint,)`` [rad], digging, at ``throttle_start``."""
        self.dig.reset(theta0)
        self.throttle = float(self.p.throttle_start)
        self._cycles = 0
        self._pending: float | None = None
        self.mode = "dig"
        self.k = 0
        self.y = np.zeros(self.spec.n_joint)
        self.phase_log: list[tuple[int, str]] = [(0, "approach")]
        self.breaks: list[tuple[int, str, float]] = []
        """``(step, "idle" | "free", throttle)`` of every break."""

    def _log_dig(self) -> None:
        for k, ph in self.dig.phase_log[self._dig_logged :]:
            self.phase_log.append((self._dig_start + k, ph))
        self._dig_logged = len(self.dig.phase_log)

    def _start_break(self) -> None:
        r, p = self.rng, self.p
        if r.uniform() < p.p_throttle:  # from the break's first step on
            self._pending = float(r.choice(np.asarray(p.throttle_levels, dtype=np.float64)))
        idle = r.uniform() < p.p_idle
        self.mode = "idle" if idle else "free"
        lo, hi = (p.idle_min_s, p.idle_max_s) if idle else (p.free_min_s, p.free_max_s)
        self.t_left = float(r.uniform(lo, hi))
        self.target: dict[str, float] | None = None
        self.breaks.append((self.k, self.mode, self._pending or self.throttle))
        self.phase_log.append((self.k, self.mode))

    def _new_target(self, theta: np.ndarray) -> None:
        r, d = self.rng, self.dig
        reach = np.deg2rad(self.p.swing_reach_deg)
        self.target = {
            "swing": float(theta[d.col["swing"]] + r.uniform(-reach, reach)),
            "boom": d._clip_target("boom", r.uniform(0.1, 0.8)),
            "arm": d._clip_target("arm", r.uniform(0.7, 2.1)),
            "bucket": d._clip_target("bucket", r.uniform(-0.4, 2.2)),
        }
        self.levels = {n: d._level() for n in self.target}
        self.t_move = 0.0
        self.pause = float(r.uniform(0.0, d.p.pause_max))

    def _free(self, theta: np.ndarray, omega: np.ndarray, tip: np.ndarray) -> np.ndarray:
        d = self.dig
        if self.target is None:
            self._new_target(theta)
        assert self.target is not None
        self.t_move += self.dt
        raw = np.zeros(self.spec.n_joint)
        if self.pause > 0:
            self.pause -= self.dt
            return raw
        low = float(tip[2]) < self.ground_z + d.p.clearance
        th = {n: float(theta[d.col[n]]) for n in self.target}
        if low:  # keep clear of the ground: raise the boom target, hold the arm
            self.target["boom"] = max(
                self.target["boom"], d._clip_target("boom", th["boom"] + 0.15)
            )
        reached = True
        for n, tgt in self.target.items():
            err = tgt - th[n]
            f = d._press(n, err, float(omega[d.col[n]]), self.levels[n])
            if n == "arm" and low:
                f = 0.0
            k = d.col[n]
            raw[k] = f * (d.u_max[k] if f >= 0 else -d.u_min[k])
            reached = reached and abs(err) <= d.TOL[n]
        if reached or self.t_move > self.p.move_timeout_s:
            self.target = None
        return raw

    # ------------------------------------------------------------------ step
    def __call__(
        self,
        theta: np.ndarray,
        omega: np.ndarray,
        *,
        tip: np.ndarray,
        payload_fraction: float = 0.0,
    ) -> np.ndarray:
        """Joystick command ``u: (n_joint,)`` for the current true state (see
        :meth:`DigOperator.__call__`); :attr:`throttle` is the throttle for this step."""
        d = self.dig
        if self._pending is not None:
            self.throttle, self._pending = self._pending, None
        if self.k == 0:
            self._dig_start, self._dig_logged = 0, 1
        if self.mode == "dig":
            before = d.cycles
            u = d(theta, omega, tip=tip, payload_fraction=payload_fraction)
            self._log_dig()
            self.y = u.copy()
            self.k += 1
            if d.cycles > before and self.rng.uniform() < self.p.p_break:
                self._start_break()
            return u
        raw = np.zeros(self.spec.n_joint) if self.mode == "idle" else self._free(theta, omega, tip)
        self.y = self.y + d.alpha * (raw - self.y)
        self.t_left -= self.dt
        self.k += 1
        if self.t_left <= 0:  # back to digging, in a new direction
            y = self.y.copy()
            self._cycles += d.cycles
            d.reset(np.asarray(theta, dtype=np.float64))
            d.y = y
            self._dig_start, self._dig_logged = self.k, 1
            self.phase_log.append((self.k, "approach"))
            self.mode = "dig"
        return np.clip(self.y, d.u_min, d.u_max)
