"""The two single environments: gymnasium compliance, determinism, pickling, safety, tasks."""

from __future__ import annotations

import pickle
import re
import warnings
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch
from gymnasium.utils.env_checker import check_env

import excavator_surrogate.env as E
from excavator_surrogate.env import (
    ActionError,
    ExcavatorMujocoEnv,
    ExcavatorSurrogateEnv,
    ReachTask,
)
from excavator_surrogate.env.safety import GuardConfig
from excavator_surrogate.errors import ConfigError, ExsurError
from excavator_surrogate.spec import EXCAVATOR, JointSpec, MachineSpec
from excavator_surrogate.surrogate.angles import joint_limits


def _env(kind: str, ckpt: Path, **kw: object) -> gym.Env:
    if kind == "mujoco":
        return ExcavatorMujocoEnv(**kw)  # type: ignore[arg-type]
    return ExcavatorSurrogateEnv(ckpt, **kw)  # type: ignore[arg-type]


KINDS = ["mujoco", "surrogate"]


@pytest.mark.parametrize("kind", KINDS)
def test_check_env(kind: str, stateful_ckpt: Path) -> None:
    env = _env(kind, stateful_ckpt)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # unbounded Box / non-normalised action warnings
        check_env(env, skip_render_check=True)
    assert env.action_space.shape == (EXCAVATOR.n_joint,)
    assert env.action_space.dtype == np.float32
    assert env.observation_space.shape == (2 * EXCAVATOR.n_joint,)
    assert env.observation_space.dtype == np.float32
    np.testing.assert_array_equal(env.action_space.low, [-1000] * 4)


def test_registered_ids(stateful_ckpt: Path) -> None:
    assert E.MUJOCO_ID in gym.registry and E.SURROGATE_ID in gym.registry
    env = gym.make(E.SURROGATE_ID, ckpt=str(stateful_ckpt))
    obs, _ = env.reset(seed=0)
    assert obs.shape == (8,)
    assert env.spec is not None and env.spec.max_episode_steps == E.MAX_EPISODE_STEPS
    env.close()


@pytest.mark.parametrize("kind", KINDS)
def test_same_seed_same_trajectory(kind: str, stateful_ckpt: Path) -> None:
    runs = []
    for _ in range(2):
        env = _env(kind, stateful_ckpt)
        obs, _ = env.reset(seed=123)
        env.action_space.seed(7)
        traj = [obs]
        for _ in range(15):
            traj.append(env.step(env.action_space.sample())[0])
        runs.append(np.array(traj))
    np.testing.assert_array_equal(runs[0], runs[1])
    env = _env(kind, stateful_ckpt)
    other, _ = env.reset(seed=124)
    assert not np.array_equal(other, runs[0][0])


@pytest.mark.parametrize("kind", KINDS)
def test_pickle_round_trip_steps_identically(kind: str, stateful_ckpt: Path) -> None:
    env = _env(kind, stateful_ckpt)
    env.reset(seed=1)
    rng = np.random.default_rng(0)
    for _ in range(8):  # mid-episode: delay history / recurrent state are non-trivial
        env.step(rng.uniform(-1000, 1000, 4))
    clone = pickle.loads(pickle.dumps(env))
    for _ in range(10):
        a = rng.uniform(-1000, 1000, 4)
        o1, r1, te1, tr1, _ = env.step(a)
        o2, r2, te2, tr2, _ = clone.step(a)
        np.testing.assert_array_equal(o1, o2)
        assert (r1, te1, tr1) == (r2, te2, tr2)


@pytest.mark.parametrize("kind", KINDS)
def test_reset_at_given_pose_at_rest(kind: str, stateful_ckpt: Path) -> None:
    env = _env(kind, stateful_ckpt)
    theta0 = np.array([3.0, 0.2, 1.5, 0.5])
    obs, _ = env.reset(options={"theta0": theta0})
    np.testing.assert_allclose(obs[:4], theta0, atol=1e-6)
    np.testing.assert_array_equal(obs[4:], 0.0)
    with pytest.raises(ConfigError, match="outside the joint limits"):
        env.reset(options={"theta0": [0.0, 5.0, 1.5, 0.5]})
    with pytest.raises(ConfigError, match="finite"):
        env.reset(options={"theta0": [0.0, 0.0]})


