"""``ExcavatorSurrogate-v0``: a trained LSTM/GRU surrogate behind the Gymnasium API."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import mujoco
import numpy as np
import torch

from ..data.episode import Episode
from ..devices import resolve_device
from ..spec import MachineSpec
from ..surrogate.checkpoint import check_compatible, load_checkpoint
from ..surrogate.model import Surrogate
from .base import ExcavatorEnv
from .engine import Mode, SurrogateEngine
from .kernels import Impl
from .render import RENDER_SIZE, PoseScene
from .safety import ActionMode, ActionScale, GuardConfig
from .starts import RecordedStarts, warn_short_history
from .tasks import Task
from .uncertainty import notes, step_info, wanted


def recorded_starts_of(
    source: str | Path | Sequence[Episode] | RecordedStarts | None, sur: Surrogate
) -> RecordedStarts | None:
    """The ``recorded_starts`` argument of the surrogate envs as a sampler of histories of
    ``sur``'s window (None stays None)."""
    if source is None or isinstance(source, RecordedStarts):
        return source
    return RecordedStarts(source, spec=sur.spec, window=sur.window)


def load_surrogate(
    ckpt: str | Path | Surrogate,
    *,
    device: str | torch.device = "cpu",
    spec: MachineSpec | None = None,
) -> Surrogate:
    """A :class:`Surrogate` from a checkpoint path (or the object itself), in eval mode.

    ``device``: ``cpu``, ``cuda[:N]`` or ``auto`` (see :func:`~excavator_surrogate.devices.resolve_device`).
    ``spec``: the machine the caller expects; a checkpoint of other joints, command ranges or
    rate raises :class:`~excavator_surrogate.errors.CheckpointError`.
    """
    device = resolve_device(device)
    sur = (
        ckpt.to(device).eval()
        if isinstance(ckpt, Surrogate)
        else load_checkpoint(ckpt, device=device)
    )
    if spec is not None:
        label = ckpt if not isinstance(ckpt, Surrogate) else f"surrogate '{sur.name}'"
        check_compatible(sur.spec, spec, ckpt=label, data_name=f"machine '{spec.name}'")
    return sur


