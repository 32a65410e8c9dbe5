"""What a training config will cost before it runs: its trainings, their rounds, its epochs
and caps, and its time on the reference machine (:mod:`.plan`'s cost model; nothing here
reads this computer's clock).  ``exsur train DATASET --dry-run`` prints it.

The estimate covers the stateful sub-sequence training of the recipe (:mod:`.auto`) and of
any preset in that mode; the windowed mode has no cost model, and gets no estimate.  Unlike
the plan, which budgets a validation for every epoch, it counts the epochs the training
loop will validate (:func:`~.selection.validation_start`: on one short segment only the
second half of the plan, where validation is trained on only the last epoch), so its
headroom (the cap over the estimated time) says how much slower than the reference a
computer may be and still train every network whole.  The training steps are priced as the
plan prices them (:data:`~.plan.STEP_S`): AVX2-only 2-core computers needed 1.3-2.1x of it
(a Zen 3, quiet, 1.25-1.66x on the stroke case's; computer D 1.9-2.1x on 150-step
sub-sequences; docs/real-history.md).  Validation is priced as today's code runs it
(:data:`VAL_PAIR_STEP_S`, :data:`VAL_RUN_STEP_S`), not at the plan's
:data:`~.plan.VAL_STEP_S`: the plan keeps that older, 4-6x higher price so that the same
data plan the same epochs, and an estimate at it made a long log's training look 2-3x as
long as it is.

A network other than the recipe's (:data:`~.plan.STEP_NET`) trains at another speed, which
the cost model does not know: its estimate has no time (:attr:`WorkEstimate.unmodelled`)
until :meth:`WorkEstimate.with_speed` scales the reference network's times by the ratio
:mod:`.speed_probe` measured on this computer (what the dry runs print).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

from ..cpus import usable_cpus
from ..data.dataset import Dataset
from .batches import sequence_cap, val_min_steps
from .config import TrainConfig
from .plan import (
    STEP_NET,
    epoch_sizes,
    epoch_train_s,
    prior_members,
    probe_members,
)
from .selection import validation_start

VAL_PAIR_STEP_S = 1.0e-4
"""Reference machine: an epoch's validation free run as today's code runs it (the epoch's two
candidates batched, stepped in NumPy:
:func:`~excavator_surrogate.surrogate.validation.free_run_errors`), per sample of the longest
validation run, one core [s]; plus :data:`VAL_RUN_STEP_S` for each run in the batch
(:func:`val_epoch_s`).  Fitted in session 101 on computer B's recipe trainings, each
network's mean time per validated epoch over its own training pace against
:data:`~.plan.STEP_S` (0.79-0.97), per sample: one 2000-sample segment (the continuous and
7-minute loader logs, 24 networks) 1.09-1.27e-4 s, two sessions of 3000 samples
1.30-1.43e-4 s, h1-dev's 24 runs of at most 641 samples 4.2-5.6e-4 s.  On a Zen 4 (AVX-512,
no AMX; session 108) the continuous log's 36 networks validated at 0.79-1.12x this price
over their own pace (median 1.00): validation kept B's ratio to the training steps there."""
VAL_RUN_STEP_S = 1.5e-5
"""Reference machine: what each validation run adds to a step of :data:`VAL_PAIR_STEP_S` [s]."""


def val_epoch_s(val_steps: int, n_run: int) -> float:
    """One validated epoch's free run of its two candidates on the reference machine [s]::

        val_steps * (VAL_PAIR_STEP_S + n_run * VAL_RUN_STEP_S)

    ``val_steps``: samples of the longest validation run; ``n_run``: the runs batched."""
    return val_steps * (VAL_PAIR_STEP_S + n_run * VAL_RUN_STEP_S)


@dataclass(frozen=True)
class SpeedRatio:
    """A config's network's time over the recipe's (:data:`~.plan.STEP_NET` in
    :data:`~.plan.STEP_SHAPE`'s sub-sequences), both timed on this computer side by side
    (:func:`~.speed_probe.measure_speed`)."""

    train: float
    """Training, per sub-sequence step (burn-in included), each in its own sub-sequences."""
    val: float
    """An epoch's validation free run (two candidates, the same episodes)."""
    teacher: float | None = None
    """Training in the teacher-forced warm-up of a ``feedback = "free"`` config
    (:func:`teacher_forced_epochs`), per sub-sequence step (None: no such warm-up, every
    epoch at :attr:`train`)."""
    seconds: float = 0.0
    """Wall time the measurement took [s]."""


