"""Action checks and the divergence guard shared by every excavator environment.

- Non-finite actions (NaN / ±inf) always raise :class:`ActionError` (one line naming the
  environment, the action index and the joint).
- Out-of-range actions are clipped to ``[u_min, u_max]`` (``action_mode="clip"``, the
  default) or rejected with :class:`ActionError` (``action_mode="reject"``).
- :class:`DivergenceGuard` inspects each new state: NaN/inf angles or velocities, joint-limit
  violations beyond a margin and runaway velocities are reported in ``info`` and end the
  episode by *truncation*; the loop never crashes on a diverging surrogate.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from ..errors import ExsurError
from ..spec import MachineSpec
from .inputs import ActionLayout

ActionMode = Literal["clip", "reject"]
ACTION_MODES: tuple[str, ...] = ("clip", "reject")
ActionScale = Literal["raw", "normalized"]
ACTION_SCALES: tuple[str, ...] = ("raw", "normalized")

GUARD_OK = 0
"""Guard code: state is fine."""
GUARD_LIMIT = 1
"""Guard code: a joint left its ``[theta_min, theta_max]`` range by more than the margin."""
GUARD_OMEGA = 2
"""Guard code: a joint's speed exceeded ``omega_max``."""
GUARD_NAN = 3
"""Guard code: the state holds NaN or inf."""
GUARD_NAMES = {GUARD_OK: "", GUARD_LIMIT: "joint_limit", GUARD_OMEGA: "omega_max", GUARD_NAN: "nan"}


class ActionError(ExsurError, ValueError):
    """An action that cannot be applied (non-finite, wrong shape, or out of range in reject mode)."""


def check_action_scale(scale: str) -> ActionScale:
    """``scale`` if it is ``"raw"`` or ``"normalized"``, else :class:`ActionError`."""
    if scale not in ACTION_SCALES:
        raise ActionError(f"action_scale must be 'raw' or 'normalized', got {scale!r}")
    return scale  # type: ignore[return-value]


def check_action_mode(action_mode: str) -> None:
    """Raise :class:`ActionError` if ``action_mode`` is not ``"clip"`` or ``"reject"``."""
    if action_mode not in ACTION_MODES:
        raise ActionError(f"action_mode must be 'clip' or 'reject', got {action_mode!r}")


class ActionChecker:
    """Validates and conditions batches of actions ``(n_envs, n_action)`` and returns commands
    [command units].

    Args:
        spec: the machine (command ranges per joint).
        layout: the action's columns (default: every command column of ``spec``: the
            joints', then the exogenous inputs').
        env_name: used in error messages.
        action_mode: ``"clip"`` (clip to the range) or ``"reject"`` (raise on out-of-range).
        atol: tolerance for ``reject`` (values within ``atol`` of a bound are clipped silently).
        scale: ``"raw"`` (actions are commands) or ``"normalized"`` (actions in ``[-1, 1]``,
            checked and clipped there, then mapped linearly onto ``[u_min, u_max]``: ``u =
            u_min + (a + 1) / 2 · (u_max - u_min)``, the map of
            :func:`~excavator_surrogate.control.sb3_vec.unit_to_command`).
    """

    def __init__(
        self,
        spec: MachineSpec,
        *,
        env_name: str,
        action_mode: ActionMode = "clip",
        atol: float = 1e-6,
        layout: ActionLayout | None = None,
        scale: ActionScale = "raw",
    ) -> None:
        check_action_mode(action_mode)
        self.scale = check_action_scale(scale)
        self.spec = spec
        self.layout = layout or ActionLayout(spec)
        cols = self.layout.columns
        self.names = tuple(c.name for c in cols)
        """Names of the action's columns."""
        self.env_name = env_name
        self.action_mode = action_mode
        self.atol = float(atol)
        self.u_min = np.array([c.u_min for c in cols], dtype=np.float64)
        self.u_max = np.array([c.u_max for c in cols], dtype=np.float64)
        unit = np.ones(len(cols))
        self._lo, self._hi = (
            (-unit, unit) if self.scale == "normalized" else (self.u_min, self.u_max)
        )

    def __call__(self, action: object, *, n_envs: int | None = None) -> np.ndarray:
        """Return the action as float64 ``(n_envs, n_action)`` (or ``(n_action,)`` if ``n_envs`` is None).

        Raises:
            ActionError: wrong shape, NaN/inf, or out of range with ``action_mode="reject"``.
        """
        n_action = len(self.names)
        shape = (n_action,) if n_envs is None else (n_envs, n_action)
        kind = np.asarray(action).dtype.kind
        if kind not in "biufO":
            what = "complex" if kind == "c" else f"of dtype {np.asarray(action).dtype}"
            raise ActionError(
                f"{self.env_name}: action is {what}; give real numbers (float32/float64), one per "
                f"column {list(self.names)}"
            )
        try:
            u = np.asarray(action, dtype=np.float64)
        except (TypeError, ValueError) as e:
            raise ActionError(f"{self.env_name}: action is not numeric ({e})") from e
        if u.shape != shape:  # never reshaped: a transposed batch would swap envs' commands
            raise ActionError(
                f"{self.env_name}: action has shape {u.shape}, expected {shape} "
                f"(one command per column {list(self.names)})"
            )
        finite = np.isfinite(u)
        if not finite.all():
            idx = np.argwhere(~finite)[0]
            raise ActionError(
                f"{self.env_name}: {self._where(idx)} is {float(u[tuple(idx)])}; actions must be finite"
            )
        lo, hi = self._lo, self._hi
        if self.action_mode == "reject":
            bad = (u < lo - self.atol) | (u > hi + self.atol)
            if bad.any():
                idx = np.argwhere(bad)[0]
                k = int(idx[-1])
                raise ActionError(
                    f"{self.env_name}: {self._where(idx)} = {u[tuple(idx)]:.6g} is outside "
                    f"[{lo[k]:g}, {hi[k]:g}] (action_mode='reject'; use action_mode='clip' to clip)"
                )
        u = np.clip(u, lo, hi)
        if self.scale == "normalized":
            u = self.u_min + 0.5 * (u + 1.0) * (self.u_max - self.u_min)
        return u

    def _where(self, idx: np.ndarray) -> str:
        k = int(idx[-1])
        env = f"env {int(idx[0])} " if idx.size == 2 else ""
        return f"{env}action[{k}] ({self.names[k]})"


