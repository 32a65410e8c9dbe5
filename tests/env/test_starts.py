"""Starting the surrogate from a recorded history: the engine against ClosedLoop, the envs
against the free run of ``exsur evaluate``, and the one-line errors."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest

from excavator_surrogate.data.episode import Episode
from excavator_surrogate.env import (
    ExcavatorMujocoEnv,
    ExcavatorSurrogateEnv,
    OnnxStepper,
    RecordedStarts,
    SurrogateVectorEnv,
    export_onnx,
)
from excavator_surrogate.env.engine import SurrogateEngine
from excavator_surrogate.env.starts import check_history, check_theta0
from excavator_surrogate.errors import ConfigError
from excavator_surrogate.spec import EXCAVATOR, JointSpec, MachineSpec
from excavator_surrogate.surrogate.checkpoint import load_checkpoint
from excavator_surrogate.surrogate.ensemble import merge
from excavator_surrogate.surrogate.rollout import ClosedLoop, rollout
from tests.helpers.surrogates import VARIANTS, variant_surrogate

MID = np.array([0.0, 0.0, 1.5, 0.5])


def _log(rng: np.random.Generator, n: int, n_step: int) -> tuple[np.ndarray, np.ndarray]:
    """A machine-like record: smooth angles in the limits, commands in the range;
    (n, n_step, 4) and (n, n_step, 4)."""
    steps = rng.normal(0.0, 0.02, (n, n_step, 4)).cumsum(axis=1)
    theta = MID + rng.uniform(-0.2, 0.2, (n, 1, 4)) + steps
    u = rng.uniform(-1000, 1000, (n, n_step, 4))
    return theta, u


@pytest.mark.parametrize("n_hist", [3, 10], ids=["short", "full"])
@pytest.mark.parametrize("variant", list(VARIANTS))
@pytest.mark.parametrize(
    ("mode", "cell"),
    [("stateful", "lstm"), ("stateful", "gru"), ("windowed", "lstm"), ("windowed", "arx")],
)
def test_engine_history_equals_closed_loop(mode: str, cell: str, variant: str, n_hist: int) -> None:
    """``reset_history`` puts an env where ClosedLoop's ``reset`` on the same history puts
    it (a windowed history shorter than the window padded with its first sample), also for
    a masked reset of a running engine (the ring's position is not 0); the env left out
    goes on as if nothing happened."""
    sur = variant_surrogate(mode=mode, cell=cell, **VARIANTS[variant])
    rng = np.random.default_rng(3)
    n = 3
    theta, u = _log(rng, n, n_hist)
    eng = SurrogateEngine(sur, n_envs=n)
    twin = SurrogateEngine(sur, n_envs=n)
    for e in (eng, twin):
        e.reset(np.repeat(MID[None], n, 0))
    for _ in range(4):
        u0 = rng.uniform(-1000, 1000, (n, 4))
        eng.step(u0)
        twin.step(u0)
    mask = np.array([True, False, True])
    eng.reset_history(theta, u[:, :-1], mask)
    np.testing.assert_array_equal(eng.theta.numpy()[mask], theta[mask, -1])
    ref = ClosedLoop(sur)
    ref.reset(theta[mask], u[mask, :-1])
    for _ in range(20):
        u_k = rng.uniform(-1000, 1000, (n, 4))
        th, om = eng.step(u_k)
        th_r, om_r = ref.step(u_k[mask])
        th_t, _ = twin.step(u_k)
        np.testing.assert_allclose(th.numpy()[mask], th_r.double().numpy(), atol=1e-5)
        np.testing.assert_allclose(om.numpy()[mask], om_r.double().numpy(), atol=1e-4)
        np.testing.assert_allclose(th.numpy()[1], th_t.numpy()[1], atol=1e-12)


def test_member_kernel_history_equals_closed_loop(make_surrogate) -> None:
    """A merged seed ensemble started from a history: the member kernel, the dense cell and
    the module kernels all continue ClosedLoop's warm-up."""
    kw = dict(mode="stateful", end_stops=True, drive=20.0, play=(0.05,), omega_in=True)
    ens = merge([make_surrogate(seed=s, hidden=16, **kw) for s in range(3)])
    rng = np.random.default_rng(4)
    n = 4
    theta, u = _log(rng, n, 12)
    ref = ClosedLoop(ens)
    ref.reset(theta, u[:, :-1])
    engines = [SurrogateEngine(ens, n_envs=n, impl=k) for k in ("members", "cell", "module")]
    assert engines[0].impl == "members"
    for e in engines:
        e.reset_history(theta, u[:, :-1])
    for _ in range(15):
        u_k = rng.uniform(-1000, 1000, (n, 4))
        th_r, _ = ref.step(u_k)
        for e in engines:
            np.testing.assert_allclose(e.step(u_k)[0].numpy(), th_r.double().numpy(), atol=1e-5)


@pytest.mark.parametrize("ckpt_name", ["stateful_ckpt", "windowed_ckpt"])
def test_env_from_history_continues_the_evaluate_free_run(
    ckpt_name: str, request: pytest.FixtureRequest
) -> None:
    """The single and the vector env started from a log's first ``n_hist`` samples, then
    stepped with the log's commands, give the free run ``rollout(warmup=n_hist)`` (what
    ``exsur evaluate`` reports); the start's observation holds the history's last angle
    and its last backward difference as ω; a masked vector reset from per-env histories
    leaves the other env's state alone."""
    ckpt = request.getfixturevalue(ckpt_name)
    sur = load_checkpoint(ckpt)
    rng = np.random.default_rng(5)
    n_hist, n_step = 9, 40
    theta, u = _log(rng, 2, n_step)
    theta[:, :, 0] += 7.0  # an unwrapped swing: the observation wraps it, the state does not
    th_free, _ = rollout(sur, theta, u, warmup=n_hist)

    env = ExcavatorSurrogateEnv(ckpt)
    obs, info = env.reset(
        options={"history": {"theta": theta[0, :n_hist], "u": u[0, : n_hist - 1]}}
    )
    np.testing.assert_array_equal(info["theta"], theta[0, n_hist - 1])
    w_last = (theta[0, n_hist - 1] - theta[0, n_hist - 2]) / EXCAVATOR.dt
    np.testing.assert_allclose(obs[4:], w_last, rtol=1e-6)
    assert obs[0] == pytest.approx(theta[0, n_hist - 1, 0] - 2 * np.pi, abs=1e-6)
    for k in range(n_hist - 1, n_step - 1):
        env.step(u[0, k])
        np.testing.assert_allclose(env.unwrapped.theta, th_free[0, k + 1], atol=1e-5)

    venv = SurrogateVectorEnv(ckpt, 3)
    venv.reset(seed=0)
    for _ in range(3):
        venv.step(rng.uniform(-1000, 1000, (3, 4)))
    kept = venv.engine.export_row(1)
    theta3 = np.concatenate([theta, theta[:1]])[:, :n_hist]
    u3 = np.concatenate([u, u[:1]])[:, : n_hist - 1]
    mask = np.array([True, False, True])
    obs, _ = venv.reset(options={"history": {"theta": theta3, "u": u3}, "reset_mask": mask})
    np.testing.assert_allclose(obs[0], obs[2])
    np.testing.assert_allclose(venv.engine.export_row(1)["theta"], kept["theta"])
    for k in range(n_hist - 1, n_step - 1):
        u_k = np.stack([u[0, k], rng.uniform(-1000, 1000, 4), u[0, k]])
        venv.step(u_k)
        np.testing.assert_allclose(
            venv.engine.theta.numpy()[[0, 2]], th_free[[0, 0], k + 1], atol=1e-5
        )


@pytest.mark.parametrize(
    ("history", "match"),
    [
        ({"theta": np.zeros((5, 4))}, r"must be a dict with 'theta' .* and 'u'"),
        ([np.zeros((5, 4)), np.zeros((4, 4))], r"must be a dict with 'theta'"),
        ({"theta": np.zeros((5, 4)), "u": np.zeros((5, 4))}, r"needs 'theta' \(n_hist >= 2, 4\)"),
        ({"theta": np.zeros((1, 4)), "u": np.zeros((0, 4))}, r"n_hist >= 2"),
        ({"theta": "abc", "u": np.zeros((4, 4))}, r"history\['theta'\] must be an array"),
        (
            {"theta": MID + np.zeros((5, 4)), "u": np.full((4, 4), np.nan)},
            r"\['u'\]\[0, 0\] is not finite",
        ),
        (
            {"theta": MID + np.zeros((5, 4)), "u": np.tile([0.0, 0.0, 1500.0, 0.0], (4, 1))},
            r"history\['u'\]\[0, 2\] \(arm\) = 1500 is outside its range \[-1000, 1000\]",
        ),
        (
            {"theta": MID + np.zeros((5, 4)) + np.array([0, 3.0, 0, 0]), "u": np.zeros((4, 4))},
            r"theta0\[1\] \(boom\) .* outside the joint limits",
        ),
        (
            {
                "theta": MID + np.zeros((5, 4)) + np.outer(np.arange(5) >= 3, [0, 0, 1.2, 0]),
                "u": np.zeros((4, 4)),
            },
            r"history\['theta'\] of arm jumps between samples 2 and 3 \(24 rad/s, beyond the guard's omega_max 20\)",
        ),
    ],
    ids=["no-u", "not-a-dict", "u-length", "one-sample", "text", "nan", "range", "limits", "jump"],
)
def test_bad_history_is_one_clear_line(stateful_ckpt, history, match: str) -> None:
    env = ExcavatorSurrogateEnv(stateful_ckpt)
    with pytest.raises(ConfigError, match=match):
        env.reset(options={"history": history})


def test_a_swing_stored_wrapped_across_pi_is_no_jump(stateful_ckpt) -> None:
    theta = MID + np.zeros((6, 4))
    theta[:, 0] = [3.10, 3.12, 3.14, -3.14, -3.12, -3.10]  # 0.02 rad a sample, wrapped
    obs, _ = ExcavatorSurrogateEnv(stateful_ckpt).reset(
        options={"history": {"theta": theta, "u": np.zeros((5, 4))}}
    )
    assert obs[4] == pytest.approx(0.02 / EXCAVATOR.dt, rel=1e-3)


def test_history_is_refused_where_it_cannot_be_honoured(stateful_ckpt) -> None:
    """Both a pose and a history; the plant (its hidden state is not in a log); a vector
    env's per-env history of the wrong count."""
    hist = {"theta": MID + np.zeros((5, 4)), "u": np.zeros((4, 4))}
    env = ExcavatorSurrogateEnv(stateful_ckpt)
    with pytest.raises(ConfigError, match="not both"):
        env.reset(options={"history": hist, "theta0": MID})
    plant = ExcavatorMujocoEnv()
    with pytest.raises(
        ConfigError, match=r"ExcavatorMujoco-v0: options\['history'\] starts only a surrogate"
    ):
        plant.reset(options={"history": hist})
    venv = SurrogateVectorEnv(stateful_ckpt, 3)
    bad = {"theta": np.zeros((2, 5, 4)) + MID, "u": np.zeros((2, 4, 4))}
    with pytest.raises(ConfigError, match=r"or with a first axis of 3 envs"):
        venv.reset(options={"history": bad})


@pytest.mark.parametrize(
    ("mode", "cell", "exporter"),
    [("stateful", "lstm", "torchscript"), ("windowed", "lstm", "torchscript")],
)
@pytest.mark.parametrize("n_hist", [3, 10], ids=["short", "full"])
@pytest.mark.parametrize("variant", ["stops", "velocity", "delayed-map", "parallel-map"])
def test_onnx_stepper_history_equals_closed_loop(
    mode: str, cell: str, exporter: str, variant: str, n_hist: int, tmp_path
) -> None:
    """The torch-free runtime starts from a history as ClosedLoop does (command states,
    delay line, velocity feature, a map joint's own angle)."""
    sur = variant_surrogate(mode=mode, cell=cell, **VARIANTS[variant])
    stepper = OnnxStepper(export_onnx(sur, tmp_path / "m.onnx", exporter=exporter))
    rng = np.random.default_rng(6)
    theta, u = _log(rng, 3, n_hist)
    th0 = stepper.reset_history(theta, u[:, :-1])
    np.testing.assert_allclose(th0, theta[:, -1], atol=1e-6)
    ref = ClosedLoop(sur)
    ref.reset(theta, u[:, :-1])
    for _ in range(20):
        u_k = rng.uniform(-1000, 1000, (3, 4))
        th, om = stepper.step(u_k)
        th_r, om_r = ref.step(u_k)
        np.testing.assert_allclose(om, om_r.double().numpy(), atol=2e-4)
        np.testing.assert_allclose(th, th_r.double().numpy(), atol=1e-5)


def _episodes(lengths: list[int], seed: int = 7) -> list[Episode]:
    rng = np.random.default_rng(seed)
    out = []
    for i, n in enumerate(lengths):
        theta, u = _log(rng, 1, n)
        t = np.arange(n) * EXCAVATOR.dt
        out.append(Episode(EXCAVATOR, t, u[0], theta[0], np.zeros((n, 4)), name=f"ep{i}"))
    return out


def test_recorded_starts_draw_every_moment_uniformly() -> None:
    """Each draw is the slice of one episode that ends at a moment with W - 1 samples before
    it; over many draws every such moment comes up, about equally often (an episode shorter
    than W has none)."""
    eps = _episodes([8, 5, 2])
    starts = RecordedStarts(eps, spec=EXCAVATOR, window=3)
    assert starts.n_moment == 6 + 3
    rng = np.random.default_rng(0)
    seen: dict[tuple[int, int], int] = {}
    for _ in range(3000):
        th, u = starts.draw(rng)
        assert th.shape == (3, 4) and u.shape == (2, 4)
        hits = [
            (e, k)
            for e, ep in enumerate(eps[:2])
            for k in range(2, len(ep.u))
            if np.array_equal(ep.theta[k - 2 : k + 1], th) and np.array_equal(ep.u[k - 2 : k], u)
        ]
        assert len(hits) == 1
        seen[hits[0]] = seen.get(hits[0], 0) + 1
    assert len(seen) == 9
    assert min(seen.values()) > 3000 / 9 * 0.75 and max(seen.values()) < 3000 / 9 * 1.25


def test_envs_with_recorded_starts(stateful_ckpt, tmp_path) -> None:
    """Random resets start at recorded moments: the single env at its generator's draw (the
    same seed, the same start), continuing as ClosedLoop from that history; the vector env's
    env i as a single env seeded seed + i, autoresets too; a pose given still wins; a
    dataset folder works; logs of another machine are refused."""
    from excavator_surrogate.data import write_dataset

    eps = _episodes([40, 25])
    sur = load_checkpoint(stateful_ckpt)
    w = sur.window
    env = ExcavatorSurrogateEnv(stateful_ckpt, recorded_starts=eps)
    obs, info = env.reset(seed=3)
    th, u = RecordedStarts(eps, spec=EXCAVATOR, window=w).draw(np.random.default_rng(3))
    np.testing.assert_array_equal(info["theta"], th[-1])
    ref = ClosedLoop(sur)
    ref.reset(th[None], u[None])
    u_k = np.array([300.0, -200.0, 500.0, 0.0])
    env.step(u_k)
    np.testing.assert_allclose(env.unwrapped.theta, ref.step(u_k[None])[0][0].double(), atol=1e-5)
    np.testing.assert_array_equal(env.reset(seed=3)[0], obs)
    assert env.reset(options={"theta0": MID})[1]["theta"].tolist() == MID.tolist()

    write_dataset(tmp_path / "data", [(ep, "train") for ep in eps])
    venv = SurrogateVectorEnv(
        stateful_ckpt, 3, recorded_starts=tmp_path / "data", max_episode_steps=2
    )
    obs_v, _ = venv.reset(seed=10)
    for i in range(3):
        one = ExcavatorSurrogateEnv(stateful_ckpt, recorded_starts=eps)
        np.testing.assert_allclose(obs_v[i], one.reset(seed=10 + i)[0], atol=1e-6)
    for _ in range(3):  # the time limit ends every episode: the autoreset draws again
        venv.step(np.zeros((3, 4)))
    drawn = RecordedStarts(eps, spec=EXCAVATOR, window=w)
    for i in range(3):
        g = np.random.default_rng(10 + i)
        drawn.draw(g)
        np.testing.assert_array_equal(venv.engine.theta.numpy()[i], drawn.draw(g)[0][-1])

    other = _episodes([20])
    other[0] = Episode(
        EXCAVATOR.with_rate(10.0),
        *(getattr(other[0], k) for k in ("time", "u", "theta", "omega")),
        name="slow",
    )
    with pytest.raises(
        ConfigError, match=r"episode 'slow' is of another machine than the surrogate"
    ):
        ExcavatorSurrogateEnv(stateful_ckpt, recorded_starts=other)
    with pytest.raises(ConfigError, match=r"no episode has the \d+ samples a recorded start needs"):
        ExcavatorSurrogateEnv(stateful_ckpt, recorded_starts=_episodes([2]))


def test_a_history_shorter_than_the_window_warns(stateful_ckpt) -> None:
    """The warm-up is padded then, unlike the one evaluate validated: one warning that says
    how many samples to give; a full window is quiet."""
    env = ExcavatorSurrogateEnv(stateful_ckpt)
    w = env.engine.window
    short = {"theta": MID + np.zeros((3, 4)), "u": np.zeros((2, 4))}
    with pytest.warns(UserWarning, match=rf"has 3 samples, fewer than the model's window W = {w}"):
        env.reset(options={"history": short})
    full = {"theta": MID + np.zeros((w, 4)), "u": np.zeros((w - 1, 4))}
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        env.reset(options={"history": full})


def test_a_last_angle_a_hair_past_a_stop_starts_there_with_one_warning(stateful_ckpt) -> None:
    """As a start pose may: one warning for all the envs of a vector reset (not one each),
    none for a recorded start, which is the machine's own state."""
    stop = EXCAVATOR.joints[1].theta_max
    theta = MID + np.zeros((6, 4))
    theta[-1, 1] = stop + 0.01
    hist = {"theta": theta, "u": np.zeros((5, 4))}
    venv = SurrogateVectorEnv(stateful_ckpt, 4)
    with pytest.warns(UserWarning) as got:
        venv.reset(options={"history": hist})
    msgs = [str(w.message) for w in got if "end stop" in str(w.message)]
    assert len(msgs) == 1 and "the histories of 4 env(s) (first: env 0) end up to 0.573" in msgs[0]
    np.testing.assert_allclose(venv.engine.theta.numpy()[:, 1], stop)
    ep = _episodes([12])[0]
    ep.theta[:, 1] = stop + 0.01  # recorded a hair past the stop: starts there, quietly
    env = ExcavatorSurrogateEnv(stateful_ckpt, recorded_starts=[ep])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        _, info = env.reset(seed=0)
    assert info["theta"][1] == stop
    far = _episodes([12])[0]
    far.theta[:, 1] = stop + 0.5  # beyond what a start pose may: no moment to draw
    with pytest.raises(ConfigError, match="ending inside the joint limits"):
        ExcavatorSurrogateEnv(stateful_ckpt, recorded_starts=[far])


STROKE = MachineSpec(
    (
        JointSpec("swing", periodic=True),
        JointSpec("boom", kind="linear", unit="mm", theta_min=0.2507, theta_max=2.0317),
        JointSpec("arm", theta_min=0.5, theta_max=2.7),
    )
)


def test_a_stroke_is_named_in_its_unit_at_reset() -> None:
    """A stroke outside its limits, past its stop, and jumping: in mm (was '3 rad ... by
    55.5 deg', '40 rad/s')."""
    with pytest.raises(ConfigError) as err:
        check_theta0(STROKE, [0.0, 3.0, 1.0], where="r")
    assert str(err.value) == (
        "r: theta0[1] (boom) = 3 m (3000 mm) is outside the joint limits [250.7, 2031.7] mm "
        "by 968.3 mm, more than 2% of the range: give a start pose inside them"
    )
    with pytest.warns(UserWarning, match=r"= 2.05 m \(2050 mm\) is 18.3 mm beyond its end stop "):
        check_theta0(STROKE, [0.0, 2.05, 1.0], where="r")
    theta = np.tile([0.0, 1.0, 1.0], (4, 1))
    theta[3, 1] = 2.0
    with pytest.raises(ConfigError, match=r"\(20000 mm/s, beyond the guard's omega_max 10 m/s = "):
        check_history(STROKE, {"theta": theta, "u": np.zeros((3, 3))}, where="r", omega_max=10.0)
    theta[3] = [0.0, 2.05, 2.71]  # both past a stop: the angle in deg, the stroke in mm
    with pytest.warns(UserWarning, match=r"ends up to 0.573 deg, 18.3 mm \(boom\) beyond an end"):
        check_history(STROKE, {"theta": theta, "u": np.zeros((3, 3))}, where="r")
    with pytest.raises(ConfigError, match=r"finite values \(angles in rad, strokes in m\)"):
        check_theta0(STROKE, [0.0, np.nan, 1.0], where="r")


def test_an_angle_is_named_as_before_at_reset() -> None:
    with pytest.raises(ConfigError) as err:
        check_theta0(EXCAVATOR, [0.0, 3.0, 1.5, 0.5], where="r")
    boom = EXCAVATOR.joints[1]
    assert str(err.value) == (
        f"r: theta0[1] (boom) = 3 rad is outside the joint limits [{boom.theta_min}, "
        f"{boom.theta_max}] by {math.degrees(3.0 - boom.theta_max):.3g} deg, more than 2% of "
        "the range: give a start pose inside them"
    )
    with pytest.warns(UserWarning, match=r"= 0.86 rad is 0.573 deg beyond its end stop 0.85 rad"):
        check_theta0(EXCAVATOR, [0.0, boom.theta_max + 0.01, 1.5, 0.5], where="r")
    with pytest.raises(ConfigError, match=r"finite angles in rad for joints"):
        check_theta0(EXCAVATOR, [0.0, np.nan, 1.5, 0.5], where="r")
