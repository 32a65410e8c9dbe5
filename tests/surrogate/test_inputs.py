"""Exogenous inputs: a machine whose joint speed scales with the engine speed, imported from
CSV with an ``[[inputs]]`` table, through features, rollouts and checkpoints."""

from __future__ import annotations

import tomllib
from pathlib import Path

import numpy as np
import pytest

from excavator_surrogate.data import load_dataset, read_episode
from excavator_surrogate.errors import ConfigError, DataError
from excavator_surrogate.ingest import import_logs, parse_mapping
from excavator_surrogate.spec import InputSpec, JointSpec, MachineSpec
from excavator_surrogate.surrogate import load_checkpoint, rollout, save_checkpoint
from excavator_surrogate.surrogate.features import encode_np
from excavator_surrogate.surrogate.reference import rollout_reference
from tests.helpers.ingest import assert_nothing_written
from tests.helpers.surrogates import make_surrogate

MAPPING = """\
[machine]
name = "rpm2"
rate_hz = 20.0
[time]
column = "t"
[import]
min_steps = 40
[split]
fractions = [0.5, 0.5, 0.0]
[[joints]]
name = "boom"
angle = { column = "boom_deg", unit = "deg" }
command = { column = "boom_pct", unit = "%", range = [-1000.0, 1000.0] }
[[joints]]
name = "arm"
angle = { column = "arm_deg", unit = "deg" }
command = { column = "arm_pct", unit = "%", range = [-1000.0, 1000.0] }
[[inputs]]
name = "engine_rpm"
column = "rpm"
unit = "physical"
physical_unit = "rpm"
range = [800.0, 2200.0]
[[inputs]]
name = "throttle"
column = "throttle_pct"
unit = "%"
range = [0.0, 1.0]
"""