@dataclass(frozen=True)
class GuardConfig:
    """Thresholds of the divergence guard."""

    limit_margin: float | None = 0.1
    """Truncate when a joint is beyond its limit by more than this [rad]; None disables."""
    omega_max: float | None = 20.0
    """Truncate when any ``|ω|`` exceeds this [rad/s]; None disables."""


class DivergenceGuard:
    """Checks batches of states ``(n_envs, n_joint)`` for NaN/inf, joint-limit and speed violations.

    Joint-limit violations are *reported* (``limit_violation`` per joint) whenever a joint is
    outside ``[theta_min, theta_max]``; the episode is truncated only beyond ``limit_margin``.
    """

    def __init__(self, spec: MachineSpec, config: GuardConfig | None = None) -> None:
        self.spec = spec
        self.config = config or GuardConfig()
        inf = np.inf
        self.theta_min = np.array(
            [-inf if j.periodic or j.theta_min is None else j.theta_min for j in spec.joints]
        )
        self.theta_max = np.array(
            [inf if j.periodic or j.theta_max is None else j.theta_max for j in spec.joints]
        )

    def check(self, theta: np.ndarray, omega: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Inspect a batch of states.

        Args:
            theta: (n_envs, n_joint) angles [rad].
            omega: (n_envs, n_joint) velocities [rad/s].

        Returns:
            ``code`` (n_envs,) int8 (``GUARD_*``, the most severe per env) and ``limit_violation``
            (n_envs, n_joint) bool (outside the joint limits, any margin).
        """
        cfg = self.config
        code = np.zeros(theta.shape[0], dtype=np.int8)
        with np.errstate(invalid="ignore"):
            violation = (theta < self.theta_min) | (theta > self.theta_max)
            if cfg.limit_margin is not None and violation.any():
                m = cfg.limit_margin
                far = (theta < self.theta_min - m) | (theta > self.theta_max + m)
                code[far.any(axis=1)] = GUARD_LIMIT
            if cfg.omega_max is not None:
                code[np.abs(omega).max(axis=1) > cfg.omega_max] = GUARD_OMEGA
            # one reduction finds NaN and ±inf in either array
            total = theta.sum(axis=1) + omega.sum(axis=1)
        bad = ~np.isfinite(total)
        if bad.any():
            code[bad] = GUARD_NAN
        return code, violation
