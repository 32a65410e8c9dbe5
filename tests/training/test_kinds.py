"""Two kinds of network chosen per joint (``prior_choice``): the choice on a plant where each
kind is exact on one joint, and a short training (the composite's maths: test_composite.py)."""

from __future__ import annotations

import csv
import dataclasses
from pathlib import Path

import numpy as np
import pytest
import torch

from excavator_surrogate.data import Dataset
from excavator_surrogate.errors import ConfigError
from excavator_surrogate.evaluate.training_report import choices_markdown
from excavator_surrogate.surrogate.checkpoint import load_checkpoint
from excavator_surrogate.surrogate.ensemble import merge
from excavator_surrogate.surrogate.model import Surrogate
from excavator_surrogate.surrogate.series import with_map_joints
from excavator_surrogate.surrogate.structured import fit_prior
from excavator_surrogate.training.api import train
from excavator_surrogate.training.composite import composite, in_prior_form
from excavator_surrogate.training.kinds import (
    choice_joints,
    choice_options,
    choose_kinds,
    map_pinned,
    model_kind,
)
from excavator_surrogate.training.resume import start
from tests.helpers.surrogates import free_run_checked, teacher_forced_omega, tiny_surrogate
from tests.helpers.training import tiny_train_config
from tests.surrogate.test_structured import SPEC, _episode

TRAIN = [_episode(s) for s in range(3)]
SMALL = dict(window=6, burn_in=6)  # the plant's delays (3, 5) fit in the window


def _prior_net(seed: int, *, exact: tuple[bool, ...]) -> Surrogate:
    """An untrained network correcting the plant's delayed map, with a silent head on the
    joints ``exact`` (there it is the plant)."""
    torch.manual_seed(seed)
    cfg = tiny_train_config(prior=True, **SMALL)
    st = start(cfg, cfg.model_config(SPEC.n_feature, SPEC.n_joint), SPEC, TRAIN, None)
    pick = torch.tensor(exact)
    with torch.no_grad():
        st.net.head[2].weight[pick] = 0.0
        st.net.head[2].bias[pick] = 0.0
    return Surrogate(
        net=st.net.eval(),
        spec=SPEC,  # as the plain test networks' (no envelope from the data)
        norm=st.norm,
        model_cfg=st.model_cfg,
        mode="stateful",
        train_config={"seed": seed},
        metrics={},
        name="lstm",
        end_stops=False,
    )


def _plain_net(seed: int) -> Surrogate:
    return tiny_surrogate(SPEC, TRAIN, window=6, hidden=8, seed=seed)


def _omega(sur: Surrogate, ep, n: int = 80) -> np.ndarray:
    """Teacher-forced omega (n, n_joint) [rad/s] of ``sur`` on the episode's first samples."""
    return teacher_forced_omega(sur, ep, n).numpy()


def test_the_choice_takes_each_joint_from_the_kind_that_drives_it() -> None:
    """'Plain' networks exact on joint b (it follows the map), map-correcting ones exact on
    joint a: the choice takes a from the map-correcting ones, and the composite drives the
    plant on both joints; its free run equals the plain loop."""
    fit = fit_prior(TRAIN, SPEC, max_delay=5)
    plains = [with_map_joints(_plain_net(s), fit, [False, True], lags=(3, 5)) for s in (0, 1)]
    priors = [_prior_net(s + 10, exact=(True, False)) for s in (0, 1)]
    val = [_episode(7)]
    model, record = choose_kinds(plains, priors, val, drive="validation")
    assert record["candidates"] == ["a"] and record["chosen"] == ["a"]
    assert record["val_theta_rmse_prior"][0] < 0.05 * record["val_theta_rmse_plain"][0]
    ep = _episode(9)
    om = free_run_checked(model, ep)
    w = model.window
    np.testing.assert_allclose(om[w:], ep.omega[w:80], atol=1e-4)  # the plant, both joints


def test_when_every_joint_prefers_the_map_the_known_score_is_not_run_again(monkeypatch) -> None:
    """Map-correcting networks exact on both joints: both are candidates; the set of both is
    the map-correcting ensemble, already scored, so only the two single-joint sets run."""
    import excavator_surrogate.training.sets as sets

    runs = []
    real = sets.free_run_error
    monkeypatch.setattr(sets, "free_run_error", lambda *a, **k: runs.append(1) or real(*a, **k))
    plains = [_plain_net(s) for s in (0, 1)]
    priors = [_prior_net(s + 10, exact=(True, True)) for s in (0, 1)]
    model, record = choose_kinds(plains, priors, [_episode(7)], drive="validation")
    assert record["candidates"] == ["a", "b"] and record["chosen"] == ["a", "b"]
    assert len(record["tried"]) == 3 and len(runs) == 2
    assert "ensemble" in model.metrics and model.metrics["ensemble"]["n_member"] == 2


