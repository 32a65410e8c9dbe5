"""Track the digging reference on an excavator environment: MPPI (surrogate / oracle) and PI.

:func:`compare_tracking` runs, in one call, on ``ExcavatorMujoco-v0``:

- MPPI planning through the surrogate (:class:`~.predict.SurrogatePredictor`, synced to the
  machine's measured history);
- the same MPPI planning through the plant model itself (:class:`~.predict.PlantPredictor`,
  ``mujoco.rollout`` on a copy of the plant: the oracle);
- the PI baseline (:class:`~.pi.JointPI`) with gains tuned on the surrogate;

and reports the tracking RMSE per joint and the wall time per control step of each.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from typing import Any, Protocol

import numpy as np

from ..env.base import ExcavatorEnv
from ..errors import ConfigError
from ..surrogate.model import Surrogate
from .mppi import MPPI, MPPIConfig
from .pi import KP_GRID, TI, JointPI
from .predict import PlantPredictor, SurrogatePredictor
from .reference import dig_reference, horizon_window


class Controller(Protocol):
    """A tracking controller driven sample by sample by :func:`track`."""

    def reset(self, theta0: np.ndarray) -> None:
        """Start at rest at ``theta0`` (n_joint,) [rad]."""
        ...

    def act(self, k: int, obs: np.ndarray, theta_ref: np.ndarray) -> np.ndarray:
        """Command (n_joint,) at sample ``k`` from the observation ``[θ, ω]`` and the whole
        reference ``theta_ref`` (n_step, n_joint) [rad]."""
        ...

    def observe(self, u: np.ndarray, theta: np.ndarray) -> None:
        """The machine applied ``u`` and then measured ``theta`` (unwrapped) [rad]."""
        ...

    def control_step_times(self) -> list[float]:
        """Wall time of every control step so far [s]."""
        ...


class MPPIController:
    """:class:`~.mppi.MPPI` as a :class:`Controller` (plans every ``replan`` samples)."""

    def __init__(self, mppi: MPPI) -> None:
        self.mppi = mppi

    def reset(self, theta0: np.ndarray) -> None:
        """Reset planner and predictor."""
        self.mppi.reset(theta0)

    def act(self, k: int, obs: np.ndarray, theta_ref: np.ndarray) -> np.ndarray:
        """The plan's command for sample ``k`` (tracks samples k+1..k+N)."""
        del obs
        return self.mppi.act(k, horizon_window(theta_ref, k, self.mppi.cfg.n_horizon))

    def observe(self, u: np.ndarray, theta: np.ndarray) -> None:
        """Keep the predictor synced to the machine."""
        self.mppi.observe(u, theta)

    def control_step_times(self) -> list[float]:
        """Planning time of every control step [s]."""
        return list(self.mppi.stats.plan_s)


class PIController:
    """:class:`~.pi.JointPI` as a :class:`Controller`: target ``theta_ref[k+1]``."""

    def __init__(self, pi: JointPI) -> None:
        self.pi = pi
        self._times: list[float] = []

    def reset(self, theta0: np.ndarray) -> None:
        """Clear the integrator and the timings."""
        del theta0
        self.pi.reset()
        self._times = []

    def act(self, k: int, obs: np.ndarray, theta_ref: np.ndarray) -> np.ndarray:
        """PI command toward the next reference sample."""
        t0 = time.perf_counter()
        u = self.pi(obs, theta_ref[min(k + 1, len(theta_ref) - 1)])
        self._times.append(time.perf_counter() - t0)
        return u

    def observe(self, u: np.ndarray, theta: np.ndarray) -> None:
        """Nothing to do (the PI reads the observation)."""
        del u, theta

    def control_step_times(self) -> list[float]:
        """Time of every ``act`` [s]."""
        return list(self._times)


@dataclass
class TrackResult:
    """One tracking run."""

    name: str
    theta: np.ndarray
    """(n_step, n_joint) measured angles [rad] (unwrapped), sample 0 = start."""
    u: np.ndarray
    """(n_step - 1, n_joint) applied commands."""
    rmse: np.ndarray
    """(n_joint,) RMS tracking error over samples 1..n_step-1 [rad] (periodic joints wrapped)."""
    step_s: float
    """Mean wall time per control step [s]."""
    n_control: int
    """Number of control steps."""
    total_s: float
    """Wall time of the whole run (controller + machine) [s]."""
    truncated: bool = False
    """The environment truncated the run (divergence guard)."""
    extra: dict[str, Any] = field(default_factory=dict)


def tracking_error(theta: np.ndarray, theta_ref: np.ndarray, periodic: np.ndarray) -> np.ndarray:
    """``theta - theta_ref`` (..., n_joint) [rad] with periodic joints wrapped to [-π, π)."""
    e = np.asarray(theta, dtype=np.float64) - theta_ref
    if periodic.any():
        e[..., periodic] = (e[..., periodic] + np.pi) % (2 * np.pi) - np.pi
    return e


