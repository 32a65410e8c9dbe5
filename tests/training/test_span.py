"""How much of the training's command range validation spans, and the choices it allows."""

from __future__ import annotations

import numpy as np
import pytest

from excavator_surrogate.data import Dataset
from excavator_surrogate.data.episode import Episode
from excavator_surrogate.training.auto import auto_config
from excavator_surrogate.training.kinds import choose_kinds
from excavator_surrogate.training.map_joints import choose_map_joints, pinned_joints
from excavator_surrogate.training.span import command_span, joint_spans, span_note
from tests.helpers.surrogates import tiny_surrogate
from tests.surrogate.test_prior import _static_episode
from tests.surrogate.test_structured import SPEC, TRUTH

TRAIN = [_static_episode(s) for s in range(3)]  # random holds over the whole range


def _held(levels: list[tuple[float, float]], *, hold: int = 40, name: str = "v") -> Episode:
    """Runs of the delay-free plant through holds of ``(u_a, u_b)``, each ``hold`` samples,
    with a rest between them (a step test's validation)."""
    u = np.concatenate([np.array([[0.0, 0.0]] * hold + [lv] * hold) for lv in levels])
    theta = np.zeros_like(u)
    for t in range(len(u) - 1):
        theta[t + 1] = theta[t] + SPEC.dt * np.array(
            [f.speed(u[t, j]) for j, f in enumerate(TRUTH)]
        )
    omega = np.vstack([np.zeros((1, 2)), np.diff(theta, axis=0) / SPEC.dt])
    return Episode(
        spec=SPEC, time=np.arange(len(u)) * SPEC.dt, u=u, theta=theta, omega=omega, name=name
    )


# validation at one command level either way, a little beyond the dead zones (160 / -200
# and 100 / -100): h1-dev's shape, every validation run at 50 % duty
LOW = [_held([(400.0, 400.0), (-400.0, -400.0)])]


def _span_by_hand(train, val, j: int, a_pos: float, a_neg: float) -> float:
    u_t = np.concatenate([e.u[:, j] for e in train])
    u_v = np.concatenate([e.u[:, j] for e in val])
    out = []
    for sign, edge in ((1, a_pos), (-1, -a_neg)):
        t, v = sign * u_t, sign * u_v
        t, v = t[t > edge], v[v > edge]
        out.append((np.percentile(v, 99) - edge) / (np.percentile(t, 99) - edge))
    return min(1.0, *out)


def test_the_span_is_the_reach_of_validation_beyond_the_dead_zone_in_the_weaker_direction():
    spans = command_span(TRAIN, LOW, SPEC)
    for j, f in enumerate(TRUTH):  # the fit finds the plant's dead zones exactly
        assert spans[j] == pytest.approx(_span_by_hand(TRAIN, LOW, j, f.a_pos, f.a_neg))
    assert all(0.2 < s < 0.5 for s in spans)  # (400 - 160) / (~990 - 160) = 0.29, ...
    full = command_span(TRAIN, [_static_episode(s) for s in (7, 8)], SPEC)
    assert all(s > 0.9 for s in full)
    # one direction never reached by validation: nothing of it is covered
    up_only = [_held([(400.0, 900.0)])]
    assert command_span(TRAIN, up_only, SPEC) == [0.0, 0.0]
    # a direction the training never drives needs no cover
    pushed = [_held([(900.0, 900.0)] * 3)]
    assert command_span(pushed, [_held([(900.0, 900.0)])], SPEC) == [1.0, 1.0]


def test_joint_spans_and_its_note():
    spans, spanned = joint_spans(TRAIN, LOW, SPEC, min_span=0.5)
    assert spans == command_span(TRAIN, LOW, SPEC) and spanned == [False, False]
    assert joint_spans(TRAIN, LOW, SPEC, min_span=0.0) == (None, [True, True])
    note = span_note(spans, SPEC, min_span=0.5)
    assert note.startswith("a ") and ", b " in note and note.endswith(" %")
    assert span_note([0.9, 0.2], SPEC, min_span=0.5) == "b 20 %"


def test_the_map_is_no_candidate_where_validation_spans_too_little():
    """The plant is the map: on validation that spans the range it is chosen (the map
    choice's own test); at one low command level the network keeps every joint, and the
    record says why.  With min_span = 0 the map wins there too."""
    net = tiny_surrogate(SPEC, mode="stateful", window=6, seed=3)
    new, rec = choose_map_joints(net, TRAIN, LOW)
    assert new is None and rec["chosen"] == [] and rec["candidates"] == []
    assert rec["unspanned"] == ["a", "b"] and rec["min_span"] == 0.5
    assert "command range" in rec["why"] and "no joint follows the map" in rec["why"]
    assert pinned_joints(net, TRAIN, LOW, parallel=True) == [False, False]
    anyway, rec0 = choose_map_joints(net, TRAIN, LOW, min_span=0.0)
    assert anyway is not None and rec0["chosen"] == ["a", "b"] and rec0["span"] is None
    assert pinned_joints(net, TRAIN, LOW, parallel=True, min_span=0.0) == [True, True]


