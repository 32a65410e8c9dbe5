"""SurrogateVectorEnv against plain loops: single envs in a SyncVectorEnv and ClosedLoop."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import warnings
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch
from gymnasium.vector import AutoresetMode, SyncVectorEnv

import excavator_surrogate.env as E
from excavator_surrogate.env import (
    ActionError,
    ExcavatorSurrogateEnv,
    ReachTask,
    SurrogateVectorEnv,
)
from excavator_surrogate.env.engine import SurrogateEngine
from excavator_surrogate.errors import ConfigError
from excavator_surrogate.spec import EXCAVATOR, JointSpec, MachineSpec
from excavator_surrogate.surrogate.angles import joint_limits
from excavator_surrogate.surrogate.checkpoint import save_checkpoint
from excavator_surrogate.surrogate.rollout import ClosedLoop
from tests.helpers.surrogates import VARIANTS, tiny_surrogate, variant_surrogate

N_ENVS = 3
LIMIT = 7  # short episodes so autoresets happen within the test


TASKS = {
    "random-target": lambda: ReachTask(EXCAVATOR, tol=0.0),
    # the task chooses the random start poses (swing near the target)
    "start-radius": lambda: ReachTask(
        EXCAVATOR, target=np.array([3.0, 0.1, 1.5, 0.5]), tol=0.0, start_radius=0.4
    ),
}


def _sync(ckpt: Path, mode: AutoresetMode, task: str = "random-target") -> SyncVectorEnv:
    def make() -> gym.Env:
        env = ExcavatorSurrogateEnv(ckpt, task=TASKS[task]())
        return gym.wrappers.TimeLimit(env, LIMIT)

    return SyncVectorEnv([make for _ in range(N_ENVS)], autoreset_mode=mode)


@pytest.mark.parametrize("task", list(TASKS))
@pytest.mark.parametrize("ckpt_name", ["stateful_ckpt", "windowed_ckpt"])
@pytest.mark.parametrize("mode", [AutoresetMode.NEXT_STEP, AutoresetMode.SAME_STEP])
def test_matches_sync_vector_env_of_single_envs(
    ckpt_name: str, mode: AutoresetMode, task: str, request: pytest.FixtureRequest
) -> None:
    ckpt = request.getfixturevalue(ckpt_name)
    vec = SurrogateVectorEnv(
        ckpt,
        N_ENVS,
        task=TASKS[task](),
        max_episode_steps=LIMIT,
        autoreset_mode=mode,
    )
    assert vec.metadata["autoreset_mode"] == mode
    assert vec.engine.mode == ("stateful" if ckpt_name == "stateful_ckpt" else "windowed")
    ref = _sync(ckpt, mode, task)
    o1, i1 = vec.reset(seed=5)
    o2, i2 = ref.reset(seed=5)
    np.testing.assert_allclose(o1, o2, atol=1e-6)
    np.testing.assert_array_equal(i1["target"], i2["target"])
    rng = np.random.default_rng(0)
    n_done = 0
    for _ in range(2 * LIMIT + 3):
        a = rng.uniform(-1000, 1000, (N_ENVS, 4)).astype(np.float32)
        obs, rew, term, trunc, info = vec.step(a)
        obs2, rew2, term2, trunc2, info2 = ref.step(a)
        np.testing.assert_allclose(obs, obs2, atol=1e-5)
        np.testing.assert_allclose(rew, rew2, atol=1e-5)
        np.testing.assert_array_equal(term, term2)
        np.testing.assert_array_equal(trunc, trunc2)
        # which envs hold each entry (on a NEXT_STEP reset, the reset's entries only)
        none = np.zeros(N_ENVS, dtype=bool)
        for k in {k for k in (*info, *info2) if not k.startswith(("_", "final_"))}:
            np.testing.assert_array_equal(
                info.get(f"_{k}", none), info2.get(f"_{k}", none), err_msg=k
            )
        n_done += int(trunc.sum())
        if mode == AutoresetMode.SAME_STEP and "final_obs" in info2:
            np.testing.assert_array_equal(info["_final_obs"], info2["_final_obs"])
            for x, y in zip(
                info["final_obs"][info["_final_obs"]], info2["final_obs"][info2["_final_obs"]]
            ):
                np.testing.assert_allclose(x, y, atol=1e-5)
    assert n_done >= 2 * N_ENVS  # autoresets were exercised


class CountdownTask:
    """Ends each env's episode 1 to 4 steps after its reset (drawn from the env's generator),
    so the envs end and autoreset at different steps; ``left`` is a reset (-1 outside the
    mask) and a step entry, ``budget`` a reset entry only."""

    def __init__(self) -> None:
        self.left = np.zeros(0, dtype=np.int64)

    def reset(self, theta, *, mask, rng, options=None) -> dict[str, np.ndarray]:
        if len(self.left) != len(mask):
            self.left = np.zeros(len(mask), dtype=np.int64)
        self.left[mask] = rng.integers(1, 5, int(mask.sum()))
        return {"left": np.where(mask, self.left, -1), "budget": self.left.copy()}

    def evaluate(self, theta, omega, u) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
        self.left -= 1
        return -self.left.astype(float), self.left <= 0, {"left": self.left.copy()}


@pytest.mark.parametrize("mode", [AutoresetMode.NEXT_STEP, AutoresetMode.SAME_STEP])
def test_autoreset_info_of_envs_ending_apart_matches_sync_vector_env(
    stateful_ckpt: Path, mode: AutoresetMode
) -> None:
    """On a step that autoresets some envs, the task's reset entries are masked True for those
    envs only, and an entry of both the step and the reset holds each env's own, as in a
    ``SyncVectorEnv`` of single envs (``_budget`` had been True for every env)."""
    vec = SurrogateVectorEnv(
        stateful_ckpt, N_ENVS, task=CountdownTask(), max_episode_steps=LIMIT, autoreset_mode=mode
    )

    def make() -> gym.Env:
        return gym.wrappers.TimeLimit(
            ExcavatorSurrogateEnv(stateful_ckpt, task=CountdownTask()), LIMIT
        )

    ref = SyncVectorEnv([make for _ in range(N_ENVS)], autoreset_mode=mode)
    none = np.zeros(N_ENVS, dtype=bool)

    def same(got: dict, want: dict) -> None:
        for k in ("left", "budget"):
            m = want.get(f"_{k}", none)
            np.testing.assert_array_equal(got.get(f"_{k}", none), m, err_msg=k)
            if m.any():
                np.testing.assert_array_equal(got[k][m], want[k][m], err_msg=k)

    same(vec.reset(seed=2)[1], ref.reset(seed=2)[1])
    rng = np.random.default_rng(0)
    n_some = 0
    for _ in range(12):
        a = rng.uniform(-300, 300, (N_ENVS, 4)).astype(np.float32)
        *_, term, trunc, info = vec.step(a)
        *_, term2, trunc2, info2 = ref.step(a)
        np.testing.assert_array_equal(term | trunc, term2 | trunc2)
        same(info, info2)
        if "final_info" in info2:
            same(info["final_info"], info2["final_info"])
        n_some += int(0 < info2.get("_budget", none).sum() < N_ENVS)
    assert n_some >= 2  # steps that reset some envs, not all


def test_module_and_cell_kernels_agree(stateful_ckpt: Path) -> None:
    rng = np.random.default_rng(1)
    envs = [SurrogateVectorEnv(stateful_ckpt, 4, impl=impl) for impl in ("cell", "module")]
    assert envs[1].engine.impl == "module"
    obs = [e.reset(seed=3)[0] for e in envs]
    for _ in range(30):
        a = rng.uniform(-1000, 1000, (4, 4))
        obs = [e.step(a)[0] for e in envs]
        np.testing.assert_allclose(obs[0], obs[1], atol=1e-5)


@pytest.mark.parametrize("variant", list(VARIANTS))
@pytest.mark.parametrize(
    ("mode", "cell"),
    [("stateful", "lstm"), ("stateful", "gru"), ("windowed", "lstm"), ("windowed", "arx")],
)
def test_engine_matches_closed_loop_reference(mode: str, cell: str, variant: str) -> None:
    """The batched engine equals the surrogate package's ClosedLoop with an at-rest history
    (with end stops: driven into them, and both stop at the same place; with command play
    features: the engine carries the same play states; with the velocity feature: the same
    fed-back velocities, clipped at the stops; with a delayed static map: the same delay
    line of commands)."""
    end_stops = VARIANTS[variant]["end_stops"]
    sur = variant_surrogate(mode=mode, cell=cell, **VARIANTS[variant])
    rng = np.random.default_rng(2)
    n, w = 3, sur.window
    theta0 = rng.uniform(-0.3, 0.3, (n, 4)) + np.array([0.0, 0.0, 1.5, 0.5])
    eng = SurrogateEngine(sur, n_envs=n)
    eng.reset(theta0)
    ref = ClosedLoop(sur)
    ref.reset(np.repeat(theta0[:, None], w, axis=1), np.zeros((n, w - 1, 4)))
    for _ in range(25):
        u = rng.uniform(-1000, 1000, (n, 4))
        th, om = eng.step(u)
        th_r, om_r = ref.step(u)
        np.testing.assert_allclose(th.numpy(), th_r.double().numpy(), atol=1e-5)
        np.testing.assert_allclose(om.numpy(), om_r.double().numpy(), atol=1e-4)
    if end_stops:
        lo, hi = joint_limits(sur.spec)
        th = th.numpy()
        assert (th >= lo - 1e-6).all() and (th <= hi + 1e-6).all()
        assert (np.isclose(th, lo) | np.isclose(th, hi)).any()


@pytest.mark.parametrize("ckpt_name", ["stateful_ckpt", "windowed_ckpt"])
def test_masked_reset_leaves_other_envs_untouched(
    ckpt_name: str, request: pytest.FixtureRequest
) -> None:
    ckpt = request.getfixturevalue(ckpt_name)
    a_env = SurrogateVectorEnv(ckpt, N_ENVS, max_episode_steps=None)
    b_env = SurrogateVectorEnv(ckpt, N_ENVS, max_episode_steps=None)
    theta0 = np.array([[0.5, 0.1, 1.2, 0.3], [-1.0, 0.0, 1.6, 0.8], [2.0, -0.2, 2.0, 1.0]])
    a_env.reset(options={"theta0": theta0})
    b_env.reset(options={"theta0": theta0})
    rng = np.random.default_rng(3)
    new_pose = np.array([1.0, 0.3, 1.0, 0.0])
    single = ExcavatorSurrogateEnv(ckpt)
    for k in range(12):
        if k == 5:
            mask = np.array([False, True, False])
            obs_b, _ = b_env.reset(
                options={"theta0": np.tile(new_pose, (N_ENVS, 1)), "reset_mask": mask}
            )
            np.testing.assert_allclose(obs_b[1, :4], new_pose, atol=1e-6)
            single.reset(options={"theta0": new_pose})
        a = rng.uniform(-1000, 1000, (N_ENVS, 4))
        oa = a_env.step(a)[0]
        ob = b_env.step(a)[0]
        np.testing.assert_array_equal(oa[[0, 2]], ob[[0, 2]])
        if k >= 5:
            np.testing.assert_allclose(ob[1], single.step(a[1])[0], atol=1e-5)


def test_masked_reset_seeds_only_the_envs_it_resets(stateful_ckpt: Path) -> None:
    """A seed given with a ``reset_mask`` seeds the masked envs only, as in ``SyncVectorEnv``:
    the others keep their generators, so their next poses and targets are those of their
    first seeds (the vector env had re-seeded every env)."""
    vec = SurrogateVectorEnv(
        stateful_ckpt,
        N_ENVS,
        task=TASKS["random-target"](),
        max_episode_steps=LIMIT,
        autoreset_mode=AutoresetMode.DISABLED,
    )
    ref = _sync(stateful_ckpt, AutoresetMode.DISABLED)
    calls = [
        {"seed": 0},
        {"seed": 100, "options": {"reset_mask": np.array([True, False, False])}},
        {"options": {"reset_mask": np.array([False, True, True])}},
        {"seed": [7, 8, 9], "options": {"reset_mask": np.array([False, False, True])}},
        {},
    ]
    for kw in calls:
        mask = kw.get("options", {}).get("reset_mask", np.ones(N_ENVS, dtype=bool))
        o1, i1 = vec.reset(**kw)
        o2, i2 = ref.reset(**{k: (dict(v) if k == "options" else v) for k, v in kw.items()})
        np.testing.assert_allclose(o1[mask], o2[mask], atol=1e-6)
        np.testing.assert_array_equal(i1["target"][mask], i2["target"][mask])


def test_vector_safety_and_guard(stateful_ckpt: Path, make_surrogate) -> None:
    vec = SurrogateVectorEnv(stateful_ckpt, N_ENVS)
    vec.reset(seed=0)
    bad = np.zeros((N_ENVS, 4))
    bad[2, 1] = np.nan
    with pytest.raises(ActionError, match=r"env 2 action\[1\] \(boom\) is nan"):
        vec.step(bad)
    strict = SurrogateVectorEnv(stateful_ckpt, N_ENVS, action_mode="reject")
    strict.reset(seed=0)
    with pytest.raises(ActionError, match="outside"):
        strict.step(np.full((N_ENVS, 4), 2000.0))
    sur = make_surrogate()
    with torch.no_grad():
        sur.net.head[2].bias.fill_(float("nan"))
    nan_env = SurrogateVectorEnv(sur, N_ENVS)
    obs0, _ = nan_env.reset(seed=0)
    obs, _, term, trunc, info = nan_env.step(np.zeros((N_ENVS, 4)))
    assert trunc.all() and not term.any() and (info["guard"] == E.safety.GUARD_NAN).all()
    np.testing.assert_array_equal(obs, obs0)  # last finite state
    obs, rew, _, trunc, _ = nan_env.step(np.zeros((N_ENVS, 4)))  # autoreset, no crash
    assert np.isfinite(obs).all() and not trunc.any() and (rew == 0).all()


def test_wrong_shaped_actions_raise_like_sync_vector_env(stateful_ckpt: Path) -> None:
    """An action batch of the right size but the wrong shape (transposed, flat) is refused,
    as ``SyncVectorEnv`` of the single envs refuses it; it had been reshaped, handing env 0
    half of env 1's commands."""
    a = np.random.default_rng(0).uniform(-1000, 1000, (N_ENVS, 4))
    vec = SurrogateVectorEnv(stateful_ckpt, N_ENVS)
    for env in (vec, _sync(stateful_ckpt, AutoresetMode.NEXT_STEP)):
        env.reset(seed=0)
        for bad in (a.T, a.reshape(4, N_ENVS), a.reshape(-1), a[None]):
            with pytest.raises(ActionError, match="shape"):
                env.step(bad)
    with pytest.raises(ActionError, match=rf"shape \(4, {N_ENVS}\), expected \({N_ENVS}, 4\)"):
        vec.step(a.T)