@pytest.mark.parametrize("kind", KINDS)
def test_a_pose_a_hair_beyond_an_end_stop_starts_at_the_stop(
    kind: str, stateful_ckpt: Path
) -> None:
    """A pose read off a log at a stop, plus sensor noise: the boom's stop is 0.85 rad and
    its range 1.6 rad, so up to 0.032 rad beyond starts at the stop, with a warning."""
    env = _env(kind, stateful_ckpt)
    with pytest.warns(UserWarning, match=r"theta0\[1\] \(boom\).*beyond its end stop 0.85"):
        obs, info = env.reset(options={"theta0": [0.0, 0.86, 1.5, 0.5]})
    np.testing.assert_allclose(obs[:4], [0.0, 0.85, 1.5, 0.5], atol=1e-6)
    np.testing.assert_allclose(info["theta"], [0.0, 0.85, 1.5, 0.5])
    with pytest.warns(UserWarning, match=r"theta0\[2\] \(arm\).*beyond its end stop 0.55"):
        obs, _ = env.reset(options={"theta0": [0.0, 0.0, 0.53, 0.5]})
    np.testing.assert_allclose(obs[2], 0.55, atol=1e-6)
    with pytest.raises(ConfigError, match=r"by 2.86 deg, more than 2% of the range"):
        env.reset(options={"theta0": [0.0, 0.9, 1.5, 0.5]})
    with warnings.catch_warnings():  # on the stop itself: no warning
        warnings.simplefilter("error")
        obs, _ = env.reset(options={"theta0": [0.0, 0.85, 0.55, 0.5]})
    np.testing.assert_allclose(obs[1:3], [0.85, 0.55], atol=1e-6)


def test_swing_is_wrapped_in_observation(stateful_ckpt: Path) -> None:
    env = ExcavatorMujocoEnv()
    env.reset(options={"theta0": [3.1, 0.0, 1.5, 0.5]})
    for _ in range(20):  # full positive swing command: crosses +pi
        obs, *_ = env.step(np.array([1000.0, 0, 0, 0]))
    assert env.unwrapped.theta[0] > np.pi
    assert -np.pi <= obs[0] < np.pi
    np.testing.assert_allclose(obs[0], env.unwrapped.theta[0] - 2 * np.pi, atol=1e-5)
    unwrapped = ExcavatorMujocoEnv(wrap_theta=False)
    assert unwrapped.observation_space.high[0] == np.inf


@pytest.mark.parametrize("kind", KINDS)
def test_nan_and_out_of_range_actions(kind: str, stateful_ckpt: Path) -> None:
    env = _env(kind, stateful_ckpt)
    env.reset(seed=0)
    with pytest.raises(ActionError, match=r"action\[2\] \(arm\) is nan") as err:
        env.step(np.array([0.0, 0.0, np.nan, 0.0]))
    assert isinstance(err.value, ExsurError) and isinstance(err.value, ValueError)
    assert "\n" not in str(err.value) and "Excavator" in str(err.value)
    with pytest.raises(ActionError, match="inf"):
        env.step(np.array([np.inf, 0.0, 0.0, 0.0]))
    _, _, _, _, info = env.step(np.array([5000.0, 0, 0, 0]))  # clip (default)
    assert info["u"][0] == 1000.0
    strict = _env(kind, stateful_ckpt, action_mode="reject")
    strict.reset(seed=0)
    with pytest.raises(ActionError, match=r"action\[0\] \(swing\) = 5000 is outside"):
        strict.step(np.array([5000.0, 0, 0, 0]))
    with pytest.raises(ActionError, match="shape"):
        strict.step(np.zeros(3))
    for bad in (np.zeros((2, 2)), np.zeros((1, 4))):  # the right size is not the right shape
        with pytest.raises(ActionError, match=re.escape(f"shape {bad.shape}, expected (4,)")):
            env.step(bad)
    with pytest.raises(ActionError, match="action_mode"):
        _env(kind, stateful_ckpt, action_mode="wrap")


