"""ONNX export of the single-step model and the onnxruntime stepper."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import onnx
import pytest

from excavator_surrogate.cli import main
from excavator_surrogate.env import OnnxStepper, export_onnx
from excavator_surrogate.env.engine import SurrogateEngine
from excavator_surrogate.errors import CheckpointError
from excavator_surrogate.surrogate.angles import joint_limits
from tests.helpers.surrogates import VARIANTS, variant_surrogate


def _step_side_by_side(
    stepper: OnnxStepper, engine: SurrogateEngine, *, n_step: int, seed: int
) -> np.ndarray:
    """Reset both runtimes at the same random poses, step them with the same random commands
    and assert they agree every step; returns the last angles (n_envs, 4)."""
    n = engine.n_envs
    rng = np.random.default_rng(seed)
    theta0 = rng.uniform(-0.3, 0.3, (n, 4)) + np.array([0.0, 0.0, 1.5, 0.5])
    stepper.reset(theta0)
    engine.reset(theta0)
    for _ in range(n_step):
        u = rng.uniform(-1000, 1000, (n, 4))
        th, om = stepper.step(u)
        th_t, om_t = engine.step(u)
        np.testing.assert_allclose(om, om_t.numpy(), atol=2e-4, rtol=0)
        np.testing.assert_allclose(th, th_t.numpy(), atol=1e-5, rtol=0)
    return th


@pytest.mark.parametrize(
    ("mode", "cell", "exporter"),
    [
        ("stateful", "lstm", "dynamo"),
        ("stateful", "gru", "torchscript"),
        ("windowed", "lstm", "dynamo"),
        ("windowed", "arx", "torchscript"),
    ],
)
@pytest.mark.parametrize("variant", list(VARIANTS))
def test_onnx_stepper_matches_torch(
    mode: str, cell: str, exporter: str, variant: str, tmp_path: Path
) -> None:
    kw = VARIANTS[variant]
    end_stops, play, omega_in = kw["end_stops"], kw["play"], kw["omega_in"]
    sur = variant_surrogate(mode=mode, cell=cell, **kw)
    lagged = bool(sur.norm.lags)  # a delayed map: its delay line travels in z
    assert lagged == (variant == "delayed-map" and cell != "arx")
    path = export_onnx(sur, tmp_path / "model.onnx", exporter=exporter)
    model = onnx.load(str(path))
    onnx.checker.check_model(model)
    names = [i.name for i in model.graph.input]
    expect = ["theta", "u", "h", "c"] if mode == "stateful" else ["theta", "u"]
    assert names == expect + (["z"] if play or lagged else []) + (["w"] if omega_in else [])
    stepper = OnnxStepper(path)
    assert stepper.spec == sur.spec and stepper.mode == mode
    th = _step_side_by_side(stepper, SurrogateEngine(sur, n_envs=5), n_step=40, seed=0)
    if end_stops:  # driven into the stops: both runtimes rest on them
        assert (
            np.isclose(th, joint_limits(sur.spec)[0]) | np.isclose(th, joint_limits(sur.spec)[1])
        ).any()


def test_state_is_exposed_and_batch_is_dynamic(make_surrogate, tmp_path: Path) -> None:
    import onnxruntime as ort

    sur = make_surrogate()
    path = export_onnx(sur, tmp_path / "m.onnx", exporter="torchscript")
    sess = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    assert [o.name for o in sess.get_outputs()] == ["omega", "theta_next", "h_out", "c_out"]
    for n in (1, 7):
        h = np.zeros((2, n, 16), np.float32)
        out = sess.run(
            None,
            {
                "theta": np.zeros((n, 4), np.float32),
                "u": np.zeros((n, 4), np.float32),
                "h": h,
                "c": h,
            },
        )
        assert out[0].shape == (n, 4) and out[2].shape == (2, n, 16)


def test_cli_export(
    stateful_ckpt: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "sub" / "model.onnx"
    assert main(["export", str(stateful_ckpt), "--out", str(out)]) == 0
    assert out.is_file() and "max |torch - onnxruntime|" in capsys.readouterr().out
    assert main(["export", str(tmp_path / "missing.pt"), "--out", str(out)]) == 2
    assert "checkpoint not found" in capsys.readouterr().err
    with pytest.raises(CheckpointError):
        OnnxStepper(tmp_path / "nope.onnx")


def test_onnx_runs_a_merged_ensemble(make_surrogate, tmp_path: Path) -> None:
    """A merged seed ensemble exports like any stateful checkpoint and matches the engine
    (with play features and the velocity feature: inputs z, then w)."""
    from excavator_surrogate.surrogate.ensemble import merge

    kw = dict(mode="stateful", play=(0.05, 0.2), omega_in=True)
    sur = merge([make_surrogate(seed=0, **kw), make_surrogate(seed=1, hidden=8, **kw)])
    stepper = OnnxStepper(export_onnx(sur, tmp_path / "ens.onnx", exporter="torchscript"))
    _step_side_by_side(stepper, SurrogateEngine(sur, n_envs=2), n_step=30, seed=1)
