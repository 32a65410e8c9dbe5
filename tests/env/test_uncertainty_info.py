"""The surrogate's bands and out-of-distribution flags in the environments' step ``info``."""

from __future__ import annotations

import copy
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.vector import AutoresetMode
from gymnasium.wrappers.vector import DictInfoToList

from excavator_surrogate.env import SURROGATE_ID, ExcavatorSurrogateEnv, SurrogateVectorEnv
from excavator_surrogate.env.engine import SurrogateEngine
from excavator_surrogate.env.uncertainty import INFO_KEYS
from excavator_surrogate.spec import EXCAVATOR
from excavator_surrogate.surrogate.coverage import CoverageRecord, channel_names, ood_flags
from excavator_surrogate.surrogate.ensemble import merge
from excavator_surrogate.surrogate.uncertainty import (
    Calibration,
    UncertainPrediction,
    bands,
    member_runs,
)
from tests.helpers.surrogates import on_parallel_map, on_static_map

KW = dict(end_stops=True, play=(0.05, 0.2), omega_in=True)
EPS32 = float(np.finfo(np.float32).eps)


def _record(rng: np.random.Generator) -> CoverageRecord:
    """A coverage record whose boxes cut through the commands and angles the tests drive
    (so flags fire and stay off), with a grid holding some empty cells."""
    spec = EXCAVATOR
    n_j = spec.n_joint
    lo = np.concatenate([np.full(n_j, -600.0), [0.0, 0.3, 1.2, 0.2], np.full(n_j, -5.0)])
    hi = np.concatenate([np.full(n_j, 600.0), [6.0, 0.9, 2.4, 1.4], np.full(n_j, 5.0)])
    lo[n_j] = -7.0  # swing angle: never out of its box
    grid = (rng.uniform(size=(n_j, 10, 10)) > 0.7).astype(np.int64)
    return CoverageRecord(channel_names(spec), lo, hi, grid, n_sample=1000)


@pytest.fixture(scope="module")
def ens(make_surrogate):
    """A merged 3-member stateful ensemble with a coverage record (not calibrated)."""
    sur = merge([make_surrogate(seed=s, hidden=16, mode="stateful", **KW) for s in range(3)])
    sur.metrics["coverage"] = _record(np.random.default_rng(0)).to_dict()
    return sur


def _drive(rng: np.random.Generator, n: int, n_step: int):
    theta0 = rng.uniform(-0.3, 0.3, (n, 4)) + np.array([0.0, 0.4, 1.6, 0.6])
    u = rng.uniform(-1000, 1000, (n, n_step, 4))
    return theta0, u


def _plain(sur, theta0: np.ndarray, u: np.ndarray, design: str = "shared"):
    """The plain loop (``member_runs``) from the environments' at-rest warm-up."""
    w = sur.window
    n, _, n_u = u.shape
    u_full = np.concatenate([np.zeros((n, w - 1, n_u)), u, np.zeros((n, 1, n_u))], axis=1)
    th_hist = np.repeat(theta0[:, None], w, axis=1)
    return member_runs(sur, th_hist, u_full, warmup=w, design=design), u_full


