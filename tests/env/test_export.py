"""ONNX export of the single-step model and the onnxruntime stepper."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import onnx
import pytest
import torch

from excavator_surrogate.cli import main
from excavator_surrogate.env import OnnxStepper, export_onnx
from excavator_surrogate.env.engine import SurrogateEngine
from excavator_surrogate.env.fused import rest_command
from excavator_surrogate.errors import CheckpointError, ConfigError
from excavator_surrogate.spec import EXCAVATOR
from excavator_surrogate.surrogate.angles import joint_limits
from excavator_surrogate.surrogate.ensemble import merge
from excavator_surrogate.surrogate.rollout import ClosedLoop
from tests.helpers.cli import fails
from tests.helpers.surrogates import (
    PARALLEL_JOINTS,
    VARIANTS,
    on_parallel_map,
    tiny_surrogate,
    variant_surrogate,
)


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


DYNAMO_VARIANTS = ("prior", "delayed-map", "parallel-map")
"""The variants an LSTM is exported with the dynamo exporter in (3-9 s an export on a slow
computer; torchscript takes 0.1-1 s).  Between them they carry every part of the others'
graphs: end stops, play, the velocity feature with its residual head, a speed prior, a map in
series and in parallel, and a graph without ``z``."""


def _runtimes() -> list:
    """(mode, cell, exporter, variant) of the stepper-against-torch test: each variant as a
    stateful LSTM and GRU and a windowed LSTM and ARX; the LSTMs of :data:`DYNAMO_VARIANTS`
    through dynamo (the default exporter), every other graph through torchscript."""
    cases = []
    for variant in VARIANTS:
        for mode, cell in (("stateful", "lstm"), ("stateful", "gru"), ("windowed", "lstm")):
            dynamo = cell == "lstm" and variant in DYNAMO_VARIANTS
            cases.append((mode, cell, "dynamo" if dynamo else "torchscript", variant))
        cases.append(("windowed", "arx", "torchscript", variant))
    return [pytest.param(*c, id=f"{c[3]}-{c[0]}-{c[1]}-{c[2]}") for c in cases]


def test_the_dynamo_variants_carry_every_feature_of_the_others() -> None:
    """What :data:`DYNAMO_VARIANTS` claims: every option any variant sets, and a graph
    without ``z`` (no play, no map), is set in one of them."""
    options = {k for kw in VARIANTS.values() for k, v in kw.items() if v}
    assert options <= {k for v in DYNAMO_VARIANTS for k, on in VARIANTS[v].items() if on}
    no_z = ("play", "delayed_map", "parallel_map")
    assert any(not any(VARIANTS[v].get(k) for k in no_z) for v in DYNAMO_VARIANTS)


@pytest.mark.parametrize(("mode", "cell", "exporter", "variant"), _runtimes())
def test_onnx_stepper_matches_torch(
    mode: str, cell: str, exporter: str, variant: str, tmp_path: Path
) -> None:
    kw = VARIANTS[variant]
    end_stops, play, omega_in = kw["end_stops"], kw["play"], kw["omega_in"]
    sur = variant_surrogate(mode=mode, cell=cell, **kw)
    lagged = bool(sur.norm.lags)  # a delayed map: its delay line travels in z
    own = sur.norm.own is not None  # a map in parallel: the network's own angle travels in z
    assert own == (variant == "parallel-map" and cell != "arx")
    assert lagged == (variant in ("delayed-map", "parallel-map") and cell != "arx")
    path = export_onnx(sur, tmp_path / "model.onnx", exporter=exporter)
    model = onnx.load(str(path))
    onnx.checker.check_model(model)
    names = [i.name for i in model.graph.input]
    expect = ["theta", "u", "h", "c"] if mode == "stateful" else ["theta", "u"]
    has_z = bool(play) or lagged or own
    assert names == expect + (["z"] if has_z else []) + (["w"] if omega_in else [])
    outs = [o.name for o in model.graph.output]
    expect = ["omega", "theta_next"] + (["h_out", "c_out"] if mode == "stateful" else [])
    assert outs == expect + (["z_out"] if has_z and (mode == "stateful" or own) else [])
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


def _reset_at_rest(loop: ClosedLoop, theta0: np.ndarray) -> None:
    """:meth:`ClosedLoop.reset` as the runtimes reset: ``W`` samples at ``theta0`` (n,
    n_joint) [rad] under the rest command (``W - 1`` warm-up steps)."""
    w, spec = loop.sur.window, loop.sur.spec
    theta_hist = np.repeat(theta0[:, None], w, axis=1)
    u_hist = np.broadcast_to(rest_command(spec), (len(theta0), w - 1, spec.n_u))
    loop.reset(theta_hist, np.ascontiguousarray(u_hist))


@pytest.mark.parametrize(
    ("mode", "cell", "exporter", "kw", "delay"),
    [
        # the stateful dynamo graph on a map in parallel: test_onnx_stepper_matches_torch
        ("stateful", "lstm", "torchscript", VARIANTS["parallel-map"], (2, 0, 0, 0)),
        ("stateful", "gru", "torchscript", VARIANTS["parallel-map"], (2, 0, 0, 0)),
        ("windowed", "lstm", "dynamo", VARIANTS["parallel-map"], (2, 0, 0, 0)),
        ("windowed", "gru", "torchscript", VARIANTS["parallel-map"], (1, 0, 0, 0)),
        ("stateful", "lstm", "torchscript", dict(end_stops=True, prior=True), (2, 0, 0, 1)),
        ("stateful", "gru", "torchscript", {}, None),  # z: the own rows only
        ("windowed", "lstm", "torchscript", {}, None),
    ],
    ids=["lstm", "gru", "window-lstm", "window-gru", "prior", "own-rows-only", "window-own-only"],
)
def test_parallel_map_graph_matches_the_closed_loop(
    mode: str, cell: str, exporter: str, kw: dict, delay, tmp_path: Path
) -> None:
    """Joints on a static map in parallel: the graph (stateful, or windowed with ``z_out``)
    stepped by the stepper equals :class:`ClosedLoop` reset at rest, angles, velocities and
    the network's own angle and velocity in ``z``; the metadata names the joints."""
    kw = {k: v for k, v in kw.items() if k != "parallel_map"}
    base = variant_surrogate(
        mode=mode, cell=cell, **{"end_stops": False, "play": (), "omega_in": False, **kw}
    )
    sur = on_parallel_map(base, delay=delay)
    assert sur.norm.n_own == 2
    path = export_onnx(sur, tmp_path / "par.onnx", exporter=exporter)
    meta = {p.key: p.value for p in onnx.load(str(path)).metadata_props}
    assert json.loads(meta["exsur_own"]) == PARALLEL_JOINTS
    stepper = OnnxStepper(path)
    assert stepper.n_state == sur.norm.n_state and stepper.n_command == sur.norm.n_command
    loop = ClosedLoop(sur)
    n = 5
    rng = np.random.default_rng(2)
    theta0 = rng.uniform(-0.3, 0.3, (n, 4)) + np.array([0.0, 0.0, 1.5, 0.5])
    stepper.reset(theta0)
    _reset_at_rest(loop, theta0)
    c = sur.norm.n_command
    np.testing.assert_allclose(stepper.z, loop.z.numpy(), atol=1e-6, rtol=0)
    pick = np.array(PARALLEL_JOINTS)
    for _ in range(40):
        u = rng.uniform(-1000, 1000, (n, 4))
        th, om = stepper.step(u)
        th_t, om_t = loop.step(torch.as_tensor(u, dtype=torch.float32))
        np.testing.assert_allclose(th, th_t.numpy(), atol=1e-5, rtol=0)
        np.testing.assert_allclose(om, om_t.numpy(), atol=2e-4, rtol=0)
        z_t = loop.z.numpy()
        np.testing.assert_allclose(stepper.z, z_t, atol=1e-5, rtol=1e-5)
    # the network's own angle of the map joints is not the reported one
    assert np.abs(stepper.z[:, c][:, pick] - th[:, pick]).max() > 1e-2