def test_divergence_guard_truncates_without_crashing(make_surrogate) -> None:
    sur = make_surrogate()
    with torch.no_grad():
        sur.net.head[2].bias.fill_(float("nan"))  # a diverging model: NaN velocities
    env = ExcavatorSurrogateEnv(sur)
    obs0, _ = env.reset(seed=0)
    obs, _, terminated, truncated, info = env.step(np.zeros(4))
    assert truncated and not terminated and info["guard"] == "nan"
    assert np.isfinite(obs).all()  # last finite state is kept in the observation
    np.testing.assert_array_equal(obs, obs0)
    # joint-limit guard: a fast model leaves the boom range -> reported and truncated
    fast = make_surrogate()
    with torch.no_grad():
        fast.net.head[2].weight.zero_()
        fast.net.head[2].bias.fill_(0.0)
        fast.norm.y_mean[:] = 4.0  # +4 rad/s on every joint: +0.2 rad per step
    env = ExcavatorSurrogateEnv(fast, guard=GuardConfig(limit_margin=0.05, omega_max=None))
    env.reset(options={"theta0": [0.0, 0.8, 1.5, 0.5]})
    _, _, _, truncated, info = env.step(np.zeros(4))
    assert info["limit_violation"][1] and truncated and info["guard"] == "joint_limit"


@pytest.mark.parametrize("mode", ["stateful", "windowed"])
def test_resting_at_its_own_end_stop_is_no_limit_violation(make_surrogate, mode: str) -> None:
    # float32's nearest 2.65 (the arm's upper stop) is 2.6500001 and its -0.6 (the bucket's
    # lower stop) is -0.60000002: clipped there, the env read outside its own float64 limits
    sur = make_surrogate(mode=mode, end_stops=True)
    with torch.no_grad():
        sur.net.head[2].weight.zero_()
        sur.net.head[2].bias.fill_(0.0)
        sur.norm.y_mean[:] = torch.tensor([0.0, 0.0, 4.0, -4.0])  # arm out, bucket in
    env = ExcavatorSurrogateEnv(sur, guard=GuardConfig(limit_margin=0.0, omega_max=None))
    env.reset(options={"theta0": [0.0, 0.8, 2.6, -0.5]})
    for _ in range(5):
        _, _, _, truncated, info = env.step(np.zeros(4))
    lo, hi = joint_limits(sur.spec)
    assert env.theta[2] == hi[2] and env.theta[3] == lo[3]
    assert not info["limit_violation"].any() and not truncated and info["guard"] == ""


def test_hydraulic_plant_option_errors_clearly() -> None:
    try:
        env = ExcavatorMujocoEnv(plant="hydraulic")
    except ConfigError as e:
        assert "plant='hydraulic' is not available" in str(e)
    else:  # once the hydraulic plant lands this must simply work
        env.reset(seed=0)
        env.step(np.zeros(4))
    with pytest.raises(ConfigError, match="ideal"):
        ExcavatorMujocoEnv(plant="soil")  # type: ignore[arg-type]


