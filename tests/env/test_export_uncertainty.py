"""The optional ``omega_members`` output of the ONNX export (``exsur export --uncertainty``)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import onnx
import pytest

from excavator_surrogate.cli import main
from excavator_surrogate.env import OnnxStepper, export_onnx
from excavator_surrogate.env.engine import SurrogateEngine
from excavator_surrogate.errors import ConfigError
from excavator_surrogate.surrogate.checkpoint import save_checkpoint
from excavator_surrogate.surrogate.coverage import CoverageRecord, channel_names, ood_flags
from excavator_surrogate.surrogate.ensemble import merge
from tests.helpers.surrogates import on_static_map

EPS32 = float(np.finfo(np.float32).eps)


@pytest.mark.parametrize(
    ("exporter", "kw"),
    [
        ("torchscript", dict(play=(0.05, 0.2), omega_in=True)),
        ("dynamo", dict(omega_in=True, residual=True)),
        ("torchscript", dict(prior=True)),
        ("torchscript", dict(map_joints=True)),
        ("dynamo", dict(map_joints=True)),
        ("torchscript", dict(map_joints="delayed", play=(0.1,))),
    ],
    ids=["play-velocity", "residual", "prior", "map-torchscript", "map-dynamo", "delayed-map"],
)
def test_members_output_matches_the_engine(make_surrogate, tmp_path: Path, exporter, kw) -> None:
    """onnxruntime's ``omega_members`` equal the engine's members (same network call) every
    step, their mean is the central omega, and the metadata carries M; also with joints on
    the static map, which each member drives with its own gain."""
    on_map = kw.pop("map_joints", False)
    sur = merge([make_surrogate(seed=s, hidden=8, mode="stateful", **kw) for s in range(3)])
    if on_map:  # "delayed": the swing's and the bucket's maps read earlier commands
        sur = on_static_map(sur, delay=(3, 0, 0, 1) if on_map == "delayed" else None)
    path = export_onnx(sur, tmp_path / "ens.onnx", exporter=exporter, uncertainty=True)
    names = [o.name for o in onnx.load(str(path)).graph.output]
    assert names[-1] == "omega_members"
    stepper = OnnxStepper(path)
    assert stepper.n_member == 3
    n = 4
    engine = SurrogateEngine(sur, n_envs=n, uncertainty=True)
    rng = np.random.default_rng(3)
    theta0 = rng.uniform(-0.3, 0.3, (n, 4)) + np.array([0.0, 0.0, 1.5, 0.5])
    stepper.reset(theta0)
    engine.reset(theta0)
    spread = []
    for _ in range(20):
        u = rng.uniform(-1000, 1000, (n, 4))
        _, om = stepper.step(u)
        engine.step(u)
        om_m = engine.unc.omega_members.numpy()
        tol = 1e3 * EPS32 * (1.0 + np.abs(om_m).max())  # float32 graph vs float32 torch
        assert stepper.omega_members.shape == (3, n, 4)
        np.testing.assert_allclose(stepper.omega_members, om_m, atol=tol, rtol=0)
        # the members' mean is the central velocity (before any speed bound: none here)
        np.testing.assert_allclose(stepper.omega_members.mean(0), om, atol=tol, rtol=0)
        spread.append(np.std(stepper.omega_members, axis=0))
    # members disagree; on a map joint only where the map moves it (a command in the dead
    # zone gives every member's gain times 0)
    spread = np.stack(spread)  # (n_step, n, 4)
    moving = [1, 2] if on_map else [0, 1, 2, 3]
    assert spread[..., moving].min() > 10 * tol
    assert spread.max(axis=0).min() > 10 * tol


def _recipe_limits(stepper: OnnxStepper) -> tuple[np.ndarray, np.ndarray] | None:
    """The end stops of docs/env.md's band recipe, from the file's metadata alone (None: the
    graph has none)."""
    meta = stepper.session.get_modelmeta().custom_metadata_map
    if meta["exsur_end_stops"] != "1":
        return None
    joints = json.loads(meta["exsur_spec"])["joints"]
    bound = lambda j, k, inf: inf if j["periodic"] or j[k] is None else j[k]  # noqa: E731
    lo = np.array([bound(j, "theta_min", -np.inf) for j in joints])
    hi = np.array([bound(j, "theta_max", np.inf) for j in joints])
    return lo, hi


def test_band_recipe_keeps_the_members_inside_the_stops(make_surrogate, tmp_path: Path) -> None:
    """docs/env.md's angle-band recipe on the graph's outputs (``omega_members``, ``omega``,
    ``theta_next``, the stops of ``exsur_spec``) gives the engine's ``theta_band``, also with
    joints resting on their end stops (where the sum without the clip grows past 1 rad)."""
    sur = merge([make_surrogate(seed=s, end_stops=True, drive=20.0 + 10 * s) for s in range(3)])
    stepper = OnnxStepper(
        export_onnx(sur, tmp_path / "d.onnx", exporter="torchscript", uncertainty=True)
    )
    lim = _recipe_limits(stepper)
    assert lim is not None
    lo, hi = lim
    engine = SurrogateEngine(sur, n_envs=2, uncertainty=True)
    theta0 = np.array([[0.0, 0.0, 1.5, 0.5], [0.3, 0.2, 1.2, 0.1]])
    stepper.reset(theta0)
    engine.reset(theta0)
    dev = np.zeros((3, 2, 4))
    free = np.zeros_like(dev)  # the same sum without the clip
    u = np.zeros((2, 4))
    for _ in range(120):
        th, om = stepper.step(u)
        engine.step(u)
        th, om = th.astype(np.float64), om.astype(np.float64)
        # dev_m <- dev_m + T_s (omega_m - omega)
        dev += sur.spec.dt * (stepper.omega_members - om)
        free += sur.spec.dt * (stepper.omega_members - om)
        # dev_m <- clip(theta' + dev_m, min(lo, theta'), max(hi, theta')) - theta'
        dev = np.clip(th + dev, np.minimum(lo, th), np.maximum(hi, th)) - th
        band = engine.unc.bands()[0].numpy()  # uncalibrated: the raw member std
        np.testing.assert_allclose(dev.std(0, ddof=1), band, atol=1e-4, rtol=0)
    at_stop = (np.abs(th - lo) < 1e-6) | (np.abs(th - hi) < 1e-6)
    assert at_stop[:, 1:].all()  # the driven joints rest on their stops; the swing turns
    assert band[at_stop].max() < 1e-4 and free.std(0, ddof=1)[at_stop].min() > 1.0


def test_uncertainty_export_refuses_what_has_none(make_surrogate, tmp_path: Path, capsys) -> None:
    single = make_surrogate(seed=0, hidden=8, mode="stateful")
    with pytest.raises(ConfigError, match="no ensemble members"):
        export_onnx(single, tmp_path / "a.onnx", exporter="torchscript", uncertainty=True)
    ens = merge([make_surrogate(seed=s, hidden=8, mode="stateful") for s in range(2)])
    with pytest.raises(ConfigError, match="stateful"):
        export_onnx(ens, tmp_path / "b.onnx", mode="windowed", uncertainty=True)
    assert not list(tmp_path.glob("*.onnx"))
    # the CLI: verified against torch, members included; the records in the metadata
    ens.metrics["uncertainty"] = {
        "levels": [0.9],
        "theta": [[2.0] * 4],
        "omega": [[3.0] * 4],
        "n_step": 5,
    }
    ckpt = save_checkpoint(tmp_path / "ens.pt", ens)
    out = tmp_path / "ens.onnx"
    argv = ["export", str(ckpt), "--out", str(out), "--uncertainty", "--exporter", "torchscript"]
    assert main(argv) == 0
    assert "max |torch - onnxruntime|" in capsys.readouterr().out
    meta = {p.key: p.value for p in onnx.load(str(out)).metadata_props}
    assert meta["exsur_members"] == "2" and json.loads(meta["exsur_coverage"]) == {}
    assert json.loads(meta["exsur_uncertainty"])["theta"] == [[2.0] * 4]
    single_ckpt = save_checkpoint(tmp_path / "single.pt", single)
    argv = ["export", str(single_ckpt), "--out", str(tmp_path / "s.onnx"), "--uncertainty"]
    assert main(argv) == 2
    assert "no ensemble members" in capsys.readouterr().err


def _record(spec, rng: np.random.Generator, *, turned: bool = False) -> CoverageRecord:
    """A coverage record whose boxes cut through what the test drives (flags fire and stay
    off), with a grid holding empty cells.  ``turned``: the swing (periodic) was fitted on
    ``[c - pi, c + pi)`` round ``c`` = 3.2 rad (``turn_centre``), its box 5 % wider: a swing
    near 0 checks on both turns (below 0.058 rad one turn up), else a record without
    ``turn_centre`` whose swing box spans two turns (checked where it is)."""
    n_j = spec.n_joint
    swing = (-0.25, 6.65) if turned else (-7.0, 7.0)
    lo = np.concatenate([np.full(n_j, -600.0), [swing[0], 0.3, 1.2, 0.2], np.full(n_j, -0.5)])
    hi = np.concatenate([np.full(n_j, 600.0), [swing[1], 0.9, 2.4, 1.4], np.full(n_j, 0.5)])
    grid = (rng.uniform(size=(n_j, 10, 10)) > 0.6).astype(np.int64)
    centre = np.array([3.2] + [0.0] * (n_j - 1)) if turned else None
    return CoverageRecord(channel_names(spec), lo, hi, grid, n_sample=1000, turn_centre=centre)


@pytest.mark.parametrize(
    ("exporter", "kw", "turned"),
    [
        ("torchscript", dict(play=(0.05, 0.2)), False),
        ("torchscript", dict(omega_in=True, residual=True), False),
        ("torchscript", dict(play=(0.05, 0.2)), True),
        ("dynamo", dict(omega_in=True, residual=True), True),  # the default exporter
    ],
    ids=["omega_prev-input", "velocity-feature", "turn-centre", "turn-centre-dynamo"],
)
def test_ood_output_equals_the_python_flags(
    make_surrogate, tmp_path: Path, exporter, kw, turned
) -> None:
    """The graph's ``ood`` output is ``ood_flags`` of the sample each step predicts from
    (theta[k], omega[k], u[k]) and the engine's flag, step by step; without a velocity
    feature omega[k] enters as ``omega_prev``.  Also with a record that keeps the swing's fit
    centre, where every swing angle turns round it (``coverage.on_box_turn``)."""
    sur = merge([make_surrogate(seed=s, hidden=8, mode="stateful", **kw) for s in range(2)])
    rec = _record(sur.spec, np.random.default_rng(1), turned=turned)
    sur.metrics["coverage"] = rec.to_dict()
    path = export_onnx(sur, tmp_path / "ens.onnx", exporter=exporter, uncertainty=True)
    model = onnx.load(str(path))
    assert [o.name for o in model.graph.output][-2:] == ["omega_members", "ood"]
    has_prev = "omega_prev" in [i.name for i in model.graph.input]
    assert has_prev == (not kw.get("omega_in", False))
    assert {p.key: p.value for p in model.metadata_props}["exsur_ood"] == "1"
    stepper = OnnxStepper(path)
    n = 6
    engine = SurrogateEngine(sur, n_envs=n, uncertainty=True)
    rng = np.random.default_rng(4)
    theta0 = rng.uniform(-0.3, 0.3, (n, 4)) + np.array([0.0, 0.6, 1.8, 0.8])
    stepper.reset(theta0)
    engine.reset(theta0)
    fired, n_flag, n_turned = [], 0, 0
    for _ in range(30):
        u = rng.uniform(-1000, 1000, (n, 4))
        theta_k, omega_k = stepper.theta.astype(np.float64), stepper.w.astype(np.float64)
        n_turned += int((theta_k[:, 0] < 3.2 - np.pi).sum())
        stepper.step(u)
        engine.step(u)
        u32 = u.astype(np.float32).astype(np.float64)  # what the graph saw
        want = ood_flags(rec, sur.spec, theta_k, omega_k, u32)
        assert stepper.ood is not None and stepper.ood.dtype == bool
        np.testing.assert_array_equal(stepper.ood, want)
        np.testing.assert_array_equal(stepper.ood, engine.unc.ood.numpy())
        fired.append(want)
        n_flag += int(want.sum())
    share = n_flag / np.size(fired)
    assert 0.05 < share < 0.95  # both outcomes are exercised
    assert n_turned > 0 or not turned  # swing angles below c - pi: one turn up


@pytest.mark.parametrize(
    ("exporter", "kw"),
    [
        ("torchscript", dict(play=(0.05, 0.2))),
        ("torchscript", dict(omega_in=True, residual=True)),  # dynamo's graph: the test above
    ],
    ids=["omega_prev-input", "velocity-feature"],
)
def test_ood_after_a_history_and_a_measurement(
    make_surrogate, tmp_path: Path, exporter, kw
) -> None:
    """From a recorded history, and after a measured angle, the sample the next step predicts
    from moves at the measured ``wrap(theta[k] - theta[k-1]) / T_s`` (what the env's
    observation shows): the graph fed it as ``w`` / ``omega_prev``, the engine and
    ``ood_flags`` flag the same joints (the engine had checked 0 rad/s there)."""
    sur = merge([make_surrogate(seed=s, hidden=8, mode="stateful", **kw) for s in range(2)])
    rec = _record(sur.spec, np.random.default_rng(1))
    sur.metrics["coverage"] = rec.to_dict()
    spec, dt = sur.spec, sur.spec.dt
    stepper = OnnxStepper(
        export_onnx(sur, tmp_path / "e.onnx", exporter=exporter, uncertainty=True)
    )
    n = 6
    engine = SurrogateEngine(sur, n_envs=n, uncertainty=True)
    rng = np.random.default_rng(5)
    pose = rng.uniform(-0.3, 0.3, (n, 1, 4)) + np.array([0.0, 0.6, 1.8, 0.8])
    th_hist = np.repeat(pose, 8, axis=1)
    th_hist[:, -1] += rng.uniform(-0.06, 0.06, (n, 4))  # the last sample moves, up to 1.2 rad/s
    u_hist = rng.uniform(-1000, 1000, (n, 7, 4))
    stepper.reset_history(th_hist, u_hist)
    engine.reset_history(th_hist, u_hist)
    th32 = th_hist.astype(np.float32).astype(np.float64)  # what the graph saw
    theta_k, omega_k = th32[:, -1], (th32[:, -1] - th32[:, -2]) / dt
    moved = 0
    for _ in range(2):
        u = rng.uniform(-1000, 1000, (n, 4))
        u32 = u.astype(np.float32).astype(np.float64)
        stepper.step(u)
        engine.step(u)
        want = ood_flags(rec, spec, theta_k, omega_k, u32)
        np.testing.assert_array_equal(stepper.ood, want)
        np.testing.assert_array_equal(engine.unc.ood.numpy(), want)
        moved += int((want != ood_flags(rec, spec, theta_k, 0 * omega_k, u32)).sum())
        # a measured sample: engine.observe; the graph's recipe feeds theta and w measured
        meas = engine.theta.numpy() + rng.uniform(-0.06, 0.06, (n, 4))
        w_meas = (meas - engine.theta_prev.numpy()) / dt
        engine.observe(meas)
        stepper.theta, stepper.w = meas.astype(np.float32), w_meas.astype(np.float32)
        theta_k, omega_k = meas.astype(np.float32), w_meas.astype(np.float32)
    assert moved > 0  # the measured velocity decided flags


def test_onnx_stepper_reset_clears_the_last_step_outputs(make_surrogate, tmp_path: Path) -> None:
    """After a reset the last episode's ``ood`` (3, 4) and ``omega_members`` (2, 3, 4) had
    stayed; now both are None until the next step, which gives the new batch's."""
    sur = merge([make_surrogate(seed=s, hidden=8, mode="stateful") for s in range(2)])
    sur.metrics["coverage"] = _record(sur.spec, np.random.default_rng(1)).to_dict()
    stepper = OnnxStepper(
        export_onnx(sur, tmp_path / "e.onnx", exporter="torchscript", uncertainty=True)
    )
    pose = np.array([0.0, 0.6, 1.8, 0.8])
    stepper.reset(np.zeros((3, 4)) + pose)
    stepper.step(np.full((3, 4), 1000.0))
    assert stepper.ood is not None and stepper.ood.any()
    stepper.reset(pose[None])
    assert stepper.ood is None and stepper.omega_members is None
    stepper.step(np.zeros((1, 4)))
    assert stepper.ood.shape == (1, 4) and stepper.omega_members.shape == (2, 1, 4)
    stepper.reset_history(np.zeros((2, 3, 4)) + pose, np.zeros((2, 2, 4)))
    assert stepper.ood is None and stepper.omega_members is None


