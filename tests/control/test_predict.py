"""Batched predictors against plain loops of single rollouts."""

from __future__ import annotations

import pickle

import numpy as np
import pytest

from excavator_surrogate.control.predict import PlantPredictor, SurrogatePredictor
from excavator_surrogate.env.mujoco_env import ExcavatorMujocoEnv
from excavator_surrogate.errors import ConfigError, ExsurError
from excavator_surrogate.simulate.hydraulics import HydraulicTransform
from excavator_surrogate.surrogate.rollout import ClosedLoop
from tests.helpers.surrogates import on_parallel_map, on_static_map, tiny_surrogate

THETA0 = np.array([0.2, 0.1, 1.5, 0.6])
K, N, N_HIST = 4, 6, 9


def _history(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """A made-up measured history: angles (N_HIST + 1, 4) and commands (N_HIST, 4)."""
    u = rng.uniform(-800, 800, (N_HIST, 4))
    theta = THETA0 + np.cumsum(rng.normal(0, 0.01, (N_HIST + 1, 4)), axis=0)
    theta[0] = THETA0
    return theta, u


@pytest.mark.parametrize(
    ("mode", "cell", "play", "omega_in", "delayed_map"),
    [
        ("stateful", "lstm", (), False, False),
        ("stateful", "gru", (0.05,), False, False),
        ("windowed", "lstm", (0.05, 0.1), False, False),
        ("stateful", "lstm", (), True, False),
        ("windowed", "lstm", (0.05,), True, False),
        ("stateful", "lstm", (0.05,), False, True),
        ("windowed", "gru", (), False, True),
        ("stateful", "lstm", (0.05,), True, "parallel"),
        ("windowed", "lstm", (), False, "parallel"),
    ],
)
def test_surrogate_batch_matches_single_closed_loops(
    mode: str, cell: str, play: tuple, omega_in: bool, delayed_map: bool | str
) -> None:
    """Synced to a measured history, the K-candidate batched rollout equals K single
    ClosedLoop rollouts, each warmed up on the at-rest samples plus the full history (with
    the velocity feature: the measured velocities of that history; with a delayed static
    map: the commands of that history in its delay line)."""
    sur = tiny_surrogate(mode=mode, cell=cell, play=play, window=5, omega_in=omega_in)
    if delayed_map == "parallel":  # the network reads the measured angles while synced
        sur = on_parallel_map(sur, delay=(3, 0, 0, 1))
    elif delayed_map:
        sur = on_static_map(sur, delay=(3, 0, 0, 1))
    rng = np.random.default_rng(0)
    theta, u_hist = _history(rng)
    pred = SurrogatePredictor(sur, n_batch=K)
    pred.reset(theta[0])
    for k in range(N_HIST):
        pred.observe(u_hist[k], theta[k + 1])
    u = rng.uniform(-1000, 1000, (K, N, 4))
    got = pred.predict(u)
    assert got.shape == (K, N, 4)
    w = sur.window
    th_hist = np.concatenate([np.repeat(theta[:1], w - 1, axis=0), theta])
    u_full = np.concatenate([np.zeros((w - 1, 4)), u_hist])
    _assert_single_closed_loops(sur, th_hist, u_full, u, got)
    # a second call starts again from the synced state: same input, same output
    np.testing.assert_array_equal(pred.predict(u), got)
    # taking over mid-motion: warmed up on the history alone, as ClosedLoop on it
    pred.reset_history(theta, u_hist)
    _assert_single_closed_loops(sur, theta, u_hist, u, pred.predict(u))


def _assert_single_closed_loops(
    sur, th_hist: np.ndarray, u_hist: np.ndarray, u: np.ndarray, got: np.ndarray
) -> None:
    """``got`` (K, N, 4) equals K single ClosedLoop runs of the candidates ``u`` (K, N, 4),
    each warmed up on ``th_hist`` (n_hist, 4) and ``u_hist`` (n_hist - 1, 4)."""
    for i in range(u.shape[0]):
        ref = ClosedLoop(sur)
        ref.reset(th_hist[None], u_hist[None])
        for n in range(u.shape[1]):
            th, _ = ref.step(u[i, n][None])
            np.testing.assert_allclose(got[i, n], th[0].double().numpy(), atol=2e-5)


def test_plant_oracle_matches_stepping_copies_of_the_plant() -> None:
    """The oracle's mujoco.rollout from the plant's state equals stepping pickled copies of
    the hydraulic plant env (physics state and transform history) one command at a time."""
    env = ExcavatorMujocoEnv(plant="hydraulic")
    env.reset(options={"theta0": THETA0})
    rng = np.random.default_rng(1)
    for _ in range(7):
        env.step(rng.uniform(-1000, 1000, 4).astype(np.float32))
    pred = PlantPredictor(env.plant)
    u = rng.uniform(-1000, 1000, (3, N, 4))
    got = pred.predict(u)
    for i in range(3):
        copy = pickle.loads(pickle.dumps(env))
        for n in range(N):
            copy.step(u[i, n].astype(np.float32))
            np.testing.assert_allclose(got[i, n], copy.theta, atol=1e-6)
    before = env.plant.physics_state()
    pred.predict(u)
    np.testing.assert_array_equal(env.plant.physics_state(), before)  # the plant is untouched
    env.close()


def test_tiled_transform_continues_the_history() -> None:
    rng = np.random.default_rng(2)
    tr = HydraulicTransform()
    tr.reset(n_batch=1, substeps=25, timestep=0.002)
    tr(rng.uniform(-1000, 1000, (1, 12, 4)))
    more = rng.uniform(-1000, 1000, (1, 5, 4))
    tiled = tr.tiled(3)
    out = tiled(np.repeat(more, 3, axis=0))
    ref = tr(more)
    for i in range(3):
        np.testing.assert_array_equal(out[i], ref[0])


def test_bias_correction_adds_the_measured_velocity_error() -> None:
    """With bias_gain = 1 the correction is the last step's (measured - predicted) / T_s,
    ramped over the horizon; with 0 the predictor is unchanged."""
    sur = tiny_surrogate()
    rng = np.random.default_rng(3)
    theta, u_hist = _history(rng)
    plain = SurrogatePredictor(sur, n_batch=K)
    fixed = SurrogatePredictor(sur, n_batch=K, bias_gain=1.0)
    for p in (plain, fixed):
        p.reset(theta[0])
        for k in range(N_HIST):
            p.observe(u_hist[k], theta[k + 1])
    # the last one-step prediction of the synced engine, redone by hand
    ref = SurrogatePredictor(sur, n_batch=K)
    ref.reset(theta[0])
    for k in range(N_HIST - 1):
        ref.observe(u_hist[k], theta[k + 1])
    pred, _ = ref.sync.step(u_hist[-1][None])
    b = (theta[-1] - pred[0].numpy()) / sur.spec.dt
    np.testing.assert_allclose(fixed.bias, b, atol=1e-9)
    u = rng.uniform(-1000, 1000, (K, N, 4))
    ramp = np.arange(1, N + 1)[:, None] * sur.spec.dt
    np.testing.assert_allclose(fixed.predict(u), plain.predict(u) + ramp * b, atol=1e-9)
    with pytest.raises(ConfigError, match="bias_gain"):
        SurrogatePredictor(sur, n_batch=K, bias_gain=2.0)


def test_the_bias_correction_stays_inside_the_end_stops() -> None:
    """The bias is a velocity the rollout did not see: added as a ramp after the envelope,
    it had carried a predicted arm 20 degrees past its stop."""
    from excavator_surrogate.surrogate.angles import envelope

    sur = tiny_surrogate(end_stops=True)
    lo, hi, _ = envelope(sur.spec)
    p = SurrogatePredictor(sur, n_batch=K, bias_gain=1.0)
    plain = SurrogatePredictor(sur, n_batch=K)
    start = np.where(np.isfinite(hi), hi - 0.01, 0.0)
    for q in (p, plain):
        q.reset(start)
    p.bias[:] = 2.0  # [rad/s]: 0.1 rad a sample at 20 Hz
    u = np.random.default_rng(4).uniform(-1000, 1000, (K, N, 4))
    got, ref = p.predict(u), plain.predict(u)
    assert np.isfinite(hi).sum() >= 3 and (got <= hi).all() and (got >= lo).all()
    ramp = np.arange(1, N + 1)[:, None] * sur.spec.dt
    np.testing.assert_allclose(got, np.clip(ref + ramp * 2.0, lo, hi), atol=1e-9)
    assert (got[..., np.isfinite(hi)] == hi[np.isfinite(hi)]).any()  # some reached a stop


def _assert_split_close(got: np.ndarray, ref: np.ndarray, theta_now: np.ndarray) -> None:
    """``got`` equals ``ref`` (n_batch, n_step, n_joint) up to float32 roundings of each step's
    angle change from ``theta_now`` (n_joint,), summed over the steps, times a margin of 4
    for the recurrent state."""
    steps = np.abs(np.diff(ref, axis=1, prepend=np.broadcast_to(theta_now, ref[:, :1].shape)))
    atol = 4 * np.finfo(np.float32).eps * steps.max() * ref.shape[1]
    assert atol > 0
    err = np.abs(got - ref).max()
    assert err <= atol, f"split differs by {err:.3g} > {atol:.3g}"


@pytest.mark.parametrize(
    ("mode", "omega_in", "delayed_map"),
    [
        ("stateful", False, False),
        ("windowed", False, False),
        ("stateful", True, False),
        ("stateful", False, True),
    ],
)
def test_worker_processes_split_the_candidates(
    mode: str, omega_in: bool, delayed_map: bool
) -> None:
    """Candidates split over this process and two spawned workers give the same angles as
    one process, call after call (each call re-sends the synced state).

    Not bitwise: each process runs another batch shape (3, 2, 2 rows against 7), and the CPU's
    kernels may round those differently.  The network runs in float32 and its velocity is
    integrated in float64, so the two may differ by float32 roundings of each step's angle
    change, summed over the horizon (with margin for the recurrent state); a wrong split,
    a stale state or a swapped row is off by orders of magnitude more."""
    from excavator_surrogate.surrogate.ensemble import merge

    kw = dict(mode=mode, play=(0.05,), window=5, omega_in=omega_in)
    members = [tiny_surrogate(seed=s, **kw) for s in range(2)]
    sur = merge(members)
    if delayed_map:  # the workers get the delay line with the synced state
        sur = on_static_map(sur, delay=(2, 0, 0, 1))
    rng = np.random.default_rng(3)
    theta, u_hist = _history(rng)
    one = SurrogatePredictor(sur, n_batch=7, bias_gain=0.2)
    three = SurrogatePredictor(sur, n_batch=7, bias_gain=0.2, workers=3)
    try:
        assert [w.impl for w in three.workers] == (
            ["cell", "cell"] if mode == "stateful" else ["window", "window"]
        )
        for pred in (one, three):
            pred.reset(theta[0])
        for k in range(N_HIST):
            for pred in (one, three):
                pred.observe(u_hist[k], theta[k + 1])
            if k % 4 == 0:
                u = rng.uniform(-1000, 1000, (7, N, 4))
                _assert_split_close(three.predict(u), one.predict(u), theta[k + 1])
    finally:
        three.close()
    assert three.workers == []
    u = rng.uniform(-1000, 1000, (7, N, 4))
    # closed: in this process, the same shape and threads as ``one``: bitwise
    np.testing.assert_array_equal(three.predict(u), one.predict(u))


def test_worker_errors_are_one_line() -> None:
    sur = tiny_surrogate()
    with pytest.raises(ConfigError, match="workers must be in"):
        SurrogatePredictor(sur, n_batch=2, workers=3)
    pred = SurrogatePredictor(sur, n_batch=4, workers=2)
    try:
        pred.workers[0]._proc.kill()
        pred.workers[0]._proc.join()
        pred.reset(THETA0)
        with pytest.raises(ExsurError, match="rollout worker process died; rerun with workers=1"):
            pred.predict(np.zeros((4, N, 4)))
        assert pred.workers == []  # closed: the next call runs in this process
        assert pred.predict(np.zeros((4, N, 4))).shape == (4, N, 4)
    finally:
        pred.close()