@pytest.mark.parametrize("kind", KINDS)
def test_reach_task_reward_and_termination(kind: str, stateful_ckpt: Path) -> None:
    target = np.array([0.0, 0.1, 1.5, 0.5])
    env = _env(
        kind, stateful_ckpt, task=ReachTask(EXCAVATOR, target=target, tol=0.05, omega_tol=1.0)
    )
    _, info = env.reset(options={"theta0": target + np.array([0.02, 0.0, 0.0, 0.0])})
    np.testing.assert_array_equal(info["target"], target)
    _, reward, terminated, _, info = env.step(np.zeros(4))
    assert reward == pytest.approx(-info["distance"]) and reward <= 0
    assert terminated  # within tolerance at rest
    _, info = env.reset(options={"theta0": [1.0, 0.1, 1.5, 0.5]})
    _, reward, terminated, _, info = env.step(np.zeros(4))
    assert not terminated and reward < -0.9


@pytest.mark.parametrize("kind", KINDS)
def test_reach_task_success_bonus_on_the_terminating_step(kind: str, stateful_ckpt: Path) -> None:
    target = np.array([0.0, 0.1, 1.5, 0.5])
    task = ReachTask(EXCAVATOR, target=target, tol=0.05, omega_tol=1.0, success_bonus=10.0)
    env = _env(kind, stateful_ckpt, task=task)
    env.reset(options={"theta0": target + np.array([0.02, 0.0, 0.0, 0.0])})
    _, reward, terminated, _, info = env.step(np.zeros(4))
    assert terminated and reward == pytest.approx(10.0 - info["distance"])
    env.reset(options={"theta0": [1.0, 0.1, 1.5, 0.5]})
    _, reward, terminated, _, info = env.step(np.zeros(4))
    assert not terminated and reward == pytest.approx(-info["distance"])


@pytest.mark.parametrize("kind", KINDS)
def test_reach_task_start_radius_chooses_the_random_start(kind: str, stateful_ckpt: Path) -> None:
    target = np.array([2.8, 0.1, 1.5, 0.5])
    task = ReachTask(EXCAVATOR, target=target, start_radius=0.3)
    env = _env(kind, stateful_ckpt, task=task, reset_margin=0.25)
    lo = np.array([j.theta_min for j in EXCAVATOR.joints[1:]])
    hi = np.array([j.theta_max for j in EXCAVATOR.joints[1:]])
    swing = []
    for seed in range(40):
        env.reset(seed=seed)
        theta0 = env.unwrapped.theta
        swing.append(theta0[0])
        margin = 0.25 * (hi - lo)
        assert np.all(theta0[1:] >= lo + margin - 1e-9) and np.all(theta0[1:] <= hi - margin + 1e-9)
    swing = np.array(swing)
    # unwrapped start within the radius of the target (no wrap across ±π in between)
    assert np.all(np.abs(swing - 2.8) <= 0.3) and swing.max() > 3.0 and swing.min() < 2.6
    # the given pose still wins over the task's random start
    env.reset(options={"theta0": [0.0, 0.1, 1.5, 0.5]})
    assert env.unwrapped.theta[0] == 0.0


def test_reach_task_start_radius_needs_a_fixed_target() -> None:
    with pytest.raises(ConfigError, match="start_radius needs a fixed target"):
        ReachTask(EXCAVATOR, start_radius=0.5)
    with pytest.raises(ConfigError, match="start_radius"):
        ReachTask(EXCAVATOR, target=np.zeros(4), start_radius=-1.0)
    assert (
        ReachTask(EXCAVATOR, target=np.zeros(4)).sample_start(np.random.default_rng(0), margin=0.1)
        is None
    )


def test_spaces_follow_the_machine_spec(make_surrogate) -> None:
    spec = MachineSpec(
        joints=(JointSpec("a", u_min=-5, u_max=5), JointSpec("b", periodic=True, u_min=0, u_max=2)),
        rate_hz=10.0,
    )
    env = ExcavatorSurrogateEnv(make_surrogate(spec=spec))
    assert env.action_space.shape == (2,) and env.observation_space.shape == (4,)
    np.testing.assert_array_equal(env.action_space.low, [-5, 0])
    assert env.observation_space.high[1] == pytest.approx(np.pi)
    assert env.metadata["render_fps"] == 10.0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        check_env(env, skip_render_check=True)