@dataclass(frozen=True)
class WorkEstimate:
    """The planned work of one training config on one dataset, at the reference machine's
    speed (:data:`~.plan.STEP_S`, :func:`val_epoch_s`)."""

    n_seq: int
    """Training sub-sequences per epoch (the validation runs' too where they are trained on)."""
    epochs: int
    """Planned epochs of every network."""
    teacher_epochs: int
    """Of :attr:`epochs`, those trained teacher-forced before a ``feedback = "free"``
    config's free-run feedback (:func:`teacher_forced_epochs`; each takes
    :attr:`teacher_train_s`)."""
    members: int
    """Plain ensemble members."""
    map_correcting: int
    """Networks that correct the static valve map (the kind choice; 0 without it)."""
    probes: int
    """Networks trained only to decide the exogenous input choice (its losing way; 0 without it)."""
    workers: int
    """Trainings run at once."""
    train_s: float
    """One epoch's training steps on the reference machine [s] (the reference network's, in
    batches of its ``seq_batch``, times :attr:`speed` where it was measured)."""
    val_s: float
    """One validated epoch's free run on the reference machine [s] (both candidates,
    :func:`val_epoch_s`; times :attr:`speed` where it was measured)."""
    teacher_train_s: float
    """One teacher-forced warm-up epoch's training steps on the reference machine [s]
    (:attr:`train_s` until :attr:`speed` scales it by its own ratio: a teacher-forced epoch
    of a network trained on its free runs costs about half of one of them)."""
    validated: int
    """Epochs validated (the last ones: :func:`~.selection.validation_start`)."""
    cap_s: float
    """Each training's wall-time cap [s] (0: none)."""
    unmodelled: tuple[str, ...] = ()
    """The config's fields that differ from the network the reference times were measured
    with (:data:`~.plan.STEP_NET`), as ``"name = value"``: the times do not hold for it
    unless :attr:`speed` scales them."""
    speed: SpeedRatio | None = None
    """This config's network's time over the reference network's, measured on this computer
    (:meth:`with_speed`; None: not measured)."""

    @property
    def timed(self) -> bool:
        """Whether :attr:`train_s` and :attr:`val_s` hold for this config: its network is the
        reference's, or its speed against it was measured."""
        return not self.unmodelled or self.speed is not None

    def with_speed(self, speed: SpeedRatio) -> WorkEstimate:
        """This estimate for a network that trains ``speed`` times as long as the reference's::

        train_s'         = train_s * speed.train
        teacher_train_s' = teacher_train_s * speed.teacher   (speed.train where None)
        val_s'           = val_s * speed.val
        """
        if self.speed is not None:
            raise ValueError("this estimate is already scaled by a measured speed")
        if self.teacher_epochs and speed.teacher is None:
            raise ValueError(
                f"this estimate has {self.teacher_epochs} teacher-forced warm-up epoch(s): the "
                "speed ratio must time them (SpeedRatio.teacher)"
            )
        teacher = speed.train if speed.teacher is None else speed.teacher
        return replace(
            self,
            train_s=self.train_s * speed.train,
            teacher_train_s=self.teacher_train_s * teacher,
            val_s=self.val_s * speed.val,
            speed=speed,
        )

    @property
    def trainings(self) -> int:
        """Networks trained in all."""
        return self.members + self.map_correcting + self.probes

    @property
    def rounds(self) -> int:
        """Rounds of :attr:`workers` trainings at once."""
        return math.ceil(self.trainings / self.workers)

    @property
    def steps_s(self) -> float:
        """One network's training steps over its planned epochs on the reference machine [s]::

        (epochs - teacher_epochs) * train_s + teacher_epochs * teacher_train_s
        """
        free = self.epochs - self.teacher_epochs
        return free * self.train_s + self.teacher_epochs * self.teacher_train_s

    @property
    def training_s(self) -> float:
        """One network's planned epochs on the reference machine [s]::

        steps_s + validated * val_s
        """
        return self.steps_s + self.validated * self.val_s

    @property
    def total_s(self) -> float:
        """Every round's trainings on the reference machine [s] (the choices after training
        not counted)."""
        return self.rounds * self.training_s

    @property
    def headroom(self) -> float:
        """How many times slower than the reference a computer may train and still finish
        every network's planned epochs within the cap (``inf`` without a cap)."""
        return self.cap_s / self.training_s if self.cap_s > 0 else math.inf

    @property
    def epochs_in_cap(self) -> int:
        """The epochs a network trains on the reference machine before the cap stops it (the
        first epoch that ends past the cap is the last; the teacher-forced epochs come first,
        the validated ones last): :attr:`epochs` where the cap leaves room for them all."""
        if self.headroom >= 1:
            return self.epochs
        costs = (
            (self.teacher_train_s if e < self.teacher_epochs else self.train_s)
            + (self.val_s if e >= self.epochs - self.validated else 0.0)
            for e in range(self.epochs)
        )
        return min(self.epochs, 1 + sum(t <= self.cap_s for t in itertools.accumulate(costs)))