def test_an_unspanned_joint_stays_with_the_plain_networks_in_the_kind_choice():
    """test_kinds' setup: the map-correcting networks are exact on joint a and win it; told
    that validation does not span a, the choice keeps it plain and says so."""
    from tests.training.test_kinds import _episode, _plain_net, _prior_net

    plains = [_plain_net(s) for s in (0, 1)]
    priors = [_prior_net(s + 10, exact=(True, False)) for s in (0, 1)]
    val = [_episode(7)]
    _, record = choose_kinds(plains, priors, val, drive="validation")
    assert "a" in record["chosen"] and record["unspanned"] == []
    _, record = choose_kinds(plains, priors, val, drive="validation", spanned=[False, True])
    assert "a" not in record["chosen"] and record["unspanned"] == ["a"]


def test_the_recipe_trains_plain_members_when_validation_spans_no_joint():
    """A step test validated at one low duty: no map-correcting networks, the budget goes
    to plain members, and the recipe says why; validation over the range keeps the kinds."""
    low = Dataset(spec=SPEC)
    low.episodes["train"] = list(TRAIN)
    low.episodes["val"] = list(LOW)
    cfg, why = auto_config(low, cpus=2)
    assert not cfg.prior_choice and cfg.static_map
    assert any("one kind of network (plain): validation commands a " in w for w in why)
    wide = Dataset(spec=SPEC)
    wide.episodes["train"] = list(TRAIN)
    wide.episodes["val"] = [_static_episode(7)]
    kinds, _ = auto_config(wide, cpus=2)
    assert kinds.prior_choice and kinds.members <= cfg.members
    forced, _ = auto_config(low, cpus=2, overrides={"prior_choice": True})
    assert forced.prior_choice
    off, _ = auto_config(low, cpus=2, overrides={"choice_min_span": 0.0})
    assert off.prior_choice


def test_validation_at_one_command_level_averages_the_selected_epoch_with_the_last():
    """Many validation runs at one low duty (h1-dev's shape) cannot pick the epoch for the
    other duties alone: the recipe averages it with the last and says why; validation over
    the range, or one short segment, keeps the selected epoch, and an override wins."""
    from excavator_surrogate.training.auto import SHORT_VAL_EPISODES

    low = Dataset(spec=SPEC)
    low.episodes["train"] = list(TRAIN)
    low.episodes["val"] = [
        _held([(400.0, 400.0), (-400.0, -400.0)], name=f"v{i}") for i in range(SHORT_VAL_EPISODES)
    ]
    cfg, why = auto_config(low, cpus=2, overrides={"train_on_val": False})
    assert cfg.average_last
    assert any("averaged with the last epoch's" in w for w in why)
    # trained on validation too (the recipe's default there): the last epoch is the selected one
    cfg, why = auto_config(low, cpus=2)
    assert cfg.average_last and cfg.train_on_val
    assert any("averaged with the raw weights" in w for w in why)
    wide = Dataset(spec=SPEC)
    wide.episodes["train"] = list(TRAIN)
    wide.episodes["val"] = [_static_episode(7 + i) for i in range(SHORT_VAL_EPISODES)]
    cfg, why = auto_config(wide, cpus=2)
    assert not cfg.average_last and not any("averaged with" in w for w in why)
    short = Dataset(spec=SPEC)
    short.episodes["train"] = list(TRAIN)
    short.episodes["val"] = list(LOW)  # one segment: the short split's rule alone
    assert not auto_config(short, cpus=2)[0].average_last
    off, why = auto_config(low, cpus=2, overrides={"average_last": False})
    assert not off.average_last and not any("averaged with" in w for w in why)