@pytest.mark.parametrize(
    "mode,impl,on_map",
    [
        ("stateful", "members", False),
        ("stateful", "cell", False),
        ("stateful", "module", False),
        ("windowed", "auto", False),
        ("stateful", "cell", True),
        ("windowed", "auto", True),
        ("stateful", "members", "delayed"),
        ("windowed", "auto", "delayed"),
        ("stateful", "members", "parallel"),
        ("windowed", "auto", "parallel"),
    ],
)
def test_engine_bands_and_flags_equal_the_plain_loop(
    ens, make_surrogate, mode, impl, on_map
) -> None:
    """The engine's members' omega (from the same network call), integrated deviations and
    OOD flags equal ``member_runs`` (design shared) and ``ood_flags`` on its run; also with
    joints on the static map, whose members drive it with their own gains."""
    sur = ens
    if mode == "windowed" or on_map:
        kw = dict(KW, omega_in=False) if on_map else KW
        sur = merge([make_surrogate(seed=s, hidden=16, mode=mode, **kw) for s in range(3)])
        sur.metrics["coverage"] = ens.metrics["coverage"]
    if on_map == "parallel":  # the network reads its own angles of the map joints
        sur = on_parallel_map(sur, delay=(2, 0, 0, 1))
        assert sur.metrics["ensemble"]["own_gain_dev"][0][0] < 0
    elif on_map:  # "delayed": the swing's map reads the command 2 samples back
        sur = on_static_map(sur, delay=(2, 0, 0, 1) if on_map == "delayed" else None)
        assert sur.metrics["ensemble"]["map_gain_dev"][0][0] < 0
    rng = np.random.default_rng(1)
    n, n_step, w = 5, 25, sur.window
    theta0, u = _drive(rng, n, n_step)
    eng = SurrogateEngine(sur, n_envs=n, mode=mode, impl=impl, uncertainty=True)
    assert eng.unc is not None and eng.unc.n_member == len(sur.metrics["ensemble"]["members"])
    eng.reset(theta0)
    th_band, om_band, flags, om = [], [], [], []
    for k in range(n_step):
        _, o = eng.step(u[:, k])
        om.append(o.numpy().copy())
        t_b, o_b = eng.unc.bands()
        th_band.append(t_b.numpy().copy())
        om_band.append(o_b.numpy().copy())
        flags.append(eng.unc.ood.numpy().copy())
    (th_c, om_c, th_m, om_m), u_full = _plain(sur, theta0, u)
    sl = slice(w, w + n_step)  # engine step k predicts sample w - 1 + k + 1
    th_ref, om_ref = np.std(th_m, axis=0, ddof=1)[:, sl], np.std(om_m, axis=0, ddof=1)[:, sl]
    # float32 network, float64 integration: a few ulp of the largest velocity per step,
    # accumulated over the run for the angles
    scale = 1.0 + np.nanmax(np.abs(om_m))
    tol_w = 1e3 * EPS32 * scale
    tol_t = tol_w * n_step * sur.spec.dt
    np.testing.assert_allclose(np.stack(om, 1), om_c[:, sl], atol=tol_w, rtol=0)
    np.testing.assert_allclose(np.stack(om_band, 1), om_ref, atol=tol_w, rtol=0)
    np.testing.assert_allclose(np.stack(th_band, 1), th_ref, atol=tol_t, rtol=0)
    # the members do disagree (a map joint by its gain spread x the distance moved, which
    # random commands may leave near 0 in one env)
    last = np.stack(th_band, 1)[:, -1]
    assert (np.median(last, axis=0) if on_map else last.min()).min() > 10 * tol_t
    if on_map:  # angle spread = sigma_j |theta_k - theta_start| on the map joints
        moved = np.abs(th_c[:, sl] - th_c[:, w - 1 : w])[..., [0, 3]]
        np.testing.assert_allclose(
            np.stack(th_band, 1)[..., [0, 3]], moved * np.array([0.2, 0.3]), atol=tol_t, rtol=1e-3
        )
    # flags of step k: the sample it predicted from (theta[k], omega[k], u[k]); at rest
    # before the first step (omega 0 where the plain loop has NaN)
    om_in = om_c.copy()
    om_in[:, w - 1] = 0.0
    ref = ood_flags(
        CoverageRecord.from_dict(sur.metrics["coverage"]), sur.spec, th_c, om_in, u_full
    )[:, w - 1 : w - 1 + n_step]
    got = np.stack(flags, 1)
    # a sample on a cell or box edge may fall either way within rounding: allow a few
    assert (got != ref).mean() < 0.01
    assert 0.05 < ref.mean() < 0.95  # the record cuts through the run: the test can fail


def test_members_driven_into_the_stops_stay_inside_them(make_surrogate) -> None:
    """Members pushing into a stop the central run rests on: their deviations had kept
    integrating (a 90 % band of +-932 degrees on a boom of 92), MPPI's risk with them.  The
    engine's member angles stay inside the stops and equal the plain loop's."""
    sur = merge(
        [make_surrogate(seed=s, hidden=16, mode="stateful", drive=20.0, **KW) for s in range(3)]
    )
    rng = np.random.default_rng(2)
    n, n_step, w = 3, 120, sur.window
    theta0, u = _drive(rng, n, n_step)
    eng = SurrogateEngine(sur, n_envs=n, mode="stateful", uncertainty=True)
    eng.reset(theta0)
    lo, hi = sur.limits_np()[:2]
    th_band = []
    for k in range(n_step):
        th, _ = eng.step(u[:, k])
        members = th.numpy()[None] + eng.unc.dev.numpy()
        assert (members >= np.minimum(lo, th.numpy()) - 1e-12).all()
        assert (members <= np.maximum(hi, th.numpy()) + 1e-12).all()
        th_band.append(eng.unc.bands()[0].numpy().copy())
    (th_c, _, th_m, _), _ = _plain(sur, theta0, u)
    stopped = np.isfinite(hi)
    at_stop = np.isclose(th_c[:, -1, stopped], lo[stopped]) | np.isclose(
        th_c[:, -1, stopped], hi[stopped]
    )
    assert at_stop.mean() > 0.5  # the test can fail: the runs rest on their stops
    ref = np.std(th_m, axis=0, ddof=1)[:, w : w + n_step]
    np.testing.assert_allclose(np.stack(th_band, 1), ref, atol=1e-4, rtol=0)
    assert (ref[..., stopped] <= (hi - lo)[stopped]).all()