def estimate_work(
    cfg: TrainConfig, dataset: Dataset, *, cpus: int | None = None
) -> WorkEstimate | None:
    """The planned work of ``cfg`` on ``dataset`` (``None`` in the windowed mode, which has
    no cost model).  ``cpus`` (default: those this process may use) bounds the workers where
    ``cfg.member_workers`` is 0, as the training's pool does."""
    return estimate_sizes(
        cfg,
        train=[e.n_step for e in dataset.train],
        val=[e.n_step for e in dataset.val],
        n_input=dataset.spec.n_input,
        cpus=cpus,
    )


def estimate_sizes(
    cfg: TrainConfig,
    *,
    train: Sequence[int],
    val: Sequence[int],
    n_input: int,
    cpus: int | None = None,
) -> WorkEstimate | None:
    """:func:`estimate_work` from the data's sizes alone, e.g. of a dataset not simulated yet.

    Args:
        cfg: the training config.
        train: samples of each training episode.
        val: samples of each validation episode.
        n_input: exogenous input columns of the data.
        cpus: CPUs the pool plans for (default: those this process may use).
    """
    if cfg.mode != "stateful":
        return None
    runs = [n for n in val if n >= val_min_steps(cfg.window)]  # those the training free-runs
    n_seq, val_steps = epoch_sizes(
        list(train), runs, on_val=cfg.train_on_val, seq_len=cfg.seq_len, burn_in=cfg.burn_in
    )
    cap = sequence_cap(cfg.epoch_samples, seq_len=cfg.seq_len, burn_in=cfg.burn_in)
    if cap is not None:  # the epoch's cap, as Stateful.batches cuts its starts
        n_seq = min(n_seq, cap)
    if cfg.val_steps > 0:  # validation runs truncated to val_steps samples
        val_steps = min(val_steps, cfg.val_steps)
    # the reference network's batches: a measured speed ratio (per step) scales these
    ref_batch = int(STEP_NET["seq_batch"])  # type: ignore[call-overload]
    train_s = epoch_train_s(n_seq, seq_len=cfg.seq_len, seq_batch=ref_batch)
    start = validation_start(cfg)
    probe = n_input > 0 and cfg.exogenous == "choose" and cfg.input_dropout == 0
    members = max(1, cfg.members)
    n_prior = prior_members(members) if cfg.prior_choice else 0
    n_probe = probe_members(members) if probe else 0
    workers = min(cfg.member_workers or cpus or usable_cpus(), members + n_prior + n_probe)
    return WorkEstimate(
        n_seq=n_seq,
        epochs=cfg.epochs,
        teacher_epochs=teacher_forced_epochs(cfg),
        members=members,
        map_correcting=n_prior,
        probes=n_probe,
        workers=max(1, workers),
        train_s=train_s,
        val_s=val_epoch_s(val_steps, max(1, len(runs))),
        teacher_train_s=train_s,
        validated=max(0, cfg.epochs - start),
        cap_s=float(cfg.max_train_seconds or 0.0),
        unmodelled=tuple(
            f"{k} = {getattr(cfg, k)!r}" for k, v in STEP_NET.items() if getattr(cfg, k) != v
        ),
    )