def test_make_vec_entry_point(stateful_ckpt: Path) -> None:
    envs = gym.make_vec(
        E.SURROGATE_ID, num_envs=5, vectorization_mode="vector_entry_point", ckpt=str(stateful_ckpt)
    )
    assert isinstance(envs.unwrapped, SurrogateVectorEnv)
    obs, _ = envs.reset(seed=0)
    assert obs.shape == (5, 8) and obs.dtype == np.float32
    assert envs.observation_space.shape == (5, 8) and envs.action_space.shape == (5, 4)
    obs, rew, term, trunc, _ = envs.step(envs.action_space.sample())
    assert obs.shape == (5, 8) and rew.shape == term.shape == trunc.shape == (5,)
    assert envs.observation_space.contains(obs)


def test_one_task_object_serves_each_env_its_own_episodes(stateful_ckpt: Path) -> None:
    """``gym.make_vec(..., task=one_object)`` (sync, and the batched env given the same
    object) rewards each env against its own target, as a ``SyncVectorEnv`` with a task per
    env does: each env copies the task (the sync envs had shared one, so every env was
    rewarded against the last reset env's target)."""
    one = TASKS["random-target"]()
    kw = dict(num_envs=N_ENVS, ckpt=str(stateful_ckpt), max_episode_steps=LIMIT, task=one)
    envs = [
        gym.make_vec(E.SURROGATE_ID, vectorization_mode=vm, **kw)
        for vm in ("sync", "vector_entry_point")
    ]
    ref = _sync(stateful_ckpt, AutoresetMode.NEXT_STEP)
    for env in (*envs, ref):
        env.reset(seed=5)
    rng = np.random.default_rng(0)
    for _ in range(LIMIT + 2):
        a = rng.uniform(-1000, 1000, (N_ENVS, 4)).astype(np.float32)
        _, rew, *_ = ref.step(a)
        for env in envs:
            np.testing.assert_allclose(env.step(a)[1], rew, atol=1e-5)


