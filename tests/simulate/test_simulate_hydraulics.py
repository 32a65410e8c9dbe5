"""Stage II hydraulic stand-in: every effect on/off, streaming consistency, plain-loop reference."""

from __future__ import annotations

import dataclasses
import math

import mujoco
import numpy as np
import pytest

from excavator_surrogate.errors import ConfigError
from excavator_surrogate.simulate.excitation import generate
from excavator_surrogate.simulate.hydraulics import (
    EFFECTS,
    HydraulicConfig,
    HydraulicTransform,
    resolve,
)
from excavator_surrogate.simulate.plant import MujocoExcavator, PlantConfig
from excavator_surrogate.simulate.relief import ReliefAntiWindup
from excavator_surrogate.simulate.soil import ChainHook
from excavator_surrogate.spec import EXCAVATOR, JointSpec, MachineSpec

H = 0.002  # physics step of the packaged MJCF [s]
POSE = np.array([0.3, 0.05, 1.6, 0.9])


def _reference(
    cfg: HydraulicConfig, spec: MachineSpec, u: np.ndarray, *, substeps: int, timestep: float
) -> np.ndarray:
    """Plain scalar loops over batch, time and joints: the specification of the transform."""
    n_batch, n_step, n_joint = u.shape
    p = resolve(cfg, spec)
    dt = substeps * timestep
    n_delay = round(cfg.delay_s / timestep) if cfg.transport_delay else 0
    out = np.zeros((n_batch, n_step * substeps, n_joint))
    for b in range(n_batch):
        play = [0.0] * n_joint
        q_ctrl = []
        for k in range(n_step):
            q = []
            for j in range(n_joint):
                x = u[b, k, j] / p.u_pos[j] if u[b, k, j] >= 0 else u[b, k, j] / p.u_neg[j]
                x = min(max(x, -1.0), 1.0)
                if p.play[j] > 0:
                    play[j] = min(max(play[j], x - p.play[j]), x + p.play[j])
                    s = play[j] / (1.0 - p.play[j])
                else:
                    s = x
                dz = p.dz_pos[j] if s >= 0 else p.dz_neg[j]
                r = min(max((abs(s) - dz) / (1.0 - dz), 0.0), 1.0) ** p.gamma[j]
                q.append(p.g_pos[j] * r if s >= 0 else -p.g_neg[j] * r)
            if cfg.drift:
                f = 1.0 - cfg.drift_amplitude * math.exp(-k * dt / cfg.drift_tau_s)
                q = [v * f for v in q]
            q = [v * (1.0 - cfg.day_slowdown) for v in q]
            if cfg.flow_sharing:
                demand = sum(abs(v) * p.flow[j] for j, v in enumerate(q))
                if demand > cfg.pump_max_lpm:
                    q = [v * cfg.pump_max_lpm / demand for v in q]
            q_ctrl.append(q)
        z = [0.0] * n_joint
        limited = []
        for k in range(n_step):
            for _ in range(substeps):
                for j in range(n_joint):
                    step = p.accel[j] * timestep
                    z[j] += min(max(q_ctrl[k][j] - z[j], -step), step)
                limited.append(list(z))
        y = [0.0] * n_joint
        for n in range(n_step * substeps):
            x = limited[n - n_delay] if n >= n_delay else [0.0] * n_joint
            for j in range(n_joint):
                a = 1.0 if p.lag[j] == 0 else 1.0 - math.exp(-timestep / p.lag[j])
                y[j] += a * (x[j] - y[j])
                out[b, n, j] = y[j] * (p.u_pos[j] if y[j] >= 0 else p.u_neg[j])
    return out