def test_parallel_map_members_match_the_closed_loop(tmp_path: Path) -> None:
    """A merged ensemble on a map in parallel: ``omega_members`` of the graph equal the
    closed loop's members, which drive a map joint with gain ``1 + own_gain_dev[m]``."""
    kw = dict(mode="stateful", play=(0.05,), omega_in=True, residual=True, hidden=8)
    members = [tiny_surrogate(EXCAVATOR, seed=s, **kw) for s in (7, 8, 9)]
    sur = on_parallel_map(merge(members), delay=(2, 0, 0, 0))
    path = export_onnx(sur, tmp_path / "ens.onnx", exporter="torchscript", uncertainty=True)
    stepper = OnnxStepper(path)
    assert stepper.n_member == 3
    loop = ClosedLoop(sur, members=True)
    n = 4
    rng = np.random.default_rng(5)
    theta0 = rng.uniform(-0.3, 0.3, (n, 4)) + np.array([0.0, 0.0, 1.5, 0.5])
    stepper.reset(theta0)
    _reset_at_rest(loop, theta0)
    pick = np.array(PARALLEL_JOINTS)
    spread = []
    for _ in range(25):
        u = rng.uniform(-1000, 1000, (n, 4))
        th, om = stepper.step(u)
        th_t, om_t = loop.step(torch.as_tensor(u, dtype=torch.float32))
        np.testing.assert_allclose(th, th_t.numpy(), atol=1e-5, rtol=0)
        np.testing.assert_allclose(om, om_t.numpy(), atol=2e-4, rtol=0)
        assert stepper.omega_members is not None and loop.omega_members is not None
        om_m = loop.omega_members.numpy()
        np.testing.assert_allclose(stepper.omega_members, om_m, atol=1e-5, rtol=1e-5)
        spread.append(np.std(stepper.omega_members, axis=0))
    assert np.stack(spread)[..., pick].max() > 1e-4  # the map joints spread by the gains