def test_calibrated_band_and_masked_resets(ens) -> None:
    """A calibrated checkpoint reports k_90 max(std, floor); a masked reset zeroes the angle
    band of the reset envs only; the vector env's keys are the single env's, batched."""
    sur = copy.deepcopy(ens)
    k90 = np.array([[1.0, 1.0, 1.0, 1.0], [30.0, 40.0, 50.0, 60.0]])
    floor = np.full(4, 1e-4)
    sur.metrics["uncertainty"] = Calibration(
        levels=(0.5, 0.9),
        theta=k90,
        omega=2 * k90,
        n_step=10,
        theta_floor=floor,
        omega_floor=floor,
    ).to_dict()
    rng = np.random.default_rng(2)
    n = 4
    theta0, u = _drive(rng, n, 12)
    venv = SurrogateVectorEnv(sur, n, max_episode_steps=None, autoreset_mode=AutoresetMode.DISABLED)
    raw = SurrogateEngine(sur, n_envs=n, impl=venv.engine.impl, uncertainty=True)
    raw.unc.calibrated = False
    venv.reset(options={"theta0": theta0})
    raw.reset(theta0)
    for k in range(12):
        _, _, _, _, info = venv.step(u[:, k].astype(np.float32))
        raw.step(np.clip(u[:, k].astype(np.float32), -1000, 1000))
    s_t, s_w = (b.numpy() for b in raw.unc.bands())
    assert info["uncertainty"].all() and info["band_calibrated"].all()
    np.testing.assert_allclose(info["theta_band"], k90[1] * np.maximum(s_t, floor), rtol=1e-9)
    np.testing.assert_allclose(info["omega_band"], 2 * k90[1] * np.maximum(s_w, floor), rtol=1e-9)
    assert info["theta_band"].shape == (n, 4) and info["ood"].shape == (n, 4)
    mask = np.array([True, False, True, False])
    venv.reset(options={"theta0": theta0, "reset_mask": mask})
    _, _, _, _, info2 = venv.step(np.zeros((n, 4), dtype=np.float32))
    # one step after the reset: deviation of one step only, far below the continued envs'
    assert info2["theta_band"][mask].max() < info["theta_band"][~mask].min()
    single = ExcavatorSurrogateEnv(sur)
    single.reset(seed=0)
    _, _, _, _, one = single.step(np.zeros(4, dtype=np.float32))
    assert set(INFO_KEYS) <= set(one) and set(INFO_KEYS) <= set(info)
    for k in INFO_KEYS:
        assert np.shape(one[k]) == np.shape(info[k])[1:], k
    assert single.uncertainty_note == ""


def test_single_network_says_it_has_no_uncertainty(make_surrogate) -> None:
    """A single network: no bands (None, never zeros) and ``uncertainty`` False, with a note;
    its coverage record still flags; without a record the flags say they were not checked."""
    sur = make_surrogate(seed=0, hidden=16, mode="stateful", **KW)
    env = ExcavatorSurrogateEnv(sur)
    env.reset(seed=0)
    _, _, _, _, info = env.step(np.zeros(4, dtype=np.float32))
    assert not info["uncertainty"]
    assert info["theta_band"] is None and info["omega_band"] is None
    assert not info["ood_checked"] and "single network" in env.uncertainty_note
    assert "coverage" in env.uncertainty_note
    sur.metrics = dict(sur.metrics or {}, coverage=_record(np.random.default_rng(0)).to_dict())
    venv = SurrogateVectorEnv(sur, 3, max_episode_steps=None)
    venv.reset(seed=0)
    u = np.full((3, 4), 900.0, dtype=np.float32)  # beyond the record's +-600 box
    _, _, _, _, info = venv.step(u)
    assert info["ood_checked"].all() and info["ood"].all() and info["ood_any"].all()
    assert not info["uncertainty"].any()
    for k in ("theta_band", "omega_band"):  # what SyncVectorEnv batches from the single env's
        assert info[k].shape == (3,) and all(b is None for b in info[k]), k
    off = SurrogateVectorEnv(sur, 3, max_episode_steps=None, uncertainty=False)
    off.reset(seed=0)
    _, _, _, _, info = off.step(u)
    assert not info["ood_checked"].any() and "not tracked" in off.uncertainty_note


