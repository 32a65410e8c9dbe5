"""The amount of training and the budget: rounds, caps and sub-sequences
(``training/plan.py``; the recipe that uses them: ``tests/surrogate/test_auto.py``)."""

from __future__ import annotations

import numpy as np
import pytest


def test_every_round_of_the_pool_fits_the_budget():
    """Two workers run the trainings in rounds: an odd count leaves one idle in the last
    round, so 6 members and 3 map-correcting networks take 5 rounds, and each training's cap
    is a fifth of the budget (not 2 / 9 of it, which a computer that needed the whole cap ran
    11 % past the budget).  One worker: one round per training."""
    from excavator_surrogate.training.plan import member_budget_s, plan_members, trainings

    assert trainings(6, probe=False, kinds=True) == 9
    assert member_budget_s(6, 600, cpus=2, probe=False, kinds=True) == pytest.approx(120)
    assert member_budget_s(4, 600, cpus=2, probe=False, kinds=True) == pytest.approx(200)
    assert member_budget_s(6, 600, cpus=2, probe=True) == pytest.approx(150)  # 6 + 2
    assert member_budget_s(9, 600, cpus=2, probe=True) == pytest.approx(100)  # 9 + 2
    assert member_budget_s(8, 600, cpus=2, probe=False, kinds=True) == pytest.approx(100)
    assert member_budget_s(2, 600, cpus=1, probe=False, kinds=True) == pytest.approx(200)
    # the plan reads the same cap: h1-dev's 72 s members fit 6 + 3 in 2 x 600 / 9 = 133 s
    # at 60 %, but not twice over in the fifth of it the five rounds leave; in 900 s they do
    assert plan_members(72.3, 600, cpus=2, probe=False, kinds=True) == 4
    assert plan_members(72.3, 900, cpus=2, probe=False, kinds=True) == 6
    for members in (4, 6, 8):
        for probe, kinds in ((False, False), (True, False), (False, True), (True, True)):
            cap = member_budget_s(members, 600, cpus=2, probe=probe, kinds=kinds)
            rounds = -(-trainings(members, probe=probe, kinds=kinds) // 2)
            assert rounds * cap <= 600 + 1e-9


def test_sequences_are_counted_as_the_epoch_tiles_them():
    from excavator_surrogate.training.batches import sequence_starts
    from excavator_surrogate.training.plan import count_sequences

    class _Data:
        starts = np.array([0, 500, 700])
        lengths = np.array([500, 200, 60])

    n = count_sequences(_Data.lengths, seq_len=50, burn_in=10)
    rng = np.random.default_rng(0)
    assert len(sequence_starts(_Data, 50, 10, rng)) <= n
    zero_offset = sum(max(0, (int(L) - 1 - 50) // 41 + 1) for L in _Data.lengths)
    assert n == zero_offset


def test_the_choices_networks_are_counted_before_training():
    """The input choice's probe is 2 networks per way, at most half the members; the kind
    choice's map-correcting networks are the largest divisor of the members up to half, so
    every composite group holds as many plain networks.  Both enter :func:`trainings`."""
    from excavator_surrogate.training.plan import prior_members, probe_members, trainings

    assert [probe_members(m) for m in (1, 2, 3, 4, 6, 8)] == [1, 1, 1, 2, 2, 2]
    assert [prior_members(k) for k in (1, 2, 3, 4, 5, 6, 8)] == [1, 1, 1, 2, 1, 3, 4]
    for members in (2, 4, 6, 8):
        for probe in (False, True):
            for kinds in (False, True):
                want = members + probe * probe_members(members) + kinds * prior_members(members)
                assert trainings(members, probe=probe, kinds=kinds) == want


def test_an_epochs_sizes_count_the_validation_runs_only_where_they_are_trained_on():
    """``epoch_sizes``, which the recipe plans with and the dry run estimates with: the
    validation runs' sub-sequences join the epoch with ``on_val``; validation's length is its
    longest run, or the longest training run where there is none."""
    from excavator_surrogate.training.plan import count_sequences, epoch_sizes

    train, val = [500, 200], [300, 60]
    alone = count_sequences(np.array(train), seq_len=50, burn_in=10)
    both = count_sequences(np.array(train + val), seq_len=50, burn_in=10)
    assert epoch_sizes(train, val, on_val=False, seq_len=50, burn_in=10) == (alone, 300)
    assert epoch_sizes(train, val, on_val=True, seq_len=50, burn_in=10) == (both, 300)
    assert both > alone
    assert epoch_sizes(train, [], on_val=True, seq_len=50, burn_in=10) == (alone, 500)