@pytest.mark.parametrize("existing", [False, True], ids=["new", "existing"])
def test_a_graph_onnxruntime_cannot_load_leaves_nothing_at_out(
    existing: bool, stateful_ckpt: Path, tmp_path: Path
) -> None:
    """Opset 17 of a stateful graph through the dynamo exporter (its version converter) is a
    graph onnxruntime refuses (InvalidGraph).  It used to be renamed onto ``out`` before
    anything loaded it: a broken file, or a good earlier export replaced by one."""
    out = tmp_path / "m.onnx"
    if existing:
        out.write_bytes(b"an earlier export")
    with pytest.raises(ConfigError) as err:
        export_onnx(stateful_ckpt, out, opset=17, exporter="dynamo")
    msg = str(err.value)
    assert msg.startswith(f"{out}: the dynamo exporter wrote opset 17 but onnxruntime cannot load")
    assert "--opset 18" in msg and "--exporter torchscript" in msg  # what to do instead
    if existing:
        assert out.read_bytes() == b"an earlier export"
    else:
        assert not out.exists()
    assert [p.name for p in tmp_path.iterdir()] == (["m.onnx"] if existing else [])


def test_verify_runs_on_the_temporary_file_before_the_rename(
    stateful_ckpt: Path, tmp_path: Path
) -> None:
    """``verify`` sees the complete graph, not yet at ``out``; its failure leaves ``out``."""
    out = tmp_path / "m.onnx"
    out.write_bytes(b"an earlier export")
    seen: list[Path] = []

    def refuse(path: Path) -> None:
        assert path != out and path.parent == out.parent
        assert OnnxStepper(path).spec == EXCAVATOR and out.read_bytes() == b"an earlier export"
        seen.append(path)
        raise ConfigError("the graph does not match torch")

    with pytest.raises(ConfigError, match="does not match torch"):
        export_onnx(stateful_ckpt, out, exporter="torchscript", verify=refuse)
    assert len(seen) == 1 and not seen[0].exists()
    assert [p.name for p in tmp_path.iterdir()] == ["m.onnx"]
    assert out.read_bytes() == b"an earlier export"
    assert export_onnx(stateful_ckpt, out, exporter="torchscript", verify=seen.append) == out
    assert len(seen) == 2 and OnnxStepper(out).mode == "stateful"


