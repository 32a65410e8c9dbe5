"""The Stage I MuJoCo plant: delay, stiffness, limits, velocity map, determinism, batching."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from excavator_surrogate.errors import ConfigError
from excavator_surrogate.simulate.hooks import ZeroOrderHold
from excavator_surrogate.simulate.plant import MujocoExcavator, PlantConfig
from excavator_surrogate.spec import EXCAVATOR


@pytest.fixture(scope="module")
def plant() -> MujocoExcavator:
    return MujocoExcavator()


def _pose(spec=EXCAVATOR, frac: float = 0.5) -> np.ndarray:
    return np.array(
        [
            0.3 if j.theta_min is None else j.theta_min + frac * (j.theta_max - j.theta_min)
            for j in spec.joints
        ]
    )


def test_geometry_matches_spec(plant: MujocoExcavator) -> None:
    m = plant.model
    assert m.opt.timestep == pytest.approx(0.002)
    assert plant.substeps == 25
    np.testing.assert_allclose(plant.omega_max, [0.68, 0.45, 0.55, 1.0], rtol=1e-12)
    for k, j in enumerate(EXCAVATOR.joints):
        a = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_ACTUATOR, j.name)
        jid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, j.name)
        if j.periodic:
            assert not m.jnt_limited[jid] and not m.actuator_actlimited[a]
            continue
        # the servo setpoint stops exactly at the spec limits; the hard stops lie just outside
        np.testing.assert_allclose(
            m.actuator_actrange[a] / plant.gear[k], [j.theta_min, j.theta_max]
        )
        assert m.jnt_range[jid, 0] < j.theta_min and m.jnt_range[jid, 1] > j.theta_max


def test_step_is_delayed_by_50_ms() -> None:
    fine = MujocoExcavator(PlantConfig(rate_hz=500.0))  # one physics step per sample
    assert fine.substeps == 1
    theta0 = _pose()
    n = 60
    u = np.zeros((1, n, EXCAVATOR.n_joint))
    u[0, 5:] = 600.0  # step at t = 10 ms
    theta = fine.simulate(u, theta0=theta0[None])["theta"][0]
    t = np.arange(n) * fine.dt
    moved = np.any(theta != theta0, axis=1)
    assert not moved[t <= 0.010 + 0.050 + 1e-9].any()  # nothing until 50 ms after the step
    assert moved[np.flatnonzero(t > 0.060 + 1e-9)[0]]  # then motion on the next physics step
    # at 20 Hz: sample 1 shows no motion, sample 2 does
    th = MujocoExcavator().simulate(np.full((1, 4, 4), 600.0), theta0=theta0[None])["theta"][0]
    assert np.array_equal(th[1], th[0]) and np.all(th[2] != th[0])


def test_no_sag_at_zero_command(plant: MujocoExcavator) -> None:
    rng = np.random.default_rng(3)
    for frac in (0.1, 0.5, 0.9):
        theta0 = _pose(frac=frac) + rng.uniform(-0.01, 0.01, 4)
        theta = plant.rollout(np.zeros((1, 200, 4)), theta0=theta0[None])["theta"][0]  # 10 s
        assert np.abs(theta - theta0).max() < 1e-9


def test_stiff_against_load_changes(plant: MujocoExcavator) -> None:
    """Moving the arm and bucket changes the boom's gravity load: deflection stays tiny, no drift."""
    u = np.zeros((1, 120, 4))
    u[0, :40, 2] = 1000.0
    u[0, :40, 3] = -800.0
    theta0 = np.array([0.0, 0.3, 0.8, 1.5])
    theta = plant.rollout(u, theta0=theta0[None])["theta"][0]
    assert np.abs(theta[:, 1] - theta0[1]).max() < 1e-3  # boom deflection < 0.06 deg
    assert np.abs(theta[60:, 1] - theta[60, 1]).max() < 1e-9  # and no drift once at rest


