"""Spaces and ``info`` as Gymnasium and Stable-Baselines3 users expect them: normalised
actions (``action_scale="normalized"``) that pass both checkers without a warning, finite
observation bounds from the envelope, the same ``info`` keys in the single and vector envs."""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import excavator_surrogate.env as E
from excavator_surrogate.env.safety import ActionError, GuardConfig
from excavator_surrogate.env.uncertainty import INFO_KEYS
from excavator_surrogate.spec import EXCAVATOR
from tests.helpers.surrogates import tiny_surrogate

KINDS = ["mujoco", "surrogate"]


def _env(kind: str, ckpt: Path, **kw) -> gym.Env:
    if kind == "mujoco":
        return E.ExcavatorMujocoEnv(**kw)
    return E.ExcavatorSurrogateEnv(str(ckpt), **kw)


def _raw(a: np.ndarray) -> np.ndarray:
    """The command of a normalised action, from the spec's ranges (all [-1000, 1000] here)."""
    lo = np.array([j.u_min for j in EXCAVATOR.joints])
    hi = np.array([j.u_max for j in EXCAVATOR.joints])
    return lo + 0.5 * (np.asarray(a, dtype=np.float64) + 1.0) * (hi - lo)


@pytest.mark.parametrize("kind", KINDS)
def test_normalized_actions_pass_both_checkers_without_warnings(
    kind: str, stateful_ckpt: Path
) -> None:
    sb3 = pytest.importorskip("stable_baselines3.common.env_checker")
    env = _env(kind, stateful_ckpt, action_scale="normalized")
    assert env.action_space == gym.spaces.Box(-1.0, 1.0, (4,), np.float32)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_env(env, skip_render_check=True)
        sb3.check_env(env, warn=True)
    # the raw scale (the default) is the one both checkers warn about
    with pytest.warns(UserWarning, match="symmetric and normalized"):
        sb3.check_env(_env(kind, stateful_ckpt), warn=True)


@pytest.mark.parametrize("kind", KINDS)
def test_normalized_action_is_the_raw_command_mapped_linearly(
    kind: str, stateful_ckpt: Path
) -> None:
    a = np.array([[0.5, -0.25, 1.0, -1.0], [0.0, 0.8, -0.6, 0.3], [2.0, -3.0, 0.0, 0.1]])
    raw_env, norm_env = (
        _env(kind, stateful_ckpt),
        _env(kind, stateful_ckpt, action_scale="normalized"),
    )
    raw_env.reset(seed=4)
    norm_env.reset(seed=4)
    for row in a:
        clipped = np.clip(row, -1.0, 1.0)
        o1, *_, i1 = raw_env.step(_raw(clipped).astype(np.float32))
        o2, *_, i2 = norm_env.step(row.astype(np.float32))
        np.testing.assert_allclose(i2["u"], _raw(clipped), rtol=0, atol=1e-3)
        np.testing.assert_allclose(i2["u"], i1["u"], rtol=0, atol=1e-3)
        np.testing.assert_allclose(o2, o1, rtol=1e-5, atol=1e-6)
    assert _raw([-1, 1, 0, 0]).tolist() == [-1000.0, 1000.0, 0.0, 0.0]
    rej = _env(kind, stateful_ckpt, action_scale="normalized", action_mode="reject")
    rej.reset(seed=0)
    with pytest.raises(ActionError, match=r"= 1.5 is outside \[-1, 1\]"):
        rej.step(np.array([0.0, 1.5, 0.0, 0.0], np.float32))
    with pytest.raises(ActionError, match="action_scale must be 'raw' or 'normalized'"):
        _env(kind, stateful_ckpt, action_scale="unit")


