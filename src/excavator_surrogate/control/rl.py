"""RL through the surrogate with Stable-Baselines3 (PPO), evaluated unchanged on the plant.

:func:`compare_rl` trains the same PPO policy twice for the same number of env-steps:

- on :class:`~excavator_surrogate.env.vector.SurrogateVectorEnv` (``n_envs`` surrogates in
  one torch batch), and
- on a ``gymnasium.vector.SyncVectorEnv`` of ``ExcavatorMujoco-v0`` plants,

both through :class:`~.sb3_vec.GymnasiumVecEnv`, for a :class:`~excavator_surrogate.env.tasks.ReachTask`
(a fixed target pose from random start poses).  Both policies are then evaluated,
deterministically and unchanged, on the plant (return and success rate: the episode
terminated because the target was reached and held still).  During the surrogate training
a callback records the learning curve on the plant and on the surrogate (evaluation time is
excluded from the training wall time).

Needs the ``[control]`` extra (``pip install excavator-surrogate[control]``).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from functools import partial
from typing import Any

import numpy as np

from ..errors import ConfigError
from ..spec import MachineSpec
from ..surrogate.model import Surrogate


@dataclass(frozen=True)
class RLConfig:
    """Options of :func:`compare_rl`."""

    n_envs: int = 128
    """Parallel environments of each training run (the same for surrogate and plant)."""
    total_steps: int = 1_000_000
    """Env-step budget of each training run; PPO trains whole updates, so it takes
    :attr:`train_steps` (this rounded down to a multiple of ``n_envs * n_steps``)."""
    n_steps: int = 32
    """PPO rollout length per env (one update every ``n_envs * n_steps`` env-steps)."""
    batch_size: int = 1024
    """PPO minibatch size."""
    n_epochs: int = 5
    """PPO epochs per update."""
    learning_rate: float = 1e-3
    """Adam learning rate."""
    gamma: float = 0.98
    """Discount factor."""
    episode_steps: int = 300
    """Time limit of a reach episode [samples] (300 = 15 s at 20 Hz: a half turn of the
    acceleration-limited swing takes about 10 s)."""
    target: tuple[float, ...] = (0.5, 0.5, 0.5, 0.5)
    """Target pose: radians for periodic joints, fractions of the range for limited ones."""
    start_margin: float = 0.25
    """Fraction of each limited joint's range avoided by random start poses."""
    start_radius: float | None = 1.0
    """The swing starts within ± this of its target [rad]; ``None``: anywhere on the circle."""
    success_bonus: float = 10.0
    """Reward on the step that reaches the target and holds still (ends the episode)."""
    tol: float = 0.1
    """Angle tolerance of success [rad]."""
    omega_tol: float = 0.1
    """Velocity tolerance of success [rad/s]."""
    n_eval: int = 16
    """Evaluation episodes (fixed seeds; the same start poses on every environment)."""
    n_curve: int = 8
    """Learning-curve points: evaluations during training, evenly spread over the PPO updates
    (at most one per update, so ``min(n_curve, updates)`` of them)."""
    plant: str | None = None
    """``ExcavatorMujoco-v0`` plant: ``ideal`` or ``hydraulic``; None: the one the surrogate
    was trained on (``hydraulic`` if its checkpoint does not record it; another plant than
    the surrogate's is refused, :func:`~excavator_surrogate.env.plants.checkpoint_plant`)."""
    seed: int = 0
    """Seed of PPO and of the training environments."""

    def __post_init__(self) -> None:
        if self.n_envs < 1 or self.total_steps < self.n_envs * self.n_steps:
            raise ConfigError(
                f"rl: need n_envs >= 1 and total_steps >= n_envs * n_steps, got {self.n_envs}, "
                f"{self.total_steps}, {self.n_steps}"
            )
        flags = {"n_eval": "--rl-eval", "episode_steps": "--rl-episode-steps", "n_curve": ""}
        for name, flag in flags.items():
            if getattr(self, name) < 1:  # checked before any run (MPPI ran first, then PPO failed)
                raise ConfigError(
                    f"rl: {name}{f' ({flag})' if flag else ''} must be >= 1, got "
                    f"{getattr(self, name)}"
                )

    @property
    def train_steps(self) -> int:
        """Env-steps each training run takes: ``total_steps`` rounded down to whole PPO updates
        of ``n_envs * n_steps`` env-steps."""
        per_update = self.n_envs * self.n_steps
        return self.total_steps // per_update * per_update

    def curve_updates(self) -> list[int]:
        """The PPO updates (1-based) after whose rollout the learning curve is evaluated:
        ``round(i · n_update / n_curve)`` for i = 1..n_curve, rounded half up, each once (none
        is 0); the last is the last update."""
        n_update = self.train_steps // (self.n_envs * self.n_steps)
        # u_i = ⌊(2 i n_update + n_curve) / (2 n_curve)⌋ = round(i · n_update / n_curve), halves up
        at = {
            (2 * i * n_update + self.n_curve) // (2 * self.n_curve)
            for i in range(1, self.n_curve + 1)
        }
        return sorted(at - {0})