def test_joint_limits_hold_and_swing_is_unlimited(plant: MujocoExcavator) -> None:
    n = 200  # 10 s at full command: more than any joint's range
    for sign in (1.0, -1.0):
        out = plant.rollout(np.full((1, n, 4), 1000.0 * sign), theta0=_pose()[None])
        theta = out["theta"][0]
        for k, j in enumerate(EXCAVATOR.joints):
            if j.periodic:
                # unwrapped swing: 0.68 rad/s for (10 s - 50 ms delay - one sample)
                assert sign * (theta[-1, k] - theta[0, k]) > 6.0
                continue
            # transient overshoot at an abrupt full-speed stop stays well inside the hard stops
            assert theta[:, k].min() > j.theta_min - 3e-3
            assert theta[:, k].max() < j.theta_max + 3e-3
            limit = j.theta_max if sign > 0 else j.theta_min
            assert abs(theta[-1, k] - limit) < 1e-3  # reached and held at the limit
            assert abs(out["omega"][0, -1, k]) < 1e-6


def test_velocity_monotonic_and_linear_in_command(plant: MujocoExcavator) -> None:
    levels = np.linspace(-1000.0, 1000.0, 11)
    theta0 = np.array([0.0, 0.05, 1.6, 0.95])
    u = np.repeat(levels[:, None, None], 20, axis=1) * np.ones((1, 1, 4))  # 1 s each
    omega = plant.rollout(u, theta0=np.tile(theta0, (len(levels), 1)))["omega"]
    steady = omega[:, -5:].mean(axis=1)  # (n_level, n_joint)
    assert np.all(np.diff(steady, axis=0) > 0)
    np.testing.assert_allclose(steady, levels[:, None] / 1000.0 * plant.omega_max, atol=2e-3)


def test_sampling_convention(plant: MujocoExcavator) -> None:
    rng = np.random.default_rng(0)
    u = rng.uniform(-1000, 1000, (2, 50, 4))
    out = plant.rollout(u, theta0=np.stack([_pose(frac=0.3), _pose(frac=0.6)]))
    theta, omega = out["theta"], out["omega"]
    assert np.all(omega[:, 0] == 0.0)
    np.testing.assert_array_equal(omega[:, 1:], (theta[:, 1:] - theta[:, :-1]) / plant.dt)
    # the last command is never applied
    u2 = u.copy()
    u2[:, -1] = -u2[:, -1]
    np.testing.assert_array_equal(plant.rollout(u2, theta0=theta[:, 0])["theta"], theta)