def _commands(seed: int, n_batch: int = 2, n_step: int = 24) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.repeat(rng.uniform(-1000, 1000, (n_batch, n_step // 3, 4)), 3, axis=1)


def _transform(cfg: HydraulicConfig, *, n_batch: int = 1, substeps: int = 25) -> HydraulicTransform:
    t = HydraulicTransform(cfg)
    t.reset(n_batch=n_batch, substeps=substeps, timestep=H)
    return t


@pytest.mark.parametrize("which", ["all", "one_by_one"])
def test_vectorised_transform_matches_plain_loop_reference(which: str) -> None:
    u = _commands(0)
    base = dataclasses.replace(HydraulicConfig(drift=True), drift_tau_s=0.5, day_slowdown=0.15)
    cfgs = [base] if which == "all" else [HydraulicConfig.ideal(**{e: True}) for e in EFFECTS]
    for cfg in cfgs:
        got = _transform(cfg, n_batch=2, substeps=10)(u)
        want = _reference(cfg, EXCAVATOR, u, substeps=10, timestep=H)
        np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-9)


def test_transform_is_streaming_consistent() -> None:
    u = _commands(1, n_step=60)
    cfg = HydraulicConfig(drift=True)
    t = _transform(cfg, n_batch=2)
    whole = t(u)
    t.reset(n_batch=2, substeps=25, timestep=H)
    chunks = np.concatenate([t(u[:, i : i + 7]) for i in range(0, 60, 7)], axis=1)
    t.reset(n_batch=2, substeps=25, timestep=H)
    steps = np.concatenate([t(u[:, i : i + 1]) for i in range(60)], axis=1)
    np.testing.assert_array_equal(whole, chunks)
    np.testing.assert_array_equal(whole, steps)
    # and every row of a batch is the single-episode result
    t1 = _transform(cfg)
    np.testing.assert_array_equal(t1(u[1:2]), whole[1:2])


def test_all_effects_off_is_the_ideal_plant() -> None:
    u = _commands(2)
    np.testing.assert_allclose(
        _transform(HydraulicConfig.ideal())(u[:1]), np.repeat(u[:1], 25, axis=1), atol=1e-9
    )
    theta0 = np.stack([POSE, POSE + 0.1])
    ideal = MujocoExcavator().rollout(u, theta0=theta0)
    hyd = MujocoExcavator(command_transform=HydraulicTransform(HydraulicConfig.ideal(relief=False)))
    got = hyd.rollout(u, theta0=theta0)
    np.testing.assert_allclose(got["theta"], ideal["theta"], atol=1e-9)
    assert not np.any(hyd.model.actuator_forcelimited)


def test_batched_rollout_equals_python_loop_with_hydraulics() -> None:
    u = _commands(3, n_step=45)
    theta0 = np.stack([POSE, np.array([-2.0, -0.3, 1.0, 0.2])])
    plant = MujocoExcavator(
        PlantConfig(chunk_mb=0.4), command_transform=HydraulicTransform(HydraulicConfig(drift=True))
    )
    a, b = plant.simulate(u, theta0=theta0), plant.rollout(u, theta0=theta0)
    np.testing.assert_array_equal(a["theta"], b["theta"])
    np.testing.assert_array_equal(a["omega"], b["omega"])


# ---------------------------------------------------------------------------- single effects
def test_dead_zone_no_motion_below_threshold() -> None:
    u = np.full((1, 40, 4), 100.0)  # 10 % of the range, inside every dead zone
    for on, moves in ((True, False), (False, True)):
        plant = MujocoExcavator(command_transform=HydraulicTransform(HydraulicConfig(dead_zone=on)))
        theta = plant.rollout(u, theta0=POSE[None])["theta"][0]
        assert np.any(np.abs(theta - POSE) > 1e-3) == moves
        if not moves:
            np.testing.assert_allclose(theta, np.broadcast_to(POSE, theta.shape), atol=1e-9)
    # asymmetric: the boom's up threshold (18 %) exceeds its down threshold (12 %)
    t = _transform(HydraulicConfig.ideal(dead_zone=True))
    out = t(np.array([[[0.0, 150.0, 0.0, 0.0], [0.0, -150.0, 0.0, 0.0]]]))
    assert np.all(out[0, :25, 1] == 0) and np.all(out[0, 25:, 1] < 0)


def test_progressive_gain_curve_and_asymmetric_speed() -> None:
    x = np.array([[[500.0, 500.0, 500.0, 500.0], [1000.0, 1000.0, -1000.0, -1000.0]]])
    p = HydraulicConfig()
    out = _transform(HydraulicConfig.ideal(gain_curve=True))(x)
    np.testing.assert_allclose(out[0, 0] / 1000.0, 0.5 ** np.array(p.curve_exponent))
    out = _transform(HydraulicConfig.ideal(asymmetry=True))(
        np.array([[[1000.0] * 4, [-1000.0] * 4]])
    )
    np.testing.assert_allclose(out[0, 0] / 1000.0, p.gain_pos)
    np.testing.assert_allclose(out[0, 25] / -1000.0, p.gain_neg)


def test_boom_rises_more_slowly_than_it_falls() -> None:
    plant = MujocoExcavator(command_transform=HydraulicTransform())
    up = np.zeros((1, 60, 4))
    up[..., 1] = 1000.0
    w_up = plant.rollout(up, theta0=np.array([[0.0, -0.6, 1.6, 0.9]]))["omega"][0, :, 1].max()
    w_down = -plant.rollout(-up, theta0=np.array([[0.0, 0.7, 1.6, 0.9]]))["omega"][0, :, 1].min()
    assert 0.3 < w_up < 0.9 * w_down


def test_valve_lag_and_transport_delay_make_the_response_later() -> None:
    step = np.full((1, 12, 4), 1000.0)

    def first(cfg: HydraulicConfig, level: float) -> int:
        out = _transform(cfg)(step)[0, :, 3]  # bucket
        return int(np.flatnonzero(out >= level * out.max())[0])

    none = HydraulicConfig.ideal()
    assert first(none, 0.01) == 0
    assert first(HydraulicConfig.ideal(transport_delay=True), 0.01) == round(0.05 / H)
    tau = HydraulicConfig().lag_s[3]
    assert first(HydraulicConfig.ideal(valve_lag=True), 1 - math.exp(-1)) == pytest.approx(
        tau / H, abs=1
    )
    # in the plant: the first moving sample comes later than in the ideal plant
    u = np.full((1, 12, 4), 800.0)

    def moved(transform: HydraulicTransform | None) -> int:
        th = MujocoExcavator(command_transform=transform).rollout(u, theta0=POSE[None])["theta"][0]
        return int(np.flatnonzero(np.abs(th[:, 3] - POSE[3]) > 1e-3)[0])

    assert moved(
        HydraulicTransform(HydraulicConfig.ideal(transport_delay=True, valve_lag=True))
    ) > moved(None)


def test_acceleration_limit_ramps_the_demand() -> None:
    cfg = HydraulicConfig.ideal(accel_limit=True)
    out = _transform(cfg)(np.full((1, 80, 4), 1000.0))[0] / 1000.0
    rate = np.diff(out, axis=0).max(axis=0) / H
    np.testing.assert_allclose(rate, cfg.accel_max, rtol=1e-9)
    swing_full = int(np.flatnonzero(out[:, 0] >= 1.0 - 1e-12)[0]) * H
    assert swing_full == pytest.approx(1.0 / cfg.accel_max[0], abs=2 * H)


def test_flow_sharing_slows_simultaneous_motion() -> None:
    alone = np.zeros((1, 40, 4))
    alone[..., 1] = 1000.0  # boom up
    together = np.full((1, 40, 4), 1000.0)
    theta0 = np.array([[0.0, -0.6, 0.8, -0.3]])
    for on in (True, False):
        plant = MujocoExcavator(
            command_transform=HydraulicTransform(HydraulicConfig(flow_sharing=on))
        )
        w_alone = plant.rollout(alone, theta0=theta0)["omega"][0, -5:, 1].mean()
        w_all = plant.rollout(together, theta0=theta0)["omega"][0, -5:, 1].mean()
        if on:
            assert w_all < 0.7 * w_alone
        else:
            assert w_all == pytest.approx(w_alone, rel=0.02)


def test_hysteresis_gives_different_output_rising_and_falling() -> None:
    cfg = HydraulicConfig.ideal(hysteresis=True)
    b = cfg.play
    x = np.concatenate([np.linspace(0, 1000, 11), np.linspace(1000, 0, 11)])
    out = _transform(cfg)(np.repeat(x[None, :, None], 4, axis=2))[0, ::25, 0]
    rising, falling = out[5], out[-6]  # command 500 on the way up and on the way down
    assert falling - rising == pytest.approx(2 * b / (1 - b) * 1000.0)
    assert out[10] == pytest.approx(1000.0) and out[-1] == pytest.approx(b / (1 - b) * 1000.0)
    # inside the dead zone after release: the residual spool offset gives no flow
    both = HydraulicConfig.ideal(hysteresis=True, dead_zone=True)
    assert _transform(both)(np.repeat(x[None, :, None], 4, axis=2))[0, -1, 0] == 0.0


def test_drift_changes_speed_slowly() -> None:
    cfg = dataclasses.replace(
        HydraulicConfig.ideal(drift=True), drift_amplitude=0.2, drift_tau_s=10.0
    )
    t = _transform(cfg, substeps=1)
    t.reset(n_batch=1, substeps=1, timestep=0.05)
    out = t(np.full((1, 1200, 4), 1000.0))[0, :, 0] / 1000.0
    assert out[0] == pytest.approx(0.8) and out[-1] == pytest.approx(1.0, abs=1e-3)
    assert np.all(np.diff(out) > 0)


def test_the_days_slow_down_scales_every_valves_speed() -> None:
    u = _commands(1)
    cfg = HydraulicConfig.ideal(dead_zone=True, gain_curve=True, asymmetry=True, valve_lag=True)
    base = _transform(cfg, n_batch=2, substeps=10)(u)
    slow = _transform(dataclasses.replace(cfg, day_slowdown=0.2), n_batch=2, substeps=10)(u)
    np.testing.assert_allclose(slow, 0.8 * base, rtol=1e-12, atol=1e-9)  # the linear stages
    assert np.abs(base).max() > 100.0


class _Load:
    """External torque on one joint during [t0, t1) (an obstacle the arm pushes against)."""

    def __init__(self, dof: int, torque: float, t0: float, t1: float) -> None:
        self.dof, self.torque, self.t0, self.t1 = dof, torque, t0, t1

    def __call__(self, model: mujoco.MjModel, data: mujoco.MjData) -> None:
        data.qfrc_applied[:] = 0.0
        if self.t0 <= data.time < self.t1:
            data.qfrc_applied[self.dof] = self.torque


@pytest.mark.parametrize("case", ["relief", "no_relief", "relief_no_antiwindup"])
def test_relief_makes_a_loaded_joint_stall(case: str) -> None:
    cfg = HydraulicConfig(relief=case != "no_relief")
    plant = MujocoExcavator(command_transform=HydraulicTransform(cfg))
    load = _Load(int(plant._vadr[2]), -2.0e6, 1.0, 2.0)  # beyond the arm's 1.5 MN m crowd relief
    plant.force_hook = (
        load if case == "relief_no_antiwindup" else ChainHook(ReliefAntiWindup(), load)
    )
    u = np.zeros((1, 70, 4))
    u[..., 2] = 1000.0  # arm in, full
    out = plant.simulate(u, theta0=np.array([[0.0, 0.0, 0.7, 0.5]]))
    theta, omega = out["theta"][0, :, 2], out["omega"][0, :, 2]
    demanded = cfg.gain_pos[2] * plant.omega_max[2]
    advance = theta[40] - theta[20]  # during the 1 s load
    if case == "no_relief":
        assert advance > 0.8 * demanded  # the ideal servo overpowers any load
    else:
        assert advance < 0.0  # the relief valve gives way: stalled and pushed back
    after = omega[42:]
    if case == "relief":
        assert after.max() < 1.1 * demanded  # no lunge when the load goes away
    elif case == "relief_no_antiwindup":
        assert after.max() > 2.0 * demanded  # why the anti-windup hook exists


def test_relief_limits_are_actuator_forceranges() -> None:
    cfg = HydraulicConfig()
    plant = MujocoExcavator(command_transform=HydraulicTransform(cfg))
    a = plant._act
    assert np.all(plant.model.actuator_forcelimited[a])
    np.testing.assert_allclose(
        plant.model.actuator_forcerange[a, 1] * plant.gear, cfg.relief_pos_nm
    )
    np.testing.assert_allclose(
        plant.model.actuator_forcerange[a, 0] * plant.gear, -np.array(cfg.relief_neg_nm)
    )
    # PlantConfig limits take precedence
    own = MujocoExcavator(
        PlantConfig(force_min=(-1.0, -2.0, -3.0, -4.0), force_max=(1.0, 2.0, 3.0, 4.0)),
        command_transform=HydraulicTransform(cfg),
    )
    np.testing.assert_allclose(own.model.actuator_forcerange[a, 1] * own.gear, [1, 2, 3, 4])
    with pytest.raises(ConfigError):
        MujocoExcavator(PlantConfig(force_min=(1.0, 0, 0, 0), force_max=(2.0, 1, 1, 1)))


def test_config_errors_and_generic_spec() -> None:
    with pytest.raises(ConfigError, match="3 values for 4 joints"):
        HydraulicTransform(HydraulicConfig(lag_s=(0.1, 0.1, 0.1)))
    with pytest.raises(ConfigError):
        HydraulicConfig.ideal(soil=True)
    with pytest.raises(ConfigError):
        HydraulicConfig(pump_max_lpm=0.0)
    with pytest.raises(ConfigError, match="day_slowdown"):
        HydraulicConfig(day_slowdown=1.0)
    # two joints: scalars broadcast, nothing assumes four joints
    spec = MachineSpec(
        joints=(JointSpec("a", theta_min=-1, theta_max=1), JointSpec("b")), rate_hz=20.0
    )
    cfg = HydraulicConfig(
        **{f: 0.1 for f in ("dead_zone_pos", "dead_zone_neg", "lag_s")},
        curve_exponent=1.5,
        gain_pos=0.9,
        gain_neg=1.0,
        flow_full_lpm=300.0,
        accel_max=2.0,
        relief_pos_nm=1e5,
        relief_neg_nm=1e5,
    )
    t = HydraulicTransform(cfg, spec=spec)
    t.reset(n_batch=3, substeps=4, timestep=0.0125)
    assert t(np.full((3, 5, 2), 700.0)).shape == (3, 20, 2)
    lo, hi = t.force_limits()  # type: ignore[misc]
    assert lo.shape == hi.shape == (2,)


def test_hydraulic_excitation_stays_off_the_end_stops() -> None:
    transform = HydraulicTransform()
    plant = MujocoExcavator(command_transform=transform)
    model = transform.nominal_model(omega_max=plant.omega_max)
    rng = np.random.default_rng(5)
    lo = np.array([-np.inf, -0.75, 0.55, -0.6])
    hi = np.array([np.inf, 0.85, 2.65, 2.5])
    for kind in ("multisine", "steps"):
        u = generate(
            kind, rng, 3000, EXCAVATOR, theta0=POSE, omega_max=plant.omega_max, velocity_map=model
        )
        theta = plant.rollout(u[None], theta0=POSE[None])["theta"][0]
        pinned = ((theta - lo) < 0.02) | ((hi - theta) < 0.02)
        assert pinned.mean() < 0.03, (kind, pinned.mean(axis=0))
