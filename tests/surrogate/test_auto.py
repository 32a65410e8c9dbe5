"""``exsur train DATASET`` without a preset: the recipe follows the data."""

from __future__ import annotations

import numpy as np
import pytest

from excavator_surrogate.data import Dataset
from excavator_surrogate.errors import ConfigError, DataError
from excavator_surrogate.surrogate.synthetic import synthetic_episode, synthetic_spec
from excavator_surrogate.training.auto import WINDOW, auto_config, held_inputs
from excavator_surrogate.training.batches import split_episodes as _episodes
from excavator_surrogate.training.plan import POST_SHARE


def _dataset(lengths: list[int], *, val_n_step: int = 200) -> Dataset:
    spec = synthetic_spec(3)
    ds = Dataset(spec=spec)
    for i, n in enumerate(lengths):
        ds.episodes["train"].append(synthetic_episode(spec, kind="step", n_step=n, seed=i))
    ds.episodes["val"].append(synthetic_episode(spec, kind="step", n_step=val_n_step, seed=99))
    return ds


LONG_VAL = 2000
"""The long log's validation segment [samples]: 100 s at 20 Hz, as the continuous case's."""


def _long_log() -> Dataset:
    """One 400-s log at 20 Hz validated on the next 100 s: its planned epochs fill the
    fewest members' budget (the continuous case's shape)."""
    return _dataset([8000], val_n_step=LONG_VAL)


def test_short_runs_that_end_at_a_stop_are_all_trained_on():
    # the h1 shape: many runs of 110-2000 samples
    ds = _dataset([110, 115, 150, 300, 600, 2000])
    cfg, why = auto_config(ds, cpus=2)
    assert cfg.window == WINDOW and cfg.burn_in == WINDOW
    assert cfg.seq_len + 1 <= 110
    train_eps, _ = _episodes(cfg, ds)
    assert len(train_eps) == len(ds.train)
    assert any("none is left out" in w for w in why)


def test_long_episodes_use_the_longest_sequence_and_very_short_ones_shrink_the_window():
    cfg, _ = auto_config(_dataset([3000, 3000]), cpus=2)
    assert cfg.seq_len == 150
    cfg, why = auto_config(_dataset([40, 45, 50]), cpus=2)
    assert cfg.window < WINDOW and cfg.seq_len + 1 <= 40
    assert len(_episodes(cfg, _dataset([40, 45, 50]))[0]) == 3
    assert any("shortest runs" in w for w in why)


def test_members_and_budget_follow_the_cpus():
    ds = _long_log()  # one long log: its planned epochs fill the fewest members' budget
    two, _ = auto_config(ds, cpus=2, budget_s=600)
    one, _ = auto_config(ds, cpus=1, budget_s=600)
    # 4 plain members and 2 map-correcting networks, 2 at a time: 600 s x 2 / 6, less the
    # share held back for the choices after training
    rest = 1 - POST_SHARE
    assert (two.members, two.member_workers) == (4, 2)
    assert two.max_train_seconds == pytest.approx(200 * rest)
    # 2 plain and 1 map-correcting network, one at a time: 600 s / 3
    assert (one.members, one.member_workers) == (2, 1)
    assert one.max_train_seconds == pytest.approx(200 * rest)
    plain, _ = auto_config(ds, cpus=2, budget_s=600, overrides={"prior_choice": False})
    assert plain.members == 4 and plain.max_train_seconds == pytest.approx(300 * rest)


