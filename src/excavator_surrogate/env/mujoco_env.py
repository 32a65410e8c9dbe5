"""``ExcavatorMujoco-v0``: the MuJoCo excavator plant behind the Gymnasium API."""

from __future__ import annotations

import importlib
from typing import Any, Literal

import mujoco
import numpy as np

from ..errors import ConfigError
from ..simulate.plant import MujocoExcavator, PlantConfig
from ..spec import EXCAVATOR, MachineSpec
from .base import ExcavatorEnv
from .render import RENDER_SIZE
from .safety import ActionMode, ActionScale, GuardConfig
from .tasks import Task

PlantKind = Literal["ideal", "hydraulic"]

_INTEGRATION = mujoco.mjtState.mjSTATE_INTEGRATION.value

HYDRAULIC_MODULE = "excavator_surrogate.simulate.hydraulics"
"""Module expected to provide the hydraulic command transform (``HydraulicTransform``)."""


def hydraulic_transform(config: Any = None) -> Any:
    """The hydraulic :class:`~excavator_surrogate.simulate.hooks.CommandTransform`, if installed.

    Raises:
        ConfigError: the hydraulic plant is not available in this version.
    """
    try:
        mod = importlib.import_module(HYDRAULIC_MODULE)
    except ModuleNotFoundError as e:
        if e.name != HYDRAULIC_MODULE:
            raise
        mod = None
    cls = getattr(mod, "HydraulicTransform", None) if mod is not None else None
    if cls is None:
        raise ConfigError(
            "ExcavatorMujoco-v0: plant='hydraulic' is not available in this version "
            f"({HYDRAULIC_MODULE}.HydraulicTransform not found); use plant='ideal'"
        )
    return cls() if config is None else cls(config)