def test_cli_export_of_an_opset_onnxruntime_refuses_keeps_the_earlier_file(
    stateful_ckpt: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "m.onnx"
    assert main(["export", str(stateful_ckpt), "--out", str(out), "--exporter", "torchscript"]) == 0
    before = out.read_bytes()
    capsys.readouterr()
    line = fails(
        capsys, "export", stateful_ckpt, "--out", out, "--opset", 17, "--exporter", "dynamo"
    )
    assert out.read_bytes() == before  # the refused graph never replaced it
    assert [p.name for p in tmp_path.iterdir()] == ["m.onnx"]
    assert line.startswith(f"exsur: error: {out}: the dynamo exporter wrote opset 17 but")
    assert "--exporter torchscript" in line


def test_cli_torchscript_export_of_an_opset_it_cannot_write_is_one_line(
    stateful_ckpt: Path, tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    """torchscript at opset 24 (past its last) raised RuntimeError (a traceback, exit 1) after
    torch's C++ log printed the whole TorchScript graph on stdout."""
    out = tmp_path / "m.onnx"
    argv = ("export", stateful_ckpt, "--out", out, "--exporter", "torchscript", "--opset", 24)
    line = fails(capfd, *argv)
    assert f"{out}: the torchscript ONNX exporter cannot write opset 24" in line
    assert "use an opset from 11 to 23" in line
    assert capfd.readouterr().out == ""
    assert list(tmp_path.iterdir()) == []


def test_cli_refused_opset_prints_one_line_and_no_library_traceback(
    stateful_ckpt: Path, tmp_path: Path
) -> None:
    """``exsur export --opset 11``: onnxscript's version converter logged a warning and its
    traceback (17 lines) on stderr before exsur's line.  A separate process: in-process,
    pytest's log capture on the root logger would take those lines off stderr."""
    out = tmp_path / "m.onnx"
    argv = [
        "export",
        str(stateful_ckpt),
        "--out",
        str(out),
        "--opset",
        "11",
        "--exporter",
        "dynamo",
    ]
    run = subprocess.run(
        [sys.executable, "-m", "excavator_surrogate.cli", *argv],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert run.returncode == 2, run.stderr
    err = run.stderr.splitlines()
    assert len(err) == 1 and "Traceback" not in run.stderr, run.stderr
    assert err[0].startswith(f"exsur: error: {out}: the ONNX exporter cannot write opset 11")
    assert "--exporter torchscript" in err[0]
    assert run.stdout == "" and list(tmp_path.iterdir()) == []


def test_an_opset_no_exporter_writes_is_refused_before_anything_is_traced(
    stateful_ckpt: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Opset 3 or 999 was traced (3-16 s with dynamo) before the opset the file got was
    checked; below onnxruntime's first opset or past onnx's last, nothing is traced now."""
    import excavator_surrogate.env.export as export

    def traced(*args, **kwargs):
        raise AssertionError("traced")

    monkeypatch.setattr(export, "_export", traced)
    out = tmp_path / "m.onnx"
    last = onnx.defs.onnx_opset_version()
    cases = [
        (6, "auto", "(onnxruntime runs opsets 7 and up); use --opset 18 or leave the option out"),
        (last + 1, "dynamo", f"defines opsets up to {last}); use --opset 18"),
        (3, "torchscript", "7 and up); use an opset from 11 to 23 or leave --opset out"),
    ]
    for opset, exporter, why in cases:
        with pytest.raises(ConfigError) as err:
            export_onnx(stateful_ckpt, out, opset=opset, exporter=exporter)
        assert str(err.value).startswith(f"{out}: the ONNX exporter cannot write opset {opset} ")
        assert why in str(err.value)
    with pytest.raises(ConfigError, match=r"opset must be an integer \(default 18\), got '18'"):
        export_onnx(stateful_ckpt, out, opset="18")  # type: ignore[arg-type]
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(AssertionError, match="traced"):  # the first and last opsets go on
        export_onnx(stateful_ckpt, out, opset=7)
    with pytest.raises(AssertionError, match="traced"):
        export_onnx(stateful_ckpt, out, opset=last)


def test_auto_exports_an_opset_below_18_with_torchscript(
    stateful_ckpt: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """``--exporter auto`` (the default) with ``--opset 17``: dynamo's down-conversion gives a
    graph onnxruntime refuses, so auto takes torchscript, which writes it."""
    import onnx

    out = tmp_path / "m17.onnx"
    assert main(["export", str(stateful_ckpt), "--out", str(out), "--opset", "17"]) == 0
    assert "max |torch - onnxruntime|" in capsys.readouterr().out  # stepped against torch
    opsets = {o.domain: o.version for o in onnx.load(str(out)).opset_import}
    assert opsets.get("", opsets.get("ai.onnx")) == 17


@pytest.mark.parametrize(
    ("blocked", "exporter", "missing"),
    [
        (("onnx", "onnxruntime", "onnxscript"), "auto", "onnx, onnxruntime"),
        (("onnx", "onnxruntime", "onnxscript"), "dynamo", "onnx, onnxruntime, onnxscript"),
        (("onnxscript",), "dynamo", "onnxscript"),
    ],
)
def test_cli_export_without_the_extra_names_it(
    stateful_ckpt: Path,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
    blocked,
    exporter,
    missing,
) -> None:
    """Without the export extra each exporter's line sent the user to the other one and
    never named the package; now one line names the extra (nothing written)."""
    for name in blocked:  # import fails, importlib.util.find_spec gives None
        monkeypatch.setitem(sys.modules, name, None)
    out = tmp_path / "m.onnx"
    line = fails(capsys, "export", stateful_ckpt, "--out", out, "--exporter", exporter)
    assert line == (
        f"exsur: error: exsur export needs the export extra (missing: {missing}): "
        "pip install 'excavator-surrogate[export]'"
    )
    assert list(tmp_path.iterdir()) == []


def test_onnx_stepper_refuses_wrong_shapes_in_one_line(stateful_ckpt: Path, tmp_path: Path) -> None:
    """A wrong shape was reshaped (a transposed ``u`` scrambled across rows) or failed with
    NumPy's or onnxruntime's error; now one ConfigError names the shape and the columns."""
    stepper = OnnxStepper(export_onnx(stateful_ckpt, tmp_path / "m.onnx", exporter="torchscript"))
    with pytest.raises(ConfigError, match=r"call reset\(theta0\) or reset_history"):
        stepper.step(np.zeros(4))
    cols = r"u \(swing, boom, arm, bucket\)"
    stepper.reset(np.tile([0.0, 0.2, 1.5, 0.5], (4, 1)))
    for bad in ((4, 5), (3, 4), (4,), (4, 4, 1), (16,)):
        with pytest.raises(ConfigError, match=rf"must have shape \(4, 4\).*{cols}\), got") as e:
            stepper.step(np.zeros(bad))
        assert "\n" not in str(e.value)
    stepper.reset(np.zeros((2, 4)))
    with pytest.raises(ConfigError, match=r"\(2, 4\)"):  # (n_u, n_batch): refused
        stepper.step(np.zeros((4, 2)))
    for bad in ((2, 3), (2, 1, 4), ()):
        with pytest.raises(ConfigError, match=r"theta0 must have shape \(n_batch, 4\)"):
            stepper.reset(np.zeros(bad))
    with pytest.raises(ConfigError, match=r"u_hist must have shape \(1, 5, 4\).*" + cols):
        stepper.reset_history(np.zeros((1, 6, 4)), np.zeros((1, 5, 3)))
    with pytest.raises(ConfigError, match="theta_hist must have shape"):
        stepper.reset_history(np.zeros((1, 1, 4)), np.zeros((1, 0, 4)))
    stepper.reset(np.zeros(4))  # one row: 1-d angles and commands
    theta, _ = stepper.step(np.zeros(4))
    assert theta.shape == (1, 4)
