"""The amount of training and the budget: rounds, caps, sub-sequences and run time
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

    assert trainings(6, choose=False, kinds=True) == 9
    assert member_budget_s(6, 600, cpus=2, choose=False, kinds=True) == pytest.approx(120)
    assert member_budget_s(4, 600, cpus=2, choose=False, kinds=True) == pytest.approx(200)
    assert member_budget_s(6, 600, cpus=2, choose=True) == pytest.approx(150)  # 6 + 2
    assert member_budget_s(9, 600, cpus=2, choose=True) == pytest.approx(100)  # 9 + 2
    assert member_budget_s(8, 600, cpus=2, choose=False, kinds=True) == pytest.approx(100)
    assert member_budget_s(2, 600, cpus=1, choose=False, kinds=True) == pytest.approx(200)
    # the plan reads the same cap: h1-dev's 72 s members fit 6 + 3 in 2 x 600 / 9 = 133 s
    # at 60 %, but not twice over in the fifth of it the five rounds leave; in 900 s they do
    assert plan_members(72.3, 600, cpus=2, choose=False, kinds=True) == 4
    assert plan_members(72.3, 900, cpus=2, choose=False, kinds=True) == 6
    for members in (4, 6, 8):
        for choose, kinds in ((False, False), (True, False), (False, True), (True, True)):
            cap = member_budget_s(members, 600, cpus=2, choose=choose, kinds=kinds)
            rounds = -(-trainings(members, choose=choose, kinds=kinds) // 2)
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


def test_the_run_time_counts_the_epochs_the_training_loop_validates():
    """run_s against a plain loop over the epochs, validated as training/loop.py does."""
    from excavator_surrogate.training.plan import VAL_PAIR_SHARE, run_s
    from excavator_surrogate.training.selection import first_validated

    for epochs in (1, 5, 7, 10, 40, 81):
        for select_after, smooth in ((0.0, 0), (0.5, 4), (0.5, 0)):
            start = first_validated(epochs, select_after, smooth=smooth, plateau=False)
            total = 0.0
            for epoch in range(epochs):
                total += 2.0 + (VAL_PAIR_SHARE * 3.0 if epoch >= start else 0.0)
            got = run_s(epochs, train_s=2.0, val_s=3.0, select_after=select_after, smooth=smooth)
            assert got == pytest.approx(total)


def test_whole_epochs_are_the_most_a_computer_twice_as_slow_trains_within_the_cap():
    """The stroke case's epoch (150 batches of 150 steps, two 2000-step validation runs):
    the share fits 10 at 60 %, a computer HEADROOM times slower trains 7 within 170 s."""
    from excavator_surrogate.training.plan import HEADROOM, run_s, whole_epochs

    kw = dict(train_s=150 * 150 * 4.5e-4, val_s=2 * 1998 * 3e-4, select_after=0.5, smooth=4)
    n = whole_epochs(10, cap_s=170.0, **kw)
    assert n == 7
    assert HEADROOM * run_s(n, **kw) <= 170.0 < HEADROOM * run_s(n + 1, **kw)
    assert whole_epochs(10, cap_s=1e6, **kw) == 10  # never more than the plan
    assert whole_epochs(10, cap_s=1.0, **kw) == 1  # never fewer than one