def test_cheap_epochs_buy_more_members_within_the_budget():
    """Members beyond MEMBERS are planned only where a computer MEMBER_HEADROOM times slower
    than the reference still trains each whole within its cap: the h1 shape's planned epochs
    (about TARGET_PASSES passes) fit 6 of them in 1000 s (8 would leave such a computer
    short), 8 in a larger budget, and MEMBERS in the default 600 s."""
    from excavator_surrogate.training.plan import (
        MAX_MEMBERS,
        MEMBER_HEADROOM,
        MEMBERS,
        PLAN_SHARE,
        count_sequences,
        epoch_cost_s,
    )

    many = _dataset([600] * 100)  # the h1 shape: many short runs, cheap epochs
    plain = {"prior_choice": False}  # the plain ensemble alone
    budget = 1000
    cfg, why = auto_config(many, cpus=2, budget_s=budget, overrides=plain)
    assert (cfg.members, cfg.member_workers) == (6, 2)
    share = budget * 2 / 6
    assert cfg.max_train_seconds == pytest.approx((1 - POST_SHARE) * share)
    n_seq = count_sequences(np.array([600] * 100), seq_len=cfg.seq_len, burn_in=cfg.burn_in)
    cost = epoch_cost_s(n_seq, seq_len=cfg.seq_len, seq_batch=cfg.seq_batch, val_steps=200)
    member_s = cfg.epochs * cost
    assert MEMBER_HEADROOM * member_s <= cfg.max_train_seconds  # whole, twice as slow
    # 8 members would fit the reference machine's plan, but not a computer twice as slow
    eight = budget * 2 / MAX_MEMBERS
    assert member_s <= PLAN_SHARE * eight < MEMBER_HEADROOM * member_s / (1 - POST_SHARE)
    assert any("as many members as the budget fits" in w for w in why)
    big, _ = auto_config(many, cpus=2, budget_s=1500, overrides=plain)
    assert big.members == MAX_MEMBERS and big.epochs == cfg.epochs
    one, _ = auto_config(many, cpus=1, budget_s=2000, overrides=plain)
    assert one.members == MAX_MEMBERS // 2
    # a smaller budget fits fewer members at the same planned epochs, never fewer than MEMBERS
    tight, _ = auto_config(many, cpus=2, budget_s=600, overrides=plain)
    assert tight.members == MEMBERS and tight.epochs == cfg.epochs
    assert auto_config(many, cpus=2, budget_s=10)[0].members == MEMBERS
    # the recipe's kind choice: a third more trainings per member, so fewer members fit
    kinds, _ = auto_config(many, cpus=2, budget_s=1500)
    assert kinds.prior_choice and MEMBERS <= kinds.members < big.members
    given, why = auto_config(many, cpus=2, overrides={"members": 3})
    assert given.members == 3 and not any("as many members" in w for w in why)


def test_overrides_are_strict():
    ds = _dataset([300, 300])
    cfg, why = auto_config(ds, overrides={"members": 1, "seed": 7}, cpus=2)
    assert (cfg.members, cfg.seed) == (1, 7) and "overridden" in why[-1]
    with pytest.raises(ConfigError, match="hiden"):
        auto_config(ds, overrides={"hiden": 3})


def test_no_training_episode_is_a_data_error():
    ds = _dataset([300])
    ds.episodes["train"] = []
    with pytest.raises(DataError, match="no training episodes"):
        auto_config(ds)


def test_recipe_reasons_are_written_next_to_the_config_once(tmp_path):
    import tomllib

    from excavator_surrogate.training import train

    ds = _dataset([120, 130])
    cfg, why = auto_config(ds, overrides={"members": 1, "epochs": 1, "hidden": 8}, cpus=1)
    from excavator_surrogate.training.auto import recipe_table

    train(cfg, ds, out=tmp_path, show_progress=False, notes={"recipe": recipe_table(why)})
    written = tomllib.loads((tmp_path / "config.toml").read_text())
    assert written["train"]["hidden"] == 8 and written["train"]["seq_len"] == cfg.seq_len
    assert written["recipe"] == recipe_table(why) and written["recipe"]


def test_the_amount_of_training_follows_the_data_and_the_budget_not_the_clock():
    from excavator_surrogate.training.plan import (
        MIN_EPOCHS,
        PLAN_SHARE,
        count_sequences,
        epoch_cost_s,
    )

    many = _dataset([600] * 150)  # many runs (600 sub-sequences): the floor of epochs
    cfg, why = auto_config(many, cpus=2)
    assert cfg.epochs == cfg.patience == MIN_EPOCHS
    assert any("epochs planned" in w for w in why)
    one = _long_log()  # one continuous log: more passes, within the budget
    cfg1, _ = auto_config(one, cpus=2)
    assert cfg1.epochs > MIN_EPOCHS
    lengths = np.array([e.n_step for e in one.train])
    n_seq = count_sequences(lengths, seq_len=cfg1.seq_len, burn_in=cfg1.burn_in)
    cost = epoch_cost_s(n_seq, seq_len=cfg1.seq_len, seq_batch=cfg1.seq_batch, val_steps=LONG_VAL)
    assert cfg1.epochs * cost <= PLAN_SHARE * cfg1.max_train_seconds / (1 - POST_SHARE) + cost
    small, _ = auto_config(one, cpus=2, overrides={"max_train_seconds": 60})
    assert small.epochs < cfg1.epochs and small.max_train_seconds == pytest.approx(
        20 * (1 - POST_SHARE)
    )  # 60 s for 4 members and 2 map-correcting networks, 2 at a time
    assert auto_config(one, cpus=2)[0] == cfg1  # planned from the data: the same every time