def test_make_vec_entry_point_refuses_a_render_mode(stateful_ckpt: Path) -> None:
    """The batched env does not render, so ``render_mode="rgb_array"`` is refused in one
    line naming the mode that renders (it was dropped: ``render()`` then raised
    NotImplementedError); None is accepted."""
    kw = dict(num_envs=2, vectorization_mode="vector_entry_point", ckpt=str(stateful_ckpt))
    for mode in ("rgb_array", "human"):
        with pytest.raises(ConfigError, match="vectorization_mode='sync'") as err:
            gym.make_vec(E.SURROGATE_ID, render_mode=mode, **kw)
        assert "\n" not in str(err.value) and repr(mode) in str(err.value)
    envs = gym.make_vec(E.SURROGATE_ID, render_mode=None, **kw)
    assert envs.metadata["render_modes"] == [] and envs.render_mode is None


_FORKED = """
import sys
import gymnasium as gym
import excavator_surrogate.env  # noqa: F401
envs = gym.make_vec("ExcavatorSurrogate-v0", num_envs=2, vectorization_mode="async",
                    vector_kwargs={"context": "fork"}, ckpt=sys.argv[1])
envs.reset(seed=0)
for _ in range(3):
    envs.step(envs.action_space.sample())
envs.close()
print("stepped")
"""


