"""How an environment's action maps onto the machine's command vector ``u`` (n_u,).

A machine's commands are its joints' commands, then its exogenous inputs' (engine speed,
throttle, gear: ``MachineSpec.inputs``).  By default an environment's action is the whole
vector, so an agent sets the engine speed like any command.  An env kwarg
``inputs={"engine_rpm": 1800.0}`` fixes inputs instead: they are left out of the action
(which shrinks to the remaining columns) and held at that value on every step and during
the reset warm-up.  Inputs that are in the action start at the centre of their range
during the warm-up.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from ..errors import ConfigError
from ..spec import InputSpec, JointSpec, MachineSpec


@dataclass(frozen=True)
class ActionLayout:
    """The action columns of an environment and the values of the fixed inputs."""

    spec: MachineSpec
    """The machine."""
    fixed: tuple[tuple[str, float], ...] = ()
    """``(input name, value)`` of the inputs held fixed (left out of the action)."""

    @classmethod
    def make(
        cls, spec: MachineSpec, inputs: Mapping[str, float] | None, *, where: str
    ) -> ActionLayout:
        """Check ``inputs`` (names of ``spec.inputs``, finite values inside their ranges).

        Raises:
            ConfigError: an unknown input name, or a value that is not finite or out of range.
        """
        fixed: list[tuple[str, float]] = []
        by_name = {i.name: i for i in spec.inputs}
        for name, value in (inputs or {}).items():
            if name not in by_name:
                known = ", ".join(by_name) or "none"
                raise ConfigError(
                    f"{where}: inputs names '{name}', which is not an exogenous input of "
                    f"machine '{spec.name}' (its inputs: {known})"
                )
            i = by_name[name]
            v = float(value)
            if not (np.isfinite(v) and i.u_min <= v <= i.u_max):
                raise ConfigError(
                    f"{where}: inputs['{name}'] = {value!r} is outside [{i.u_min:g}, {i.u_max:g}]"
                )
            fixed.append((name, v))
        order = [i.name for i in spec.inputs]
        return cls(spec, tuple(sorted(fixed, key=lambda f: order.index(f[0]))))

    @property
    def columns(self) -> tuple[JointSpec | InputSpec, ...]:
        """Specs of the action's columns: the joints, then the inputs that are not fixed."""
        held = dict(self.fixed)
        return tuple(c for c in self.spec.u_specs if c.name not in held)

    @property
    def n_action(self) -> int:
        """Width of the action."""
        return len(self.columns)

    @property
    def index(self) -> np.ndarray:
        """(n_action,) positions of the action's columns in ``u``."""
        names = [c.name for c in self.columns]
        return np.array([k for k, n in enumerate(self.spec.u_names) if n in names], dtype=int)

    def rest(self) -> np.ndarray:
        """The at-rest command (n_u,): joints at 0 clipped into range, fixed inputs at their
        value, the other inputs at the centre of their range."""
        held = dict(self.fixed)
        joints = [min(max(0.0, j.u_min), j.u_max) for j in self.spec.joints]
        inputs = [held.get(i.name, i.u_center) for i in self.spec.inputs]
        return np.array(joints + inputs, dtype=np.float64)

    def full(self, action: np.ndarray) -> np.ndarray:
        """Commands ``u`` (..., n_u) from actions (..., n_action), the fixed inputs filled in."""
        action = np.asarray(action, dtype=np.float64)
        if not self.fixed:
            return action
        u = np.broadcast_to(self.rest(), (*action.shape[:-1], self.spec.n_u)).copy()
        u[..., self.index] = action
        return u