def _task(spec: MachineSpec, cfg: RLConfig) -> Any:
    from ..env.tasks import ReachTask
    from .reference import pose

    return ReachTask(
        spec,
        target=pose(spec, cfg.target),
        tol=cfg.tol,
        omega_tol=cfg.omega_tol,
        success_bonus=cfg.success_bonus,
        start_radius=cfg.start_radius,
    )


def _plant_env(spec: MachineSpec, cfg: RLConfig) -> Any:
    import gymnasium as gym

    from ..env.mujoco_env import ExcavatorMujocoEnv

    env = ExcavatorMujocoEnv(
        plant=cfg.plant,  # type: ignore[arg-type]
        spec=spec,
        task=_task(spec, cfg),
        reset_margin=cfg.start_margin,
    )
    return gym.wrappers.TimeLimit(env, cfg.episode_steps)


def plant_vector_env(spec: MachineSpec, cfg: RLConfig, n_envs: int, autoreset: Any) -> Any:
    """``SyncVectorEnv`` of ``n_envs`` ``ExcavatorMujoco-v0`` plants with the reach task."""
    import gymnasium as gym

    return gym.vector.SyncVectorEnv(
        [partial(_plant_env, spec, cfg) for _ in range(n_envs)], autoreset_mode=autoreset
    )


def surrogate_vector_env(sur: Surrogate, cfg: RLConfig, n_envs: int, autoreset: Any) -> Any:
    """:class:`~excavator_surrogate.env.vector.SurrogateVectorEnv` with the reach task."""
    from ..env.vector import SurrogateVectorEnv

    return SurrogateVectorEnv(
        sur,
        n_envs,
        task=_task(sur.spec, cfg),
        reset_margin=cfg.start_margin,
        max_episode_steps=cfg.episode_steps,
        autoreset_mode=autoreset,
    )


def evaluate(policy: Any, env: Any, *, seed: int) -> dict[str, float]:
    """Run one episode per sub-env of the vector ``env`` (seeded ``seed + i``) with
    ``policy(obs) -> commands`` (n_envs, n_joint); each env counts until its first end.

    Returns mean ``return``, ``success`` rate (terminated: target reached and held still)
    and mean episode ``length``.
    """
    obs, _ = env.reset(seed=seed)
    n = env.num_envs
    ret = np.zeros(n)
    length = np.zeros(n, dtype=int)
    done = np.zeros(n, dtype=bool)
    success = np.zeros(n, dtype=bool)
    while not done.all():
        obs, r, term, trunc, _ = env.step(policy(obs).astype(np.float32))
        live = ~done
        ret[live] += r[live]
        length[live] += 1
        success |= live & term
        done |= term | trunc
    return {
        "return": float(ret.mean()),
        "success": float(success.mean()),
        "length": float(length.mean()),
    }


def _policy(model: Any, low: np.ndarray, high: np.ndarray) -> Any:
    from .sb3_vec import unit_to_command

    def act(obs: np.ndarray) -> np.ndarray:
        a, _ = model.predict(obs, deterministic=True)
        return unit_to_command(a, low, high)

    return act


def require_sb3() -> None:
    """Raise a one-line :class:`ConfigError` unless Stable-Baselines3 is installed."""
    try:
        import stable_baselines3  # noqa: F401
    except ImportError as e:  # pragma: no cover - depends on the install
        raise ConfigError(
            "RL needs Stable-Baselines3: pip install 'excavator-surrogate[control]'"
        ) from e