def test_a_short_run_trains_both_kinds_and_records_the_choice(tmp_path: Path) -> None:
    ds = Dataset(spec=SPEC)
    ds.episodes["train"] = TRAIN
    ds.episodes["val"] = [_episode(7)]
    cfg = tiny_train_config(prior_choice=True, members=2, epochs=2, static_map=True, **SMALL)
    best = train(cfg, ds, out=tmp_path / "m", show_progress=False)
    for folder in ("plain/member_0", "plain/member_1", "prior/member_0"):  # 2 plain, 1 prior
        assert (tmp_path / "m" / folder / "best.pt").is_file()
    assert not (tmp_path / "m" / "prior" / "member_1").exists()
    sur = load_checkpoint(best)
    record = sur.metrics["training"]["kinds"]
    assert set(record) >= {"candidates", "chosen", "why", "val_theta_rmse_prior"}
    rows = list(csv.DictReader((tmp_path / "m" / "log.csv").open()))
    assert [r["kind"] for r in rows] == ["plain", "plain", "prior", model_kind(record)]
    assert "kinds" in (tmp_path / "m" / "config.toml").read_text()
    table = choices_markdown(sur.metrics["training"], spec=sur.spec)  # the evaluation's table
    joint_rows = [ln for ln in table.splitlines() if ln.startswith("| ") and "Joint" not in ln]
    assert len(joint_rows) == len(SPEC.names) and all(r.count("**") == 2 for r in joint_rows)
    with pytest.raises(ConfigError, match="prior_choice trains both kinds"):
        tiny_train_config(prior_choice=True, prior=True, members=2)


def test_a_network_that_corrects_a_map_can_put_a_joint_on_a_map() -> None:
    """with_map_joints on a map-correcting network (delays 3 and 5): the picked joint follows
    the new map (delayed: its feature; undelayed: the current command's column), the other
    keeps its output; a delay the features do not carry is refused."""
    net = _prior_net(0, exact=(False, False))
    ep = _episode(9)
    before = _omega(net, ep)
    delayed = fit_prior([_episode(s) for s in range(3)], SPEC, max_delay=5)
    hyb = with_map_joints(net, delayed, [True, False])
    om = _omega(hyb, ep)
    np.testing.assert_allclose(om[:, 1], before[:, 1], atol=1e-5)
    np.testing.assert_allclose(om[3:79, 0], ep.omega[4:80, 0], atol=1e-5)  # s(u[k - 3])
    assert hyb.net.prior.cols.tolist()[0] == hyb.norm.lag_start
    undelayed = fit_prior([_episode(s) for s in range(3)], SPEC)
    hyb0 = with_map_joints(net, undelayed, [True, False])
    assert hyb0.net.prior.cols.tolist()[0] == SPEC.n_angle_feature
    np.testing.assert_allclose(_omega(hyb0, ep)[:, 1], before[:, 1], atol=1e-5)
    bad = {**delayed, "delay": [2, 5]}
    with pytest.raises(ValueError, match="not a feature"):
        with_map_joints(net, bad, [True, False])


def test_what_works_per_network_is_refused_with_the_kind_choice_even_for_one_member(
    tmp_path: Path,
) -> None:
    """One plain member and one map-correcting network are two trainings: a resume or an
    on_epoch hook cannot apply to both, so it is refused, not silently dropped."""
    ds = Dataset(spec=SPEC)
    ds.episodes["train"] = TRAIN
    ds.episodes["val"] = [_episode(7)]
    cfg = tiny_train_config(prior_choice=True, members=1, epochs=1, **SMALL)
    with pytest.raises(ConfigError, match="prior_choice = true: on_epoch works per member"):
        train(cfg, ds, out=tmp_path / "m", on_epoch=lambda *a: False, show_progress=False)
    assert not (tmp_path / "m").exists()


def test_the_margin_decides_where_a_tie_goes() -> None:
    """Map-correcting networks that run exactly as the plain ones (a tie on every joint): the
    default margin keeps the plain networks; a negative margin makes every joint a candidate
    and takes them from the map-correcting networks, whose free run is the same."""
    plains = [_plain_net(s) for s in (0, 1)]
    carrier = _prior_net(10, exact=(False, False))
    priors = [in_prior_form(p, carrier) for p in plains[::-1]]  # no group pairs a net with itself
    val = [_episode(7)]
    model, record = choose_kinds(plains, priors, val, drive="validation")
    assert record["candidates"] == [] and record["chosen"] == [] and record["margin"] == 0.05
    np.testing.assert_allclose(
        record["val_theta_rmse_prior"], record["val_theta_rmse_plain"], rtol=1e-5
    )
    tied, record = choose_kinds(plains, priors, val, drive="validation", margin=-0.05)
    assert record["candidates"] == ["a", "b"] and record["chosen"] == ["a", "b"]
    ep = _episode(9)
    np.testing.assert_allclose(free_run_checked(tied, ep), free_run_checked(model, ep), atol=1e-5)


