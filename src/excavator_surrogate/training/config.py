"""The ``[train]`` table: :class:`TrainConfig`, and which knobs each training mode reads.

A knob that the chosen ``mode`` does not read (``horizon`` under ``stateful``, ``seq_len`` under
``windowed`` ...) is an error unless it keeps its default, so a preset never sets a value that is
silently ignored.  :meth:`TrainConfig.for_mode` switches mode and drops the other mode's knobs.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace
from typing import Any, Literal

from ..config import PresetConfig, check_types
from ..errors import ConfigError
from ..spec import MachineSpec
from ..surrogate.model import ModelConfig

MODE_FIELDS: dict[str, tuple[str, ...]] = {
    "windowed": ("horizon", "batch_size"),
    "stateful": (
        "seq_len",
        "burn_in",
        "tbptt",
        "seq_batch",
        "feedback",
        "teacher_epochs",
        "fused_backward",
        "periodic_offsets",
        "angle_noise",
        "input_dropout",
    ),
}
"""Fields read by one training mode only (every other field is read by both)."""

MAX_MEMBERS = 64
"""Most seed-ensemble members (each one is a full training run)."""


@dataclass(frozen=True)
class TrainConfig(PresetConfig, table="train"):
    """Surrogate training options (``[train]`` table of a preset)."""

    window: int = 30
    """Window length W [samples]; also the warm-up of every closed-loop rollout."""
    hidden: int = 128
    """Recurrent state width."""
    layers: int = 2
    """Stacked recurrent layers."""
    head_hidden: int = 128
    """Width of the FC layer of the output head."""
    cell: Literal["lstm", "gru"] = "lstm"
    """Recurrent cell (``gru`` is the same-size baseline)."""
    mode: Literal["windowed", "stateful"] = "windowed"
    """Training (and rollout) mode: sliding windows (paper) or carried state (faster)."""
    horizon: int = 1
    """Windowed: H, rollout steps in the loss (1 = one-step training); stateful mode has no H: its
    loss runs over TBPTT chunks of ``tbptt`` steps (free-run with ``feedback = "free"``)."""
    lambda_bias: float = 0.0
    """Weight of the mean-bias penalty over the horizon (paper: 0.3 for compound data)."""
    lr: float = 1e-3
    """Adam learning rate."""
    weight_decay: float = 0.0
    """Decoupled weight decay (AdamW): each optimiser step shrinks every weight by
    ``lr * weight_decay`` of itself (0 = plain Adam, the paper's; ours, an option:
    docs/real-history.md has where it helped and where it hurt)."""
    batch_size: int = 256
    """Windowed: windows per batch; per process with DDP (global batch = batch_size x world size)."""
    epochs: int = 50
    """Planned epochs: the amount of training, fixed before it starts (early stopping by
    ``patience`` may end it sooner; the cosine schedule runs over it)."""
    patience: int = 25
    """Early stopping: epochs without a better validation free-run error."""
    min_delta: float = 0.0
    """Relative improvement of the validation error that counts as better."""
    plateau_factor: float = 0.5
    """ReduceLROnPlateau factor on the validation error."""
    plateau_patience: int = 10
    """ReduceLROnPlateau patience [epochs] (the free-run error is noisy: keep this generous)."""
    min_lr: float = 1e-5
    """Lower bound of the learning rate."""
    lr_schedule: Literal["plateau", "cosine"] = "plateau"
    """``plateau``: ReduceLROnPlateau on the validation error (paper); ``cosine``: decay from ``lr``
    to ``min_lr`` over the planned epochs (progress = epoch / epochs; never the wall clock)."""
    grad_clip: float = 1.0
    """Clip the gradient norm to this value (0 disables)."""
    seed: int = 0
    """Seed of weight init and sampling (epoch e samples with seed (seed, e))."""
    seq_len: int = 150
    """Stateful: sub-sequence length [samples] including the burn-in."""
    burn_in: int = 30
    """Stateful: leading samples fed with recorded data, without loss or gradient."""
    tbptt: int = 10
    """Stateful: steps per truncated-BPTT chunk (one optimiser step per chunk)."""
    seq_batch: int = 16
    """Stateful: sub-sequences per batch (per process with DDP)."""
    feedback: Literal["free", "teacher"] = "teacher"
    """Stateful: after the burn-in, feed recorded angles (teacher, fast) or integrated ones (free)."""
    teacher_epochs: int = 1
    """Stateful free mode: the first epochs are teacher-forced (curriculum)."""
    fused_backward: bool = True
    """Stateful free mode: back-propagate each chunk by hand in one step (:mod:`.free_run`,
    ~1.5x the samples/s; the same gradients up to float rounding) where the net allows it;
    False: through autograd, operator by operator (the reference)."""
    epoch_samples: int = 0
    """Cap on target samples per epoch (0 = every training sample once)."""
    val_steps: int = 0
    """Truncate validation episodes to this many samples for the free-run (0 = full length)."""
    select_after: float = 0.0
    """Share of the planned ``epochs`` before which no epoch competes for ``best.pt`` (0 = every
    epoch; the recipe sets 0.5 when validation is one or a few episodes)."""
    select_smooth: int = 0
    """Score an epoch by the larger of its validation error and the median of the last
    ``select_smooth + 1`` epochs' (0 = its own error): on a short validation split one lucky
    epoch in a noisy stretch cannot win."""
    average_last: bool = False
    """``best.pt`` holds the selected epoch's weights averaged with the last epoch's (raw),
    weight by weight: for validation that cannot vouch for the commands the model must
    generalise to (the recipe sets it when validation spans too little of every joint's
    command range, as at h1-dev's one duty level)."""
    train_on_val: bool = False
    """The networks also train on the validation episodes, and only the last epoch competes
    (validation scores it alone): for validation that vouches for no joint's other commands
    and so only picks the epoch (the recipe sets it where it sets ``average_last`` and nothing
    else is chosen on validation: h1-dev's one duty level, whose runs are data the other
    duties lack).  Validation scores are then in-sample."""
    exogenous: Literal["use", "ignore", "choose"] = "use"
    """Exogenous inputs (``spec.inputs``): ``use`` them; ``ignore`` them (the network trains on the
    data without them, :mod:`.ignored`, and is stored with zero weights for them, so the
    model cannot depend on them); or ``choose`` the way that scores
    better on validation (``use`` only if better by :data:`~.input_choice.INPUT_MARGIN`): with
    ``input_dropout`` > 0 on the same networks run both ways (:mod:`.dual`), else train 2
    networks each way (at most half the members, :func:`~.plan.probe_members`), then
    the rest the chosen way."""
    input_dropout: float = 0.0
    """Share of the training sub-sequences whose exogenous inputs are blanked (held at their
    training mean, feature 0: what a network that ignores them sees), teacher-forced stateful
    mode only.  One network then runs both ways: with the inputs, and with their input weights
    zeroed.  With ``exogenous = "choose"`` and > 0 every member trains so and the choice is
    made on the same networks (:mod:`.dual`: no network is trained only to lose the choice);
    0 (the recipe's): the choice trains networks each way (:mod:`.variants`)."""
    inputs_per_joint: bool = True
    """With ``exogenous = "choose"``: where the inputs' members beat the others on some
    joints and not on all, those joints may take them alone: each seed's two networks become
    one whose joint is the one's or the other's, kept if it beats the members that ignore the
    inputs as the whole ``use`` must; with ``prior_choice`` the kinds are then chosen with
    these pairs as the plain networks (:mod:`.variants`; false: all joints or none)."""
    max_train_seconds: float = 0.0
    """Wall-time cap for training incl. validation [s] (0 = none): it only stops a slow or busy
    computer before the planned ``epochs``, and the run then says so (log, ``best.pt`` metrics
    ``training.budget_cut``, reports); it never changes what the planned epochs compute."""
    device: str = "cpu"
    """Torch device: ``cpu``, ``cuda``, ``cuda:N`` or ``auto`` (CUDA if available, else CPU)."""
    num_threads: int = 1
    """Torch intra-op threads (0 keeps torch's default; 1 is fastest for these small nets on shared CPUs)."""
    ema_decay: float = 0.0
    """Keep an exponential moving average of the weights (decay per optimiser step, e.g. 0.999);
    each epoch both the raw and the averaged weights are validated and the better one competes
    for ``best.pt`` (0 = off)."""
    play: tuple[float, ...] = ()
    """Half-widths of play (backlash) operators on the scaled commands whose states are extra
    input features (valve hysteresis memory; ours, not the paper's); empty = paper's 9-D input."""
    velocity_input: bool = False
    """Feed the previous angular velocity ``wrap(theta[k] - theta[k-1]) / T_s`` as ``n_joint``
    more input features: measured while synced to a machine, the integrated prediction in a
    free run (the state of acceleration-limited hydraulics; ours, not the paper's)."""
    residual: bool = False
    """With ``velocity_input``: the net predicts the change of the velocity, added to the
    velocity feature (``omega[k+1] = omega[k] + net``; ours, not the paper's)."""
    periodic_offsets: bool = False
    """Stateful mode: each training sub-sequence sees the angles of its periodic joints (the
    swing) turned by its own random offset, so the network cannot tie the dynamics to where
    the machine points (a machine on level ground moves alike in every direction; ours, not
    the paper's; the data-driven recipe turns it on)."""
    angle_noise: float = 0.0
    """Stateful, teacher-forced: each training sub-sequence's non-periodic joint angles, as the
    network reads them, drift from the measured ones by a random walk from 0 whose standard
    deviation at the sub-sequence's end is this share of the joint's training standard
    deviation (a free run reads its own drifting angles; ours, not the paper's; 0 = off)."""
    static_map: bool = False
    """After training, a joint that the static valve map (dead zone, gain per direction, delay,
    fitted on the training split) drives within 5 % of the network on validation may follow the map
    (:mod:`.map_joints`: a near tie goes to the simpler model; ours; the recipe turns it on)."""
    map_periodic: bool = True
    """With ``static_map``: a periodic joint (the swing) whose map with the fitted delay alone
    runs its validation free run with angle R^2 >= 0.95 follows the map, whatever the network
    scores there (no end stop resets its drift; :mod:`.map_joints`)."""
    map_parallel: bool = True
    """With ``static_map``: the joints on the map are composed in parallel (the network keeps
    reading its own angles of them, so the other joints run as in its own free run;
    :mod:`~excavator_surrogate.surrogate.own_angles`), and with ``map_periodic`` any joint,
    not only a periodic one, whose map alone validates with angle R^2 >= 0.95 follows it;
    false: in series, as before session 30 (the network reads the map's angles)."""
    map_end_stops: bool = True
    """A joint on the static map (``static_map``) stops at the training data's angle range, as
    the structured baseline does, even where a positive ``limit_margin`` widens the networks'
    stops: the map has no angle to correct its drift, and an end stop is its only reset (needs
    ``end_stops``; a negative ``limit_margin`` keeps the network's)."""
    map_refit_share: float = 0.0
    """With ``static_map``: when the validation episodes hold at least this share of the
    training's samples, the joints on the map take it fitted again on both splits after the
    choice (:func:`~.map_fit.refit_map`; 0 = never)."""
    map_val_gain: bool = True
    """With ``static_map``: after the choice, the joints on the map take its gains scaled to
    validation's speed, the data nearest the test in time (:mod:`.map_fit`; ours, since
    session 109; false: the training's gains, as before)."""
    net_val_gain: bool = False
    """After training (and the static map choice), a joint a network drives takes validation's
    speed where every one of at least 2 validation episodes measured the network more than 5 %
    too slow, or too fast (:mod:`.net_gain`; ours, since session 111; the recipe turns it on)."""
    map_blocks: bool = True
    """With ``static_map`` and one validation episode: a joint the map ties or beats on the
    whole validation free run follows it only if it also does on both halves of the episode,
    each free-run from its own warm-up (:mod:`.map_blocks`; ours, since session 100; false:
    the whole run alone decides, as before)."""
    prior: bool = False
    """The head corrects a static per-joint valve map (dead zone, gain per direction, delay)
    fitted on the training split by least squares: ``omega[k+1] = s(u[k - d]) + net`` (ours,
    not the paper's; an option, not the recipe's: docs/real-history.md has where it helped)."""
    prior_choice: bool = False
    """Beside the ``members`` plain networks, about half as many more correct the static map
    (as with ``prior``, the same seeds); per joint, one kind drives it (``prior_drive``;
    :mod:`.kinds`; ours; the recipe turns it on where validation spans a joint's commands,
    ``choice_min_span``)."""
    prior_drive: str = "spanned"
    """With ``prior_choice``: which joints the map-correcting networks drive. ``"spanned"``:
    every joint whose validation spans its commands (``choice_min_span``) and that does not
    take exogenous inputs its own way, without a comparison on validation (one validation
    segment misranked the kinds on the operator logs; :mod:`.kinds`); ``"validation"``: per
    joint, the kind (or the even blend) that validates better, kept as a set."""
    prior_margin: float = 0.05
    """With ``prior_drive = "validation"``: a joint is a candidate for the map-correcting
    networks when their validation angle RMSE on it is below ``1 - prior_margin`` times the
    plain ensemble's (a near tie stays plain; negative: a near tie goes to the map-correcting
    networks; :mod:`.kinds`)."""
    prior_blend: bool = True
    """With ``prior_drive = "validation"``: the even blend of both kinds (each ensemble's
    omega weighted 1/2) is a third option per joint beside the plain and the map-correcting
    ensemble, held to the same margin over the plain one; the lowest validation angle RMSE of
    the options drives the joint (:mod:`.kinds`; false: each joint is one kind's)."""
    prior_skip_pinned: bool = True
    """With ``prior_drive = "validation"`` and ``static_map``: a joint that the static map
    choice will put on the map whatever the networks (``map_periodic``: its delayed map alone
    validates with angle R^2 >= 0.95) cannot refuse a set of the kind choice on its own score;
    it still counts in the whole validation error that ranks the sets (:mod:`.kinds`; false:
    every joint can)."""
    choice_min_span: float = 0.5
    """With ``static_map`` or ``prior_choice``: a joint may follow the map, or the networks
    that correct it, only where validation commands it over at least this share of the
    training's command range beyond the dead zone, in each direction (:mod:`.span`; elsewhere
    the plain networks drive it; the recipe trains no map-correcting networks when no joint
    reaches it; 0 = every joint may)."""
    members: int = 1
    """Seed ensemble: train this many members independently (seeds ``seed``, ``seed + 1``, ...),
    each selected by its own validation free run, and merge them into one network whose omega is
    the members' mean (``OUT/member_<i>/``; ours, not the paper's).  1 = a single network."""
    bootstrap: bool = False
    """Each network trains on its own bootstrap resample of the training episodes (as many
    drawn with replacement, from its seed): ensemble members differ by their data, not only by
    their seed (bagging; ours, not the paper's)."""
    member_workers: int = 0
    """Members trained in parallel processes, each with ``num_threads`` threads (0 = one
    process per member, up to the CPU count; 1 = one after the other in this process, and so
    are a run's models)."""
    end_stops: bool = True
    """Keep free runs inside the machine's envelope: clip angles to the joint limits (end stops)
    and velocities to the speed bounds, in training rollouts and in every rollout of the trained
    model (stored in the checkpoint's spec)."""
    limit_margin: float = 0.0
    """End stops the spec lacks come from the angle range seen in training, widened by this
    fraction of the range on each side (0: the range itself, where real runs end; negative:
    none from data; 0.02 before session 36, docs/real-history.md)."""
    speed_margin: float = 0.25
    """Speed bounds the spec lacks are the largest |omega| seen in training times
    ``1 + speed_margin`` (negative: none from data)."""
    tensorboard: bool = True
    """Write TensorBoard scalars to ``OUT/tb`` (skipped if tensorboard is not installed)."""

    @property
    def map_stops_at_range(self) -> bool:
        """Whether a joint on the static map stops at the training range: ``map_end_stops``,
        unless a negative ``limit_margin`` asks for no end stops from the data."""
        return self.map_end_stops and self.limit_margin >= 0

    def teacher_forced(self, epoch: int) -> bool:
        """Whether epoch ``epoch`` (from 0) trains on recorded angles: every epoch with
        ``feedback = "teacher"``, the first ``teacher_epochs`` with ``"free"``."""
        return self.feedback == "teacher" or epoch < self.teacher_epochs

    def __post_init__(self) -> None:
        check_types(self, "[train]")  # a wrong type: one line, not a failed comparison below
        checks = [
            (self.window >= 1, "window must be >= 1"),
            (
                self.hidden >= 1 and self.layers >= 1 and self.head_hidden >= 1,
                "hidden/layers/head_hidden must be >= 1",
            ),
            (self.horizon >= 1, "horizon must be >= 1"),
            (all(0 < b <= 1 for b in self.play), "play widths must be in (0, 1]"),
            (self.lambda_bias >= 0, "lambda_bias must be >= 0"),
            (0 < self.lr <= 1, f"lr = {self.lr!r} must be in (0, 1] (typical: 1e-4 to 1e-2)"),
            (
                math.isfinite(self.angle_noise) and 0 <= self.angle_noise <= 1,
                f"angle_noise = {self.angle_noise!r} must be in [0, 1] (typical: 0.02 to 0.1)",
            ),
            (
                math.isfinite(self.weight_decay) and self.weight_decay >= 0,
                f"weight_decay = {self.weight_decay!r} must be >= 0 (typical: 0.01 to 1)",
            ),
            (self.seed >= 0, f"seed = {self.seed} must be >= 0 (numpy seeds are non-negative)"),
            (self.seed < 2**32, f"seed = {self.seed} must be < 2**32 (a 32-bit seed)"),
            (
                self.max_train_seconds >= 0,
                f"max_train_seconds = {self.max_train_seconds!r} must be >= 0 (0 = unlimited)",
            ),
            (self.batch_size >= 1 and self.seq_batch >= 1, "batch sizes must be >= 1"),
            (self.epochs >= 1, "epochs must be >= 1"),
            (self.burn_in >= 1, "burn_in must be >= 1"),
            (self.seq_len > self.burn_in, "seq_len must exceed burn_in"),
            (self.tbptt >= 1, "tbptt must be >= 1"),
            (self.velocity_input or not self.residual, "residual needs velocity_input = true"),
            (not (self.prior and self.residual), "prior and residual exclude each other"),
            (
                not (self.prior_choice and (self.prior or self.residual)),
                "prior_choice trains both kinds itself: set prior = false and residual = false",
            ),
            (
                math.isfinite(self.map_refit_share) and self.map_refit_share >= 0,
                f"map_refit_share = {self.map_refit_share!r} must be >= 0 (0 = never refit)",
            ),
            (
                0.0 <= self.choice_min_span <= 1.0,
                "choice_min_span must be in [0, 1] (0 = every joint may follow the map)",
            ),
            (
                self.prior_drive in ("spanned", "validation"),
                f"prior_drive = {self.prior_drive!r} must be spanned or validation",
            ),
            (
                -1.0 < self.prior_margin < 1.0,
                "prior_margin must be in (-1, 1) (typical: -0.05 to 0.05)",
            ),
            (
                not (self.static_map and (self.prior or self.residual)),
                "static_map needs a network without prior or residual head",
            ),
            (
                1 <= self.members <= MAX_MEMBERS,
                f"members = {self.members} must be in [1, {MAX_MEMBERS}] (4 already average "
                "out the seed; each member is a full training)",
            ),
            (
                isinstance(self.bootstrap, bool),
                f"bootstrap = {self.bootstrap!r} must be true or false",
            ),
            (math.isfinite(self.limit_margin), "limit_margin must be finite"),
            (math.isfinite(self.speed_margin), "speed_margin must be finite"),
            (self.member_workers >= 0, "member_workers must be >= 0"),
            (0 < self.plateau_factor < 1, "plateau_factor must be in (0, 1)"),
            (self.cell in ("lstm", "gru"), "cell must be lstm or gru"),
            (self.mode in ("windowed", "stateful"), "mode must be windowed or stateful"),
            (self.lr_schedule in ("plateau", "cosine"), "lr_schedule must be plateau or cosine"),
            (self.feedback in ("free", "teacher"), "feedback must be free or teacher"),
            (
                0 <= self.select_after < 1,
                f"select_after = {self.select_after!r} must be in [0, 1) (a share of epochs)",
            ),
            (self.select_smooth >= 0, f"select_smooth = {self.select_smooth} must be >= 0"),
            (
                isinstance(self.average_last, bool),
                f"average_last = {self.average_last!r} must be true or false",
            ),
            (
                isinstance(self.train_on_val, bool),
                f"train_on_val = {self.train_on_val!r} must be true or false",
            ),
            (
                self.exogenous in ("use", "ignore", "choose"),
                f"exogenous = {self.exogenous!r} must be use, ignore or choose",
            ),
            (
                0 <= self.input_dropout < 1,
                f"input_dropout = {self.input_dropout!r} must be in [0, 1) (a share of the "
                "training sub-sequences)",
            ),
            (
                self.input_dropout == 0 or self.feedback == "teacher",
                f"input_dropout = {self.input_dropout!r} blanks the inputs of teacher-forced "
                'sub-sequences: set feedback = "teacher" or input_dropout = 0',
            ),
        ]
        for ok, msg in checks:
            if not ok:
                raise ConfigError(f"[train] {msg}")
        self._check_size()
        defaults = {f.name: f.default for f in fields(self)}
        for other, names in MODE_FIELDS.items():
            if other == self.mode:
                continue
            for name in names:
                if getattr(self, name) != defaults[name]:
                    raise ConfigError(
                        f"[train] {name} = {getattr(self, name)!r} is read only by mode = "
                        f'"{other}" (this config trains mode = "{self.mode}"): remove it'
                    )

    def _check_size(self) -> None:
        """Refuse a network whose training state cannot fit in memory, before any allocation:
        parameters x 16 B (weights, gradients, Adam's two moments), counted with one input
        feature and one joint (a lower bound: the data only adds to it)."""
        from ..surrogate.sizes import check_fits, n_param

        n = n_param(self.model_config(1, 1)) * max(1, self.members)
        check_fits(
            16 * n,
            what=f"[train] hidden = {self.hidden}, layers = {self.layers}, head_hidden = "
            f"{self.head_hidden}"
            + (f", members = {self.members}" if self.members > 1 else "")
            + f": {n:.3g} parameters x 16 B (weights, gradients, Adam state)",
            fix="lower train.hidden / train.head_hidden",
        )

    @classmethod
    def adapt_table(cls, table: dict[str, Any], *, changed: set[str]) -> dict[str, Any]:
        """Check a ``[train]`` table against its mode: a knob of the other mode is an error, even
        at its default, unless ``mode`` is among the ``changed`` (overridden) keys: then the other
        mode's knobs are dropped, unless overridden too (``exsur train --mode windowed`` on a
        stateful preset)."""
        mode = table.get("mode", cls.mode)
        if mode not in MODE_FIELDS:
            return table  # from_dict names the bad mode
        other = {n for m, ns in MODE_FIELDS.items() if m != mode for n in ns}
        if "mode" in changed:
            return {k: v for k, v in table.items() if k not in other - changed}
        stray = sorted(other & set(table))
        if stray:
            owner = next(m for m, ns in MODE_FIELDS.items() if stray[0] in ns)
            raise ConfigError(
                f'[train] {stray[0]} is read only by mode = "{owner}" (this table trains '
                f'mode = "{mode}"): remove it (exsur config show marks the knobs not read)'
            )
        return table

    @classmethod
    def mode_bases(cls, preset: dict[str, Any], **overrides: Any) -> dict[str, TrainConfig]:
        """One config per mode from a ``[train]`` table that may set both modes' knobs (the
        base of a sweep over modes): each drops the other mode's knobs."""
        return {m: cls.from_preset(preset, **{**overrides, "mode": m}) for m in MODE_FIELDS}

    def unread_fields(self) -> tuple[str, ...]:
        """Knobs this config's mode does not read (they must keep their defaults)."""
        return tuple(n for m, ns in MODE_FIELDS.items() if m != self.mode for n in ns)

    def for_mode(self, mode: str) -> TrainConfig:
        """This config trained in ``mode``: the other mode's knobs go back to their defaults."""
        defaults = {f.name: f.default for f in fields(self)}
        reset = {n: defaults[n] for m, ns in MODE_FIELDS.items() if m != mode for n in ns}
        return replace(self, mode=mode, **reset)  # type: ignore[arg-type]

    def n_feature(self, spec: MachineSpec) -> int:
        """Feature columns a network trained with this config reads on ``spec``: the spec's
        own (angles, commands, exogenous inputs), then per joint one per play operator and one
        for the velocity feature."""
        return spec.n_feature + (len(self.play) + self.velocity_input) * spec.n_joint

    def model_config(self, n_feature: int, n_joint: int) -> ModelConfig:
        """Architecture implied by this config."""
        return ModelConfig(
            n_feature=n_feature,
            n_joint=n_joint,
            window=self.window,
            hidden=self.hidden,
            n_layer=self.layers,
            cell=self.cell,
            head_hidden=self.head_hidden,
            residual=self.residual,
            prior=self.prior,
        )
