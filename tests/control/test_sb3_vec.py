"""The Stable-Baselines3 adapter against the Gymnasium vector env it wraps."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from gymnasium.vector import AutoresetMode

from excavator_surrogate.control.rl import RLConfig, evaluate, surrogate_vector_env
from excavator_surrogate.errors import ConfigError

pytest.importorskip("stable_baselines3")

from excavator_surrogate.control.sb3_vec import GymnasiumVecEnv, unit_to_command

CFG = RLConfig(n_envs=3, n_steps=4, total_steps=12, episode_steps=5, n_eval=2)


def test_adapter_steps_like_the_vector_env(tiny_ckpt: Path) -> None:
    """Same observations and rewards as stepping the SAME_STEP vector env directly with the
    mapped commands; SB3's terminal_observation / TimeLimit.truncated on episode ends."""
    same = AutoresetMode.SAME_STEP
    vec = GymnasiumVecEnv(surrogate_vector_env(_sur(tiny_ckpt), CFG, 3, same))
    ref = surrogate_vector_env(_sur(tiny_ckpt), CFG, 3, same)
    assert vec.action_space.low.min() == -1.0 and vec.action_space.high.max() == 1.0
    vec.seed(4)
    o1 = vec.reset()
    o2, _ = ref.reset(seed=[4, 5, 6])
    np.testing.assert_array_equal(o1, o2)
    rng = np.random.default_rng(0)
    n_end = 0
    for _ in range(12):
        a = rng.uniform(-1.2, 1.2, (3, 4))
        o1, r1, d1, infos = vec.step(a)
        u = unit_to_command(a, ref.single_action_space.low, ref.single_action_space.high)
        o2, r2, term, trunc, info = ref.step(u.astype(np.float32))
        np.testing.assert_array_equal(o1, o2)
        np.testing.assert_allclose(r1, r2, rtol=1e-6)
        np.testing.assert_array_equal(d1, term | trunc)
        for i in np.flatnonzero(d1):
            n_end += 1
            np.testing.assert_array_equal(infos[i]["terminal_observation"], info["final_obs"][i])
            assert infos[i]["TimeLimit.truncated"] == bool(trunc[i] and not term[i])
    assert n_end >= 3  # every env ended at least once (5-step episodes)


def test_unit_to_command_maps_the_range() -> None:
    lo, hi = np.array([-1000.0, -500.0]), np.array([1000.0, 1500.0])
    np.testing.assert_array_equal(unit_to_command(np.array([-1.0, 1.0]), lo, hi), [-1000, 1500])
    np.testing.assert_array_equal(unit_to_command(np.array([0.0, 7.0]), lo, hi), [0, 1500])


def test_adapter_needs_same_step_autoreset(tiny_ckpt: Path) -> None:
    with pytest.raises(ConfigError, match="SAME_STEP"):
        GymnasiumVecEnv(surrogate_vector_env(_sur(tiny_ckpt), CFG, 2, AutoresetMode.NEXT_STEP))


def test_evaluate_counts_each_env_until_its_first_end(tiny_ckpt: Path) -> None:
    env = surrogate_vector_env(_sur(tiny_ckpt), CFG, 2, AutoresetMode.NEXT_STEP)
    res = evaluate(lambda obs: np.zeros((2, 4)), env, seed=0)
    assert res["length"] == CFG.episode_steps and res["success"] in (0.0, 0.5, 1.0)
    assert res["return"] < 0


def _sur(path: Path):
    from excavator_surrogate.surrogate.checkpoint import load_checkpoint

    return load_checkpoint(path)