def train(
    venv: Any, cfg: RLConfig, *, evals: dict[str, Any] | None = None, log: Any = None
) -> dict[str, Any]:
    """Train PPO on the Gymnasium vector env ``venv`` (SAME_STEP autoreset) for
    ``cfg.train_steps`` env-steps (``total_steps`` rounded down to whole updates); ``evals``
    maps names to evaluation vector envs for the learning curve, evaluated after the rollouts
    of :meth:`RLConfig.curve_updates`.  Returns ``{"model", "train_s", "train_steps",
    "curve"}`` (curve: one dict per point)."""
    require_sb3()
    from stable_baselines3 import PPO
    from stable_baselines3.common.callbacks import BaseCallback
    from stable_baselines3.common.logger import Logger

    from .sb3_vec import GymnasiumVecEnv

    vec = GymnasiumVecEnv(venv)
    low, high = vec.low, vec.high
    per_update = cfg.n_envs * cfg.n_steps
    at = set(cfg.curve_updates())
    curve: list[dict[str, Any]] = []
    eval_s = [0.0]

    def run_evals(model: Any, steps: int) -> None:
        t0 = time.perf_counter()
        point: dict[str, Any] = {"steps": steps}
        for name, env in (evals or {}).items():
            point[name] = evaluate(_policy(model, low, high), env, seed=10_000 + cfg.seed)
        curve.append(point)
        eval_s[0] += time.perf_counter() - t0
        if log is not None and evals:
            log(
                f"  {steps:>8d} steps: "
                + ", ".join(
                    f"{k} return {v['return']:.1f} success {v['success']:.2f}"
                    for k, v in point.items()
                    if k != "steps"
                )
            )

    class Curve(BaseCallback):
        def __init__(self) -> None:
            super().__init__()
            self.n = 0

        def _on_step(self) -> bool:
            return True

        def _on_rollout_end(self) -> None:
            self.n += 1
            if evals and self.n in at:
                run_evals(self.model, int(self.num_timesteps))

    model = PPO(
        "MlpPolicy",
        vec,
        n_steps=cfg.n_steps,
        batch_size=min(cfg.batch_size, per_update),
        n_epochs=cfg.n_epochs,
        learning_rate=cfg.learning_rate,
        gamma=cfg.gamma,
        seed=cfg.seed,
        device="cpu",
        verbose=0,
    )
    # SB3's default logger makes an empty ``SB3-<date>`` folder in the temp directory on every
    # learn(), even with verbose=0: a logger with no outputs writes nothing anywhere.
    model.set_logger(Logger(folder=None, output_formats=[]))
    vec.seed(cfg.seed)
    t0 = time.perf_counter()
    model.learn(total_timesteps=cfg.train_steps, callback=Curve())
    train_s = time.perf_counter() - t0 - eval_s[0]
    return {
        "model": model,
        "train_s": train_s,
        "train_steps": int(model.num_timesteps),
        "curve": curve,
        "low": low,
        "high": high,
    }


def compare_rl(sur: Surrogate, cfg: RLConfig | None = None, *, log: Any = None) -> dict[str, Any]:
    """Train on the surrogate and on the plant (same env-step budget), evaluate both on the
    plant.  Returns ``{"surrogate": {...}, "plant": {...}, "curve": [...],
    "curve_plant_trained": [...], "config": cfg}`` with, per policy, ``train_s``,
    ``train_steps`` (the env-steps trained, :attr:`RLConfig.train_steps`), ``plant``
    (return/success/length on the plant) and ``surrogate`` (on the surrogate, for the
    surrogate-trained policy)."""
    import torch
    from gymnasium.vector import AutoresetMode

    from ..env.plants import checkpoint_plant

    cfg = cfg or RLConfig()
    spec = sur.spec
    plant = checkpoint_plant(spec, cfg.plant, ckpt=f"surrogate '{sur.name}'", default="hydraulic")
    cfg = replace(cfg, plant=plant)
    torch.set_num_threads(1)
    say = log or (lambda *_: None)
    same, off = AutoresetMode.SAME_STEP, AutoresetMode.NEXT_STEP
    ev_plant = plant_vector_env(spec, cfg, cfg.n_eval, off)
    ev_sur = surrogate_vector_env(sur, cfg, cfg.n_eval, off)
    out: dict[str, Any] = {"config": cfg}
    try:
        say(f"PPO on the surrogate: {cfg.n_envs} envs, {cfg.train_steps} env-steps")
        res = train(
            surrogate_vector_env(sur, cfg, cfg.n_envs, same),
            cfg,
            evals={"plant": ev_plant, "surrogate": ev_sur},
            log=say,
        )
        pol = _policy(res["model"], res["low"], res["high"])
        out["surrogate"] = {
            "train_s": res["train_s"],
            "train_steps": res["train_steps"],
            "plant": evaluate(pol, ev_plant, seed=20_000 + cfg.seed),
            "surrogate": evaluate(pol, ev_sur, seed=20_000 + cfg.seed),
        }
        out["curve"] = res["curve"]
        say(f"PPO on the plant ({cfg.plant}): {cfg.n_envs} envs, {cfg.train_steps} env-steps")
        res = train(
            plant_vector_env(spec, cfg, cfg.n_envs, same), cfg, evals={"plant": ev_plant}, log=say
        )
        out["curve_plant_trained"] = res["curve"]
        pol = _policy(res["model"], res["low"], res["high"])
        out["plant"] = {
            "train_s": res["train_s"],
            "train_steps": res["train_steps"],
            "plant": evaluate(pol, ev_plant, seed=20_000 + cfg.seed),
        }
    finally:
        ev_plant.close()
        ev_sur.close()
    return out