def test_async_vector_env_with_forked_workers_steps(ckpt_dir: Path, make_surrogate) -> None:
    """gymnasium's ``AsyncVectorEnv`` forks its workers on Linux after it built one env in the
    parent. A 128-wide LSTM's weights are copied on torch's threads there, and the forked
    workers hung on the copy until load_checkpoint made their torch run on one thread."""
    ckpt = save_checkpoint(ckpt_dir / "wide.pt", make_surrogate(hidden=128))
    proc = subprocess.Popen(
        [sys.executable, "-c", _FORKED, str(ckpt)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "OMP_NUM_THREADS": "2"},  # a parent on threads, as on any multi-core
        start_new_session=True,  # its forked workers die with it on a timeout
    )
    try:
        out, err = proc.communicate(timeout=120)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.communicate()
        pytest.fail("the forked workers hung (torch's thread pool across fork)")
    assert proc.returncode == 0 and "stepped" in out, err[-2000:]


@pytest.mark.parametrize("mode", ["stateful", "windowed"])
def test_engine_runs_a_merged_ensemble_like_its_members_averaged(mode: str, make_surrogate) -> None:
    """A seed ensemble merged into one network (exsur merge / train --members) steps in the
    engine exactly as its members stepped one by one with their omega averaged (plain loop)."""
    from excavator_surrogate.surrogate.ensemble import merge
    from excavator_surrogate.surrogate.reference import rollout_reference

    kw = dict(mode=mode, end_stops=True, drive=20.0, play=(0.05, 0.2))
    members = [make_surrogate(seed=0, hidden=16, **kw), make_surrogate(seed=1, hidden=8, **kw)]
    rng = np.random.default_rng(4)
    n, w, n_cmd = 3, members[0].window, 25
    theta0 = rng.uniform(-0.3, 0.3, (n, 4)) + np.array([0.0, 0.0, 1.5, 0.5])
    u = rng.uniform(-1000, 1000, (n, n_cmd, 4))
    eng = SurrogateEngine(merge(members), n_envs=n)
    eng.reset(theta0)
    th = np.stack([eng.step(u[:, k])[0].numpy().copy() for k in range(n_cmd)], axis=1)
    for i in range(n):
        u_ref = np.concatenate([np.zeros((w - 1, 4)), u[i], np.zeros((1, 4))])
        th_ref, _ = rollout_reference(members, np.repeat(theta0[i][None], w, 0), u_ref)
        np.testing.assert_allclose(th[i], th_ref[w:], atol=1e-5)
    lo, hi = joint_limits(EXCAVATOR)
    assert (np.isclose(th, lo) | np.isclose(th, hi)).any()