def test_infos_and_reset_infos_follow_dummy_vec_env(tiny_ckpt: Path) -> None:
    """``infos`` were empty dicts (the README's ``u`` / ``theta`` / ``guard`` /
    ``limit_violation`` reached no callback) and ``reset_infos`` was never set.  Now both
    hold what SB3's ``DummyVecEnv`` of the single envs gives: per env the step's info (the
    final step's for an env that ended), and the autoreset's info in ``reset_infos``."""
    import gymnasium as gym
    from stable_baselines3.common.vec_env import DummyVecEnv

    from excavator_surrogate.env import ExcavatorSurrogateEnv, ReachTask
    from excavator_surrogate.spec import EXCAVATOR

    n, limit = 3, 4

    def task() -> ReachTask:
        return ReachTask(EXCAVATOR, tol=0.0)  # never reached: every episode is truncated

    def make() -> gym.Env:
        return gym.wrappers.TimeLimit(ExcavatorSurrogateEnv(tiny_ckpt, task=task()), limit)

    from excavator_surrogate.env import SurrogateVectorEnv

    venv = SurrogateVectorEnv(
        tiny_ckpt, n, task=task(), max_episode_steps=limit, autoreset_mode=AutoresetMode.SAME_STEP
    )
    vec, ref = GymnasiumVecEnv(venv), DummyVecEnv([make for _ in range(n)])
    vec.seed(7)
    ref.seed(7)
    np.testing.assert_allclose(vec.reset(), ref.reset(), atol=1e-5)
    for i in range(n):
        assert set(vec.reset_infos[i]) == set(ref.reset_infos[i]) >= {"theta", "target"}
        np.testing.assert_allclose(vec.reset_infos[i]["target"], ref.reset_infos[i]["target"])
    rng = np.random.default_rng(0)
    n_end = 0
    for _ in range(2 * limit + 1):
        a = rng.uniform(-1, 1, (n, 4)).astype(np.float32)
        o1, _, d1, infos = vec.step(a)
        o2, _, d2, ref_infos = ref.step(vec.command(a).astype(np.float32))
        np.testing.assert_allclose(o1, o2, atol=1e-5)
        np.testing.assert_array_equal(d1, d2)
        for i in range(n):
            extra = {"is_success"} if d1[i] else set()
            assert set(infos[i]) == set(ref_infos[i]) | extra
            assert {"u", "theta", "guard", "limit_violation"} <= set(infos[i])
            assert infos[i]["TimeLimit.truncated"] == ref_infos[i]["TimeLimit.truncated"]
            np.testing.assert_allclose(infos[i]["u"], ref_infos[i]["u"], rtol=1e-6)
            np.testing.assert_allclose(infos[i]["theta"], ref_infos[i]["theta"], atol=1e-5)
            if d1[i]:
                n_end += 1
                np.testing.assert_allclose(
                    infos[i]["terminal_observation"],
                    ref_infos[i]["terminal_observation"],
                    atol=1e-5,
                )
                assert set(vec.reset_infos[i]) == set(ref.reset_infos[i])
                np.testing.assert_allclose(vec.reset_infos[i]["theta"], ref.reset_infos[i]["theta"])
    assert n_end == 2 * n  # two episode ends per env


def test_set_options_reach_the_next_reset_once(tiny_ckpt: Path) -> None:
    """``set_options`` was silently dropped (the resets were random)."""
    vec = GymnasiumVecEnv(surrogate_vector_env(_sur(tiny_ckpt), CFG, 2, AutoresetMode.SAME_STEP))
    theta0 = [0.3, 0.2, 1.5, 1.0]
    vec.set_options({"theta0": theta0})
    obs = vec.reset()
    np.testing.assert_allclose(obs[:, :4], [theta0, theta0], atol=1e-6)
    np.testing.assert_allclose(vec.reset_infos[1]["theta"], theta0)
    assert vec._options == [{}, {}]  # used once, as SB3's DummyVecEnv
    assert not np.allclose(vec.reset()[:, :4], [theta0, theta0])
    vec.set_options([{"theta0": theta0}, {}])
    with pytest.raises(ConfigError, match="one options dict for all envs"):
        vec.reset()


def test_env_method_returns_one_result_per_index(tiny_ckpt: Path) -> None:
    vec = GymnasiumVecEnv(surrogate_vector_env(_sur(tiny_ckpt), CFG, 3, AutoresetMode.SAME_STEP))
    assert len(vec.env_method("reset", seed=0, indices=[0, 2])) == 2
    assert len(vec.env_method("reset", seed=0)) == 3
    assert len(vec.env_method("reset", seed=0, indices=1)) == 1
