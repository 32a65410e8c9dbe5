"""Stage II: soil resistance, payload, closed-loop digging operator, datasets and presets."""

from __future__ import annotations

import dataclasses
import os
import subprocess
import sys
from pathlib import Path

import mujoco
import numpy as np
import pyarrow.parquet as pq
import pytest

from excavator_surrogate import numerics
from excavator_surrogate.config import from_dict, load_preset
from excavator_surrogate.data import load_dataset
from excavator_surrogate.errors import ConfigError
from excavator_surrogate.simulate.config import SimulateConfig
from excavator_surrogate.simulate.excitation import DigOperator, generate
from excavator_surrogate.simulate.generate import (
    EpisodeJob,
    _soil_hook,
    build_plant,
    simulate_dataset,
    simulate_episode,
)
from excavator_surrogate.simulate.plant import default_xml
from excavator_surrogate.simulate.soil import SoilConfig, SoilHook
from excavator_surrogate.spec import EXCAVATOR


def _preset(name: str, **changes: object) -> SimulateConfig:
    return dataclasses.replace(from_dict(SimulateConfig, load_preset(name)["simulate"]), **changes)


@pytest.fixture(scope="module")
def compound_plant():
    cfg = SimulateConfig(rate_hz=10.0, plant="hydraulic", soil=SoilConfig(enabled=True))
    plant = build_plant(cfg, EXCAVATOR.with_rate(10.0), loop=True)
    return plant, _soil_hook(plant)


ABOVE = np.array([0.0, 0.4, 1.0, 0.5])  # tip about 1.9 m above ground
BELOW = np.array([0.0, -0.1, 1.0, 0.0])  # tip about 2.5 m below ground


def test_soil_resistance_only_below_ground(compound_plant) -> None:
    plant, soil = compound_plant
    assert plant.site_position(ABOVE)[2] > 1.0 and plant.site_position(BELOW)[2] < -1.0
    plant.reset(theta0=ABOVE)
    for _ in range(10):
        plant.step(np.array([300.0, 0.0, 800.0, 500.0]))
        assert soil.depth < 0 and soil.volume == 0.0
        assert np.all(plant.data.qfrc_applied == 0.0) and np.all(soil.force == 0.0)
    plant.reset(theta0=BELOW)
    tip = mujoco.mj_name2id(plant.model, mujoco.mjtObj.mjOBJ_SITE, "tip")
    jac = np.zeros((3, plant.model.nv))
    forces, powers = [], []
    for _ in range(10):
        plant.step(np.array([0.0, 0.0, 800.0, 500.0]))
        assert soil.depth > 2.0
        mujoco.mj_jacSite(plant.model, plant.data, jac, None, tip)
        forces.append(np.linalg.norm(soil.force))
        if forces[-1] > 1e3:
            powers.append(float(soil.force @ (jac @ plant.data.qvel)))
    assert max(forces) > 1e5 and np.any(plant.data.qfrc_applied != 0.0)
    assert len(powers) >= 5 and max(powers) < 0.0  # the resistance opposes the tip's motion


def test_soil_resistance_slows_digging() -> None:
    u = np.zeros((1, 30, 4))
    u[..., 3] = 1000.0  # curl the bucket
    speeds = []
    for enabled in (False, True):
        cfg = SimulateConfig(rate_hz=10.0, plant="hydraulic", soil=SoilConfig(enabled=enabled))
        plant = build_plant(cfg, EXCAVATOR.with_rate(10.0), loop=True)
        speeds.append(plant.simulate(u, theta0=BELOW[None])["omega"][0, 5:15, 3].mean())
    assert speeds[1] < 0.8 * speeds[0]