@pytest.mark.parametrize("uncertainty", [None, False])
def test_vector_info_of_a_single_network_lists_like_sync_vector_env(
    stateful_ckpt: Path, uncertainty: bool | None
) -> None:
    """Every uncertainty entry of the vector env's info is an array over the envs, as
    gymnasium's ``DictInfoToList`` asserts: a single network's bands are None per env, as a
    ``SyncVectorEnv`` of the single env lists them (they were one bare None: an
    AssertionError on the first step)."""
    kw = dict(num_envs=2, ckpt=str(stateful_ckpt), uncertainty=uncertainty)
    envs = [
        DictInfoToList(gym.make_vec(SURROGATE_ID, vectorization_mode=vm, **kw))
        for vm in ("vector_entry_point", "sync")
    ]
    for env in envs:
        env.reset(seed=0)
    for _ in range(2):
        a = np.full((2, 4), 300.0, dtype=np.float32)
        (*_, got), (*_, ref) = (env.step(a) for env in envs)
        assert len(got) == len(ref) == 2
        for one, one_ref in zip(got, ref):
            assert one["theta_band"] is None and one["omega_band"] is None
            np.testing.assert_equal(
                {k: one[k] for k in INFO_KEYS}, {k: one_ref[k] for k in INFO_KEYS}
            )


def test_angle_band_follows_the_horizon_bins_like_the_plain_loop(ens) -> None:
    """With an angle scale per horizon bin, the env's band at each step is the Python band
    (``uncertainty.bands`` on the plain loop) of the same free-run sample: the bin of the
    steps since the reset, restarted by a reset."""
    sur = copy.deepcopy(ens)
    k90 = np.array([[1.0] * 4, [30.0, 40.0, 50.0, 60.0]])
    k_h = np.stack([np.ones((3, 4)), k90[1] * np.array([[1.0], [3.0], [9.0]])])  # (2, 3, 4)
    cal = Calibration(
        levels=(0.5, 0.9),
        theta=k90,
        omega=2 * k90,
        n_step=10,
        theta_floor=np.full(4, 1e-6),
        omega_floor=np.full(4, 1e-6),
        horizon_edges=np.array([0, 3, 7]),
        theta_horizon=k_h,
    )
    sur.metrics["uncertainty"] = cal.to_dict()
    rng = np.random.default_rng(5)
    n, n_step, w = 3, 12, sur.window
    theta0, u = _drive(rng, n, n_step)
    eng = SurrogateEngine(sur, n_envs=n, uncertainty=True)
    eng.reset(theta0)
    got = []
    for k in range(n_step):
        eng.step(u[:, k])
        got.append(eng.unc.bands()[0].numpy().copy())
    (th_c, om_c, th_m, om_m), _ = _plain(sur, theta0, u)
    pred = UncertainPrediction(
        th_c, om_c, w, th_m, om_m, np.std(th_m, 0, ddof=1), np.std(om_m, 0, ddof=1)
    )
    lo, hi = bands(pred, cal)[0.9]["theta"]
    ref = ((hi - lo) / 2)[:, w : w + n_step]
    tol = 1e3 * EPS32 * (1.0 + np.nanmax(np.abs(om_m))) * n_step * sur.spec.dt * k_h.max()
    np.testing.assert_allclose(np.stack(got, 1), ref, atol=tol, rtol=0)
    # the bins matter: step 8 (horizon 7) uses 9x the first bin's scale
    s_t = np.std(th_m, 0, ddof=1)[:, w + 7]
    np.testing.assert_allclose(got[7], 9 * k90[1] * np.maximum(s_t, 1e-6), atol=tol, rtol=0)
    assert (got[7] > 3 * k90[1] * s_t + tol).all()  # not the second bin's scale
    # a reset restarts the horizon: the next band uses the first bin again
    eng.reset(theta0)
    eng.step(u[:, 0])
    np.testing.assert_allclose(eng.unc.bands()[0].numpy(), ref[:, 0], atol=tol, rtol=0)


def test_member_std_is_torch_std_over_the_members() -> None:
    """The members' loop std equals ``torch.std(x, dim=0)`` (ddof 1), NaN where x is NaN."""
    import torch

    from excavator_surrogate.env.uncertainty import member_std

    gen = torch.Generator().manual_seed(0)
    for m in (2, 3, 5):
        x = torch.randn(m, 7, 4, generator=gen, dtype=torch.float64) * 3.0 + 1.0
        x[1, 2, 3] = float("nan")
        got, ref = member_std(x), torch.std(x, dim=0)
        torch.testing.assert_close(got, ref, equal_nan=True, rtol=1e-12, atol=1e-12)
        assert torch.isnan(got[2, 3]) and bool(torch.isfinite(got[0]).all())