def test_the_config_bounds_the_margin() -> None:
    with pytest.raises(ConfigError, match="prior_margin"):
        tiny_train_config(prior_margin=1.5)


def _scaled_map(fit: dict, joint: int, factor: float) -> dict:
    """``fit`` with joint ``joint``'s gains times ``factor``."""
    out = {k: list(v) if isinstance(v, list) else v for k, v in fit.items()}
    for k in ("k_pos", "k_neg"):
        out[k][joint] *= factor
    return out


def test_the_blend_drives_a_joint_where_the_kinds_err_in_opposite_ways() -> None:
    """Joint a: the plain networks follow the plant's map 20 % too fast, the map-correcting
    ones 20 % too slow, so neither beats the other and their even blend is the plant; joint b:
    the map-correcting networks are exact.  Without the blend a stays plain; with it, a takes
    the blend and b the map-correcting networks, and the model free-runs as the plant."""
    fit = fit_prior(TRAIN, SPEC, max_delay=5)
    plains = [
        with_map_joints(_plain_net(s), _scaled_map(fit, 0, 1.2), [True, False], lags=(3, 5))
        for s in (0, 1)
    ]
    priors = [_prior_net(s + 10, exact=(True, True)) for s in (0, 1)]
    for b in priors:
        with torch.no_grad():
            b.net.prior.k_pos[0] *= 0.8
            b.net.prior.k_neg[0] *= 0.8
    val = [_episode(7)]
    _, record = choose_kinds(plains, priors, val, drive="validation", blend=False)
    assert record["chosen"] == ["b"] and record["blend"] is False and record["blended"] == []
    model, record = choose_kinds(
        plains, priors, val, drive="validation"
    )  # the default: with the blend
    assert record["chosen"] == ["a", "b"] and record["blended"] == ["a"]
    assert record["weights"] == [0.5, 1.0]
    assert record["val_theta_rmse_blend"][0] < 0.05 * record["val_theta_rmse_plain"][0]
    assert "a from the even blend of both kinds" in record["why"]
    assert model_kind(record) == "composite"
    ep = _episode(9)
    om = free_run_checked(model, ep)
    w = model.window
    np.testing.assert_allclose(om[w:], ep.omega[w:80], atol=1e-4)  # the plant, both joints


def test_what_the_choice_made_the_model() -> None:
    names = ["a", "b"]
    assert model_kind({"names": names, "chosen": []}) == "plain"
    assert model_kind({"names": names, "chosen": names}) == "prior"  # before the blend
    assert model_kind({"names": names, "chosen": names, "blended": []}) == "prior"
    assert model_kind({"names": names, "chosen": names, "blended": ["a"]}) == "composite"
    assert model_kind({"names": names, "chosen": ["a"], "blended": []}) == "composite"


def test_the_config_sets_the_choice_options() -> None:
    cfg = tiny_train_config(prior_margin=-0.05, prior_blend=False, val_steps=50)
    assert choice_options(cfg) == {
        "max_steps": 50,
        "drive": "spanned",
        "margin": -0.05,
        "blend": False,
    }
    assert choice_options(tiny_train_config(val_steps=0))["max_steps"] is None
    assert choice_options(tiny_train_config(prior_drive="validation"))["drive"] == "validation"
    with pytest.raises(ConfigError, match="prior_drive"):
        tiny_train_config(prior_drive="best")


def test_by_default_the_map_correcting_networks_drive_every_spanned_joint() -> None:
    """Plain networks exact on joint b, map-correcting ones exact on joint a: the default drive
    takes both joints from the map-correcting networks whatever validation says (their
    ensemble, merged), records both kinds' validation scores, and compares nothing."""
    fit = fit_prior(TRAIN, SPEC, max_delay=5)
    plains = [with_map_joints(_plain_net(s), fit, [False, True], lags=(3, 5)) for s in (0, 1)]
    priors = [_prior_net(s + 10, exact=(True, False)) for s in (0, 1)]
    val = [_episode(7)]
    model, record = choose_kinds(plains, priors, val)
    assert record["drive"] == "spanned" and record["chosen"] == ["a", "b"]
    assert record["tried"] == [] and record["weights"] == [1.0, 1.0]
    assert model_kind(record) == "prior"
    # b: the plain networks validated better, and were not asked
    assert record["val_theta_rmse_plain"][1] < record["val_theta_rmse_prior"][1]
    ep = _episode(9)
    np.testing.assert_allclose(
        free_run_checked(model, ep), free_run_checked(merge(priors), ep), atol=1e-5
    )
    assert "a, b: validation spans their commands" in record["why"]
    table = choices_markdown({"kinds": record}, spec=SPEC)  # the plain kind: not an option
    rows = [ln for ln in table.splitlines() if ln.startswith("| ") and "Joint" not in ln]
    assert len(rows) == 2 and all(r.split("|")[2].strip().startswith("(") for r in rows)
    assert "not compared" in table and "Close call" not in table


