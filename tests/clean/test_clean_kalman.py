"""Algorithm 1 and variants: filterpy oracle, plain-loop reference (bit-exact), batching."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from filterpy.kalman import KalmanFilter, rts_smoother

from excavator_surrogate.clean.config import METHODS, CleanConfig
from excavator_surrogate.clean.kalman import fuse
from excavator_surrogate.clean.reference import reference_fuse
from excavator_surrogate.config import from_dict
from excavator_surrogate.errors import ConfigError, DataError

DT = 0.05
INF = float("inf")


def _filterpy(z: np.ndarray, g: np.ndarray, cfg: CleanConfig, trusted: np.ndarray | None = None):
    """filterpy KalmanFilter with the same model; R_t from ``trusted`` (or R_trust throughout).

    Returns (states (n_step, dim_x), posterior covariances, the filter).
    """
    n = len(z)
    if cfg.method == "paper":
        kf = KalmanFilter(dim_x=2, dim_z=1)
        kf.F = np.array([[1.0, DT], [0.0, 1.0]])
        kf.Q = np.diag([cfg.q_theta * DT, cfg.q_omega * DT])
        kf.x = np.array([[z[0]], [g[0]]])
        kf.P = np.diag([cfg.r_trust, cfg.p0_omega])
    elif cfg.method in ("gyro", "rts"):
        kf = KalmanFilter(dim_x=2, dim_z=1, dim_u=1)
        kf.F = np.array([[1.0, -DT], [0.0, 1.0]])
        kf.B = np.array([[DT], [0.0]])
        kf.Q = np.diag([cfg.q_theta * DT + DT * DT * cfg.r_gyro, cfg.q_bias * DT])
        kf.x = np.array([[z[0]], [0.0]])
        kf.P = np.diag([cfg.r_trust, cfg.p0_bias])
    else:  # gyro3
        kf = KalmanFilter(dim_x=3, dim_z=2)
        kf.F = np.array([[1.0, DT, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
        qw = cfg.q_omega * DT
        kf.Q = np.array(
            [
                [DT * DT * qw + cfg.q_theta * DT, DT * qw, 0.0],
                [DT * qw, qw, 0.0],
                [0.0, 0.0, cfg.q_bias * DT],
            ]
        )
        kf.x = np.array([[z[0]], [g[0]], [0.0]])
        kf.P = np.diag([cfg.r_trust, cfg.p0_omega, cfg.p0_bias])
    kf.H = (
        np.eye(kf.dim_z, kf.dim_x) if cfg.method != "gyro3" else np.array([[1.0, 0, 0], [0, 1, 1]])
    )
    xs, Ps = [kf.x[:, 0].copy()], [kf.P.copy()]
    for t in range(1, n):
        if cfg.method in ("gyro", "rts"):
            kf.predict(u=np.array([[g[t]]]))
        else:
            kf.predict()
        r = cfg.r_trust if trusted is None or trusted[t] else cfg.r_untrust
        if cfg.method == "gyro3":
            kf.update(np.array([[z[t]], [g[t]]]), R=np.diag([r, cfg.r_gyro]))
        else:
            kf.update(z[t], R=r)
        xs.append(kf.x[:, 0].copy())
        Ps.append(kf.P.copy())
    return np.array(xs), np.array(Ps), kf


@pytest.fixture(scope="module")
def signals() -> tuple[np.ndarray, np.ndarray]:
    from excavator_surrogate.clean.synthetic import smooth_random_motion
    from excavator_surrogate.simulate.sensors import SensorConfig, apply_sensors

    rng = np.random.default_rng(11)
    th, om = smooth_random_motion(1200, 2, dt=DT, rng=rng)
    tm, omm, _ = apply_sensors(th, om, dt=DT, config=SensorConfig(spike_rate=0.2), rng=rng)
    return tm, omm


ENGINES = ["vector", "loop"]


@pytest.mark.parametrize("engine", ENGINES)
@pytest.mark.parametrize("method", ["paper", "gyro", "gyro3"])
def test_matches_filterpy_with_fixed_r(signals, method: str, engine: str) -> None:
    tm, omm = signals
    cfg = CleanConfig(method=method, tau_jump=INF, tau_cons=INF)
    res = fuse(tm, omm, dt=DT, config=cfg, engine=engine)
    assert res.trusted.all()
    for j in range(tm.shape[1]):
        xs, _, _ = _filterpy(tm[:, j], omm[:, j], cfg)
        np.testing.assert_allclose(res.theta[:, j], xs[:, 0], rtol=0, atol=1e-9)
        if res.bias is not None:
            np.testing.assert_allclose(res.bias[:, j], xs[:, -1], rtol=0, atol=1e-9)


@pytest.mark.parametrize("engine", ENGINES)
@pytest.mark.parametrize("method", ["paper", "gyro", "gyro3"])
def test_matches_filterpy_with_adaptive_r(signals, method: str, engine: str) -> None:
    tm, omm = signals
    cfg = CleanConfig(method=method, max_untrusted_s=0.0)  # guard off: pure R switching
    res = fuse(tm, omm, dt=DT, config=cfg, engine=engine)
    assert 0 < (~res.trusted).sum() < res.trusted.size
    for j in range(tm.shape[1]):
        xs, _, _ = _filterpy(tm[:, j], omm[:, j], cfg, trusted=res.trusted[:, j])
        np.testing.assert_allclose(res.theta[:, j], xs[:, 0], rtol=0, atol=1e-9)


@pytest.mark.parametrize("engine", ENGINES)
def test_rts_matches_filterpy_smoother(signals, engine: str) -> None:
    tm, omm = signals
    cfg = CleanConfig(method="rts", max_untrusted_s=0.0)
    res = fuse(tm, omm, dt=DT, config=cfg, engine=engine)
    fwd = fuse(tm, omm, dt=DT, config=dataclasses.replace(cfg, method="gyro"), engine=engine)
    np.testing.assert_array_equal(res.trusted, fwd.trusted)
    for j in range(tm.shape[1]):
        z, g = tm[:, j], omm[:, j]
        xs, Ps, kf = _filterpy(z, g, cfg, trusted=res.trusted[:, j])
        # filterpy's smoother has no control input: shift by the open-loop control response U,
        # U_k = F U_{k-1} + B u_k, so that x - U follows x_{k+1} = F x_k exactly
        n = len(z)
        U = np.zeros((n, 2))
        for k in range(1, n):
            U[k] = kf.F @ U[k - 1] + np.array([DT * g[k], 0.0])
        xsm, _, _, _ = rts_smoother(xs - U, Ps, [kf.F] * n, [kf.Q] * n)
        np.testing.assert_allclose(res.theta[:, j], xsm[:, 0] + U[:, 0], rtol=0, atol=1e-9)
        np.testing.assert_allclose(res.bias[:, j], xsm[:, 1] + U[:, 1], rtol=0, atol=1e-9)


READINGS = {
    "default": {},
    "literal": {"jump_ref": "raw", "cons_mode": "samples"},
    "guard": {"max_untrusted_s": 0.4, "cons_window": 3},
}


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("reading", sorted(READINGS))
def test_vectorised_equals_plain_loop_exactly(
    make_batch, heavy_faults, method: str, reading: str
) -> None:
    data = make_batch(1, 700, 3, dt=DT, seed=5, sensor=heavy_faults)
    tm, omm = data["theta"][0], data["omega"][0]
    cfg = CleanConfig(method=method, **READINGS[reading])
    res = fuse(tm, omm, dt=DT, config=cfg, engine="vector")
    ref = reference_fuse(tm, omm, dt=DT, config=cfg)
    assert (~res.trusted).any()
    np.testing.assert_array_equal(res.trusted, ref["trusted"])
    np.testing.assert_array_equal(res.theta, ref["theta"])
    if method == "paper":
        assert res.bias is None and ref["bias"] is None
    else:
        np.testing.assert_array_equal(res.bias, ref["bias"])


@pytest.mark.parametrize("engine", ENGINES)
@pytest.mark.parametrize("method", ["paper", "rts"])
def test_batch_with_padding_equals_one_by_one(make_batch, method: str, engine: str) -> None:
    data = make_batch(3, 500, 2, dt=DT, seed=6)
    nv = np.array([500, 320, 47])
    theta = data["theta"].copy()
    omega = data["omega"].copy()
    for b, n in enumerate(nv):
        theta[b, n:] = np.nan  # padding content must not matter
        omega[b, n:] = np.nan
    cfg = CleanConfig(method=method)
    res = fuse(theta, omega, dt=DT, config=cfg, n_valid=nv, engine=engine)
    for b, n in enumerate(nv):
        one = fuse(data["theta"][b, :n], data["omega"][b, :n], dt=DT, config=cfg, engine="vector")
        np.testing.assert_array_equal(res.theta[b, :n], one.theta)
        np.testing.assert_array_equal(res.trusted[b, :n], one.trusted)


@pytest.mark.parametrize("engine", ENGINES)
def test_output_shapes_and_backward_difference(make_batch, engine: str) -> None:
    data = make_batch(2, 300, 3, dt=DT, seed=7)
    res = fuse(data["theta"], data["omega"], dt=DT, engine=engine)
    assert res.theta.shape == res.omega.shape == res.trusted.shape == (2, 300, 3)
    assert res.trusted.dtype == bool and res.trusted[:, 0].all()
    np.testing.assert_allclose(res.omega[:, 1:], np.diff(res.theta, axis=1) / DT)
    np.testing.assert_array_equal(res.omega[:, 0], res.omega[:, 1])
    one = fuse(data["theta"][1], data["omega"][1], dt=DT, engine=engine)
    np.testing.assert_array_equal(one.theta, res.theta[1])
    assert one.bias is not None and one.bias.shape == (300, 3)
    single = fuse(data["theta"][0, :1], data["omega"][0, :1], dt=DT, engine=engine)
    np.testing.assert_array_equal(single.theta, data["theta"][0, :1])
    np.testing.assert_array_equal(single.omega, np.zeros((1, 3)))


def test_bad_inputs_and_configs() -> None:
    with pytest.raises(DataError, match="n_batch, n_step, n_joint"):
        fuse(np.zeros((5, 2)), np.zeros((5, 3)), dt=DT)
    bad = np.zeros((5, 2))
    bad[3, 1] = np.nan
    with pytest.raises(DataError, match="row 3"):
        fuse(bad, np.zeros((5, 2)), dt=DT)
    with pytest.raises(ConfigError, match="engine"):
        fuse(np.zeros((5, 2)), np.zeros((5, 2)), dt=DT, engine="gpu")  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match="method"):
        CleanConfig(method="magic")  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match="r_untrust"):
        CleanConfig(r_untrust=1e-9)
    with pytest.raises(ConfigError, match="cons_window"):
        CleanConfig(cons_window=0)
    with pytest.raises(ConfigError, match="unknown key"):
        from_dict(CleanConfig, {"tau": 1.0})
    cfg = from_dict(CleanConfig, {"method": "paper", "tau_cons": 0.05, "cons_window": 4.0})
    assert cfg.method == "paper" and cfg.cons_window == 4
