"""Joints on the static valve map: chosen on validation, exact where chosen, recorded."""

from __future__ import annotations

import dataclasses
import tomllib
from pathlib import Path

import numpy as np
import torch

from excavator_surrogate.surrogate.angles import joint_limits
from excavator_surrogate.surrogate.checkpoint import load_checkpoint, save_checkpoint
from excavator_surrogate.surrogate.ensemble import member_head, merge
from excavator_surrogate.surrogate.envelope import fill_envelope
from excavator_surrogate.surrogate.rollout import rollout
from excavator_surrogate.surrogate.series import with_map_joints
from excavator_surrogate.surrogate.structured import fit_prior
from excavator_surrogate.training.map_apply import apply_map_choice
from excavator_surrogate.training.map_joints import (
    PERIODIC_MAP_R2,
    choose_map_joints,
    pinned_joints,
)
from tests.helpers.surrogates import make_surrogate, tiny_surrogate
from tests.surrogate.test_prior import _static_episode
from tests.surrogate.test_structured import SPEC


def _scaled(ep, gain: float):
    """``ep`` from a plant ``gain`` times as fast (same commands)."""
    theta = ep.theta[:1] + gain * (ep.theta - ep.theta[:1])
    return dataclasses.replace(ep, theta=theta, omega=gain * ep.omega)


def _net():
    """An untrained network: it barely moves (omega std 0.05 rad/s, small outputs)."""
    return tiny_surrogate(SPEC, mode="stateful", window=6, seed=3)


def test_a_map_that_drives_validation_better_is_chosen_and_recorded(tmp_path: Path) -> None:
    train = [_static_episode(s) for s in range(3)]
    val = [_static_episode(s) for s in (7, 8)]
    new, rec = choose_map_joints(_net(), train, val)
    assert new is not None and rec["chosen"] == ["a", "b"] and rec["candidates"] == ["a", "b"]
    assert new.metrics["map_joints"] == ["a", "b"] and new.model_cfg.prior
    assert new.metrics["val_error"] < 1e-3  # the plant is the map
    assert "follow(s) the static map" in rec["why"]
    par, rec_p = choose_map_joints(_net(), train, val, parallel=True)
    assert par is not None and par.norm.own is not None and par.norm.own.own == (True, True)
    assert rec_p["chosen"] == ["a", "b"] and rec_p["composition"] == "parallel"
    assert par.metrics["val_error"] < 1e-3
    # through the checkpoint: rewritten in place, the record in metrics.training
    path = save_checkpoint(tmp_path / "best.pt", _net())
    apply_map_choice(path, train, val)
    back = load_checkpoint(path)
    assert back.model_cfg.prior
    assert back.metrics["training"]["static_map"]["chosen"] == ["a", "b"]


