"""Ensemble uncertainty: member outputs of a merged network, calibration, coverage flags."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from excavator_surrogate.errors import CheckpointError, ConfigError
from excavator_surrogate.surrogate import rollout, rollout_reference
from excavator_surrogate.surrogate.angles import omega_target
from excavator_surrogate.surrogate.bands import (
    HORIZON_EDGES,
    NO_SPREAD_FLOOR,
    PRIOR_RUNS,
    RULE,
    _evenly,
    _pooled,
    band_scores,
    calibrate,
    calibrate_checkpoint,
    fit_horizon_scale,
    fit_scale,
    monotone_bins,
    predict_episodes,
    spread_floor,
)
from excavator_surrogate.surrogate.checkpoint import load_checkpoint, save_checkpoint
from excavator_surrogate.surrogate.coverage import (
    CoverageRecord,
    channel_names,
    fit_coverage,
    ood_flags,
)
from excavator_surrogate.surrogate.ensemble import member_head, merge
from excavator_surrogate.surrogate.rollout import ClosedLoop
from excavator_surrogate.surrogate.synthetic import synthetic_spec
from excavator_surrogate.surrogate.uncertainty import (
    NO_MEMBERS,
    Calibration,
    member_runs,
    predict_with_uncertainty,
    stored_calibration,
    stored_coverage,
)
from tests.helpers.surrogates import make_surrogate

PLAY = (0.05,)


def _members(spec, episodes, *, cell="lstm", mode="stateful", residual=False, prior=False):
    kw = dict(cell=cell, mode=mode, window=5, play=PLAY, end_stops=True, drive=3.0)
    kw |= dict(omega_in=residual, residual=residual, prior=prior)
    return [
        make_surrogate(spec, episodes[:2], seed=0, hidden=10, **kw),
        make_surrogate(spec, episodes[1:], seed=1, hidden=6, **kw),
    ]


def _batch(episodes, n):
    return np.stack([e.theta[:n] for e in episodes]), np.stack([e.u[:n] for e in episodes])


@pytest.mark.parametrize(
    ("cell", "mode", "residual", "prior"),
    [
        ("lstm", "stateful", False, False),
        ("gru", "windowed", False, False),
        ("lstm", "stateful", True, False),
        ("lstm", "stateful", False, True),
    ],
)
def test_member_rows_of_the_merged_network_equal_each_member_run_alone(
    spec, episodes, cell, mode, residual, prior
):
    members = _members(spec, episodes, cell=cell, mode=mode, residual=residual, prior=prior)
    ens = merge(members)
    theta, u = _batch(episodes, 60)
    th_c, om_c, th_m, om_m = member_runs(ens, theta, u, design="independent")
    # the central rows are the merged network's ordinary free run
    th_e, om_e = rollout(ens, theta, u)
    np.testing.assert_allclose(th_c, th_e, atol=1e-5)
    np.testing.assert_allclose(om_c, om_e, atol=1e-4)
    # float32 nets: the member rows and the plain loop differ by rounding only, which grows
    # with the step count and the angle (float32 eps 1.2e-7 x 60 steps < 1e-5 relative)
    for m, sur in enumerate(members):
        for i in range(len(episodes)):
            th_r, om_r = rollout_reference(sur, theta[i], u[i])
            np.testing.assert_allclose(th_m[m, i], th_r, atol=1e-5, rtol=1e-5)
            np.testing.assert_allclose(om_m[m, i], om_r, atol=1e-4)
    # the test can fail: the members run apart from each other and from the mean
    assert np.abs(th_m[0] - th_m[1]).max() > 1e-3
    assert np.abs(th_m[0] - th_c).max() > 1e-4


def test_member_velocities_average_to_the_merged_one(spec, episodes):
    members = [
        make_surrogate(spec, episodes[:2], mode="stateful", window=5, seed=0, hidden=10),
        make_surrogate(spec, episodes[1:], mode="stateful", window=5, seed=1, hidden=6),
    ]
    ens = merge(members)  # no end stops: the loop's omega is the network's
    theta, u = _batch(episodes, 30)
    loop = ClosedLoop(ens, members=True)
    loop.reset(theta[:, :5], u[:, :4])
    for k in range(4, 20):
        _, omega = loop.step(u[:, k])
        torch.testing.assert_close(loop.omega_members.mean(0), omega, atol=1e-6, rtol=1e-4)
    assert (loop.omega_members[0] - loop.omega_members[1]).abs().max() > 1e-4


def test_shared_design_spreads_the_members_along_one_run(spec, episodes):
    ens = merge(_members(spec, episodes))
    theta, u = _batch(episodes, 50)
    th_c, _, th_m, om_m = member_runs(ens, theta, u, design="shared")
    np.testing.assert_allclose(th_c, rollout(ens, theta, u)[0], atol=1e-5)
    assert np.isfinite(om_m[:, :, 5:]).all() and np.abs(th_m[0] - th_m[1]).max() > 0


def test_shared_member_angles_stay_inside_the_end_stops(spec, episodes):
    """Members driven into the stops the merged run rests on: their velocity deviations kept
    integrating, hundreds of degrees past a stop, and the bands grew without bound.  Checked
    against a plain per-member, per-sample loop."""
    kw = dict(mode="stateful", window=5, play=PLAY, end_stops=True, drive=20.0)
    ens = merge(
        [
            make_surrogate(spec, episodes[:2], seed=0, hidden=10, **kw),
            make_surrogate(spec, episodes[1:], seed=1, hidden=6, **kw),
        ]
    )
    theta, u = _batch(episodes, 60)
    th_c, om_c, th_m, om_m = member_runs(ens, theta, u, design="shared")
    lo, hi = ens.limits_np()[:2]
    stopped = np.isfinite(hi)
    last = th_c[:, -1, stopped]
    at_stop = np.isclose(last, lo[stopped], atol=1e-6) | np.isclose(last, hi[stopped], atol=1e-6)
    assert at_stop.any()  # the run rests on a stop
    assert (th_m <= np.maximum(hi, th_c) + 1e-12).all() and (
        th_m >= np.minimum(lo, th_c) - 1e-12
    ).all()
    # the plain loop: member by member, sample by sample
    dt = ens.spec.dt
    for m in range(th_m.shape[0]):
        for i in range(th_m.shape[1]):
            ref = th_c[i, 0].copy()
            for k in range(th_m.shape[2] - 1):
                if np.isnan(om_c[i, k + 1]).all():
                    ref = th_c[i, k + 1].copy()
                else:
                    d = np.nan_to_num(om_m[m, i, k + 1] - om_c[i, k + 1]) * dt
                    ref = ref + (th_c[i, k + 1] - th_c[i, k]) + d
                    ref = np.clip(
                        ref, np.minimum(lo, th_c[i, k + 1]), np.maximum(hi, th_c[i, k + 1])
                    )
                np.testing.assert_allclose(th_m[m, i, k + 1], ref, atol=1e-12)
    # away from the stops the deviation is the plain integral (the design's definition)
    free = ~stopped
    dev = np.cumsum(np.nan_to_num(om_m - om_c[None]) * dt, axis=2)
    np.testing.assert_allclose(th_m[..., free], (th_c[None] + dev)[..., free], atol=1e-9)
    # the spread stays within the joint's range (it had grown without bound)
    span = (hi - lo)[stopped]
    assert (np.std(th_m, 0, ddof=1)[..., stopped] <= span).all()


def test_fit_scale_recovers_a_known_scale(rng):
    n = 40_000
    c = np.array([0.5, 2.0, 7.0])  # errors are c_j x spread x N(0, 1)
    spread = rng.uniform(0.2, 3.0, size=(n, 3))
    err = c * spread * rng.normal(size=(n, 3))
    k = fit_scale(err, spread, (0.5, 0.9))
    z = np.array([[0.6745], [1.6449]])  # N(0, 1) two-sided 50 % / 90 % quantiles
    # quantile of |N(0,1)| from n samples: relative standard error << 3 %
    np.testing.assert_allclose(k / z, np.broadcast_to(c, (2, 3)), rtol=0.03)
    # and the bands cover what they say on fresh samples
    err2 = c * spread * rng.normal(size=(n, 3))
    cover = (np.abs(err2)[None] <= k[:, None] * spread[None]).mean(1)
    np.testing.assert_allclose(cover, [[0.5] * 3, [0.9] * 3], atol=0.015)


def test_a_single_network_reports_no_uncertainty(spec, episodes):
    sur = make_surrogate(spec, episodes, mode="stateful", window=5)
    theta, u = _batch(episodes, 40)
    pred = predict_with_uncertainty(sur, theta, u)
    assert pred.theta_spread is None and pred.omega_spread is None and pred.bands is None
    assert NO_MEMBERS in pred.notes
    np.testing.assert_allclose(pred.theta, rollout(sur, theta, u)[0])
    with pytest.raises(ConfigError, match="no ensemble members"):
        ClosedLoop(sur, members=True)


def test_an_ensemble_merged_before_member_biases_has_no_member_outputs(spec, episodes):
    ens = merge(_members(spec, episodes))
    del ens.metrics["ensemble"]["member_bias"]
    assert member_head(ens) is None
    theta, u = _batch(episodes, 40)
    pred = predict_with_uncertainty(ens, theta, u)
    assert pred.theta_spread is None and "merge it again" in " ".join(pred.notes)


def test_ood_flag_fires_beyond_the_training_range_and_not_inside(spec, episodes):
    rec = fit_coverage(episodes, spec)
    ep = episodes[0]
    omega = omega_target(ep.theta, spec)
    inside = ood_flags(rec, spec, ep.theta, omega, ep.u)
    # the training data itself: only its rarest samples (outside the 0.5/99.5 % box) flag
    assert inside.shape == ep.theta.shape and inside.any(-1).mean() <= 0.05
    # commands twice as large: every step whose command leaves the box is flagged
    u2 = 2.0 * ep.u
    flags = ood_flags(rec, spec, ep.theta, omega, u2)
    iu = np.arange(spec.n_joint)
    beyond = (u2[:, iu] > rec.hi[iu]) | (u2[:, iu] < rec.lo[iu])
    assert beyond.sum() > 10 and flags[beyond].all()


def test_ood_grid_flags_a_pose_and_command_never_seen_together():
    spec = synthetic_spec(1)
    n = spec.n_u  # channels: u_0, theta_0, omega_0
    grid = np.zeros((1, 8, 8), dtype=np.int64)
    grid[0, :4, :4] = 5  # low angles with low commands only
    grid[0, 1, 1] = 0  # a hole between seen cells
    rec = CoverageRecord(
        channel_names(spec), np.array([-1.0, 0.0, -9.0]), np.array([1.0, 8.0, 9.0]), grid, 80
    )
    assert len(rec.channels) == n + 2
    theta = np.array([[0.5], [1.5], [7.5], [7.5]])  # bins 0, 1, 7, 7
    u = np.array([[-0.9], [-0.6], [0.9], [-0.9]])  # bins 0, 1, 7, 0
    flags = ood_flags(rec, spec, theta, np.zeros_like(theta), u)[:, 0]
    # seen cell, hole next to seen cells, far corner never seen, high angle with low command
    assert flags.tolist() == [False, False, True, True]


def test_a_periodic_pose_is_flagged_alike_on_every_turn():
    """The network reads the swing as sin/cos: the same pose one turn on is the same input.
    The record's box had been fitted and checked on the raw angle, so -2.983 rad was flagged
    and +3.300 (the same pose) was not; a swing logged across +-pi got a box of the whole
    circle.  The torch twin (the engine's and the ONNX graph's flags) agrees."""
    import torch

    from excavator_surrogate.data import Episode
    from excavator_surrogate.env.uncertainty import OodFlags

    spec = synthetic_spec(2)
    rng = np.random.default_rng(0)
    n = 400
    t = np.arange(n) * spec.dt
    swing = np.pi + 0.15 * np.sin(0.5 * t)  # across +pi, logged wrapped
    theta = np.stack([(swing + np.pi) % (2 * np.pi) - np.pi, 0.3 * np.sin(0.3 * t)], axis=1)
    u = rng.uniform(-500, 500, (n, 2))
    ep = Episode(spec=spec, time=t, u=u, theta=theta, omega=np.zeros_like(theta), name="e")
    rec = fit_coverage([ep], spec)
    lo, hi = rec.lo[spec.n_u], rec.hi[spec.n_u]
    assert hi - lo < 0.5  # one narrow box round pi, not [-pi, pi)
    poses = np.array([[3.05, 0.0], [3.05 - 2 * np.pi, 0.0], [3.05 + 4 * np.pi, 0.0], [2.0, 0.0]])
    cmd = np.zeros((4, 2))
    flags = ood_flags(rec, spec, poses, np.zeros_like(poses), cmd)[:, 0]
    assert flags.tolist() == [False, False, False, True]  # a seen pose on three turns; 2.0 unseen
    box = OodFlags(rec, spec, dtype=torch.float64)
    got = box(torch.as_tensor(poses), torch.as_tensor(cmd), torch.zeros(4, 2, dtype=torch.float64))
    assert got.numpy().tolist() == ood_flags(rec, spec, poses, np.zeros_like(poses), cmd).tolist()


def test_coverage_record_round_trips(spec, episodes):
    rec = fit_coverage(episodes, spec, n_bin=6)
    back = CoverageRecord.from_dict(rec.to_dict())
    assert back.channels == rec.channels and back.n_bin == 6
    np.testing.assert_array_equal(back.grid, rec.grid)
    np.testing.assert_allclose(back.lo, rec.lo)


def test_checkpoints_round_trip_calibration_and_coverage(spec, episodes, tmp_path: Path):
    ens = merge(_members(spec, episodes))
    path = save_checkpoint(tmp_path / "best.pt", ens, history=[{"member": "ensemble"}])
    old = load_checkpoint(path)  # a checkpoint without the records loads as before
    assert stored_calibration(old) is None and stored_coverage(old) is None
    cal, cov = calibrate_checkpoint(path, episodes[2:], episodes[:2])
    assert cal is not None and cal.theta.shape == (2, spec.n_joint)
    assert np.isfinite(cal.theta).all() and (cal.theta[1] >= cal.theta[0]).all()
    back = load_checkpoint(path)
    cal2, cov2 = stored_calibration(back), stored_coverage(back)
    assert cal2 is not None and cov2 is not None
    np.testing.assert_allclose(cal2.theta, cal.theta)
    np.testing.assert_array_equal(cov2.grid, cov.grid)
    assert torch.load(path, weights_only=True)["history"] == [{"member": "ensemble"}]
    assert Calibration.from_dict(cal.to_dict()).levels == (0.5, 0.9)
    # the stored calibration gives bands: on the runs it was fitted on, weighed as in the
    # fit, they cover as fitted (the sample at the quantile itself may fall either side of
    # |err| <= k x spread by rounding: one sample of slack per group)
    w = 1 / (1 + PRIOR_RUNS)
    per = [j.periodic for j in spec.joints]
    fitted = [predict_episodes(back, eps) for eps in (episodes[2:], episodes[:2])]
    sc = [band_scores(r, spec.names, per) for r in fitted]
    one = [1.0 / sum(len(r.time) - r.pred.warmup for r in runs) for runs in fitted]
    scores = sc[0]
    assert scores["available"]
    for n in spec.names:
        for q, lv in (("theta", "90"), ("omega", "50")):
            got = w * sc[0][q][n][f"coverage_{lv}"] + (1 - w) * sc[1][q][n][f"coverage_{lv}"]
            assert got >= int(lv) / 100 - w * one[0] - (1 - w) * one[1] - 1e-9
        assert scores["theta"][n]["width_90"] >= scores["theta"][n]["width_50"]
    assert 0.0 <= scores["ood"]["any"] <= 1.0


def test_calibrating_a_single_network_records_coverage_only(spec, episodes, tmp_path: Path):
    sur = make_surrogate(spec, episodes, mode="stateful", window=5)
    path = save_checkpoint(tmp_path / "best.pt", sur)
    cal, _ = calibrate_checkpoint(path, episodes[2:], episodes[:2])
    back = load_checkpoint(path)
    assert cal is None and stored_calibration(back) is None and stored_coverage(back) is not None
    runs = predict_episodes(back, episodes)
    scores = band_scores(runs, spec.names, [j.periodic for j in spec.joints])
    assert not scores["available"] and NO_MEMBERS in scores["notes"]
    assert scores["ood"] is not None


def test_scales_are_the_weighted_mixture_of_validation_and_training_runs(spec, episodes):
    """:data:`RULE`: the quantile of the validation and training runs' ratios together, the
    validation runs weighing n_val / (n_val + PRIOR_RUNS); the record says which runs they
    came from, and a calibration stored before the rule loads with the same bands."""
    ens = merge(_members(spec, episodes))
    val, train = episodes[2:], episodes[:2]
    both, _ = calibrate(ens, val, train)
    only_val, _ = calibrate(ens, val, train, train_runs=0)
    only_train, _ = calibrate(ens, [], train)
    assert both is not None and only_val is not None and only_train is not None
    assert (both.rule, both.n_run, both.n_train_run) == (RULE, 1, 2)
    assert (only_val.rule, only_train.rule) == ("val", "train")
    per = np.array([j.periodic for j in spec.joints])
    runs = [predict_episodes(ens, eps, calibration=None) for eps in (val, train)]
    w = 1 / (1 + PRIOR_RUNS)
    for q in ("theta", "omega"):
        err, spread = (np.concatenate([_pooled(r, per)[q][i] for r in runs]) for i in (0, 1))
        n_v = len(_pooled(runs[0], per)[q][0])
        group = (np.arange(len(err)) >= n_v).astype(int)
        want = fit_scale(err, spread, both.levels, both.floor(q), group, (w, 1 - w))
        np.testing.assert_allclose(getattr(both, q), want, rtol=1e-12)
        assert not np.allclose(want, fit_scale(err, spread, both.levels, both.floor(q)))
    # too few samples per horizon bin here: every bin takes the one angle scale
    np.testing.assert_allclose(
        both.theta_horizon, np.broadcast_to(both.theta[:, None, :], both.theta_horizon.shape)
    )
    # a calibration stored before the rule: no rule fields, read as "val", same bands
    old = {k: v for k, v in both.to_dict().items() if k not in ("rule", "n_run", "n_train_run")}
    back = Calibration.from_dict(old)
    assert (back.rule, back.n_run, back.n_train_run) == ("val", 0, 0)
    theta, u = _batch(episodes, 40)
    a = predict_with_uncertainty(ens, theta, u, calibration=both).bands
    b = predict_with_uncertainty(ens, theta, u, calibration=back).bands
    assert a is not None and b is not None
    for lv in both.levels:
        for q in ("theta", "omega"):
            np.testing.assert_array_equal(a[lv][q][0], b[lv][q][0])


def test_fit_scale_weighs_groups_by_their_share_not_their_size():
    """10 validation samples at ratio 1 and 990 training samples at ratio 10: with shares
    (0.5, 0.5) the 40 % quantile is 1 and the 60 % one 10 (unweighted: 10 and 10)."""
    err = np.concatenate([np.full(10, 1.0), np.full(990, 10.0)])[:, None]
    spread = np.ones_like(err)
    group = np.concatenate([np.zeros(10, int), np.ones(990, int)])
    k = fit_scale(err, spread, (0.4, 0.6), group=group, share=(0.5, 0.5))
    np.testing.assert_array_equal(k[:, 0], [1.0, 10.0])
    np.testing.assert_array_equal(fit_scale(err, spread, (0.4, 0.6))[:, 0], [10.0, 10.0])
    # an empty group gives its share to the others
    k1 = fit_scale(err[10:], spread[10:], (0.4,), group=group[10:], share=(0.5, 0.5))
    assert k1[0, 0] == 10.0


def test_few_training_runs_are_picked_evenly(spec, episodes):
    many = [episodes[i % 3] for i in range(10)]
    assert _evenly(many, 32) == many
    assert _evenly(many, 0) == []
    picked = _evenly(list(range(10)), 4)  # type: ignore[arg-type]
    assert picked == [0, 3, 6, 9]


def test_horizon_scale_keeps_coverage_flat_when_error_outgrows_the_spread(rng):
    """Errors that grow like sqrt(horizon) x the spread: one scale over-covers the short
    horizons and under-covers the long ones; the per-bin scales cover ~90 % in every bin."""
    n_run, n_h = 60, 800
    h = np.tile(np.arange(n_h), n_run)
    spread = rng.uniform(0.5, 2.0, size=(h.size, 2))
    err = spread * np.sqrt(1.0 + h)[:, None] * rng.normal(size=(h.size, 2))
    edges = (0, 25, 50, 100, 200, 400)
    k_one = fit_scale(err, spread, (0.9,))
    k_bin = monotone_bins(*fit_horizon_scale(err, spread, h, (0.9,), edges=edges))
    assert k_bin.shape == (1, len(edges), 2)
    assert (np.diff(k_bin, axis=1) >= 0).all()
    err2 = spread * np.sqrt(1.0 + h)[:, None] * rng.normal(size=(h.size, 2))  # fresh runs
    b = np.searchsorted(edges, h, side="right") - 1
    inside_bin = np.abs(err2) <= k_bin[0][b] * spread
    inside_one = np.abs(err2) <= k_one[0] * spread
    # binomial standard error of a bin's coverage <= sqrt(0.09 / 1500) ~ 0.008
    for i in range(len(edges)):
        m = b == i
        np.testing.assert_allclose(inside_bin[m].mean(0), 0.9, atol=0.03)
    assert (inside_one[b == 0].mean(0) > 0.99).all() and (inside_one[b == 5].mean(0) < 0.85).all()


def test_horizon_bins_count_samples_whose_members_agree(rng):
    """A joint whose members never disagree (spread 0; floored to :data:`NO_SPREAD_FLOOR`)
    gets the quantile of its own error per horizon bin, as ``spread_floor`` says: the bins
    had counted only samples with a finite ``|err| / spread`` (none: 0 / 0, x / 0), so every
    bin was empty and one scale served every horizon.  A joint whose members disagree is
    counted as before."""
    n_run, n_h = 5, 400
    h = np.tile(np.arange(n_h), n_run)
    spread = np.stack([np.zeros(h.size), rng.uniform(0.5, 2.0, h.size)], axis=1)
    err = (1.0 + h / 50.0)[:, None] * rng.normal(size=(h.size, 2))
    floor = spread_floor(spread)
    assert floor[0] == NO_SPREAD_FLOOR
    k, counts = fit_horizon_scale(err, spread, h, (0.9,), floor)
    per_bin = [n_run * n for n in (25, 25, 50, 100, 200)] + [0] * 4
    assert counts[:, 0].tolist() == per_bin and counts[:, 1].tolist() == per_bin
    # the members-agree joint: its error's own 90 % quantile per bin, growing with the horizon
    b = np.searchsorted(HORIZON_EDGES, h, side="right") - 1
    for i in range(5):
        assert k[0, i, 0] == np.quantile(np.abs(err[b == i, 0]), 0.9, method="higher")
    assert np.all(np.diff(k[0, :5, 0]) > 0) and np.isnan(k[0, 5:, 0]).all()


def test_monotone_bins_fill_empty_bins_and_never_decrease():
    """Isotonic fit of the fitted bins (weighted by their samples), empty bins filled."""
    k = np.array([[[np.nan, 1.0], [2.0, np.nan], [1.0, 3.0], [np.nan, 2.0]]])  # (1, 4, 2)
    counts = np.array([[0, 10], [10, 0], [30, 10], [0, 30]])
    out = monotone_bins(k, counts)
    np.testing.assert_allclose(out[0, :, 0], [1.25] * 4)  # (2 x 10 + 1 x 30) / 40
    np.testing.assert_allclose(out[0, :, 1], [1.0, 1.0, 2.25, 2.25])  # (3 x 10 + 2 x 30) / 40


def test_calibration_with_horizon_bins_round_trips_and_bands_use_them(spec, episodes):
    ens = merge(_members(spec, episodes))
    cal, _ = calibrate(ens, episodes[2:], episodes[:2])
    assert cal is not None and cal.theta_horizon is not None and cal.horizon_edges is not None
    n_bin = len(cal.horizon_edges)
    k_h = np.stack([np.outer(np.arange(1, n_bin + 1), np.ones(spec.n_joint))] * 2)
    cal = Calibration(**{**cal.__dict__, "theta_horizon": k_h})
    back = Calibration.from_dict(cal.to_dict())
    np.testing.assert_array_equal(back.theta_horizon, k_h)
    np.testing.assert_array_equal(back.horizon_edges, cal.horizon_edges)
    theta, u = _batch(episodes, 60)
    pred = predict_with_uncertainty(ens, theta, u, calibration=back)
    lo, hi = pred.bands[0.9]["theta"]  # type: ignore[index]
    w = pred.warmup
    s = np.maximum(pred.theta_spread, back.floor("theta"))  # type: ignore[arg-type]
    t = w + back.horizon_edges[1]  # the first sample of the second bin
    np.testing.assert_allclose((hi - lo)[:, t] / 2, 2.0 * s[:, t], rtol=1e-12)
    np.testing.assert_allclose((hi - lo)[:, w] / 2, 1.0 * s[:, w], rtol=1e-12)
    with pytest.raises(CheckpointError, match="sizes"):
        Calibration.from_dict({**cal.to_dict(), "theta_horizon": k_h[:, :2].tolist()})
