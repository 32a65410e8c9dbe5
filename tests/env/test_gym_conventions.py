"""Gymnasium conventions: registration on ``import excavator_surrogate``, episodes, seeding
and autoreset as the Gymnasium documentation describes them."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np

import excavator_surrogate.env as E

LIMIT = 3


def test_make_after_plain_package_import(stateful_ckpt: Path) -> None:
    """A fresh interpreter: ``import excavator_surrogate`` registers both ids without
    importing torch or MuJoCo; ``gym.make`` / ``gym.make_vec`` then work."""
    code = (
        "import sys, excavator_surrogate, gymnasium as gym\n"
        "assert 'torch' not in sys.modules and 'mujoco' not in sys.modules\n"
        "ids = [i for i in gym.registry if i.startswith('Excavator')]\n"
        f"env = gym.make('ExcavatorSurrogate-v0', ckpt={str(stateful_ckpt)!r})\n"
        "obs, _ = env.reset(seed=0)\n"
        f"vec = gym.make_vec('ExcavatorSurrogate-v0', num_envs=2, vectorization_mode='vector_entry_point', ckpt={str(stateful_ckpt)!r})\n"
        "print(sorted(ids), obs.shape, vec.reset(seed=0)[0].shape)\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=120
    ).stdout
    assert out.strip() == "['ExcavatorMujoco-v0', 'ExcavatorSurrogate-v0'] (8,) (2, 8)"


def test_time_limit_truncates_not_terminates(stateful_ckpt: Path) -> None:
    env = gym.make(E.SURROGATE_ID, ckpt=str(stateful_ckpt), max_episode_steps=LIMIT)
    env.reset(seed=0)
    flags = [env.step(np.zeros(4, np.float32))[2:4] for _ in range(LIMIT)]
    assert flags == [(False, False)] * (LIMIT - 1) + [(False, True)]


def _vec(ckpt: Path) -> gym.vector.VectorEnv:
    return gym.make_vec(
        E.SURROGATE_ID,
        num_envs=2,
        vectorization_mode="vector_entry_point",
        ckpt=str(ckpt),
        max_episode_steps=LIMIT,
    )


def test_next_step_autoreset(stateful_ckpt: Path) -> None:
    """The step after an episode ends returns the reset observation (at rest: ω = 0) with
    reward 0 and no end flags, and ignores that env's action."""
    runs = []
    for last in (0.0, 900.0):
        vec = _vec(stateful_ckpt)
        assert vec.metadata["autoreset_mode"] == gym.vector.AutoresetMode.NEXT_STEP
        vec.reset(seed=3)
        a = np.full((2, 4), 300.0, np.float32)
        for _ in range(LIMIT - 1):
            vec.step(a)
        obs, rew, term, trunc, _ = vec.step(a)
        assert trunc.all() and not term.any()
        obs, rew, term, trunc, _ = vec.step(np.full((2, 4), last, np.float32))
        assert not (term | trunc).any() and np.all(rew == 0)
        np.testing.assert_array_equal(obs[:, 4:], 0.0)  # fresh episodes start at rest
        runs.append(obs)
    np.testing.assert_array_equal(runs[0], runs[1])  # the action on the reset step is ignored


def test_seeding_is_reproducible_and_advances(stateful_ckpt: Path) -> None:
    vec = _vec(stateful_ckpt)
    first, _ = vec.reset(seed=11)
    again, _ = _vec(stateful_ckpt).reset(seed=11)
    np.testing.assert_array_equal(first, again)
    assert not np.array_equal(first[0], first[1])  # env i is seeded seed + i
    nxt, _ = vec.reset()  # unseeded reset: the generators continue
    assert not np.array_equal(first, nxt)
    single = gym.make(E.SURROGATE_ID, ckpt=str(stateful_ckpt))
    np.testing.assert_allclose(single.reset(seed=12)[0], first[1], atol=1e-6)