def track(
    env: ExcavatorEnv, ctrl: Controller, theta_ref: np.ndarray, *, name: str = ""
) -> TrackResult:
    """Run ``ctrl`` on ``env`` (an unwrapped excavator env) from rest at ``theta_ref[0]``.

    Args:
        env: ``ExcavatorMujoco-v0`` or ``ExcavatorSurrogate-v0`` (``.unwrapped``).
        ctrl: the controller.
        theta_ref: (n_step, n_joint) reference [rad]; the run has ``n_step - 1`` commands.
    """
    t0 = time.perf_counter()
    obs, _ = env.reset(options={"theta0": theta_ref[0]})
    ctrl.reset(theta_ref[0])
    n_step = len(theta_ref)
    theta = [env.theta.copy()]
    us = []
    truncated = False
    for k in range(n_step - 1):
        u = np.asarray(ctrl.act(k, obs, theta_ref), dtype=np.float64)
        obs, _, _, truncated, info = env.step(u.astype(np.float32))
        u_applied = np.asarray(info["u"], dtype=np.float64)
        ctrl.observe(u_applied, env.theta.copy())
        theta.append(env.theta.copy())
        us.append(u_applied)
        if truncated:
            break
    th = np.array(theta)
    periodic = np.asarray(env.machine.periodic, dtype=bool)
    e = tracking_error(th[1:], theta_ref[1 : len(th)], periodic)
    times = ctrl.control_step_times()
    return TrackResult(
        name=name,
        theta=th,
        u=np.array(us),
        rmse=np.sqrt(np.mean(e * e, axis=0)),
        step_s=float(np.mean(times)) if times else float("nan"),
        n_control=len(times),
        total_s=time.perf_counter() - t0,
        truncated=bool(truncated),
    )


def prediction_error(
    sur: Surrogate, theta: np.ndarray, u: np.ndarray, *, n_horizon: int, every: int = 1
) -> np.ndarray:
    """How far the surrogate's open-loop predictions miss a recorded run.

    The surrogate follows the run (synced to the measured angles, as the MPPI predictor is)
    and, every ``every`` samples, predicts the next ``n_horizon`` angles under the commands
    that were actually applied.  Returns the errors ``predicted - measured`` at the end of
    each horizon (n_window, n_joint) [rad], periodic joints wrapped.

    Args:
        sur: the surrogate.
        theta: (n_step, n_joint) measured angles [rad], sample 0 at rest.
        u: (n_step - 1, n_joint) applied commands.
        n_horizon: prediction horizon [samples].
        every: spacing of the prediction starts [samples].
    """
    pred = SurrogatePredictor(sur, n_batch=1)
    pred.reset(theta[0])
    periodic = np.asarray(sur.spec.periodic, dtype=bool)
    errors = []
    for k in range(len(u)):
        if k % every == 0 and k + n_horizon <= len(u):
            th = pred.predict(u[None, k : k + n_horizon])[0, -1]
            errors.append(tracking_error(th, theta[k + n_horizon], periodic))
        pred.observe(u[k], theta[k + 1])
    return np.array(errors).reshape(-1, sur.spec.n_joint)


def tune_pi(sur_env: ExcavatorEnv, theta_ref: np.ndarray) -> JointPI:
    """PI gains tuned on the surrogate (per joint, the kp of :data:`~.pi.KP_GRID` with the
    lowest tracking RMSE of ``theta_ref``; ``ki = kp / TI``), as examples/pi_controller.py."""
    spec = sur_env.machine
    scores = []
    for kp in KP_GRID:
        gains = np.full(spec.n_joint, kp)
        res = track(sur_env, PIController(JointPI(spec, kp=gains, ki=gains / TI)), theta_ref)
        scores.append(res.rmse if not res.truncated else np.full(spec.n_joint, np.inf))
    best = np.array(KP_GRID)[np.argmin(np.array(scores), axis=0)]
    return JointPI(spec, kp=best, ki=best / TI)