def test_a_short_log_plans_fewer_epochs_than_its_budget_fits():
    """160 s of training (the wheel loader's 7-minute log): at most EPOCHS_PER_SEQUENCE epochs
    per sub-sequence, where the budget would fit more (89 with the 4 + 2 networks it plans);
    longer data and many runs plan as before."""
    from excavator_surrogate.training.plan import (
        EPOCHS_PER_SEQUENCE,
        MIN_EPOCHS,
        PLAN_SHARE,
        count_sequences,
        epoch_cost_s,
        want_epochs,
    )

    short = _dataset([3200], val_n_step=LONG_VAL)
    cfg, why = auto_config(short, cpus=2, budget_s=600)
    lengths = np.array([e.n_step for e in short.train])
    n_seq = count_sequences(lengths, seq_len=cfg.seq_len, burn_in=cfg.burn_in)
    assert n_seq == 26 and cfg.epochs == cfg.patience == int(EPOCHS_PER_SEQUENCE * n_seq) == 45
    assert any("45 epochs planned" in w and "per sub-sequence" in w for w in why)
    cost = epoch_cost_s(n_seq, seq_len=cfg.seq_len, seq_batch=cfg.seq_batch, val_steps=LONG_VAL)
    share = cfg.max_train_seconds / (1 - POST_SHARE)
    assert int(PLAN_SHARE * share / cost) > cfg.epochs  # the budget is not what limits it
    # the rule sits between the floor and the passes: it binds on short logs only
    assert want_epochs(26) == 45 and want_epochs(55) == 96 and want_epochs(557) == 54
    assert want_epochs(10) == MIN_EPOCHS  # a few sub-sequences still train the floor
    assert want_epochs(750) == MIN_EPOCHS < want_epochs(749)  # and very many: 30,000 passes
    assert max(want_epochs(n) for n in range(1, 5000)) == want_epochs(131) == 229  # the most
    longer, why = auto_config(_long_log(), cpus=2, budget_s=600)
    assert longer.epochs > 45 and not any("per sub-sequence" in w for w in why)


def test_max_seconds_zero_plans_for_the_default_budget_without_a_cap():
    cfg, _ = auto_config(_dataset([300, 300]), cpus=2, overrides={"max_train_seconds": 0})
    assert cfg.max_train_seconds == 0 and cfg.epochs >= 1
    with pytest.raises(ConfigError, match="max_train_seconds"):
        auto_config(_dataset([300, 300]), cpus=2, overrides={"max_train_seconds": -1})


def test_selection_is_sound_on_a_short_validation_split_and_unchanged_on_many_runs():
    from excavator_surrogate.training.auto import SELECT_AFTER, SELECT_SMOOTH, SHORT_VAL_EPISODES

    one_segment = _long_log()  # a continuous log: one validation segment
    cfg, why = auto_config(one_segment, cpus=2)
    assert (cfg.select_after, cfg.select_smooth) == (SELECT_AFTER, SELECT_SMOOTH)
    assert any("(short)" in w for w in why)
    many = _dataset([600] * 20)  # the h1 shape: many validation runs
    many.episodes["val"] = [
        synthetic_episode(many.spec, kind="step", n_step=200, seed=90 + i)
        for i in range(SHORT_VAL_EPISODES)
    ]
    cfg, why = auto_config(many, cpus=2)
    assert (cfg.select_after, cfg.select_smooth) == (0.0, 0)  # as before
    assert not any("(short)" in w for w in why)
    # a validation run too short to free-run after the warm-up is skipped in training, so
    # it does not count here either: the runs left are a short split
    many.episodes["val"][0] = synthetic_episode(many.spec, kind="step", n_step=WINDOW, seed=89)
    assert len(_episodes(cfg, many)[1]) == SHORT_VAL_EPISODES - 1
    cfg, why = auto_config(many, cpus=2)
    assert (cfg.select_after, cfg.select_smooth) == (SELECT_AFTER, SELECT_SMOOTH)
    assert any(f"selection on {SHORT_VAL_EPISODES - 1} validation" in w for w in why)