def write_log(path: Path, seed: int, *, n: int = 2000, rpm_max: float = 2000.0) -> dict:
    """100 Hz log: joint speed = 20 deg/s * duty * rpm / 2000 (the engine drives the pump)."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * 0.01
    duty = np.repeat(rng.uniform(-100, 100, (n // 100 + 1, 2)), 100, axis=0)[:n]
    rpm = np.repeat(rng.uniform(1000.0, rpm_max, n // 250 + 1), 250)[:n]
    speed = 20.0 * duty / 100.0 * (rpm / 2000.0)[:, None]
    deg = 30.0 + np.cumsum(speed, axis=0) * 0.01
    cols = {
        "t": t,
        "boom_deg": deg[:, 0],
        "arm_deg": deg[:, 1],
        "boom_pct": duty[:, 0],
        "arm_pct": duty[:, 1],
        "rpm": rpm,
        "throttle_pct": np.full(n, 50.0),
    }
    lines = [",".join(cols)] + [",".join(f"{cols[c][k]:.9g}" for c in cols) for k in range(n)]
    path.write_text("\n".join(lines) + "\n")
    return cols


@pytest.fixture
def rpm_dataset(tmp_path: Path):
    for i in range(2):
        write_log(tmp_path / f"run{i}.csv", seed=i)
    (tmp_path / "rpm2.toml").write_text(MAPPING)
    mapping = parse_mapping(tomllib.loads(MAPPING), path=tmp_path / "rpm2.toml")
    import_logs(
        [tmp_path / "run0.csv", tmp_path / "run1.csv"], mapping, out=tmp_path / "ds", quiet=True
    )
    return load_dataset(tmp_path / "ds", min_steps=40)


def test_import_with_inputs(rpm_dataset, tmp_path):
    ds = rpm_dataset
    spec = ds.spec
    assert spec.inputs == (
        InputSpec("engine_rpm", 800.0, 2200.0, "rpm"),
        InputSpec("throttle", 0.0, 1.0, "%"),
    )
    assert (spec.n_joint, spec.n_input, spec.n_u) == (2, 2, 4)
    assert spec.n_feature == 2 + 4
    ep = (ds.train + ds.val)[0]
    assert ep.u.shape == (ep.n_step, 4)
    cols = write_log(tmp_path / "again.csv", seed=int(ep.name[-1]))
    # u[k] is the mean over [t_k, t_k+1) of the held rpm; 50 % throttle -> 0.5
    t_log = cols["t"]
    idx = np.searchsorted(t_log, ep.time[:, None] + np.linspace(0, 0.05, 6)[:-1], side="right") - 1
    np.testing.assert_allclose(ep.u[:, 2], cols["rpm"][idx].mean(axis=1), rtol=1e-6)
    np.testing.assert_allclose(ep.u[:, 3], 0.5)
    back = read_episode(ds.root / "episodes" / f"{ep.name}.parquet")
    assert back.spec == spec and back.u.shape == ep.u.shape
    assert MachineSpec.from_dict(spec.to_dict()) == spec
    report = (ds.root / "import_report.md").read_text()
    assert "- exogenous inputs (2): engine_rpm [rpm], throttle [%]" in report


def test_old_specs_and_input_errors(tmp_path):
    old = MachineSpec(joints=(JointSpec("boom"),))
    assert "inputs" not in old.to_dict() and MachineSpec.from_dict(old.to_dict()) == old
    with pytest.raises(ConfigError, match="joint and input names must be unique"):
        MachineSpec(joints=(JointSpec("boom"),), inputs=(InputSpec("boom"),))
    bad = tomllib.loads(MAPPING)
    del bad["inputs"][0]["range"]
    with pytest.raises(ConfigError, match="input 'engine_rpm': range = \\[lo, hi\\] is required"):
        parse_mapping(bad, path="m.toml")
    # an rpm above the range: one line naming the file, column and row, nothing written
    write_log(tmp_path / "fast.csv", seed=0, rpm_max=2500.0)
    mapping = parse_mapping(tomllib.loads(MAPPING), path=tmp_path / "rpm2.toml")
    with pytest.raises(
        DataError,
        match="fast.csv, column 'rpm', row \\d+: command 2[0-9.]+ .* outside \\[800, 2200\\] "
        "after scaling \\(check unit/scale/range of input 'engine_rpm' in rpm2.toml",
    ):
        import_logs([tmp_path / "fast.csv"], mapping, out=tmp_path / "ds", quiet=True)
    assert_nothing_written(tmp_path / "ds")


@pytest.mark.parametrize(("mode", "play"), [("windowed", ()), ("stateful", (0.1, 0.3))])
def test_features_and_rollout_with_inputs(rpm_dataset, tmp_path, mode, play):
    ds = rpm_dataset
    spec = ds.spec
    eps = ds.train + ds.val
    sur = make_surrogate(spec, eps, mode=mode, cell="lstm", play=play)
    assert sur.norm.n_feature == spec.n_feature + len(play) * spec.n_joint
    ep = eps[0]
    z = sur.norm.play_from_rest_np(ep.u, spec)
    x = encode_np(ep.theta, ep.u, spec, play=play, z=z)
    assert x.shape == (ep.n_step, 2 + 4 + len(play) * 2)
    # the inputs enter scaled by their ranges: rpm 1500 -> 0, 2200 -> 1
    np.testing.assert_allclose(x[:, 4], (ep.u[:, 2] - 1500.0) / 700.0)
    if play:  # play states follow the joints' commands only
        assert z.shape == (ep.n_step, len(play), spec.n_joint)
    # batched free run == the plain loop, with the inputs in u
    n = min(e.n_step for e in eps)
    theta = np.stack([e.theta[:n] for e in eps])
    u = np.stack([e.u[:n] for e in eps])
    th_b, om_b = rollout(sur, theta, u, warmup=10)
    for b in range(len(eps)):
        th_r, om_r = rollout_reference(sur, theta[b], u[b], warmup=10)
        np.testing.assert_allclose(th_b[b], th_r, atol=1e-4)
        np.testing.assert_allclose(om_b[b], om_r, atol=1e-3, equal_nan=True)
    # the model sees the inputs: another engine speed changes the prediction
    u2 = u.copy()
    u2[:, :, 2] = 900.0
    assert not np.allclose(rollout(sur, theta, u2, warmup=10)[0], th_b)
    # checkpoint round trip keeps the spec with its inputs
    back = load_checkpoint(save_checkpoint(tmp_path / "m.pt", sur, history=[]))
    assert back.spec == spec and back.spec.inputs == spec.inputs
    np.testing.assert_allclose(rollout(back, theta, u, warmup=10)[0], th_b, atol=1e-6)


def _u(rng: np.random.Generator, n: int) -> np.ndarray:
    """(n, 4) random commands of the rpm2 machine: two joints, engine speed, throttle."""
    return np.column_stack(
        [rng.uniform(-1000, 1000, (n, 2)), rng.uniform(800, 2200, n), rng.uniform(0, 1, n)]
    )


@pytest.mark.parametrize(("mode", "play"), [("windowed", ()), ("stateful", (0.1, 0.3))])
def test_engine_and_onnx_with_inputs(rpm_dataset, tmp_path, mode, play):
    """The env engine and the ONNX export take the inputs as the last columns of u and agree
    with ClosedLoop (at an at-rest history with the inputs at the centre of their ranges)."""
    from excavator_surrogate.env import OnnxStepper, export_onnx
    from excavator_surrogate.env.engine import SurrogateEngine
    from excavator_surrogate.surrogate.rollout import ClosedLoop

    spec = rpm_dataset.spec
    sur = make_surrogate(spec, rpm_dataset.train + rpm_dataset.val, mode=mode, play=play)
    rng = np.random.default_rng(0)
    n, w = 3, sur.window
    theta0 = np.radians(rng.uniform(20, 40, (n, 2)))
    eng = SurrogateEngine(sur, n_envs=n)
    eng.reset(theta0)
    rest = np.array([0.0, 0.0, 1500.0, 0.5])
    ref = ClosedLoop(sur)
    ref.reset(np.repeat(theta0[:, None], w, axis=1), np.tile(rest, (n, w - 1, 1)))
    stepper = OnnxStepper(export_onnx(sur, tmp_path / "m.onnx", exporter="torchscript"))
    stepper.reset(theta0)
    for _ in range(20):
        u = _u(rng, n)
        th, om = eng.step(u)
        th_r, om_r = ref.step(u)
        th_o, om_o = stepper.step(u)
        np.testing.assert_allclose(th.numpy(), th_r.double().numpy(), atol=1e-5)
        np.testing.assert_allclose(om.numpy(), om_r.double().numpy(), atol=1e-4)
        np.testing.assert_allclose(om_o, om.numpy(), atol=2e-4)
        np.testing.assert_allclose(th_o, th.numpy(), atol=1e-5)


def test_env_action_with_inputs_or_fixed(rpm_dataset, tmp_path):
    """Default: the action holds the commands and the inputs; ``inputs={...}`` fixes some,
    shrinking the action, and the fixed value is what the engine gets."""
    from excavator_surrogate.env import ExcavatorSurrogateEnv, SurrogateVectorEnv
    from excavator_surrogate.env.safety import ActionError

    spec = rpm_dataset.spec
    sur = make_surrogate(spec, rpm_dataset.train, mode="stateful")
    env = ExcavatorSurrogateEnv(sur)
    assert env.action_space.shape == (4,)
    np.testing.assert_allclose(env.action_space.low, [-1000, -1000, 800, 0])
    env.reset(seed=0, options={"theta0": [0.5, 0.6]})
    _, _, _, _, info = env.step(np.array([300.0, -200.0, 1900.0, 0.7], dtype=np.float32))
    np.testing.assert_allclose(info["u"], [300.0, -200.0, 1900.0, 0.7], rtol=1e-6)
    with pytest.raises(ActionError, match="expected \\(4,\\)"):
        env.step(np.zeros(2))
    fixed = ExcavatorSurrogateEnv(sur, inputs={"engine_rpm": 1800.0})
    assert fixed.action_space.shape == (3,)
    fixed.reset(seed=0, options={"theta0": [0.5, 0.6]})
    _, _, _, _, info = fixed.step(np.array([300.0, -200.0, 0.7], dtype=np.float32))
    np.testing.assert_allclose(info["u"], [300.0, -200.0, 1800.0, 0.7], rtol=1e-6)
    # the same as giving the input in the action, from the same warm-up
    both = ExcavatorSurrogateEnv(sur, inputs={"engine_rpm": 1800.0, "throttle": 0.7})
    assert both.action_space.shape == (2,)
    a = both.reset(seed=0, options={"theta0": [0.5, 0.6]})[0]
    env.engine.u_rest = both.layout.rest()  # same warm-up inputs
    b = env.reset(seed=0, options={"theta0": [0.5, 0.6]})[0]
    np.testing.assert_allclose(a, b)
    for _ in range(5):
        oa = both.step(np.array([300.0, -200.0]))[0]
        ob = env.step(np.array([300.0, -200.0, 1800.0, 0.7]))[0]
        np.testing.assert_allclose(oa, ob, atol=1e-6)
    vec = SurrogateVectorEnv(sur, 3, inputs={"throttle": 0.5})
    assert vec.single_action_space.shape == (3,) and vec.action_space.shape == (3, 3)
    vec.reset(seed=1)
    obs, *_ = vec.step(np.tile([100.0, 100.0, 2000.0], (3, 1)))
    assert obs.shape == (3, 4) and np.isfinite(obs).all()
    with pytest.raises(ConfigError, match="inputs names 'rpm', which is not an exogenous input"):
        ExcavatorSurrogateEnv(sur, inputs={"rpm": 1800.0})
    with pytest.raises(ConfigError, match="inputs\\['engine_rpm'\\] = 5000.0 is outside"):
        SurrogateVectorEnv(sur, 2, inputs={"engine_rpm": 5000.0})


def test_planner_predictor_holds_the_inputs_it_is_given(rpm_dataset):
    """A planner plans the joints' commands: ``SurrogatePredictor(inputs=...)`` holds the
    exogenous inputs, and its candidates equal the env's steps with the same fixed inputs."""
    from excavator_surrogate.control.predict import SurrogatePredictor
    from excavator_surrogate.env import ExcavatorSurrogateEnv

    sur = make_surrogate(rpm_dataset.spec, rpm_dataset.train, mode="stateful")
    with pytest.raises(ConfigError, match="exogenous input\\(s\\) engine_rpm, throttle"):
        SurrogatePredictor(sur, n_batch=2)
    with pytest.raises(ConfigError, match="exogenous input\\(s\\) throttle, which a planner"):
        SurrogatePredictor(sur, n_batch=2, inputs={"engine_rpm": 1800.0})
    held = {"engine_rpm": 1800.0, "throttle": 0.7}
    pred = SurrogatePredictor(sur, n_batch=2, inputs=held)
    env = ExcavatorSurrogateEnv(sur, inputs=held)
    theta0 = np.array([0.5, 0.6])
    pred.reset(theta0)
    env.reset(options={"theta0": theta0})
    for u in ([300.0, -200.0], [100.0, 50.0]):  # joint commands, and the whole vector
        pred.observe(u if u[0] == 300.0 else [*u, *held.values()], env.step(np.array(u))[0][:2])
    rng = np.random.default_rng(0)
    u = rng.uniform(-1000, 1000, (2, 4, 2))
    got = pred.predict(u)
    for i in range(2):
        ref = ExcavatorSurrogateEnv(sur, inputs=held)
        ref.reset(options={"theta0": theta0})
        ref.step(np.array([300.0, -200.0]))
        ref.step(np.array([100.0, 50.0]))
        for n in range(4):
            ref.step(u[i, n])
            np.testing.assert_allclose(got[i, n], ref.theta, atol=2e-5)


def test_train_with_inputs(rpm_dataset, tmp_path):
    """``train`` on a dataset with inputs: the checkpoint's model reads them (feature width)."""
    from excavator_surrogate.training import train
    from tests.helpers.training import tiny_train_config as tiny_stateful_config

    best = train(
        tiny_stateful_config(epochs=2, play=(0.1,)),
        rpm_dataset,
        out=tmp_path / "m",
        show_progress=False,
    )
    sur = load_checkpoint(best)
    spec = rpm_dataset.spec
    assert sur.spec.mismatch(spec) is None and sur.spec.inputs == spec.inputs
    assert sur.model_cfg.n_feature == spec.n_feature + spec.n_joint
    ep = rpm_dataset.val[0]
    theta_hat, _ = rollout(sur, ep.theta[None], ep.u[None])
    assert theta_hat.shape == (1, ep.n_step, 2) and np.isfinite(theta_hat).all()