class ExcavatorMujocoEnv(ExcavatorEnv):
    r"""The MuJoCo excavator plant (Stage I of the paper) stepped at the control rate.

    ## Description
    A 4-DoF SY750H-like excavator (swing, boom, arm, bucket) in MuJoCo with flow-controlled
    (integrated-velocity) joint servos and a fixed 50 ms actuation delay
    (:class:`~excavator_surrogate.simulate.plant.MujocoExcavator`, 2 ms physics steps, 25 per
    control step at 20 Hz).  ``plant="hydraulic"`` adds the hydraulic command transform when
    it is available (error otherwise).  Interface, units and timing are identical to
    ``ExcavatorSurrogate-v0``.  Joints, ranges and rate come from the ``MachineSpec``; the
    tables show the default excavator.

    ## Action Space
    ``Box(u_min, u_max, (n_joint,), float32)``: one command per joint, held for ``T_s``
    (zero-order hold).

    | Num | Action                        | Control Min | Control Max | Name (in XML) | Joint | Type (Unit)          |
    |-----|-------------------------------|-------------|-------------|---------------|-------|----------------------|
    | 0   | swing valve command           | -1000       | 1000        | swing         | hinge | command (normalised) |
    | 1   | boom valve command            | -1000       | 1000        | boom          | hinge | command (normalised) |
    | 2   | arm valve command             | -1000       | 1000        | arm           | hinge | command (normalised) |
    | 3   | bucket valve command          | -1000       | 1000        | bucket        | hinge | command (normalised) |

    A command ``u`` demands a joint speed ``u / gear`` (``u_max`` = the joint's top speed).
    NaN/inf actions raise :class:`~.safety.ActionError`; out-of-range actions are clipped
    (``action_mode="clip"``) or raise (``action_mode="reject"``).
    ``action_scale="normalized"``: ``Box(-1, 1)`` instead, mapped linearly onto the ranges.

    ## Observation Space
    ``Box((2·n_joint,), float32)``: angles then angular velocities.

    | Num | Observation                          | Min  | Max | Name (in XML) | Joint | Type (Unit)              |
    |-----|--------------------------------------|------|-----|---------------|-------|--------------------------|
    | 0   | swing angle θ₀ (wrapped to [-π, π))  | -π   | π   | swing         | hinge | angle (rad)              |
    | 1   | boom angle θ₁                        | -0.85| 0.95| boom          | hinge | angle (rad)              |
    | 2   | arm angle θ₂                         | 0.45 | 2.75| arm           | hinge | angle (rad)              |
    | 3   | bucket angle θ₃                      | -0.7 | 2.6 | bucket        | hinge | angle (rad)              |
    | 4   | swing angular velocity ω₀            | -20  | 20 | swing         | hinge | angular velocity (rad/s) |
    | 5   | boom angular velocity ω₁             | -20  | 20 | boom          | hinge | angular velocity (rad/s) |
    | 6   | arm angular velocity ω₂              | -20  | 20 | arm           | hinge | angular velocity (rad/s) |
    | 7   | bucket angular velocity ω₃           | -20  | 20 | bucket        | hinge | angular velocity (rad/s) |

    Periodic joints (swing) are wrapped to ``[-π, π)`` (``wrap_theta=False``: unwrapped, bounds
    ±Inf); ``env.unwrapped.theta`` holds unwrapped angles.  Limited joints' bounds are their
    limits ± ``guard.limit_margin``, ω's ``±guard.omega_max`` (the divergence guard truncates
    beyond; the observation is clipped into the bounds).  ω is the mean velocity over the
    last control period, ``(θ[k] - θ[k-1]) / T_s`` (the data convention of the datasets).

    ## Info
    ``guard``, ``limit_violation``, ``u`` and ``theta`` on each step (``theta`` on reset), and
    the task's entries, as ``ExcavatorSurrogate-v0``.

    ## Rendering
    ``render_mode="rgb_array"``: offscreen frames of the plant; ``"human"``: MuJoCo's viewer
    (needs a display).  See :mod:`.render`.

    ## Rewards
    0 unless a ``task`` is given (e.g. :class:`~.tasks.ReachTask`).

    ## Starting State
    At rest in static equilibrium (servo setpoints pre-loaded against gravity, empty command
    history) at ``options["theta0"]`` or at a random pose from ``np_random``.

    ## Episode End
    Termination only through the task.  Truncation: the divergence guard (``info["guard"]``)
    and the registered time limit (1000 steps = 50 s).

    ## Arguments
    | Parameter      | Type                    | Default     | Description                                        |
    |----------------|-------------------------|-------------|----------------------------------------------------|
    | `plant`        | **str**                 | `"ideal"`   | ``ideal`` or ``hydraulic`` (if available)          |
    | `plant_config` | **PlantConfig / None**  | defaults    | MJCF file, rate, delay (``simulate.PlantConfig``)  |
    | `hydraulic_config` | **Any**             | `None`      | passed to the hydraulic transform                  |
    | `spec`         | **MachineSpec**         | `EXCAVATOR` | joints / command ranges (must match the MJCF)      |
    | `task`         | **Task / None**         | `None`      | reward/termination hook                            |
    | `action_mode`  | **str**                 | `"clip"`    | ``clip`` or ``reject`` out-of-range commands       |
    | `guard`        | **GuardConfig / None**  | defaults    | divergence-guard thresholds                        |
    | `wrap_theta`   | **bool**                | `True`      | wrap periodic θ in the observation                 |
    | `reset_margin` | **float**               | `0.1`       | fraction of joint ranges avoided by random starts  |
    | `action_scale` | **str**                 | `"raw"`     | ``raw`` commands or ``normalized`` ``[-1, 1]``     |
    | `render_mode`  | **str / None**          | `None`      | ``rgb_array`` or ``human`` (:mod:`.render`)        |
    | `render_size`  | **tuple**               | `(480, 360)`| ``(width, height)`` of ``rgb_array`` frames        |

    Pickling copies the full physics state (including the actuator delay history), so a
    restored environment continues the episode identically.
    """

    env_id = "ExcavatorMujoco-v0"

    def __init__(
        self,
        *,
        plant: PlantKind = "ideal",
        plant_config: PlantConfig | None = None,
        hydraulic_config: Any = None,
        spec: MachineSpec | None = None,
        task: Task | None = None,
        action_mode: ActionMode = "clip",
        guard: GuardConfig | None = None,
        wrap_theta: bool = True,
        reset_margin: float = 0.1,
        action_scale: ActionScale = "raw",
        render_mode: str | None = None,
        render_size: tuple[int, int] = RENDER_SIZE,
    ) -> None:
        if plant not in ("ideal", "hydraulic"):
            raise ConfigError(
                f"ExcavatorMujoco-v0: plant must be 'ideal' or 'hydraulic', got {plant!r}"
            )
        transform = hydraulic_transform(hydraulic_config) if plant == "hydraulic" else None
        self.plant_kind = plant
        self.plant = MujocoExcavator(
            plant_config, spec=spec or EXCAVATOR, command_transform=transform
        )
        super().__init__(
            spec=self.plant.spec,
            task=task,
            action_mode=action_mode,
            guard=guard,
            wrap_theta=wrap_theta,
            reset_margin=reset_margin,
            action_scale=action_scale,
            render_mode=render_mode,
            render_size=render_size,
        )

    def _scene(self) -> tuple[mujoco.MjModel, mujoco.MjData]:
        return self.plant.model, self.plant.data

    def _dyn_reset(self, theta0: np.ndarray) -> None:
        self.plant.reset(theta0=theta0)

    def _dyn_step(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return self.plant.step(u)

    def close(self) -> None:
        """Release the plant's rollout thread pool, if any."""
        self.plant.close()
        super().close()

    # ---- pickling: MuJoCo objects are rebuilt from the config and the full physics state ------

    def __getstate__(self) -> dict[str, Any]:
        state = super().__getstate__()
        plant: MujocoExcavator = state.pop("plant")
        phys = np.empty(mujoco.mj_stateSize(plant.model, _INTEGRATION))
        mujoco.mj_getState(plant.model, plant.data, phys, _INTEGRATION)
        state["_plant_pickle"] = {
            "config": plant.config,
            "spec": plant.spec,
            "transform": plant.transform,
            "physics": phys,
            "theta_prev": np.array(plant._theta, copy=True),
        }
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        snap = state.pop("_plant_pickle")
        self.__dict__.update(state)
        plant = MujocoExcavator(
            snap["config"], spec=snap["spec"], command_transform=snap["transform"]
        )
        mujoco.mj_setState(plant.model, plant.data, snap["physics"], _INTEGRATION)
        plant._theta = snap["theta_prev"]
        self.plant = plant