def _with_gear(plain: Dataset, *, held: bool = False) -> Dataset:
    """``plain`` with an exogenous input column (``gear``: -1 / +1 by turns of 40 samples,
    or 1 throughout with ``held``)."""
    from dataclasses import replace

    from excavator_surrogate.spec import InputSpec

    spec = replace(plain.spec, inputs=(InputSpec("gear", u_min=-1.0, u_max=1.0),))
    ds = Dataset(spec=spec)
    for split, eps in plain.episodes.items():
        ds.episodes[split] = [
            e.replace(spec=spec, u=np.concatenate([e.u, _gear(e.n_step, held)], axis=1))
            for e in eps
        ]
    return ds


def _gear(n_step: int, held: bool) -> np.ndarray:
    if held:
        return np.ones((n_step, 1))
    return np.where(np.arange(n_step) // 40 % 2 == 0, -1.0, 1.0)[:, None]


def test_an_input_that_never_changes_in_training_is_ignored_without_a_trial():
    """A gear never shifted: the run ignores it and plans as without the column."""
    plain = _long_log()
    without, _ = auto_config(plain, cpus=2)
    cfg, why = auto_config(_with_gear(plain, held=True), cpus=2)
    assert cfg.exogenous == "ignore"
    for name in ("members", "epochs", "max_train_seconds", "prior_choice"):
        assert getattr(cfg, name) == getattr(without, name), name
    assert any("gear = 1 never change" in w and "without a trial" in w for w in why)
    assert not any("must not hurt" in w for w in why)
    assert held_inputs(_with_gear(plain, held=True)) == {"gear": 1.0}
    assert held_inputs(_with_gear(plain)) == {}


def unread_gear_is_untried(plain: Dataset) -> None:
    """A gear on ``plain``, whose validation spans every joint, is ignored without a trial,
    with the plan of the run without it."""
    without, _ = auto_config(plain, cpus=2)
    cfg, why = auto_config(_with_gear(plain), cpus=2)
    assert cfg.exogenous == "ignore" and cfg.prior_choice
    for name in ("members", "epochs", "max_train_seconds", "train_on_val", "average_last"):
        assert getattr(cfg, name) == getattr(without, name), name
    assert any("gear ignored without a trial" in w and "drive every joint" in w for w in why)
    assert not any("must not hurt" in w for w in why)


def test_an_input_nothing_would_read_is_ignored_without_a_trial():
    """Validation spans every joint's commands: the map-correcting networks drive them all
    and never read an input chosen on validation, so the run ignores the gear without a
    trial and plans as without the column; ``exogenous = "choose"`` still tries it."""
    plain = _long_log()
    unread_gear_is_untried(plain)
    tried, why = auto_config(_with_gear(plain), cpus=2, overrides={"exogenous": "choose"})
    assert tried.exogenous == "choose" and any("must not hurt" in w for w in why)
    assert not any("ignored without a trial" in w for w in why)


def test_exogenous_inputs_are_chosen_on_validation_within_the_same_budget():
    """Where the plain networks may drive a joint (here: the kinds chosen on validation), the
    gear is tried."""
    plain = _long_log()
    without, _ = auto_config(plain, cpus=2)
    assert without.exogenous == "use"  # nothing to choose
    ds = _with_gear(plain)
    cfg, why = auto_config(ds, cpus=2, overrides={"prior_drive": "validation"})
    assert cfg.exogenous == "choose" and cfg.members == without.members == 4
    # the input choice and the kind choice: 4 members + 2 that ignore the inputs + 2
    # map-correcting networks share the budget: 540 s x 2 workers / 8 trainings
    assert cfg.input_dropout == 0.0
    assert cfg.prior_choice and not any("one kind of network" in w for w in why)
    assert cfg.max_train_seconds == pytest.approx(135 * (1 - POST_SHARE))
    assert any("must not hurt" in w and "8 trainings" in w for w in why)
    dual, why = auto_config(
        ds, cpus=2, overrides={"input_dropout": 0.5, "prior_drive": "validation"}
    )
    # every network learning both ways (dual.py), the choice costs no training: the plan
    # is the one without inputs (4 members + 2 map-correcting networks)
    assert dual.input_dropout == 0.5 and dual.exogenous == "choose"
    for name in ("members", "epochs", "max_train_seconds"):
        assert getattr(dual, name) == getattr(without, name), name
    assert any("must not hurt" in w and "no training is spent" in w for w in why)
    assert any("some joints only" in w for w in why)
    alone, why = auto_config(ds, cpus=2, overrides={"prior_choice": False})
    # the input choice alone: 4 members + 2 that ignore the inputs, 540 s x 2 / 6; and
    # there the inputs may go to some joints only
    assert not alone.prior_choice
    assert alone.max_train_seconds == pytest.approx(180 * (1 - POST_SHARE))
    assert any("some joints only" in w for w in why)
    forced, _ = auto_config(ds, cpus=2, overrides={"exogenous": "use"})
    # using the inputs outright, the run chooses the kinds instead, as without inputs
    assert forced.exogenous == "use" and forced.prior_choice
    assert forced.max_train_seconds == without.max_train_seconds


def test_the_input_choice_costs_two_trainings_however_many_members():
    """The choice's probe is 2 networks per way: a many-run log (8 members without inputs, in
    a 1200-s budget) keeps 6 with them, in the same 4 rounds of two (before: half the members
    each way, so 4 members in 3 rounds)."""
    plain = _dataset([110] * 119)
    plain.episodes["val"] = [
        synthetic_episode(plain.spec, kind="step", n_step=200, seed=900 + i) for i in range(6)
    ]
    over = {"prior_choice": False, "max_train_seconds": 1200}
    without, _ = auto_config(plain, cpus=2, overrides=over)
    ds = _with_gear(plain)
    cfg, why = auto_config(ds, cpus=2, overrides=over)
    assert (without.members, cfg.members) == (8, 6)
    assert cfg.max_train_seconds == without.max_train_seconds  # 8 trainings, 4 rounds
    assert any("2 member(s) use them and 2 ignore them" in w and "8 trainings" in w for w in why)
    dual, _ = auto_config(ds, cpus=2, overrides={**over, "input_dropout": 0.5})  # no probe
    assert dual.members == 8 and dual.max_train_seconds == without.max_train_seconds


def test_the_kind_choice_is_the_recipes_and_is_planned_within_the_same_budget():
    """prior_choice (the recipe's where validation spans a joint's commands): 4 plain members and 2
    map-correcting networks share the budget; off, the 4 plain members have it alone."""
    ds = _long_log()
    cfg, why = auto_config(ds, cpus=2)
    without, why_not = auto_config(ds, cpus=2, overrides={"prior_choice": False})
    assert cfg.prior_choice and not without.prior_choice
    assert cfg.members == without.members == 4
    assert cfg.max_train_seconds == pytest.approx(540 * 2 / 6 * (1 - POST_SHARE))
    assert cfg.epochs < without.epochs
    assert any("2 correct the static valve map" in w and "6 trainings" in w for w in why)
    assert not any("two kinds" in w for w in why_not)


def test_periodic_joints_are_turned_and_the_static_map_competes():
    """A swing (periodic joint) gets random offsets in training; without one nothing turns;
    the static map is a candidate either way."""

    def data(periodic: bool) -> Dataset:
        spec = synthetic_spec(3, periodic_first=periodic)
        ds = Dataset(spec=spec)
        ds.episodes["train"] += [
            synthetic_episode(spec, kind="step", n_step=300, seed=i) for i in (0, 1)
        ]
        ds.episodes["val"].append(synthetic_episode(spec, kind="step", n_step=200, seed=9))
        return ds

    cfg, why = auto_config(data(False), cpus=2)
    assert not cfg.periodic_offsets and cfg.static_map
    assert not any("random offset" in w for w in why)
    ds = data(True)
    cfg, why = auto_config(ds, cpus=2)
    assert cfg.periodic_offsets and cfg.static_map
    assert any("random offset" in w for w in why) and any("static valve map" in w for w in why)
    off, _ = auto_config(ds, cpus=2, overrides={"periodic_offsets": False, "static_map": False})
    assert not off.periodic_offsets and not off.static_map
    # another mode drops the recipe's stateful knobs instead of refusing them
    win, _ = auto_config(ds, cpus=2, overrides={"mode": "windowed"})
    assert win.mode == "windowed" and not win.periodic_offsets and win.static_map