class ExcavatorSurrogateEnv(ExcavatorEnv):
    r"""A trained surrogate of the excavator, stepped in closed loop at the control rate.

    ## Description
    The learned operator of the paper (2-layer LSTM, ``W = 30``) replaces the machine: each
    step feeds the current angles and the command to the network, which predicts the mean
    angular velocity over the next control period; the angle integrates as
    ``θ[k+1] = θ[k] + T_s·ω̂[k+1]``.  Interface, units and timing are identical to
    ``ExcavatorMujoco-v0``, so a controller developed here runs unchanged on the plant.
    Joints, command ranges and rate come from the checkpoint's ``MachineSpec``; the tables
    show the default 4-joint excavator (``n`` joints in general).

    ## Action Space
    ``Box(u_min, u_max, (n_joint,), float32)``: one command per joint, held for ``T_s``.  A
    surrogate trained with exogenous inputs (engine speed, gear ...: ``spec.inputs``) takes
    them as further action entries after the joints' (``n_u`` in all), unless ``inputs``
    fixes them, e.g. ``inputs={"engine_rpm": 1800.0}``: they are then held at that value and
    the action is the joints' commands (and any input not fixed).

    | Num | Action                        | Control Min | Control Max | Joint  | Type (Unit)           |
    |-----|-------------------------------|-------------|-------------|--------|-----------------------|
    | 0   | swing valve command           | -1000       | 1000        | swing  | command (normalised)  |
    | 1   | boom valve command            | -1000       | 1000        | boom   | command (normalised)  |
    | 2   | arm valve command             | -1000       | 1000        | arm    | command (normalised)  |
    | 3   | bucket valve command          | -1000       | 1000        | bucket | command (normalised)  |

    NaN/inf actions raise :class:`~.safety.ActionError`; out-of-range actions are clipped
    (``action_mode="clip"``) or raise (``action_mode="reject"``).
    ``action_scale="normalized"``: ``Box(-1, 1)`` instead, mapped linearly onto the ranges.

    ## Observation Space
    ``Box((2·n_joint,), float32)``: angles then angular velocities.

    | Num | Observation                          | Min  | Max | Joint  | Type (Unit)              |
    |-----|--------------------------------------|------|-----|--------|--------------------------|
    | 0   | swing angle θ₀ (wrapped to [-π, π))  | -π   | π   | swing  | angle (rad)              |
    | 1   | boom angle θ₁                        | -0.85| 0.95| boom   | angle (rad)              |
    | 2   | arm angle θ₂                         | 0.45 | 2.75| arm    | angle (rad)              |
    | 3   | bucket angle θ₃                      | -0.7 | 2.6 | bucket | angle (rad)              |
    | 4   | swing angular velocity ω₀            | -20  | 20 | swing  | angular velocity (rad/s) |
    | 5   | boom angular velocity ω₁             | -20  | 20 | boom   | angular velocity (rad/s) |
    | 6   | arm angular velocity ω₂              | -20  | 20 | arm    | angular velocity (rad/s) |
    | 7   | bucket angular velocity ω₃           | -20  | 20 | bucket | angular velocity (rad/s) |

    Periodic joints (swing) are wrapped to ``[-π, π)`` in the observation (``wrap_theta=False``
    keeps them unwrapped, observation bounds then ±Inf); ``env.unwrapped.theta`` always holds
    the unwrapped angles.  Limited joints' bounds are their limits ± ``guard.limit_margin``,
    ω's ``±guard.omega_max`` (the divergence guard truncates beyond; the observation is
    clipped into the bounds).  ω is the mean velocity over the last control period.

    ## Rewards
    0 unless a ``task`` is given (e.g. :class:`~.tasks.ReachTask`).

    ## Starting State
    At rest (ω = 0) at ``options["theta0"]`` or at a random pose from ``np_random``.  The
    network is warmed up on ``W - 1`` at-rest samples (θ constant, u = 0); with
    ``recorded_starts``, a random recorded moment of those logs instead.  Or mid-motion,
    after a recorded history: ``options["history"] = {"theta": (n_hist, n_joint) [rad],
    "u": (n_hist - 1, n_u)}`` warms the network up on it and starts at its last angle and
    velocity; stepping the recorded commands from there continues the free run of ``exsur
    evaluate`` (:mod:`.starts`).

    ## Episode End
    Termination only through the task.  Truncation: the divergence guard (NaN/inf state, a
    joint beyond its limit by more than ``guard.limit_margin``, ``|ω| > guard.omega_max``;
    ``info["guard"]`` names the reason) and the registered time limit (1000 steps = 50 s).

    ## Info
    ``guard`` (str, "" when fine), ``limit_violation`` (bool per joint, outside the limits),
    ``u`` (applied command, command units), ``theta`` (unwrapped angles, on reset and step),
    the surrogate's uncertainty on every step (:func:`~.uncertainty.step_info`:
    ``uncertainty``, ``band_calibrated``, ``theta_band`` / ``omega_band`` (n_joint,) [rad],
    [rad/s], ``ood`` (n_joint,) bool, ``ood_any``, ``ood_checked``; ``env.uncertainty_note``
    says what is missing) and the task's entries: the keys of
    :class:`~.vector.SurrogateVectorEnv`'s ``info``.

    ## Rendering
    ``render_mode="rgb_array"``: the predicted pose drawn on the built-in excavator's MJCF
    (the same picture ``ExcavatorMujoco-v0`` draws at that pose); ``"human"``: MuJoCo's
    viewer (needs a display).  A stroke is drawn at the angle its joint's linkage gives; a
    machine with a joint the MJCF lacks, or a stroke without a linkage, is refused when the
    env is made.  See :mod:`.render`.

    ## Arguments
    | Parameter      | Type                    | Default   | Description                                             |
    |----------------|-------------------------|-----------|---------------------------------------------------------|
    | `ckpt`         | **str / Surrogate**     | required  | checkpoint path (``exsur train``) or a loaded surrogate |
    | `device`       | **str**                 | `"cpu"`   | torch device: cpu, cuda[:N] or auto                     |
    | `mode`         | **str / None**          | `None`    | ``stateful`` / ``windowed``; default: checkpoint's mode |
    | `impl`         | **str**                 | `"cell"`  | stateful kernel: ``cell``, ``module`` or ``auto``       |
    | `task`         | **Task / None**         | `None`    | reward/termination hook                                 |
    | `action_mode`  | **str**                 | `"clip"`  | ``clip`` or ``reject`` out-of-range commands            |
    | `guard`        | **GuardConfig / None**  | defaults  | divergence-guard thresholds                             |
    | `wrap_theta`   | **bool**                | `True`    | wrap periodic θ in the observation                      |
    | `reset_margin` | **float**               | `0.1`     | fraction of joint ranges avoided by random starts       |
    | `spec`         | **MachineSpec / None**  | `None`    | expected machine: a checkpoint of another one raises    |
    | `inputs`       | **dict / None**         | `None`    | exogenous inputs held fixed (left out of the action)    |
    | `action_scale` | **str**                 | `"raw"`   | ``raw`` commands or ``normalized`` ``[-1, 1]``          |
    | `render_mode`  | **str / None**          | `None`    | ``rgb_array`` or ``human`` (the predicted pose, :mod:`.render`) |
    | `render_size`  | **tuple**               | `(480, 360)` | ``(width, height)`` of ``rgb_array`` frames          |
    | `uncertainty`  | **bool / None**         | `None`    | track bands and OOD flags; None: when the checkpoint has members or a coverage record |
    | `recorded_starts` | **path / episodes / None** | `None` | random resets start at recorded moments of these logs (a dataset folder: its train split) |
    """

    env_id = "ExcavatorSurrogate-v0"

    def __init__(
        self,
        ckpt: str | Path | Surrogate,
        *,
        device: str | torch.device = "cpu",
        mode: Mode | None = None,
        impl: Impl = "cell",
        task: Task | None = None,
        action_mode: ActionMode = "clip",
        guard: GuardConfig | None = None,
        wrap_theta: bool = True,
        reset_margin: float = 0.1,
        spec: MachineSpec | None = None,
        inputs: dict[str, float] | None = None,
        action_scale: ActionScale = "raw",
        render_mode: str | None = None,
        render_size: tuple[int, int] = RENDER_SIZE,
        uncertainty: bool | None = None,
        recorded_starts: str | Path | Sequence[Episode] | RecordedStarts | None = None,
    ) -> None:
        sur = load_surrogate(ckpt, device=device, spec=spec)
        self.ckpt = str(ckpt) if not isinstance(ckpt, Surrogate) else None
        super().__init__(
            spec=sur.spec,
            task=task,
            action_mode=action_mode,
            guard=guard,
            wrap_theta=wrap_theta,
            reset_margin=reset_margin,
            inputs=inputs,
            action_scale=action_scale,
            render_mode=render_mode,
            render_size=render_size,
        )
        # a machine the MJCF cannot pose (a joint it lacks, a stroke without a linkage) is
        # refused here, in one line, not at the first frame
        self._pose = PoseScene(self.machine, where=self.env_id) if render_mode else None
        on = wanted(sur, uncertainty)
        self.engine = SurrogateEngine(
            sur, n_envs=1, device=device, mode=mode, impl=impl, uncertainty=on
        )
        self.engine.u_rest = self.layout.rest()
        self.surrogate = sur
        self.recorded = recorded_starts_of(recorded_starts, sur)
        self.uncertainty_note = (
            "; ".join(notes(sur)) if uncertainty is not False else "uncertainty=False: not tracked"
        )
        """What the step ``info``'s uncertainty lacks ("": bands and flags)."""

    def _scene(self) -> tuple[mujoco.MjModel, mujoco.MjData]:
        """The built-in excavator's MJCF at the surrogate's predicted pose."""
        if self._pose is None:
            self._pose = PoseScene(self.machine, where=self.env_id)
        return self._pose.model, self._pose.pose(self.theta)

    def __getstate__(self) -> dict[str, Any]:
        state = super().__getstate__()
        state["_pose"] = None  # MuJoCo objects: rebuilt on the next frame
        return state

    def _dyn_reset(self, theta0: np.ndarray) -> None:
        self.engine.reset(theta0[None])

    def _dyn_reset_history(self, theta: np.ndarray, u: np.ndarray) -> None:
        warn_short_history(len(theta), self.engine.window, where=f"{self.env_id}.reset")
        self.engine.reset_history(theta[None], u[None])

    def _dyn_info(self) -> dict[str, Any]:
        info = step_info(self.engine.unc, 1, self.machine.n_joint)
        return {k: v[0] for k, v in info.items()}

    def _dyn_step(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        theta, omega = self.engine.step(u[None])
        return theta[0].cpu().numpy().copy(), omega[0].cpu().numpy()