def test_validation_at_one_command_level_is_trained_on_too():
    """Validation runs at one command level vouch for no other command, so they only rank the
    epochs: the recipe trains on them too, counts their sub-sequences in the plan and says
    so; validation over the range, or one short segment, is not trained on, and an override
    wins."""
    from excavator_surrogate.training.auto import SHORT_VAL_EPISODES
    from excavator_surrogate.training.batches import split_episodes

    low = Dataset(spec=SPEC)
    low.episodes["train"] = list(TRAIN)
    low.episodes["val"] = [
        _held([(400.0, 400.0), (-400.0, -400.0)], name=f"v{i}") for i in range(SHORT_VAL_EPISODES)
    ]
    cfg, why = auto_config(low, cpus=2)
    assert cfg.train_on_val
    assert any(f"the {SHORT_VAL_EPISODES} validation episodes are trained on too" in w for w in why)
    train_eps, val_eps = split_episodes(cfg, low)
    assert [e.name for e in val_eps] == [e.name for e in low.val]
    assert [e.name for e in train_eps] == [e.name for e in low.train + low.val]
    off, why_off = auto_config(low, cpus=2, overrides={"train_on_val": False})
    assert not off.train_on_val and not any("trained on too" in w for w in why_off)
    assert [e.name for e in split_episodes(off, low)[0]] == [e.name for e in low.train]

    def planned(w: list[str]) -> int:  # sub-sequences per epoch, from the plan's line
        (line,) = [x for x in w if "sub-sequences per epoch" in x]
        return int(line.split(": ")[1].split(" sub-sequences")[0])

    assert planned(why) > planned(why_off)
    wide = Dataset(spec=SPEC)
    wide.episodes["train"] = list(TRAIN)
    wide.episodes["val"] = [_static_episode(7 + i) for i in range(SHORT_VAL_EPISODES)]
    assert not auto_config(wide, cpus=2)[0].train_on_val
    short = Dataset(spec=SPEC)
    short.episodes["train"] = list(TRAIN)
    short.episodes["val"] = list(LOW)  # one segment: the short split's rule alone
    assert not auto_config(short, cpus=2)[0].train_on_val
    # a choice made on validation (the kinds, forced; the exogenous inputs) keeps validation
    # out of training: in-sample scores would choose
    assert not auto_config(low, cpus=2, overrides={"prior_choice": True})[0].train_on_val
    from tests.surrogate.test_auto import _with_gear

    # an exogenous input that changes: at one command level validation vouches for no input
    # either, so it is ignored without a trial and the plan is the one without it
    geared, why_g = auto_config(_with_gear(low), cpus=2)
    assert geared.exogenous == "ignore" and geared.average_last and geared.train_on_val
    for name in ("members", "epochs", "max_train_seconds", "prior_choice", "train_on_val"):
        assert getattr(geared, name) == getattr(cfg, name), name
    assert any("gear ignored without a trial" in w and "one command level" in w for w in why_g)
    assert not any("must not hurt" in w for w in why_g)
    tried, why_t = auto_config(_with_gear(low), cpus=2, overrides={"exogenous": "choose"})
    assert tried.exogenous == "choose" and tried.average_last and not tried.train_on_val
    assert any("must not hurt" in w for w in why_t)
    assert not any("ignored without a trial" in w for w in why_t)


def test_an_input_is_tried_only_where_the_plain_networks_drive_a_joint():
    """Validation spans a's commands and holds b at one low level: the map-correcting
    networks will drive a, the plain ones b, so the gear is tried.  Spanning both, the
    map-correcting networks drive every joint and never read an input chosen on
    validation: the gear is ignored without a trial, with the plan without it."""
    from excavator_surrogate.training.auto import SHORT_VAL_EPISODES
    from tests.surrogate.test_auto import _with_gear, unread_gear_is_untried

    def data(val: list[Episode]) -> Dataset:
        ds = Dataset(spec=SPEC)
        ds.episodes["train"] = list(TRAIN)
        ds.episodes["val"] = val
        return ds

    levels = [(900.0, 400.0), (-900.0, -400.0), (600.0, 400.0), (-600.0, -400.0)]
    mixed = data([_held(levels, name=f"v{i}") for i in range(SHORT_VAL_EPISODES)])
    assert joint_spans(mixed.train, mixed.val, SPEC, min_span=0.5)[1] == [True, False]
    cfg, why = auto_config(_with_gear(mixed), cpus=2)
    assert cfg.exogenous == "choose" and cfg.prior_choice
    assert any("must not hurt" in w and "ignore them, whichever way wins" in w for w in why)
    wide = data([_static_episode(7 + i) for i in range(SHORT_VAL_EPISODES)])
    assert joint_spans(wide.train, wide.val, SPEC, min_span=0.5)[1] == [True, True]
    unread_gear_is_untried(wide)
    # the kinds chosen on validation: the plain networks may drive either joint, so tried
    tried, _ = auto_config(_with_gear(wide), cpus=2, overrides={"prior_drive": "validation"})
    assert tried.exogenous == "choose"


def test_validation_too_short_to_train_on_still_scores():
    """A validation episode shorter than a training sub-sequence is scored, not trained on."""
    from excavator_surrogate.training.batches import split_episodes
    from tests.helpers.training import tiny_train_config

    ds = Dataset(spec=SPEC)
    ds.episodes["train"] = list(TRAIN)
    ds.episodes["val"] = [LOW[0], LOW[0].slice(0, 40).replace(name="short")]
    cfg = tiny_train_config(train_on_val=True, mode="stateful", seq_len=60, window=10)
    train_eps, val_eps = split_episodes(cfg, ds)
    assert [e.name for e in val_eps] == ["v", "short"]
    assert [e.name for e in train_eps] == [e.name for e in TRAIN] + ["v"]
