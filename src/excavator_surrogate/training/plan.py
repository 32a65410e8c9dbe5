"""How much training a recipe plans, and what the budget allows: the cost model, the epochs,
the ensemble's members and each training's wall-time cap (:func:`~.auto.auto_config` reads
the data, these turn its sizes into numbers).

Everything here is fixed before training starts, from the data's sizes and the budget, at
the speed of a *reference machine* (:data:`STEP_S`, :data:`VAL_STEP_S`): nothing reads this
computer's clock, so the same data and CPU count plan the same training on every computer,
idle or busy.  The wall-time budget is a cap on top of the plan, and the plan leaves room
under it:

- epochs: about :data:`TARGET_PASSES` sub-sequence passes, at least :data:`MIN_EPOCHS`, at
  most :data:`EPOCHS_PER_SEQUENCE` per sub-sequence, and no more than :data:`PLAN_SHARE` of
  each training's share of the budget fits at the reference's speed (:func:`plan_epochs`);
- members: :data:`MEMBERS` up to :data:`MAX_MEMBERS`, where a computer
  :data:`MEMBER_HEADROOM` times slower than the reference still trains each whole
  (:func:`plan_members`);
- caps: the budget over the pool's rounds (:func:`member_budget_s`), less :data:`POST_SHARE`
  for the work after training (:func:`training_cap_s`).
- trainings: the members, the input choice's probe networks (:func:`probe_members`) and the
  kind choice's map-correcting networks (:func:`prior_members`), counted by
  :func:`trainings`.

The measurements behind each constant are in ``docs/real-history.md``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

MIN_EPOCHS = 40
"""Fewest planned epochs (what the recipe trained on h1-dev's ~500 sub-sequences per epoch
before session 90; now binding above 750 sub-sequences per epoch)."""
TARGET_PASSES = 30_000
"""Sub-sequence passes the recipe aims for: h1-dev's 557 sub-sequences per epoch (its
validation runs trained on too) plan 54 epochs, with duty 80 held out 61.  18,000 passes
(40 epochs of h1-dev, 6 members) before session 90: at the held-out duties 60, 80 and 90
the 30,000 passes' 4 members won on 8 joints' medians of 9, the bucket by 17-29 % at
duties 80 and 90, on an AVX2-only Zen 3 (docs/real-history.md)."""
EPOCHS_PER_SEQUENCE = 1.75
"""Most planned epochs per sub-sequence of an epoch (above :data:`MIN_EPOCHS`): the fewer the
data, the sooner the networks fit them instead of the machine.  It binds on a short log only:
a 7-minute log's 160 s of training (26 sub-sequences) plans 45 epochs, where the budget fits
89, and its boom's test error went from 9.05 to 6.24 deg on one simulated log and from 2.50
to 2.38 on another, with the same 4 + 2 networks (docs/real-history.md); a 10-minute log
(55) keeps its budget's 81, h1-dev (557 with its validation runs) its 54.  With
:data:`TARGET_PASSES` it also bounds every plan: the two meet at 131 sub-sequences, 229
epochs, the most any data plans."""
PLAN_SHARE = 0.6
"""Share of each member's wall-time budget the planned epochs fill on the reference machine
(the rest is headroom: only a computer this much slower, or busier, hits the cap)."""
POST_SHARE = 0.15
"""Share of each training's wall-time share held back for the work after the networks train
(merging, the choices' validation free runs, the bands): the cap is the rest, and the plan is
unchanged.  On computer E that work took 15-50 s per seed (h1-dev, the operator logs); on one
twice as slow, 90 s, and h1-dev's seeds ran 689-709 s against a 600-s budget before
(docs/real-history.md)."""
STEP_S = 4.5e-4
"""Reference machine: one training step of a batch of 16 sub-sequences through the 2 x 128
LSTM, forward and backward, one core [s] (measured on h1-dev: 2.0 s for 32 batches of 109
steps with the other core busy)."""
STEP_NET: dict[str, object] = {
    "cell": "lstm",
    "hidden": 128,
    "layers": 2,
    "feedback": "teacher",
    "seq_batch": 16,
    "velocity_input": False,
    "head_hidden": 128,
    "residual": False,
}
"""The training config fields :data:`STEP_S` was measured with (the recipe's network): a
config that differs in any of them trains at another speed, which the plan does not model."""
STEP_SHAPE: dict[str, int] = {"seq_len": 150, "burn_in": 30, "tbptt": 10}
"""The recipe's sub-sequences on logs of long runs, which :data:`STEP_S` prices per step
(its burn-in steps, forward only, as dearly as the others): the shape the dry runs' speed
probe times the reference network in (``training/speed_probe.py``), so that a config with
a long burn-in or long truncated-BPTT chunks is priced at its own cost per step."""
VAL_STEP_S = 3.0e-4
"""Reference machine: one step of the validation free run over all validation episodes [s],
one candidate at a time.  The plan's constant, not a measurement of today's code: the two
candidates now free-run together (``surrogate.validation.free_run_errors``, about 0.7x
the time of two runs), and the epochs before ``select_after`` are not validated, so a long
log's member finishes well within its estimate.  The plan keeps it: more epochs in the same
budget did not pay on one long log (docs/real-history.md, "Faster, not longer").  What a
run will take is :mod:`.estimate`'s, at today's price (:data:`~.estimate.VAL_PAIR_STEP_S`:
4-6x below this on one long segment)."""
MEMBERS = 4
"""Fewest seed-ensemble members on a machine with 2 or more CPUs (half as many on one CPU)."""
MEMBER_HEADROOM = 2.0
"""The ensemble grows past :data:`MEMBERS` only where a computer this many times slower than
the reference machine still trains every planned network whole: each training's planned
time, times this, fits its wall-time cap.  A network the cap cuts is not the one an idle
computer trains, so a cap that binds changes the model.  On h1-dev computer D (AVX2 only)
needs 1.5-1.7x the reference's time; the 8 members that :data:`PLAN_SHARE` alone fitted
left it 6-16 % of their caps, and beside other work the caps cut every seed (seed 0's
bucket 1.41x worse on validation).  6 members leave D a third of each cap (1.5x its
time), and on h1-dev's validation runs 6 members of the same seeds scored as 8 did
(docs/real-history.md).  The other way, 2.5 would give h1-dev 4 members and computer F
(2x the reference's time) a third of each cap, but 4 members lost on 6 joints of 9 at the
held-out duties 60, 80 and 90, by up to 19 % (session 54).  Since session 90 h1-dev's
members train 54 epochs (:data:`TARGET_PASSES`), about 113 s each on the reference machine,
so 2 CPUs plan 4 of them (255-s caps) and 4 CPUs 8: the longer schedule was worth more than
the 2 members (docs/real-history.md)."""
MAX_MEMBERS = 8
"""Most seed-ensemble members the recipe trains (half as many on one CPU): when the planned
epochs are cheap (many short runs, h1-dev), the budget buys more members, whose average
varies less from seed to seed, and another CPU's kernels act like another draw of the seeds
(docs/design.md). On h1-dev's validation runs the bucket's error was 11-23 deg for single
members, 14.0-16.5 for 4-member ensembles and 12.8-14.0 for 8-member ones (docs/real-history.md)."""


INPUT_PROBE = 2
"""Networks per way (using the exogenous inputs, ignoring them) that decide the input choice
of :mod:`.variants`, at most half the members (:func:`probe_members`): the losing way's
networks are the choice's cost, so it stays the same however many members the budget buys."""


def probe_members(members: int) -> int:
    """Networks per way that decide the input choice of an ensemble of ``members``:
    :data:`INPUT_PROBE`, at most half of them, at least 1."""
    return max(1, min(INPUT_PROBE, members // 2))


def prior_members(members: int) -> int:
    """Map-correcting networks the kind choice (:mod:`.kinds`) trains beside a plain
    ensemble of ``members``: the largest divisor of ``members`` up to half of it (4 -> 2,
    8 -> 4, 6 -> 3; 1 for a prime), so that every group of :func:`~.composite.composite` holds as
    many plain networks."""
    return max([p for p in range(1, members // 2 + 1) if members % p == 0], default=1)


def count_sequences(lengths: np.ndarray, *, seq_len: int, burn_in: int) -> int:
    """Sub-sequences one epoch draws from episodes of ``lengths`` samples (as
    :func:`~.batches.sequence_starts` tiles them, with its random offset at zero)."""
    stride = seq_len - burn_in + 1
    last = lengths - 1 - seq_len
    return int(np.sum(np.where(last >= 0, last // stride + 1, 0)))


def epoch_sizes(
    lengths: Sequence[int], val_lengths: Sequence[int], *, on_val: bool, seq_len: int, burn_in: int
) -> tuple[int, int]:
    """``(n_seq, val_steps)``: the sub-sequences one epoch trains on (:func:`count_sequences`
    of the training episodes' ``lengths``, and of the validation episodes' ``val_lengths``
    too where they are trained on, ``on_val``) and the samples of the longest validation run
    (of the longest training episode without one).  ``val_lengths``: the validation episodes
    the training free-runs (those long enough for its window)."""
    trained = [*lengths, *val_lengths] if on_val else list(lengths)
    n_seq = count_sequences(np.array(trained, dtype=int), seq_len=seq_len, burn_in=burn_in)
    return n_seq, int(max(val_lengths, default=max(lengths, default=0)))


def epoch_cost_s(n_seq: int, *, seq_len: int, seq_batch: int, val_steps: int) -> float:
    """Estimated wall time of one epoch on the reference machine [s]:

      n_batch * seq_len * STEP_S          training (:func:`epoch_train_s`)
    + 2 * val_steps * VAL_STEP_S          free-run validation of the raw and averaged weights
    """
    train_s = epoch_train_s(n_seq, seq_len=seq_len, seq_batch=seq_batch)
    return train_s + 2 * val_steps * VAL_STEP_S


def epoch_train_s(n_seq: int, *, seq_len: int, seq_batch: int) -> float:
    """The training steps' part of :func:`epoch_cost_s` [s]: one recurrent step per sample of
    each of the ``ceil(n_seq / seq_batch)`` batches of sub-sequences::

        n_batch * seq_len * STEP_S
    """
    n_batch = math.ceil(max(n_seq, 1) / seq_batch)
    return n_batch * seq_len * STEP_S


def want_epochs(n_seq: int) -> int:
    """Epochs the recipe wants for ``n_seq`` sub-sequences per epoch, before the budget:
    :data:`TARGET_PASSES` passes, at most :data:`EPOCHS_PER_SEQUENCE` per sub-sequence, and
    at least :data:`MIN_EPOCHS`."""
    passes = math.ceil(TARGET_PASSES / max(n_seq, 1))
    return max(MIN_EPOCHS, min(passes, data_epochs(n_seq)))


def data_epochs(n_seq: int) -> int:
    """Most epochs ``n_seq`` sub-sequences per epoch bear (:data:`EPOCHS_PER_SEQUENCE`)."""
    return int(EPOCHS_PER_SEQUENCE * n_seq)


def min_members(cpus: int) -> int:
    """Fewest members the recipe trains on ``cpus`` CPUs."""
    return MEMBERS if cpus >= 2 else MEMBERS // 2


def max_members(cpus: int) -> int:
    """Most members the recipe trains on ``cpus`` CPUs."""
    return MAX_MEMBERS if cpus >= 2 else MAX_MEMBERS // 2


def trainings(members: int, *, probe: bool, kinds: bool = False) -> int:
    """Trainings an ensemble of ``members`` costs: one per member, plus the losing way's
    networks when an exogenous input is chosen by probe trainings (``probe``;
    :func:`probe_members`: 2, at most half the members; none when every network
    learns both ways, ``training/dual.py``), plus the map-correcting networks of the kind choice
    (:func:`prior_members`)."""
    extra = probe_members(members) if probe else 0
    return members + extra + (prior_members(members) if kinds else 0)


def member_budget_s(
    members: int, budget_s: float, *, cpus: int, probe: bool, kinds: bool = False
) -> float:
    """Each training's share of the budget [s] (its cap is :func:`training_cap_s` of it):
    the trainings (:func:`trainings`) run ``min(members, cpus)`` at a time, so they take
    ``ceil(trainings / workers)`` rounds, and every round must fit ``budget_s``.  An odd count
    on two workers leaves one worker idle in the last round: 9 trainings are 5 rounds, not 4.5
    (the share was ``budget_s * 2 / 9``, and a computer that needed it all ran 11 % past the
    budget)."""
    rounds = math.ceil(trainings(members, probe=probe, kinds=kinds) / min(members, cpus))
    return budget_s / rounds


def training_cap_s(share_s: float) -> float:
    """Each training's wall-time cap [s] from its share of the budget
    (:func:`member_budget_s`): the share less :data:`POST_SHARE`, held back for the work after
    training (merging, the choices, the bands)."""
    return (1.0 - POST_SHARE) * share_s


def plan_members(
    member_s: float, budget_s: float, *, cpus: int, probe: bool, kinds: bool = False
) -> int:
    """Seed-ensemble members: the most, from :func:`min_members` up to :func:`max_members` in
    steps of the parallel workers, whose planned training (``member_s`` each on the reference
    machine) a computer :data:`MEMBER_HEADROOM` times slower still finishes within each
    training's cap (:func:`training_cap_s`, the one :func:`~.auto.auto_config` sets)::

        MEMBER_HEADROOM * member_s <= (1 - POST_SHARE) * member_budget_s(n)
    """
    members = min_members(cpus)
    step = min(cpus, members)
    while members + step <= max_members(cpus):
        n = members + step
        share = member_budget_s(n, budget_s, cpus=cpus, probe=probe, kinds=kinds)
        if MEMBER_HEADROOM * member_s > training_cap_s(share):
            break
        members = n
    return members


def plan_epochs(n_seq: int, cost_s: float, *, budget_s: float) -> tuple[int, str]:
    """Planned epochs and what limited them: :func:`want_epochs`, and at most
    :data:`PLAN_SHARE` of ``budget_s`` (one member's wall-time budget) at ``cost_s`` per epoch
    (never fewer than 1)."""
    want = want_epochs(n_seq)
    fits = max(1, int(PLAN_SHARE * budget_s / cost_s))
    if fits < want:
        return fits, f"{PLAN_SHARE:.0%} of the {budget_s:.0f}-s member budget"
    if want == MIN_EPOCHS:
        return want, f"at least {MIN_EPOCHS} epochs"
    if want == data_epochs(n_seq):
        return want, (
            f"at most {EPOCHS_PER_SEQUENCE:g} epochs per sub-sequence: a short log is "
            "overfitted sooner"
        )
    return want, f"about {TARGET_PASSES} sub-sequence passes"
