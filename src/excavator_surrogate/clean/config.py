"""The ``[clean]`` table: :class:`CleanConfig` (shared by every cleaning filter).

Depends on nothing else in ``clean/``: the filters (:mod:`.kalman`), the plain per-sample
reference loop (:mod:`.reference`) and the dataset API (:mod:`.api`) all import it from here.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

from ..config import PresetConfig, check_types
from ..errors import ConfigError

Method = Literal["paper", "gyro", "gyro3", "rts"]
METHODS: tuple[str, ...] = ("paper", "gyro", "gyro3", "rts")
"""Available cleaning methods (see module docstring)."""


@dataclass(frozen=True)
class CleanConfig(PresetConfig, table="clean"):
    """Parameters of the cleaning filters (all joints share them).  Units: rad, s."""

    method: Method = "rts"
    """Filter: ``paper`` (Algorithm 1, open parts read as in docs/cleaning.md), ``gyro`` (gyro input + bias), ``gyro3`` (gyro measurement + bias), ``rts`` (gyro + RTS smoother)."""
    tau_jump: float = 0.15
    """Jump threshold tau_jump [rad] on delta_t (raw: must exceed the largest motion per sample)."""
    jump_ref: Literal["raw", "prior"] = "prior"
    """delta_t against the previous raw sample (``raw``, paper) or the filter prior (``prior``)."""
    tau_cons: float = 0.03
    """Consistency threshold tau_cons [rad] on the RMS deviation from the integrated gyro."""
    cons_window: int = 5
    """Consistency window w [samples]."""
    cons_mode: Literal["anchors", "samples"] = "anchors"
    """RMS over w gyro reconstructions of the current sample (``anchors``) or over the last w raw samples (``samples``)."""
    r_trust: float = 2.5e-5
    """Angle measurement variance R_trust when trusted [rad^2]."""
    r_untrust: float = 1.0
    """Angle measurement variance R_untrust when untrusted [rad^2] (>> r_trust)."""
    q_theta: float = 1e-6
    """Angle process-noise intensity [rad^2/s]; discrete Q_theta = q_theta * Ts."""
    q_omega: float = 0.2
    """Velocity process-noise intensity (paper, gyro3) [rad^2/s^3]; discrete Q_omega = q_omega * Ts."""
    q_bias: float = 1e-7
    """Gyro-bias process-noise intensity (gyro, gyro3, rts) [rad^2/s^3]; discrete q_bias * Ts."""
    r_gyro: float = 2.5e-5
    """Gyro white-noise variance per sample [(rad/s)^2]."""
    p0_omega: float = 1.0
    """Initial velocity variance [(rad/s)^2] (paper, gyro3)."""
    p0_bias: float = 1e-4
    """Initial gyro-bias variance [(rad/s)^2] (gyro, gyro3, rts)."""
    max_untrusted_s: float = 3.0
    """Lock-out guard: re-anchor the angle at the measurement after this long untrusted [s]; 0 disables."""
    unwrap_periodic: bool = True
    """Unwrap periodic joints' angles before filtering (episodes only)."""
    linear_m_per_rad: float = 1.0
    """Linear joints (episodes only): this many m of stroke count as 1 rad in every field above (variances by its square)."""

    def __post_init__(self) -> None:
        check_types(self, "[clean]")  # a wrong type: one line, not a failed comparison below
        if self.method not in METHODS:
            raise ConfigError(f"clean.method: must be one of {list(METHODS)}, got {self.method!r}")
        if self.jump_ref not in ("raw", "prior"):
            raise ConfigError(f"clean.jump_ref: must be 'raw' or 'prior', got {self.jump_ref!r}")
        if self.cons_mode not in ("anchors", "samples"):
            raise ConfigError(
                f"clean.cons_mode: must be 'anchors' or 'samples', got {self.cons_mode!r}"
            )
        for name in ("tau_jump", "tau_cons", "r_trust"):
            if not getattr(self, name) > 0:
                raise ConfigError(f"clean.{name}: must be positive, got {getattr(self, name)}")
        if not (math.isfinite(self.r_untrust) and self.r_untrust >= self.r_trust):
            raise ConfigError(
                f"clean.r_untrust: must be finite and >= r_trust ({self.r_trust}), got {self.r_untrust}"
            )
        for name in ("q_theta", "q_omega", "q_bias", "r_gyro", "max_untrusted_s"):
            if not getattr(self, name) >= 0:
                raise ConfigError(f"clean.{name}: must be >= 0, got {getattr(self, name)}")
        for name in ("p0_omega", "p0_bias"):
            if not getattr(self, name) > 0:
                raise ConfigError(f"clean.{name}: must be positive, got {getattr(self, name)}")
        # the divisions the filters make must stay defined: gyro3's gyro row has the
        # innovation variance S = h P h' + r_gyro; the RTS smoother inverts the prior
        # P- = A P A' + Q, positive definite when Q = diag(q_theta Ts + Ts^2 r_gyro, q_bias Ts) is
        if self.method == "gyro3" and not self.r_gyro > 0:
            raise ConfigError(
                f"clean.r_gyro: must be positive for method 'gyro3' (the gyro is a measurement "
                f"there), got {self.r_gyro}"
            )
        if self.method == "rts" and not (self.q_bias > 0 and self.q_theta + self.r_gyro > 0):
            raise ConfigError(
                "clean: method 'rts' needs a positive definite process noise (q_bias > 0, and "
                f"q_theta or r_gyro > 0), got q_bias={self.q_bias}, q_theta={self.q_theta}, "
                f"r_gyro={self.r_gyro}"
            )
        if not (math.isfinite(self.linear_m_per_rad) and self.linear_m_per_rad > 0):
            raise ConfigError(
                f"clean.linear_m_per_rad: must be positive and finite, got {self.linear_m_per_rad}"
            )
        if self.cons_window < 1:
            raise ConfigError(f"clean.cons_window: must be >= 1, got {self.cons_window}")


def max_untrusted_steps(config: CleanConfig, dt: float, n_step: int) -> int:
    """Lock-out guard length in samples (``n_step + 1`` = never)."""
    if config.max_untrusted_s <= 0:
        return n_step + 1
    return max(1, round(config.max_untrusted_s / dt))