def test_payload_fills_changes_mass_and_is_dumped(compound_plant) -> None:
    plant, soil = compound_plant
    model = plant.model
    b = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "bucket")
    plant.reset(theta0=BELOW)
    m0 = float(model.body_mass[b])
    assert m0 == 3500.0  # the empty bucket of the MJCF, whatever the previous episode did
    g0 = plant.data.qfrc_bias[plant._vadr].copy()
    for _ in range(40):  # dig: curl in the soil
        plant.step(np.array([0.0, 0.0, 800.0, 500.0]))
    assert soil.volume > 2.0
    assert model.body_mass[b] == pytest.approx(m0 + soil.payload_kg, abs=soil.config.update_kg)
    mujoco.mj_forward(model, plant.data)
    for _ in range(40):  # lift the loaded, curled bucket: the payload stays
        plant.step(np.array([0.0, 1000.0, 0.0, 1000.0]))
    assert soil.depth < -2.0 and soil.volume > 2.0
    for _ in range(40):  # dump: bucket out, arm out, above ground
        plant.step(np.array([0.0, 0.0, -600.0, -1000.0]))
    assert soil.volume == 0.0 and model.body_mass[b] == m0 and soil.stats["n_dump"] == 1
    assert soil.stats["dumped_m3"] == pytest.approx(soil.stats["dug_m3"])
    # reset restores the empty bucket and the same start
    for _ in range(20):
        plant.step(np.array([0.0, -1000.0, 800.0, 500.0]))
    plant.reset(theta0=BELOW)
    assert model.body_mass[b] == m0 and soil.volume == 0.0
    np.testing.assert_allclose(plant.data.qfrc_bias[plant._vadr], g0)


def test_runtime_mass_change_needs_no_mj_setconst() -> None:
    """Changing body_mass/inertia at run time gives the dynamics of a recompiled model."""
    xml = default_xml().read_text()
    runtime = mujoco.MjModel.from_xml_string(xml)
    compiled = mujoco.MjModel.from_xml_string(xml.replace('mass="3500"', 'mass="8500"'))
    b = mujoco.mj_name2id(runtime, mujoco.mjtObj.mjOBJ_BODY, "bucket")
    runtime.body_mass[b] = compiled.body_mass[b]
    runtime.body_inertia[b] = compiled.body_inertia[b]
    d1, d2 = mujoco.MjData(runtime), mujoco.MjData(compiled)
    for d in (d1, d2):
        d.qpos[:] = [0.3, 0.2, 1.2, 1.0]
        d.qvel[:] = [0.3, -0.2, 0.4, 0.8]
    for _ in range(100):
        mujoco.mj_step(runtime, d1)
        mujoco.mj_step(compiled, d2)
    np.testing.assert_allclose(d1.qpos, d2.qpos, atol=1e-12)
    np.testing.assert_allclose(d1.qfrc_bias, d2.qfrc_bias, rtol=1e-9)