def test_no_coverage_record_no_ood_output(make_surrogate, tmp_path: Path) -> None:
    sur = merge([make_surrogate(seed=s, hidden=8, mode="stateful") for s in range(2)])
    path = export_onnx(sur, tmp_path / "ens.onnx", exporter="torchscript", uncertainty=True)
    model = onnx.load(str(path))
    assert [o.name for o in model.graph.output][-1] == "omega_members"
    assert "omega_prev" not in [i.name for i in model.graph.input]
    assert {p.key: p.value for p in model.metadata_props}["exsur_ood"] == "0"
    stepper = OnnxStepper(path)
    stepper.reset(np.array([[0.0, 0.6, 1.8, 0.8]]))
    stepper.step(np.zeros((1, 4)))
    assert stepper.ood is None


def test_cli_checks_the_ood_output(make_surrogate, tmp_path: Path, capsys) -> None:
    """``exsur export --uncertainty`` steps the graph beside the engine and counts the flags
    that differ (none)."""
    sur = merge([make_surrogate(seed=s, hidden=8, mode="stateful") for s in range(2)])
    sur.metrics["coverage"] = _record(sur.spec, np.random.default_rng(2)).to_dict()
    ckpt = save_checkpoint(tmp_path / "ens.pt", sur)
    out = tmp_path / "ens.onnx"
    argv = ["export", str(ckpt), "--out", str(out), "--uncertainty", "--exporter", "torchscript"]
    assert main(argv) == 0
    msg = capsys.readouterr().out
    assert "OOD flags:" in msg and ", 0 differ in onnxruntime" in msg
    assert "OOD flags: 0 raised" not in msg