def teacher_forced_epochs(cfg: TrainConfig) -> int:
    """Epochs a ``feedback = "free"`` config trains teacher-forced before its free-run
    feedback (:meth:`~.config.TrainConfig.teacher_forced`, within its ``epochs``); 0 for a
    teacher-forced config, all of whose epochs train alike."""
    if cfg.feedback != "free":
        return 0
    return sum(cfg.teacher_forced(e) for e in range(cfg.epochs))


def describe_work(est: WorkEstimate | None) -> list[str]:
    """``est`` in a few lines for a person (what ``exsur train --dry-run`` prints)."""
    if est is None:
        return ["no estimate: the cost model covers the stateful training (the recipe's mode)"]
    parts = [f"{est.members} plain member(s)"]
    if est.map_correcting:
        parts.append(f"{est.map_correcting} map-correcting")
    if est.probes:
        parts.append(f"{est.probes} that decide the exogenous inputs")
    lines = [
        f"{est.trainings} training(s) ({', '.join(parts)}), {est.workers} at a time in "
        f"{est.rounds} round(s); {est.epochs} epochs of {est.n_seq} sub-sequences each",
    ]
    ref_net = ", ".join(f"{k} = {v!r}" for k, v in STEP_NET.items())
    if not est.timed:
        lines.append(
            f"no time estimate: the reference machine's per-step times were measured with "
            f"{ref_net}; this config has {', '.join(est.unmodelled)} (`--dry-run` times it "
            "against them on this computer)"
        )
        lines.append(
            f"each training capped at {est.cap_s:.0f} s of wall time; a run cut by it says so"
            if est.cap_s > 0
            else "no wall-time cap: every planned epoch runs, however long it takes"
        )
        return lines
    lines.append(
        f"about {est.training_s:.0f} s a training on the reference machine "
        f"({est.steps_s:.0f} s of training steps, {est.validated} validated "
        f"epoch(s) {est.validated * est.val_s:.0f} s), {est.total_s:.0f} s for all of them (the "
        "choices after training not counted)"
    )
    if est.speed is not None:
        lines.append(
            f"scaled by this config's network ({', '.join(est.unmodelled)}) against the "
            f"reference's, timed on this computer just now: {est.speed.train:.2f}x on the "
            f"training steps{_teacher_note(est)}, {est.speed.val:.2f}x on validation (a "
            f"{est.speed.seconds:.0f}-s "
            "probe on throwaway networks; the ratio moves with the CPU's kernels and its load)"
        )
    if est.headroom < 1:  # the cap is shorter than the plan: it will not be followed
        lines.append(
            f"warning: each training is capped at {est.cap_s:g} s of wall time, less than "
            f"its plan: the cap will cut training after about {est.epochs_in_cap} of "
            f"{est.epochs} epochs even on the reference machine, and the model will depend on "
            "the computer's speed and load; raise the cap or lower the epochs"
        )
    elif est.cap_s > 0:
        lines.append(
            f"each training capped at {est.cap_s:.0f} s of wall time: a computer up to "
            f"{est.headroom:.2f}x slower than the reference trains every network whole; a "
            "slower or busier one is cut, and the run says so (AVX2-only 2-core computers "
            "took 1.3-2.1x the reference's time on the training steps)"
        )
    else:
        lines.append("no wall-time cap: every planned epoch runs, however long it takes")
    return lines


def _teacher_note(est: WorkEstimate) -> str:
    """The measured ratio of ``est``'s teacher-forced warm-up epochs, for the speed line."""
    if not est.teacher_epochs or est.speed is None or est.speed.teacher is None:
        return ""
    return (
        f" ({est.speed.teacher:.2f}x in the {est.teacher_epochs} teacher-forced epoch(s) "
        "before the free-run feedback)"
    )