@pytest.mark.parametrize("payload_pos", [(0.9, 0.0, 0.3), (1.3, 0.2, 0.6)])
def test_payload_inertia_is_consistent(payload_pos: tuple[float, float, float]) -> None:
    """The default payload sits on the bucket's COM; the other one off it (a tensor with
    off-diagonal terms, whose principal frame is rotated)."""
    soil_cfg = SoilConfig(enabled=True, payload_pos=payload_pos)
    plant = build_plant(SimulateConfig(plant="hydraulic", soil=soil_cfg), EXCAVATOR, loop=True)
    soil = _soil_hook(plant)
    assert isinstance(soil, SoilHook)
    plant.reset(theta0=ABOVE)
    b = soil._bucket
    soil._set_payload(plant.model, 5000.0)
    m = plant.model
    assert m.body_mass[b] == pytest.approx(8500.0)
    i1, i2, i3 = sorted(m.body_inertia[b])
    assert i1 > 0 and i1 + i2 >= i3  # a physical inertia
    np.testing.assert_allclose(np.linalg.norm(m.body_iquat[b]), 1.0)
    com = (3500 * np.array([0.9, 0, 0.3]) + 5000 * np.array(soil.config.payload_pos)) / 8500
    np.testing.assert_allclose(m.body_ipos[b], com)
    # the principal inertia and frame written give the composite tensor about the new COM:
    # the empty bucket's and the payload box's, each shifted by the parallel-axis theorem
    rot = np.empty(9)
    mujoco.mju_quat2Mat(rot, m.body_iquat[b])
    r = rot.reshape(3, 3)
    half = 2 * np.array(soil.config.payload_half_m)
    box = (
        5000
        / 12
        * np.diag(
            [half[1] ** 2 + half[2] ** 2, half[0] ** 2 + half[2] ** 2, half[0] ** 2 + half[1] ** 2]
        )
    )

    def shift(mass: float, d: np.ndarray) -> np.ndarray:
        return mass * (np.sum(d * d) * np.eye(3) - np.outer(d, d))

    want = (
        np.diag(soil._inertia0)  # the MJCF's bucket has its principal axes on the body's
        + shift(3500, np.array([0.9, 0, 0.3]) - com)
        + box
        + shift(5000, np.array(soil.config.payload_pos) - com)
    )
    np.testing.assert_allclose(r @ np.diag(m.body_inertia[b]) @ r.T, want, rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(np.linalg.det(r), 1.0)  # a rotation, not a reflection
    soil._set_payload(plant.model, 0.0)  # empty again: the MJCF's own inertial
    np.testing.assert_array_equal(m.body_inertia[b], soil._inertia0)
    np.testing.assert_array_equal(m.body_iquat[b], soil._iquat0)


def test_dig_operator_digs_and_dumps() -> None:
    cfg = _preset("quick-compound")
    job = EpisodeJob("train", 0, "dig_cycle", 700, 12345)
    res = simulate_episode(job, cfg, spec=EXCAVATOR.with_rate(cfg.rate_hz))
    comp, op = res["info"]["compound"], res["info"]["operator"]
    assert comp["dug_m3"] > 3.0 and comp["n_dump"] >= 1 and comp["max_payload_kg"] > 4000
    assert 0.05 < comp["below_ground_fraction"] < 0.8
    assert op["cycles"] >= 1 and [p for _, p in op["phases"]][:6] == list(DigOperator.PHASES)
    assert np.all(np.abs(res["u"]) <= 1000.0) and np.isfinite(res["theta"]).all()
    # swings between digging and dumping: at least 45 degrees of swing travel
    assert np.ptp(res["theta"][:, 0]) > np.deg2rad(45)
    with pytest.raises(ConfigError, match="closed-loop"):
        generate("dig_cycle", 0, 10, EXCAVATOR)


_AVX512 = {"avx512f", "avx512cd", "avx512bw", "avx512dq", "avx512vl"}


def _cpu_flags() -> set[str]:
    try:
        text = Path("/proc/cpuinfo").read_text()
    except OSError:
        return set()
    line = next((x for x in text.splitlines() if x.startswith("flags")), "")
    return set(line.partition(":")[2].split())


_EPISODE = """
import hashlib
from excavator_surrogate.config import from_dict, load_preset
from excavator_surrogate.simulate.config import SimulateConfig
from excavator_surrogate.simulate.generate import EpisodeJob, simulate_episode
from excavator_surrogate.spec import EXCAVATOR
cfg = from_dict(SimulateConfig, load_preset("quick-compound")["simulate"])
job = EpisodeJob("train", 0, "dig_cycle", 100, 12345)
res = simulate_episode(job, cfg, spec=EXCAVATOR.with_rate(cfg.rate_hz))
print(hashlib.sha256(res["theta"].tobytes() + res["u"].tobytes()).hexdigest())
"""


@pytest.mark.skipif(
    not any(b["library"] == "openblas" for b in numerics.blas_kernels())
    or not _AVX512 <= _cpu_flags(),
    reason="needs NumPy on OpenBLAS and an AVX-512 CPU (OpenBLAS's SkylakeX kernels)",
)
def test_a_digging_log_does_not_depend_on_numpys_blas_kernels() -> None:
    """OpenBLAS picks its kernels by CPU (AVX-512 ones on an Intel or a Zen 4, AVX2 ones on a
    Zen 5 or an AVX2 CPU), and they round matrix products differently. The closed-loop
    operator grew such a last-bit difference of the soil hook's tip velocity and payload
    inertia into another log. The hook takes them from MuJoCo's own routines, so the same
    seed digs the same log under either kernel set (two processes on one CPU, nothing else
    differing: MuJoCo and NumPy's element-wise loops run the same code in both)."""
    base = {k: v for k, v in os.environ.items() if k != "OPENBLAS_CORETYPE"}
    digests = []
    for core in ("Haswell", "SkylakeX"):
        done = subprocess.run(
            [sys.executable, "-c", _EPISODE],
            env={**base, "OPENBLAS_CORETYPE": core},
            capture_output=True,
            text=True,
            timeout=300,
        )
        assert done.returncode == 0, done.stderr[-2000:]
        digests.append(done.stdout.strip().splitlines()[-1])
    assert digests[0] == digests[1]


def _check_stage2(path: Path, condition: str, rate_hz: float) -> None:
    ds = load_dataset(path)  # validates every episode against the contract
    for ep in ds.train + ds.val + ds.test:
        assert ep.source == "mujoco-hydraulic" and ep.condition == condition
        assert ep.spec.rate_hz == rate_hz
        assert ep.theta_true is not None and ep.omega_true is not None
        assert np.abs(ep.theta - ep.theta_true).max() > 1e-3  # measured != truth
        np.testing.assert_allclose(
            np.diff(ep.theta_true, axis=0), ep.dt * ep.omega_true[1:], atol=1e-12
        )
        assert "sensor" in ep.extra and "drift_amplitude" in ep.generator["plant"]


@pytest.mark.parametrize("name", ["quick-noload", "quick-compound"])
def test_stage2_dataset_is_deterministic_and_valid(name: str, tmp_path: Path) -> None:
    small = {
        "n_train": 2,
        "n_val": 1,
        "n_test": 1,
        "steps_train": 300,
        "steps_val": 150,
        "steps_test": 200,
    }
    cfg = _preset(name, **small)
    a = simulate_dataset(cfg, out=tmp_path / "a", workers=1)
    b = simulate_dataset(cfg, out=tmp_path / "b", workers=2)
    files = sorted(p.name for p in (a / "episodes").iterdir())
    assert len(files) == 4
    for f in files:
        assert pq.read_table(a / "episodes" / f).equals(pq.read_table(b / "episodes" / f))
    compound = name.endswith("compound")
    _check_stage2(a, "compound" if compound else "noload", 10.0 if compound else 20.0)
    if compound:
        ep = load_dataset(a).train[0]
        assert "compound" in ep.generator["plant"] and "operator" in ep.generator["plant"]


def test_stage2_presets_match_the_paper() -> None:
    noload = load_preset("paper-noload")
    cfg = from_dict(SimulateConfig, noload["simulate"])
    assert cfg.n_train == 34 and cfg.rate_hz == 20.0 and cfg.plant == "hydraulic" and cfg.sensors
    assert abs(cfg.n_train * cfg.steps_train - 650_000) < 1000 and cfg.steps_test == 7657
    # stateful one-step (teacher-forced) training, like the paper's H = 1; no horizon knob
    assert noload["train"]["mode"] == "stateful" and "horizon" not in noload["train"]
    assert noload["train"]["lambda_bias"] == 0.0
    compound = load_preset("paper-compound")
    cfg = from_dict(SimulateConfig, compound["simulate"])
    assert (
        cfg.n_train == 33
        and cfg.rate_hz == 10.0
        and cfg.soil.enabled
        and cfg.condition == "compound"
    )
    assert abs(cfg.n_train * cfg.steps_train - 84_000) < 1000 and cfg.steps_test == 2950
    assert set(cfg.train_signals) == {"dig_cycle"}
    # the paper's lambda_bias; H = 10 is approximated by free-run 10-step TBPTT chunks (the
    # stateful mode has no horizon knob, and the preset says so)
    t = compound["train"]
    assert t["lambda_bias"] == 0.3 and "horizon" not in t
    assert (t["mode"], t["feedback"], t["tbptt"]) == ("stateful", "free", 10)
    for name in ("quick-noload", "quick-compound"):
        q = from_dict(SimulateConfig, load_preset(name)["simulate"])
        # sized for the 5-minute demo: simulation takes seconds, training ~150 s per model
        assert q.plant == "hydraulic" and q.sensors and q.n_train * q.steps_train <= 150_000
    with pytest.raises(ConfigError, match="plant"):
        SimulateConfig(plant="pneumatic")
    with pytest.raises(ConfigError, match="dig_cycle"):
        SimulateConfig(train_signals=("digging",))