def test_batched_rollout_equals_python_loop() -> None:
    rng = np.random.default_rng(1)
    n_batch, n_step = 3, 60
    u = np.repeat(rng.uniform(-1000, 1000, (n_batch, n_step // 4, 4)), 4, axis=1)
    theta0 = np.stack([_pose(frac=f) for f in (0.2, 0.5, 0.8)])
    theta0[:, 0] = [-2.0, 0.0, 3.0]
    plant = MujocoExcavator(PlantConfig(n_threads=2, chunk_mb=0.5))  # several chunks, 2 threads
    a = plant.simulate(u, theta0=theta0)
    b = plant.rollout(u, theta0=theta0)
    plant.close()
    np.testing.assert_array_equal(a["theta"], b["theta"])
    np.testing.assert_array_equal(a["omega"], b["omega"])


def test_deterministic(plant: MujocoExcavator) -> None:
    u = np.random.default_rng(2).uniform(-1000, 1000, (1, 80, 4))
    a = plant.rollout(u, theta0=_pose()[None])
    b = MujocoExcavator().rollout(u, theta0=_pose()[None])
    np.testing.assert_array_equal(a["theta"], b["theta"])


class _Lag:
    """A stateful physics-rate transform (first-order valve lag, half gain) for the hook contract."""

    def reset(self, *, n_batch: int, substeps: int, timestep: float) -> None:
        self.sub, self.y, self.a = substeps, np.zeros((n_batch, 4)), timestep / 0.1

    def __call__(self, u: np.ndarray) -> np.ndarray:
        x = np.repeat(u, self.sub, axis=1)
        out = np.empty_like(x)
        for s in range(x.shape[1]):
            self.y = self.y + self.a * (0.5 * x[:, s] - self.y)
            out[:, s] = self.y
        return out


def test_command_transform_hook_in_both_paths() -> None:
    u = np.repeat(np.random.default_rng(4).uniform(-1000, 1000, (2, 10, 4)), 4, axis=1)
    theta0 = np.stack([_pose(frac=0.4), _pose(frac=0.6)])
    plant = MujocoExcavator(PlantConfig(chunk_mb=0.3), command_transform=_Lag())
    a, b = plant.simulate(u, theta0=theta0), plant.rollout(u, theta0=theta0)
    np.testing.assert_array_equal(a["theta"], b["theta"])
    ideal = MujocoExcavator(command_transform=ZeroOrderHold()).rollout(u, theta0=theta0)
    assert not np.allclose(a["theta"], ideal["theta"])


def test_force_hook_called_every_physics_step() -> None:
    calls = []

    def hook(model: mujoco.MjModel, data: mujoco.MjData) -> None:
        calls.append(data.time)
        data.qfrc_applied[:] = 0.0

    plant = MujocoExcavator(force_hook=hook)
    plant.reset(theta0=_pose())
    plant.step(np.zeros(4))
    assert len(calls) == plant.substeps
    with pytest.raises(ConfigError):
        plant.rollout(np.zeros((1, 3, 4)), theta0=_pose()[None])


def test_bad_inputs_raise_config_error(plant: MujocoExcavator) -> None:
    with pytest.raises(ConfigError):
        plant.reset(theta0=np.array([0.0, 5.0, 1.0, 1.0]))
    with pytest.raises(ConfigError):
        plant.rollout(np.zeros((1, 3, 3)), theta0=np.zeros((1, 4)))
    with pytest.raises(ConfigError):
        MujocoExcavator(PlantConfig(rate_hz=30.0))
    with pytest.raises(ConfigError):
        MujocoExcavator(PlantConfig(delay_s=0.2))


@pytest.mark.parametrize("hydraulic", [False, True])
def test_step_refuses_non_finite_commands(hydraulic: bool) -> None:
    """A NaN/Inf command is refused in one line naming the joint, before it reaches the
    transform: the hydraulic plant then still moves (a NaN used to freeze it for good)."""
    from excavator_surrogate.simulate.hydraulics import HydraulicTransform

    plant = MujocoExcavator(command_transform=HydraulicTransform() if hydraulic else None)
    theta0 = np.array([0.3, 0.2, 1.5, 1.0])
    plant.reset(theta0=theta0)
    for bad, name in ((np.array([np.nan, 800, 800, 800]), "swing"), ([0, 0, np.inf, 0], "arm")):
        with pytest.raises(ConfigError, match=rf"non-finite commands: joint '{name}'") as e:
            plant.step(bad)
        assert "\n" not in str(e.value)
    with pytest.raises(ConfigError, match=r"u must have shape \(4,\)"):
        plant.step(np.zeros(3))
    for _ in range(40):
        theta, omega = plant.step(np.full(4, 500.0))
    assert np.all(np.abs(omega) > 0.05) and np.all(np.abs(theta - theta0) > 0.1)
    with pytest.raises(ConfigError, match=r"joint 'bucket' got nan"):
        plant.simulate(np.array([[[0, 0, 0, np.nan]] * 3]), theta0=theta0[None])


def test_delay_beyond_buffer_names_setting_and_joint(tmp_path) -> None:
    """delay_s above the MJCF's ctrl history: one line naming the setting, its range and the
    joint; for the packaged machine it does not tell the user to edit the installed file."""
    with pytest.raises(ConfigError) as e:
        MujocoExcavator(PlantConfig(delay_s=0.1))
    msg = str(e.value)
    assert "simulate.delay_s" in msg and "0 <= delay_s <= 0.05" in msg
    assert "joint 'swing'" in msg and "hydraulics.delay_s" in msg and "simulate.xml" in msg
    assert "excavator.xml" not in msg and "actuator 0" not in msg and "\n" not in msg
    from excavator_surrogate.simulate.plant import default_xml

    xml = tmp_path / "machine.xml"
    xml.write_text(default_xml().read_text())
    with pytest.raises(ConfigError, match=r"machine.xml: .*joint 'swing' \(25 samples"):
        MujocoExcavator(PlantConfig(xml=str(xml), delay_s=0.1))
    MujocoExcavator(PlantConfig(delay_s=0.05)).close()  # the largest allowed value


@pytest.mark.parametrize("rate", [float("nan"), -1.0, 0.0], ids=["nan", "negative", "zero"])
def test_a_rate_that_is_no_positive_number_is_one_line(rate: float) -> None:
    with pytest.raises(ConfigError, match="rate_hz must be a positive finite number"):
        MujocoExcavator(PlantConfig(rate_hz=rate))  # NaN was a ValueError from round()