def _with_gear(ep, spec, seed: int):
    """``ep`` with an exogenous ``gear`` column (+1 / -1, held for 40 samples) that the
    plant ignores."""
    rng = np.random.default_rng(1000 + seed)
    gear = np.repeat(rng.choice([-1.0, 1.0], ep.n_step // 40 + 1), 40)[: ep.n_step]
    return dataclasses.replace(ep, spec=spec, u=np.column_stack([ep.u, gear]))


def _gear_moves(sur, ep) -> float:
    """Largest change of the free-run angles [rad] when the gear column is flipped."""
    flipped = ep.u * np.array([1.0, 1.0, -1.0])
    th = [rollout(sur, ep.theta[None], u[None])[0] for u in (ep.u, flipped)]
    return float(np.abs(th[0] - th[1]).max())


def test_a_joint_on_the_map_no_longer_reads_the_kept_inputs(tmp_path: Path) -> None:
    """The map reads only its own joint's command: once both joints follow it, the gear the
    input choice kept moves no prediction, and the record (metrics.training.exogenous, the
    run's config.toml) says so; a config.toml without the table is not touched."""
    from excavator_surrogate.config import dumps_toml
    from excavator_surrogate.spec import InputSpec

    spec = dataclasses.replace(SPEC, inputs=(InputSpec("gear", u_min=-1.0, u_max=1.0),))
    train = [_with_gear(_static_episode(s), spec, s) for s in range(3)]
    val = [_with_gear(_static_episode(s), spec, s) for s in (7, 8)]
    net = tiny_surrogate(spec, mode="stateful", window=6, seed=3)
    assert _gear_moves(net, val[0]) > 1e-4  # the network reads the gear
    inputs = {"inputs": ["gear"], "kept": True, "joints": ["a", "b"], "why": "kept"}
    net.metrics = {"training": {"exogenous": inputs}}
    path = save_checkpoint(tmp_path / "best.pt", net)
    config = tmp_path / "config.toml"
    config.write_text(dumps_toml({"train": {"epochs": 3}, "exogenous": inputs}))
    rec = apply_map_choice(path, train, val, parallel=True, config=config)
    assert rec["chosen"] == ["a", "b"]
    back = load_checkpoint(path)
    assert _gear_moves(back, val[0]) < 1e-6  # no joint reads the gear now
    got = back.metrics["training"]["exogenous"]
    assert got["kept"] is False and got["joints"] == [] and got["dropped"] == ["a", "b"]
    assert (
        got["why"]
        == "kept; the static valve map, which ignores them, drives a, b: no joint reads them"
    )
    notes = tomllib.loads(config.read_text())
    assert notes["exogenous"] == got and notes["train"] == {"epochs": 3}
    # a run whose config.toml has no [exogenous] table: the file stays as it was
    path = save_checkpoint(tmp_path / "best.pt", net)
    bare = dumps_toml({"train": {"epochs": 3}})
    config.write_text(bare)
    apply_map_choice(path, train, val, parallel=True, config=config)
    assert config.read_text() == bare
    assert load_checkpoint(path).metrics["training"]["exogenous"]["kept"] is False


def test_a_map_worse_than_the_network_on_validation_is_not_chosen(tmp_path: Path) -> None:
    """Fitted on a machine 3x as fast as the validation's, the map misses by twice the motion,
    the still network by the motion once: the network stays, and the file says why."""
    train = [_scaled(_static_episode(s), 3.0) for s in range(3)]
    val = [_static_episode(s) for s in (7, 8)]
    new, rec = choose_map_joints(_net(), train, val)
    assert new is None and rec["chosen"] == [] and rec["candidates"] == []
    path = save_checkpoint(tmp_path / "best.pt", _net())
    before = load_checkpoint(path).net.state_dict()
    apply_map_choice(path, train, val)
    back = load_checkpoint(path)
    assert not back.model_cfg.prior
    assert all(torch.equal(v, back.net.state_dict()[k]) for k, v in before.items())
    assert "network beats the static map" in back.metrics["training"]["static_map"]["why"]


def test_map_joints_follow_the_map_and_the_others_keep_the_network(spec, episodes) -> None:
    """Free runs of the hybrid: a map joint's velocity is s(u) exactly; with no map joint the
    hybrid is the network; a merged ensemble's members drive a map joint with gains around
    the map's (mean: the map exactly; spread: gain_spread x |s(u)|)."""
    members = [make_surrogate(spec, episodes, mode="stateful", seed=s) for s in range(2)]
    ens = merge(members)
    fit = fit_prior(episodes, spec)
    theta = np.stack([e.theta[:50] for e in episodes[:2]])
    u = np.stack([e.u[:50] for e in episodes[:2]])
    th0, _ = rollout(ens, theta, u)
    same = with_map_joints(ens, fit, [False] * spec.n_joint)
    th1, _ = rollout(same, theta, u)
    np.testing.assert_allclose(th1, th0, atol=1e-5)
    pick = [j == 0 for j in range(spec.n_joint)]
    hyb = with_map_joints(ens, fit, pick)
    _, om = rollout(hyb, theta, u)
    w = hyb.window
    s = hyb.net.prior.speed(torch.tensor(u[..., : spec.n_joint], dtype=torch.float32))
    # omega[k+1] = s(u[k]) for the map joint, after the warm-up
    np.testing.assert_allclose(om[:, w:, 0], s[:, w - 1 : -1, 0].numpy(), atol=1e-5)
    head = member_head(hyb)
    assert head is not None
    x = hyb.norm.encode(torch.tensor(theta[:, 5]).float(), torch.tensor(u[:, 5]).float())
    with torch.no_grad(), head.capture():
        y, _ = hyb.net.step(x, hyb.net.init_state(x.shape[0]))
    with torch.no_grad():
        y_m = head.outputs(x)
    torch.testing.assert_close(y_m.mean(0), y, atol=1e-5, rtol=0)
    # the map joint: members' spread sigma |s(u)| [rad/s] (ddof 1), the others' untouched
    spread = y_m[:, :, 0].std(0) * hyb.norm.y_std[0]
    s_now = hyb.net.prior.raw(x)[:, 0]
    sigma = fit["gain_spread"][0]
    assert sigma > 0 and float(s_now.abs().max()) > 0
    torch.testing.assert_close(spread, sigma * s_now.abs(), atol=1e-5, rtol=1e-4)
    dev = torch.tensor(hyb.metrics["ensemble"]["map_gain_dev"])
    assert float(dev[:, 1:].abs().max()) == 0.0


def test_a_map_joint_gets_a_band_from_its_error_not_zero_width(spec, episodes) -> None:
    """Merged before the members' map gains were recorded, members agree exactly on a map
    joint: its floor is one unit, so its calibrated band is the error's own quantile (finite
    scale, positive width) and the predictions say why."""
    from excavator_surrogate.surrogate.bands import NO_SPREAD_FLOOR, calibrate
    from excavator_surrogate.surrogate.uncertainty import predict_with_uncertainty

    members = [make_surrogate(spec, episodes, mode="stateful", seed=s) for s in range(2)]
    pick = [j == 0 for j in range(spec.n_joint)]
    fit = {k: v for k, v in fit_prior(episodes, spec).items() if k != "gain_spread"}
    hyb = with_map_joints(merge(members), fit, pick)
    cal, _ = calibrate(hyb, episodes[:1], episodes[1:])
    assert cal is not None
    assert cal.theta_floor[0] == NO_SPREAD_FLOOR and cal.theta_floor[1] < NO_SPREAD_FLOOR
    assert np.isfinite(cal.theta).all() and float(cal.theta[-1, 0]) < 1e6
    ep = episodes[2]
    pred = predict_with_uncertainty(hyb, ep.theta[None], ep.u[None], calibration=cal)
    lo, hi = pred.bands[0.9]["theta"]
    w = pred.warmup
    assert float(np.min(hi[0, w:, 0] - lo[0, w:, 0])) > 0.0
    assert any("no member spread there" in n for n in pred.notes)


def test_a_map_joints_spread_grows_with_the_distance_the_map_moved_it(spec, episodes) -> None:
    """With the map's gain spread, a map joint's angle spread is gain_spread x |theta_k -
    theta_0| (the members integrate gains 1 + sigma z_m), its floor an ordinary one."""
    from excavator_surrogate.surrogate.bands import NO_SPREAD_FLOOR, calibrate
    from excavator_surrogate.surrogate.uncertainty import predict_with_uncertainty

    members = [make_surrogate(spec, episodes, mode="stateful", seed=s) for s in range(3)]
    pick = [j == 0 for j in range(spec.n_joint)]
    fit = fit_prior(episodes, spec)
    hyb = with_map_joints(merge(members), fit, pick)
    cal, _ = calibrate(hyb, episodes[:1], episodes[1:])
    assert cal is not None and cal.theta_floor[0] < NO_SPREAD_FLOOR
    ep = episodes[2]
    pred = predict_with_uncertainty(hyb, ep.theta[None], ep.u[None], calibration=cal)
    w = pred.warmup
    moved = np.abs(pred.theta[0, w:, 0] - pred.theta[0, w - 1, 0])
    assert float(moved.max()) > 0.01
    np.testing.assert_allclose(
        pred.theta_spread[0, w:, 0], fit["gain_spread"][0] * moved, rtol=1e-3, atol=1e-6
    )
    assert any("gain spread" in n for n in pred.notes)


def _periodic_case(gain: float):
    """Joint ``a`` periodic (a swing); training from the plant, validation from one ``gain``
    times as fast; the "network" is the validation's own map, exact there."""
    spec = dataclasses.replace(
        SPEC, joints=(dataclasses.replace(SPEC.joints[0], periodic=True), SPEC.joints[1])
    )

    def ep(s: int, g: float):
        return dataclasses.replace(_scaled(_static_episode(s), g), spec=spec)

    train = [ep(s, 1.0) for s in range(3)]
    val = [ep(s, gain) for s in (7, 8)]
    net = tiny_surrogate(spec, mode="stateful", window=6, seed=3)
    exact = with_map_joints(net, fit_prior(val, spec), [True, True])
    return exact, train, val


def test_a_periodic_joint_that_the_map_runs_well_follows_it_whatever_the_network_scores() -> None:
    """The validation machine is 10 % faster: the network (exact there) beats the map on both
    joints by far, but the map still runs the periodic joint with R^2 >= 0.95, so that joint
    follows the map; the other joint keeps the network.  With ``periodic=False``, neither."""
    net, train, val = _periodic_case(1.1)
    new, rec = choose_map_joints(net, train, val, val_gain=False)  # the training's map
    assert rec["val_theta_r2_map_delayed"][0] >= PERIODIC_MAP_R2
    assert rec["val_theta_rmse_map"][0] > 10 * max(rec["val_theta_rmse_network"][0], 1e-6)
    assert rec["pinned"] == ["a"] and rec["chosen"] == ["a"] and rec["candidates"] == []
    assert new is not None
    assert "periodic joint" in rec["why"] and "no other joint" in rec["why"]
    # joint a moves by the training map (the network's own map is gone), b by the network's
    fit = fit_prior(train, net.spec)
    ref = with_map_joints(net, fit, [True, False])
    u = np.stack([e.u for e in val])
    th0 = np.stack([e.theta[:6] for e in val])
    np.testing.assert_allclose(rollout(new, th0, u)[0], rollout(ref, th0, u)[0], atol=1e-5)
    none, rec_off = choose_map_joints(net, train, val, periodic=False)
    assert none is None and rec_off["pinned"] == [] and rec_off["chosen"] == []
    # known before the choice, from any network of the run (the kind choice's)
    other = tiny_surrogate(net.spec, mode="stateful", window=6, seed=5)
    assert pinned_joints(other, train, val) == [True, False]
    assert pinned_joints(other, train, val, periodic=False) == [False, False]


def test_a_periodic_joint_the_map_runs_badly_is_chosen_as_any_joint() -> None:
    """Validation 3x as fast: the map's R^2 on the periodic joint falls below the line, so it
    is not pinned, and the network (exact there) keeps both joints."""
    net, train, val = _periodic_case(3.0)
    new, rec = choose_map_joints(net, train, val)
    assert rec["val_theta_r2_map_delayed"][0] < PERIODIC_MAP_R2
    assert new is None and rec["pinned"] == [] and rec["chosen"] == []


def test_the_all_map_set_reuses_the_all_map_free_run(monkeypatch) -> None:
    """With every joint a candidate on one map, the set of all of them is the all-map free run
    that scored the candidates: it is not run again, and it scores as a fresh run of it."""
    import excavator_surrogate.training.map_blocks as mb
    import excavator_surrogate.training.map_joints as mj
    import excavator_surrogate.training.sets as sets

    calls = []
    real = mj.free_run_error

    def counting(sur, episodes, **kw):
        calls.append(sur)
        return real(sur, episodes, **kw)

    monkeypatch.setattr(mj, "free_run_error", counting)  # the network's run
    monkeypatch.setattr(mb, "free_run_error", counting)  # the all-map run
    monkeypatch.setattr(sets, "free_run_error", counting)  # the sets' runs
    train = [_static_episode(s) for s in range(3)]
    val = [_static_episode(s) for s in (7, 8)]
    net = _net()
    _, rec = choose_map_joints(net, train, val, val_gain=False)  # no rescored model after it
    # the network, the all-map run, then "a" alone and "b" alone (the pair is known)
    assert len(calls) == 4 and [t["joints"] for t in rec["tried"]] == [["a", "b"], ["a"], ["b"]]
    fresh = real(with_map_joints(net, fit_prior(train, SPEC), [True, True]), val)
    assert rec["tried"][0]["val_error"] == fresh["val_error"]


def test_in_parallel_a_joint_the_map_runs_well_is_pinned_and_the_network_keeps_its_own(
    tmp_path: Path,
) -> None:
    """In parallel, any joint (not only a periodic one) whose map validates with R^2 >= 0.95
    follows it; validation from a machine 10 % faster on ``a`` and 3x on ``b``, and a network
    exact there: ``a`` follows the training map, ``b`` the network's own free run, exactly
    (the network reads its own ``a``).  With ``periodic=False``, nothing is pinned."""
    train = [_static_episode(s) for s in range(3)]
    val = [_scaled(_static_episode(s), np.array([1.1, 3.0])) for s in (7, 8)]
    net = with_map_joints(_net(), fit_prior(val, SPEC), [True, True])
    new, rec = choose_map_joints(net, train, val, parallel=True, val_gain=False)
    assert (
        rec["val_theta_r2_map_delayed"][0] >= PERIODIC_MAP_R2 > rec["val_theta_r2_map_delayed"][1]
    )
    assert rec["val_theta_rmse_map"][0] > 10 * max(rec["val_theta_rmse_network"][0], 1e-6)
    assert rec["pinned"] == ["a"] and rec["chosen"] == ["a"] and rec["composition"] == "parallel"
    assert new is not None and new.norm.own is not None and new.norm.own.own == (True, False)
    assert "in parallel" in rec["why"] and new.metrics["val_error"] == rec["parallel"]["val_error"]
    u = np.stack([e.u for e in val])
    th0 = np.stack([e.theta[:6] for e in val])
    th_new, th_net = rollout(new, th0, u)[0], rollout(net, th0, u)[0]
    np.testing.assert_allclose(th_new[..., 1], th_net[..., 1], atol=1e-5)  # the network's own
    th_map = rollout(with_map_joints(_net(), fit_prior(train, SPEC), [True, True]), th0, u)[0]
    np.testing.assert_allclose(th_new[..., 0], th_map[..., 0], atol=1e-5)  # the training map
    assert np.abs(th_new[..., 1] - th_map[..., 1]).max() > 0.1  # b is not the map's
    none, rec_off = choose_map_joints(net, train, val, parallel=True, periodic=False)
    assert none is None and rec_off["pinned"] == [] and rec_off["chosen"] == []
    assert pinned_joints(_net(), train, val, parallel=True) == [True, False]
    assert pinned_joints(_net(), train, val) == [False, False]  # in series: periodic joints only
    # through the checkpoint: rewritten in place, the free run kept
    path = save_checkpoint(tmp_path / "best.pt", net)
    apply_map_choice(path, train, val, parallel=True, val_gain=False)
    back = load_checkpoint(path)
    assert back.norm.own is not None and back.norm.own.own == (True, False)
    assert back.metrics["training"]["static_map"]["composition"] == "parallel"
    np.testing.assert_allclose(rollout(back, th0, u)[0], th_new, atol=1e-6)


def test_a_map_joint_stops_at_the_training_range_and_the_network_keeps_its_margin() -> None:
    """``end_stops``: a joint on the map stops where the structured baseline does (the
    training range), in series and in parallel, and the record says so; the network's end
    stops (the range and a margin) stay on the other joints and, in parallel, on its own
    angles; ``end_stops=False`` keeps the network's on every joint."""
    train = [_static_episode(s) for s in range(3)]
    val = [_static_episode(s) for s in (7, 8)]
    th = np.concatenate([e.theta for e in train])
    lo, hi = th.min(axis=0), th.max(axis=0)
    spec, _ = fill_envelope(SPEC, train, limit_margin=0.2, speed_margin=-1.0)
    net = dataclasses.replace(_net(), spec=spec, end_stops=True)
    wide_lo, wide_hi = joint_limits(spec)
    assert np.all(wide_lo < lo) and np.all(wide_hi > hi)
    for parallel in (False, True):
        new, rec = choose_map_joints(net, train, val, parallel=parallel)
        assert new is not None and rec["chosen"] == ["a", "b"]
        got_lo, got_hi = joint_limits(new.spec)
        np.testing.assert_allclose(got_lo, lo)
        np.testing.assert_allclose(got_hi, hi)
        np.testing.assert_allclose(rec["end_stops"]["theta_max"], hi)
        if parallel:
            np.testing.assert_allclose(new.norm.own.theta_min.numpy(), wide_lo)
        kept, rec_off = choose_map_joints(net, train, val, parallel=parallel, end_stops=False)
        assert kept is not None and rec_off["end_stops"] == "the network's"
        np.testing.assert_allclose(joint_limits(kept.spec)[1], wide_hi)
    _, rec_free = choose_map_joints(_net(), train, val)  # a network run without end stops
    assert rec_free["end_stops"] == "the network's"
    # a machine 1.5x as fast on validation: the map's free run now meets the training range
    fast = [_scaled(e, 1.5) for e in val]
    new, _ = choose_map_joints(net, train, fast, parallel=True)
    wide, _ = choose_map_joints(net, train, fast, parallel=True, end_stops=False)
    u = np.stack([e.u for e in fast])
    th0 = np.stack([e.theta[:6] for e in fast])
    th_new, th_wide = rollout(new, th0, u)[0], rollout(wide, th0, u)[0]
    assert th_new.max() <= hi.max() + 1e-6 < th_wide.max()


def test_the_map_is_refitted_on_both_splits_only_where_validation_is_a_large_share() -> None:
    """Validation from a plant 10 % faster than training's: the map still wins the choice, and
    with ``refit_share`` at or below validation's share of the samples (2/3 here) the joints
    on the map take the map fitted on both splits (gains between the two plants'), in series
    and in parallel; above it, or at 0, the map of the training split stays."""
    from excavator_surrogate.training.map_fit import refit_due

    train = [_static_episode(s) for s in range(3)]
    val = [_scaled(_static_episode(s), 1.1) for s in (7, 8)]
    assert refit_due(train, val, share=0.0) is None and refit_due(train, val, share=0.9) is None
    assert refit_due(train, val, share=0.5) == 2 / 3
    k_train = np.array(fit_prior(train, SPEC)["k_pos"])
    for parallel in (False, True):
        opts = {"parallel": parallel, "val_gain": False}  # the refit alone
        kept, rec0 = choose_map_joints(_net(), train, val, **opts)
        high, rec_h = choose_map_joints(_net(), train, val, **opts, refit_share=0.9)
        new, rec = choose_map_joints(_net(), train, val, **opts, refit_share=0.5)
        assert rec0["chosen"] == rec["chosen"] == ["a", "b"]
        assert "refit" not in rec0 and "refit" not in rec_h
        assert high.metrics["val_error"] == kept.metrics["val_error"]
        k = np.array(rec["refit"]["map"]["k_pos"])
        assert np.all(k > 1.02 * k_train) and np.all(k < 1.1 * k_train)
        assert (
            rec["refit"]["val_share"] == 2 / 3 and "refitted on training + validation" in rec["why"]
        )
        # the validation scores are those of the model returned: in-sample on the map joints
        assert new.metrics["val_error"] < 0.8 * kept.metrics["val_error"]


def test_the_map_joints_take_validations_speed() -> None:
    """Validation from a plant 10 % faster than training's: by default the joints on the map
    take the map's gains times validation's speed ratio (1.1), in series and in parallel,
    recorded and said, and then run validation as its plant does; with ``val_gain = False``
    they keep the training's gains.  The scale is clipped to ``GAIN_RANGE`` and is 1 off the
    map."""
    from excavator_surrogate.training.map_fit import GAIN_RANGE, validation_gains

    train = [_static_episode(s) for s in range(3)]
    val = [_scaled(_static_episode(s), 1.1) for s in (7, 8)]
    for parallel in (False, True):
        off, rec_off = choose_map_joints(_net(), train, val, parallel=parallel, val_gain=False)
        on, rec = choose_map_joints(_net(), train, val, parallel=parallel)
        assert rec["chosen"] == rec_off["chosen"] == ["a", "b"] and "val_gain" not in rec_off
        assert rec["val_gain"]["joints"] == ["a", "b"]
        assert np.allclose(rec["val_gain"]["gain"], 1.1, atol=0.005)
        assert "the map joints' speeds then scaled to validation's (a x1.1" in rec["why"]
        assert on.metrics["val_error"] < 1e-3 < off.metrics["val_error"]  # the plant is the map
    fit = fit_prior(train, SPEC)
    fast = [_scaled(_static_episode(s), 1.6) for s in (7, 8)]
    slow = [_scaled(_static_episode(s), 0.5) for s in (7, 8)]
    assert validation_gains(fit, fast, [True, False]) == [GAIN_RANGE[1], 1.0]
    assert validation_gains(fit, slow, [False, True]) == [1.0, GAIN_RANGE[0]]
    # episodes that disagree on the side (one faster, one slower) leave the gains alone;
    # one episode decides alone
    mixed = [_scaled(_static_episode(7), 1.2), _scaled(_static_episode(8), 0.9)]
    assert validation_gains(fit, mixed, [True, True]) == [1.0, 1.0]
    _, rec = choose_map_joints(_net(), train, mixed)
    assert "(a x1, its validation episodes disagreeing on the side, b x1, its" in rec["why"]
    g = validation_gains(fit, mixed[:1], [True, True])
    assert np.allclose(g, 1.2, atol=0.005)
    # one episode, a log's next stretch: only faster (the machine warms over a log); slower
    # leaves the gains alone, and the why says so
    assert validation_gains(fit, mixed[1:], [True, True]) == [1.0, 1.0]
    assert validation_gains(fit, slow[:1], [True, True]) == [1.0, 1.0]
    _, rec = choose_map_joints(_net(), train, mixed[1:])
    assert rec["val_gain"] == {"joints": ["a", "b"], "gain": [1.0, 1.0], "episodes": 1}
    assert "(a x1, one validation stretch not faster than the training" in rec["why"]
