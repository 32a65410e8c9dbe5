"""MPPI's risk weight: the candidates' member spread and out-of-distribution flags."""

from __future__ import annotations

import numpy as np
import pytest

from excavator_surrogate.control.mppi import MPPI, MPPIConfig
from excavator_surrogate.control.predict import SurrogatePredictor
from excavator_surrogate.errors import ConfigError
from excavator_surrogate.spec import EXCAVATOR
from excavator_surrogate.surrogate.coverage import CoverageRecord, channel_names, ood_flags
from excavator_surrogate.surrogate.ensemble import merge
from excavator_surrogate.surrogate.rollout import ClosedLoop
from tests.helpers.surrogates import tiny_surrogate

THETA0 = np.array([0.2, 0.1, 1.5, 0.6])
K, N, N_HIST = 5, 6, 9


def _history(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    u = rng.uniform(-800, 800, (N_HIST, 4))
    theta = THETA0 + np.cumsum(rng.normal(0, 0.01, (N_HIST + 1, 4)), axis=0)
    theta[0] = THETA0
    return theta, u


def _coverage() -> CoverageRecord:
    """A record whose boxes hold every angle and velocity but only commands within +/- 300
    (and an all-seen grid): the flags follow the commands."""
    names = channel_names(EXCAVATOR)
    lo = np.array([-300.0] * 4 + [-10.0] * 8)
    hi = np.array([300.0] * 4 + [10.0] * 8)
    assert len(names) == len(lo)
    return CoverageRecord(names, lo, hi, np.ones((4, 4, 4), dtype=np.int64), 100)


def _ensemble(**kw):
    sur = merge([tiny_surrogate(seed=s, **kw) for s in range(2)])
    sur.metrics["coverage"] = _coverage().to_dict()
    return sur


def _synced(pred: SurrogatePredictor, theta: np.ndarray, u_hist: np.ndarray) -> None:
    pred.reset(theta[0])
    for k in range(N_HIST):
        pred.observe(u_hist[k], theta[k + 1])


@pytest.mark.parametrize(
    ("kw", "n_batch", "impl"),
    [
        (dict(mode="stateful", cell="lstm"), K, "cell"),
        (dict(mode="stateful", cell="lstm"), 64, "members"),  # the member kernel's layout
        (dict(mode="stateful", cell="gru", play=(0.05,)), K, "cell"),
        (dict(mode="windowed", cell="lstm", window=5), K, "window"),
        (dict(mode="stateful", cell="lstm", omega_in=True, residual=True), K, "cell"),
        (dict(mode="stateful", cell="lstm", prior=True), K, "cell"),
    ],
)
def test_spread_and_flags_match_a_plain_loop_of_member_closed_loops(
    kw: dict, n_batch: int, impl: str
) -> None:
    """The batched spread equals, candidate by candidate, the std over the members of their
    velocities (ClosedLoop(members=True) on the same history) integrated along the run;
    the flags equal ood_flags on that run; the angles equal predict()."""
    sur = _ensemble(**kw)
    rng = np.random.default_rng(0)
    theta, u_hist = _history(rng)
    pred = SurrogatePredictor(sur, n_batch=n_batch)
    assert pred.batch.impl == impl
    _synced(pred, theta, u_hist)
    u = rng.uniform(-400, 400, (n_batch, N, 4))  # some steps within the +/- 300 box per joint
    th, spread, ood = pred.predict_risk(u)
    assert th.shape == spread.shape == (n_batch, N, 4)
    assert ood is not None and ood.shape == (n_batch, N)
    np.testing.assert_array_equal(th, pred.predict(u))
    w = sur.window
    th_hist = np.concatenate([np.repeat(theta[:1], w - 1, axis=0), theta])
    u_full = np.concatenate([np.zeros((w - 1, 4)), u_hist])
    dt = sur.spec.dt
    for i in range(K):
        ref = ClosedLoop(sur, members=True)
        ref.reset(th_hist[None], u_full[None])
        cum = np.zeros((2, 4))
        th_ref, om_ref = np.empty((N, 4)), np.empty((N, 4))
        for n in range(N):
            t, o = ref.step(u[i, n][None])
            th_ref[n], om_ref[n] = t[0].double().numpy(), o[0].double().numpy()
            cum += ref.omega_members[:, 0].double().numpy() * dt
            # float32 network: velocities agree to ~1e-6 rad/s, summed over n steps
            np.testing.assert_allclose(
                spread[i, n], cum.std(axis=0, ddof=1), atol=1e-6 * dt * (n + 1) * 10
            )
        np.testing.assert_allclose(th[i], th_ref, atol=2e-5)
        flags = ood_flags(_coverage(), sur.spec, th_ref, om_ref, u[i]).any(-1)
        np.testing.assert_array_equal(ood[i], flags)
    assert spread[:K, -1].min() > 0  # two different members disagree
    assert ood[:K].any() and not ood[:K].all()


def test_worker_processes_give_the_same_spread() -> None:
    """Split over this process and a spawned worker: the same angles, spread and flags as
    one process, up to float32 roundings (different batch shapes) of the integrated steps."""
    sur = _ensemble(mode="stateful", cell="lstm", play=(0.05,))
    rng = np.random.default_rng(1)
    theta, u_hist = _history(rng)
    one = SurrogatePredictor(sur, n_batch=7)
    two = SurrogatePredictor(sur, n_batch=7, workers=2)
    try:
        for p in (one, two):
            _synced(p, theta, u_hist)
        u = rng.uniform(-1000, 1000, (7, N, 4))
        a, b = one.predict_risk(u), two.predict_risk(u)
        scale = np.abs(a[0] - theta[-1]).max() + a[1].max()
        atol = 4 * np.finfo(np.float32).eps * scale * N
        for x, y in zip(a[:2], b[:2]):
            np.testing.assert_allclose(y, x, atol=atol)
        assert a[2] is not None and b[2] is not None
        assert (a[2] != b[2]).mean() < 0.05  # a flag on a box edge may flip with rounding
        assert a[1][:, -1].min() > 10 * atol  # the spread is no rounding noise
    finally:
        two.close()


class _Toy:
    """A predictor whose angle follows the command of joint 0 (1 rad per full command) and
    flags every step with a positive joint-0 command."""

    spec = EXCAVATOR
    head = object()

    def __init__(self) -> None:
        self.calls: list[str] = []

    def reset(self, theta0: np.ndarray) -> None:
        self.theta0 = np.asarray(theta0, dtype=float)

    def observe(self, u: np.ndarray, theta: np.ndarray) -> None:
        pass

    def predict(self, u: np.ndarray) -> np.ndarray:
        self.calls.append("predict")
        return self.theta0 + np.cumsum(u / 1000.0, axis=1) * 0.05

    def predict_risk(self, u: np.ndarray):
        self.calls.append("predict_risk")
        th = self.theta0 + np.cumsum(u / 1000.0, axis=1) * 0.05
        return th, np.zeros_like(th), u[..., 0] > 0


def _first_command(cfg: MPPIConfig, pred: _Toy) -> np.ndarray:
    ctl = MPPI(pred, cfg)  # type: ignore[arg-type]
    ctl.reset(THETA0)
    ref = np.repeat((THETA0 + np.array([0.5, 0, 0, 0]))[None], cfg.n_horizon, axis=0)  # swing up
    return ctl.act(0, ref)


def test_risk_zero_is_the_plain_planner_and_risk_steers_off_flagged_commands() -> None:
    cfg = MPPIConfig(n_sample=64, n_horizon=8, seed=3)
    plain, risky = _Toy(), _Toy()
    u0 = _first_command(cfg, plain)
    assert plain.calls == ["predict"]  # risk = 0: the old call, nothing else
    # the same process and shapes: the same plan as the planner without the new fields
    np.testing.assert_array_equal(u0, _first_command(cfg, _Toy()))
    assert u0[0] > 0  # tracking alone pushes joint 0 positive (flagged)
    u1 = _first_command(MPPIConfig(n_sample=64, n_horizon=8, seed=3, risk=10.0), risky)
    assert risky.calls == ["predict_risk"]
    assert u1[0] < u0[0] - 100  # the penalty holds the command back


def test_risk_needs_an_ensemble_and_valid_weights() -> None:
    with pytest.raises(ConfigError, match="risk >= 0"):
        MPPIConfig(risk=-1.0)
    with pytest.raises(ConfigError, match="ood_penalty"):
        MPPIConfig(ood_penalty=-1.0)
    single = SurrogatePredictor(tiny_surrogate(), n_batch=4)
    with pytest.raises(ConfigError, match="merged seed ensemble"):
        MPPI(single, MPPIConfig(n_sample=4, risk=1.0))
    with pytest.raises(ConfigError, match="merged seed ensemble"):
        single.predict_risk(np.zeros((4, 3, 4)))
    MPPI(single, MPPIConfig(n_sample=4))  # risk 0: any predictor