def test_vector_env_normalized_matches_the_sb3_adapter_mapping(stateful_ckpt: Path) -> None:
    vec = E.SurrogateVectorEnv(str(stateful_ckpt), 3, action_scale="normalized")
    assert vec.single_action_space == gym.spaces.Box(-1.0, 1.0, (4,), np.float32)
    vec.reset(seed=0)
    a = np.array([[0.5, -0.25, 1.0, -1.0], [0.0, 0.8, -0.6, 0.3], [1.0, -1.0, 0.0, 0.1]])
    info = vec.step(a.astype(np.float32))[4]
    np.testing.assert_allclose(info["u"], _raw(a), rtol=0, atol=1e-3)
    sb3_vec = pytest.importorskip("excavator_surrogate.control.sb3_vec")
    np.testing.assert_allclose(
        info["u"], sb3_vec.unit_to_command(a.astype(np.float32), -1000.0, 1000.0), atol=1e-9
    )


@pytest.mark.parametrize("kind", KINDS)
def test_observation_bounds_are_finite_where_the_envelope_gives_them(
    kind: str, stateful_ckpt: Path
) -> None:
    env = _env(kind, stateful_ckpt)
    lo, hi = env.observation_space.low, env.observation_space.high
    assert lo[0] == np.float32(-math.pi) and hi[0] == np.float32(math.pi)  # swing, wrapped
    for k, j in enumerate(EXCAVATOR.joints[1:], start=1):  # limits + the guard's margin
        assert lo[k] == np.float32(j.theta_min - 0.1) and hi[k] == np.float32(j.theta_max + 0.1)
    assert (lo[4:] == -20.0).all() and (hi[4:] == 20.0).all()  # the guard's omega_max
    unwrapped = _env(kind, stateful_ckpt, wrap_theta=False, guard=GuardConfig(limit_margin=None))
    assert np.isinf(unwrapped.observation_space.low[:4]).all()


def test_observations_stay_in_the_space_while_the_surrogate_diverges() -> None:
    sur = tiny_surrogate(drive=20.0)  # no end stops: runs past its joint limits
    env = E.ExcavatorSurrogateEnv(sur)
    obs, _ = env.reset(seed=0)
    for _ in range(200):
        obs, _, _, truncated, info = env.step(np.zeros(4, np.float32))
        assert env.observation_space.contains(obs)
        if truncated:
            break
    assert truncated and info["guard"] in ("joint_limit", "omega_max")
    # the observation is clipped; the state (and info["theta"]) is not
    assert not env.observation_space.contains(
        np.concatenate([info["theta"], env.unwrapped.omega]).astype(np.float32)
    )


def test_single_and_vector_envs_share_the_info_keys(stateful_ckpt: Path) -> None:
    single = gym.make(E.SURROGATE_ID, ckpt=str(stateful_ckpt))
    vec = gym.make_vec(
        E.SURROGATE_ID, num_envs=2, vectorization_mode="vector_entry_point", ckpt=str(stateful_ckpt)
    )
    plant = gym.make(E.MUJOCO_ID)
    _, r1 = single.reset(seed=0)
    _, r2 = vec.reset(seed=0)
    _, r3 = plant.reset(seed=0)
    public = lambda info: {k for k in info if not k.startswith("_")}  # noqa: E731
    assert public(r1) == public(r2) == public(r3) == {"theta"}
    u = np.array([100.0, -200.0, 300.0, 0.0], np.float32)
    *_, s1 = single.step(u)
    *_, s2 = vec.step(np.stack([u, u]))
    *_, s3 = plant.step(u)
    # the surrogate's step info adds its uncertainty (bands, OOD flags): the plant has none
    assert public(s3) == {"guard", "limit_violation", "u", "theta"}
    assert public(s1) == public(s2) == public(s3) | set(INFO_KEYS)
    assert s2["u"].shape == (2, 4) and s2["theta"].shape == (2, 4)
    np.testing.assert_allclose(s1["u"], u)
    np.testing.assert_allclose(s2["u"][0], s1["u"])
    np.testing.assert_allclose(s2["theta"][0], s1["theta"], rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(s1["theta"], single.unwrapped.theta)