def test_poses_a_hair_beyond_the_stops_start_there_with_one_warning(stateful_ckpt: Path) -> None:
    env = SurrogateVectorEnv(stateful_ckpt, N_ENVS, max_episode_steps=None)
    theta0 = np.array([[0.5, 0.86, 1.2, 0.3], [-1.0, 0.0, 1.6, 0.8], [2.0, -0.76, 2.0, 2.52]])
    with warnings.catch_warnings(record=True) as got:
        warnings.simplefilter("always")
        obs, _ = env.reset(options={"theta0": theta0})
    said = [str(w.message) for w in got if "beyond the end stops" in str(w.message)]
    assert len(said) == 1 and "2 env(s) (first: env 0) lay up to 1.15 deg beyond" in said[0]
    want = theta0.copy()
    want[0, 1], want[2, 1], want[2, 3] = 0.85, -0.75, 2.5
    np.testing.assert_allclose(obs[:, :4], want, atol=1e-6)
    with pytest.raises(ConfigError, match="outside the joint limits"):
        env.reset(options={"theta0": theta0 + np.array([0.0, 0.1, 0.0, 0.0])})


def test_a_stroke_a_hair_beyond_its_stop_is_named_in_its_unit() -> None:
    """The warning gave a stroke's 18.3 mm as '1.05 deg'."""
    spec = MachineSpec(
        (
            JointSpec("swing", periodic=True),
            JointSpec("boom", kind="linear", unit="mm", theta_min=0.2507, theta_max=2.0317),
        )
    )
    env = SurrogateVectorEnv(tiny_surrogate(spec), 2, max_episode_steps=None)
    with pytest.warns(UserWarning, match=r"lay up to 18.3 mm \(boom\) beyond the end stops"):
        env.reset(options={"theta0": np.array([0.0, 2.05])})