def test_an_unspanned_joint_or_one_with_its_own_inputs_stays_plain_under_the_default_drive() -> (
    None
):
    """The plain networks keep a joint whose validation spans too little of its commands, and
    one that takes exogenous inputs its own way (the twins); the composite is the one of
    those weights, and a model with no spanned joint is the plain ensemble."""
    plains = [_plain_net(s) for s in (0, 1)]
    priors = [_prior_net(s + 10, exact=(True, False)) for s in (0, 1)]
    val = [_episode(7)]
    ep = _episode(9)
    model, record = choose_kinds(plains, priors, val, spanned=[True, False])
    assert record["chosen"] == ["a"] and record["unspanned"] == ["b"]
    assert model_kind(record) == "composite" and "b: validation commands span" in record["why"]
    want = composite(plains, priors, [1.0, 0.0])
    np.testing.assert_allclose(free_run_checked(model, ep), free_run_checked(want, ep), atol=1e-5)
    twins = [_plain_net(s + 20) for s in (0, 1)]
    model, record = choose_kinds(plains, priors, val, twins=twins, twin_joints=[False, True])
    assert record["chosen"] == ["a"] and record["own_inputs"] == ["b"]
    want = composite(plains, priors, [1.0, 0.0], twins=twins, twin_joints=[False, True])
    np.testing.assert_allclose(free_run_checked(model, ep), free_run_checked(want, ep), atol=1e-5)
    model, record = choose_kinds(plains, priors, val, spanned=[False, False])
    assert record["chosen"] == [] and model_kind(record) == "plain"
    np.testing.assert_allclose(
        free_run_checked(model, ep), free_run_checked(merge(plains), ep), atol=1e-5
    )


def test_joints_the_static_map_will_pin_are_found_before_the_kind_choice() -> None:
    """On this plant the delayed map is exact, so in parallel the static map choice pins both
    joints (in series neither: they are not periodic); the kind choice records the joints it
    was told cannot refuse a set."""
    val = [_episode(7)]
    net = _plain_net(0)
    cfg = tiny_train_config(static_map=True, map_parallel=True, val_steps=0, **SMALL)
    assert map_pinned(cfg, net, TRAIN, val) == [True, True]
    for off in (
        {"map_parallel": False},
        {"prior_skip_pinned": False},
        {"static_map": False},
        {"map_periodic": False},
    ):
        assert map_pinned(dataclasses.replace(cfg, **off), net, TRAIN, val) is None
    # only the validation rule reads the pinned joints: the span rule does not pay for them
    validation = choice_joints(dataclasses.replace(cfg, prior_drive="validation"), net, TRAIN, val)
    assert validation["pinned"] == [True, True]
    spanned = choice_joints(cfg, net, TRAIN, val)
    assert spanned["pinned"] is None and spanned["spanned"] == validation["spanned"]
    plains = [_plain_net(s) for s in (0, 1)]
    priors = [_prior_net(s + 10, exact=(True, False)) for s in (0, 1)]
    _, record = choose_kinds(plains, priors, val, drive="validation", pinned=[False, True])
    assert record["pinned"] == ["b"]
    _, record = choose_kinds(plains, priors, val, drive="validation")
    assert record["pinned"] == []


def test_the_card_of_a_composite_names_its_members_as_compositions(tmp_path) -> None:
    from excavator_surrogate.evaluate.card import card_markdown, model_card
    from excavator_surrogate.surrogate.checkpoint import save_checkpoint

    plains = [_plain_net(s) for s in (0, 1, 2, 3)]
    priors = [_prior_net(s + 10, exact=(False, False)) for s in (0, 1)]
    model = composite(plains, priors, [0.5, 0.0])
    model.metrics["training"] = {"epochs_planned": 4, "members": [{"epochs_done": 4}] * 6}
    card = model_card(save_checkpoint(tmp_path / "c.pt", model))
    net = card["network"]
    assert net["composite"] and net["n_member"] == 2 and net["n_trained"] == 6
    text = card_markdown(card)
    assert (
        "- 2 composite LSTM members of 24 units each, each joining per joint networks of " in text
    )
    assert "the 6 trained (plain and map-correcting, weighted by the kind choice)" in text
    assert "members are compositions of the trained networks" in text
    assert "| Member | Seed |" not in text  # no seed or epoch of their own to list
    plain = model_card(save_checkpoint(tmp_path / "p.pt", merge(plains[:2])))
    assert not plain["network"]["composite"]
    assert "An ensemble of 2 LSTM networks" in card_markdown(plain)