def compare_tracking(
    sur: Surrogate,
    *,
    plant: str | None = None,
    mppi: MPPIConfig | None = None,
    time_scale: float = 1.0,
    oracle: bool = True,
    bias_gain: float = 0.1,
    cpus: int = 1,
    n_seeds: int = 1,
    log: Any = None,
) -> dict[str, Any]:
    """MPPI through the surrogate, MPPI through the plant model (oracle) and PI on the plant.

    Args:
        sur: the surrogate.
        plant: ``ideal`` or ``hydraulic`` plant of ``ExcavatorMujoco-v0``; None: the one the
            surrogate was trained on (``hydraulic`` if not recorded; another machine or plant
            is refused: :func:`~excavator_surrogate.env.plants.checkpoint_plant`).
        mppi: planner options (the same for surrogate and oracle).
        time_scale: stretches the digging reference (see :func:`~.reference.dig_reference`).
        oracle: also run the oracle (the slow part).
        bias_gain: velocity-bias correction of the surrogate predictor
            (:class:`~.predict.SurrogatePredictor`; 0: off).
        cpus: CPUs of each planner: the surrogate's candidates are split over ``cpus``
            processes (``SurrogatePredictor(workers=cpus)``), the oracle's ``mujoco.rollout``
            runs ``cpus`` threads.
        n_seeds: MPPI noise seeds ``mppi.seed, mppi.seed + 1, ...`` the two MPPI runs are
            repeated with (a seed study; ``runs`` holds the first seed's).
        log: optional ``print``-like callable for progress lines.

    Returns:
        ``{"reference": theta_ref, "time": t, "phases": [...], "runs": {name: TrackResult},
        "pi_gains": kp, "seed_runs": {seed: {name: TrackResult}}}`` (the MPPI runs of every
        seed, the first one's included).
    """
    if n_seeds < 1:
        raise ConfigError(f"compare_tracking: n_seeds must be >= 1, got {n_seeds}")
    from ..env.mujoco_env import ExcavatorMujocoEnv
    from ..env.plants import checkpoint_plant
    from ..env.surrogate_env import ExcavatorSurrogateEnv

    cfg = mppi or MPPIConfig()
    spec = sur.spec
    plant = checkpoint_plant(spec, plant, ckpt=f"surrogate '{sur.name}'", default="hydraulic")
    theta_ref, t, phases = dig_reference(spec, time_scale=time_scale)
    say = log or (lambda *_: None)
    sur_env = ExcavatorSurrogateEnv(sur)
    pi = tune_pi(sur_env, theta_ref)
    runs: dict[str, TrackResult] = {}
    env = ExcavatorMujocoEnv(plant=plant, spec=spec)  # type: ignore[arg-type]
    sur_pred = SurrogatePredictor(sur, n_batch=cfg.n_sample, bias_gain=bias_gain, workers=cpus)
    try:
        ctrls: list[tuple[str, Controller]] = [
            ("mppi_surrogate", MPPIController(MPPI(sur_pred, cfg)))
        ]
        if oracle:
            plant_pred = PlantPredictor(env.plant, n_threads=cpus)
            # the plant model knows itself: no risk weight (it has no spread)
            ctrls.append(("mppi_oracle", MPPIController(MPPI(plant_pred, replace(cfg, risk=0.0)))))
        ctrls.append(("pi", PIController(pi)))
        for name, ctrl in ctrls:
            res = track(env, ctrl, theta_ref, name=name)
            if name == "mppi_surrogate":
                res.extra["bias_rad_s"] = sur_pred.bias.tolist()  # the final velocity bias
                err = np.abs(prediction_error(sur, res.theta, res.u, n_horizon=cfg.n_horizon))
                if len(err):
                    res.extra["horizon_error_rad"] = {
                        "rms": np.sqrt(np.mean(err**2, axis=0)).tolist(),
                        "p95": np.percentile(err, 95, axis=0).tolist(),
                        "n_horizon": cfg.n_horizon,
                    }
            if name == "mppi_surrogate" and cfg.risk > 0:
                st = ctrl.mppi.stats  # type: ignore[attr-defined]
                res.extra["ood_share"] = float(np.mean(st.ood)) if st.ood else 0.0
            runs[name] = res
            say(
                f"{name}: RMSE {np.array2string(res.rmse, precision=4)} rad, "
                f"{res.step_s * 1e3:.1f} ms per control step, {res.total_s:.1f} s"
            )
        seed_runs = {cfg.seed: {k: r for k, r in runs.items() if k != "pi"}}
        preds = [("mppi_surrogate", sur_pred)] + ([("mppi_oracle", plant_pred)] if oracle else [])
        for seed in range(cfg.seed + 1, cfg.seed + n_seeds):
            cfg_s = replace(cfg, seed=seed)
            seed_runs[seed] = {
                name: track(
                    env,
                    MPPIController(
                        MPPI(pred, cfg_s if name == "mppi_surrogate" else replace(cfg_s, risk=0.0))
                    ),
                    theta_ref,
                    name=name,
                )
                for name, pred in preds
            }
            say(
                f"MPPI seed {seed}: RMSE "
                + ", ".join(
                    f"{k} {np.array2string(r.rmse, precision=4)}"
                    for k, r in seed_runs[seed].items()
                )
                + " rad"
            )
    finally:
        sur_pred.close()
        env.close()
    return {
        "reference": theta_ref,
        "time": t,
        "phases": phases,
        "runs": runs,
        "pi_gains": pi.kp,
        "seed_runs": seed_runs,
    }
