"""``exsur train DATASET`` without a preset: a training recipe chosen from the data.

Real logs are not the simulator's long multisine episodes.  They are many short runs (a step
from rest that ends against an end stop after 100-2000 samples), on a machine whose limits
nobody wrote down, at whatever rate the user resampled to.  :func:`auto_config` reads the
dataset's sizes, rate and episode lengths and returns a complete :class:`TrainConfig` plus a
list of one-line reasons (logged and recorded in ``config.toml``).

The recipe is documented in ``docs/real.md``, and the measurement behind each choice in
``docs/real-history.md``:

- the paper's network (2 x 128 LSTM, FC-ReLU-linear head, window W = 30 samples; W shrinks
  for data whose episodes are too short for it);
- ``stateful`` teacher-forced training on sub-sequences after a burn-in of W recorded
  samples (on the real logs it beat free-run feedback and the windowed one-step loss, and
  costs about one recurrent step per sample); the sub-sequence length follows the episode
  lengths so that no short run is dropped;
- a planned amount of training, fixed before it starts from the data and the budget
  (:mod:`.plan`): about :data:`~.plan.TARGET_PASSES` sub-sequence passes (at least
  :data:`~.plan.MIN_EPOCHS` epochs, and on a short log at most
  :data:`~.plan.EPOCHS_PER_SEQUENCE` epochs per sub-sequence), no more than fits
  :data:`~.plan.PLAN_SHARE` of each member's budget at the reference machine's speed; the
  cosine schedule runs over those epochs, and the wall-time budget is only a cap that stops
  a much slower or busier computer early (and says so), with :data:`~.plan.POST_SHARE` of
  it held back for the choices after training, so such a computer still ends within the
  budget.  So the same data, seed and machine give the same model on an idle or a busy
  computer;
- an exponential moving average of the weights, so the selected checkpoint does not depend on
  one lucky epoch; selection by the whole-episode validation free run;
- a seed ensemble of ``members`` networks trained side by side, one per core: 4, or up to 8
  when the planned epochs are cheap enough that the budget fits more, even on a computer
  :data:`~.plan.MEMBER_HEADROOM` times slower than the reference
  (:func:`~.plan.plan_members`);
- the envelope (end stops and speed bounds) from the spec, else from the training data;
- periodic joints (the swing) turned by a random offset per training sub-sequence, so the
  network does not tie the dynamics to where the machine points (it did: on the continuous
  case the test free run's error changed up to 5x with the swing's starting direction);
- two kinds of network (:mod:`.kinds`): beside the plain members, half as many that correct
  the static valve map (dead zone, gain per direction, delay); the map-correcting networks
  drive every joint whose validation spans its commands, the plain ones the rest, without a
  comparison on validation (``prior_drive``: on the operator logs one validation segment
  misranked the kinds, and the map-correcting networks held better off the training's
  conditions; docs/real-history.md, session 87).  Also when the run chooses its exogenous inputs (:mod:`.variants`): the
  inputs are chosen first on the plain networks, then the rest of the plain members train
  the chosen way and the map-correcting networks ignore them (8 trainings in the budget
  instead of 6; on the 10-minute loader log the throttle chosen on its validation segment
  cost the map-correcting networks' boom 1.38x held out, docs/real-history.md session 96).
  With ``input_dropout`` > 0 (not the recipe's) every network learns both ways instead
  and the choice is made on the same networks (:mod:`.dual`): the plan is then the one
  without inputs;
- exogenous inputs that never change in training, that validation at one command level
  cannot vouch for (h1-dev's step tests), or that the default would not read (validation
  spans every joint, so the map-correcting networks, blind to a chosen input, drive them
  all; only a joint given the inputs alone, on plain networks, could read them, and on these
  logs no trial helped a joint held out) are ignored without a trial: the plan, the
  networks and the training on the validation runs are those without them;
- after training, the static valve map as a candidate per joint, chosen on validation
  (:mod:`.map_joints`); then validation's speed on the map joints (:mod:`.map_fit`) and,
  where several validation episodes agree on it, on the network joints (:mod:`.net_gain`);
- neither the map nor the map-correcting networks for a joint whose validation commands span
  less than half its training command range beyond the dead zone (:mod:`.span`): there
  validation cannot vouch for them, and the plain networks drive it.  Where no joint spans
  enough (h1-dev: every validation run at one duty) no map-correcting network is trained,
  and the budget goes to plain members.

Every field can still be overridden: ``auto_config(ds, overrides={"members": 1})``, or on
the command line ``exsur train DATA --members 1``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from ..config import from_dict, to_dict
from ..cpus import cpus_note, usable_cpus
from ..data.dataset import Dataset
from ..errors import ConfigError, DataError
from .batches import val_min_steps
from .config import TrainConfig
from .map_joints import PERIODIC_MAP_R2
from .plan import (
    MEMBER_HEADROOM,
    POST_SHARE,
    epoch_cost_s,
    epoch_sizes,
    max_members,
    member_budget_s,
    min_members,
    plan_epochs,
    plan_members,
    prior_members,
    probe_members,
    training_cap_s,
    trainings,
    want_epochs,
)
from .span import joint_spans, span_note

TRAIN_BUDGET_S = 540.0
"""Wall time of the whole training (every member) on the reference 2-core machine [s]."""
WINDOW = 30
"""The paper's window W [samples] (also the warm-up of every free run)."""
MIN_WINDOW = 8
"""Smallest window the recipe shrinks to for very short episodes [samples]."""
MAX_SEQ_LEN = 150
"""Longest training sub-sequence including the burn-in [samples]."""
SEQ_BATCH = 16
"""Sub-sequences per batch."""
SHORT_VAL_EPISODES = 4
"""Validation with fewer episodes than this is short (one or two segments of a continuous
log): a single free run whose error jumps between epochs by more than the epochs differ."""
SELECT_AFTER = 0.5
"""On short validation: share of the planned epochs before which no epoch competes."""
SELECT_SMOOTH = 4
"""On short validation: an epoch's score also needs the median of the last 5 to be low."""


def auto_config(
    dataset: Dataset,
    *,
    overrides: Mapping[str, Any] | None = None,
    cpus: int | None = None,
    budget_s: float = TRAIN_BUDGET_S,
) -> tuple[TrainConfig, list[str]]:
    """The training recipe for ``dataset`` (see the module docstring).

    Args:
        dataset: the training data (``train`` split required; ``val`` used for selection).
        overrides: ``[train]`` fields that replace the recipe's choices (strictly checked).
        cpus: CPUs to plan for (default: those this process may use).
        budget_s: wall time of the whole training, all members [s].

    Returns:
        The config and one reason per choice, e.g. ``"window 30: the paper's W"``.

    Raises:
        DataError: no training episode.
    """
    lengths = np.array([e.n_step for e in dataset.train])
    if lengths.size == 0:
        raise DataError(dataset.root, "has no training episodes", fix="import or simulate some")
    counted = cpus_note() if not cpus else f"{cpus} CPU(s)"
    cpus = cpus or usable_cpus()
    why: list[str] = []
    short = int(lengths.min())
    window = WINDOW
    if short < 3 * WINDOW:
        window = max(MIN_WINDOW, short // 3)
        why.append(f"window {window}: the shortest runs hold {short} samples (paper: 30)")
    else:
        why.append(f"window {window}: the paper's W")
    seq_len = int(min(MAX_SEQ_LEN, short - 1))
    seq_len = max(seq_len, window + 10)
    n_drop = int((lengths < seq_len + 1).sum())
    why.append(
        f"stateful, teacher-forced, sub-sequences of {seq_len} samples incl. a {window}-sample "
        f"burn-in: the episodes hold {lengths.min()}-{lengths.max()} samples"
        + (f" ({n_drop} shorter ones are left out)" if n_drop else " (none is left out)")
    )
    overrides = dict(overrides or {})
    capped = True
    if overrides.get("max_train_seconds") is not None:  # --max-seconds: the whole training's
        given = float(overrides.pop("max_train_seconds"))
        if not (math.isfinite(given) and given >= 0):
            raise ConfigError(
                f"[train] max_train_seconds = {given:g}: give the training's wall-time "
                "budget in seconds (> 0; 0 = no cap, planned for the default budget)"
            )
        capped = given > 0
        budget_s = given if capped else budget_s
    # the kind choice is the recipe's, beside the input choice too, unless validation spans
    # too little of any joint's command range to choose a kind
    min_span = float(overrides.get("choice_min_span", TrainConfig.choice_min_span))
    # the validation episodes the training will free-run (too short ones are skipped there)
    val = [e for e in dataset.val if e.n_step >= val_min_steps(window)]
    spans, spanned = joint_spans(
        dataset.train, val or dataset.train, dataset.spec, min_span=min_span
    )
    kinds = bool(overrides.get("prior_choice", any(spanned)))
    short_val = len(val) < SHORT_VAL_EPISODES
    # validation at one command level (a step-test rig's one duty) vouches for no other
    # command: it only ranks epochs, and the selected epoch is averaged with the last (one
    # long log's short validation keeps its own rule: there it chooses kinds and maps too).
    # Its runs are data the other levels lack: the networks train on them too where nothing
    # is chosen on validation (an input or kind choice on in-sample scores would be biased)
    one_level = not short_val and spans is not None and not any(spanned)
    inputs = list(dataset.spec.u_names[dataset.spec.n_joint :])
    held = held_inputs(dataset)
    # the map-correcting networks never read an input a validation trial chose (variants.py),
    # so where they drive every joint only the per-joint route (a joint taking the inputs
    # alone, on plain networks) could read them: no trial either (none helped held out)
    drive = str(overrides.get("prior_drive", TrainConfig.prior_drive))
    all_mapped = kinds and all(spanned) and drive == "spanned"
    # inputs that never change in training teach nothing, validation at one command level
    # vouches for no input at the others, and where the map-correcting networks drive every
    # joint the whole-way choice reaches none: all three are ignored without a trial, and
    # the plan is the one without them (each network trains as on the data without them)
    untried = len(held) == len(inputs) or one_level or all_mapped
    default_exogenous = ("ignore" if untried else "choose") if inputs else "use"
    exogenous = str(overrides.get("exogenous", default_exogenous))
    choose = bool(inputs) and exogenous == "choose"
    # input_dropout > 0 (an override, not the recipe's): every network learns both ways and
    # the choice costs no training (dual.py); else 2 more networks decide it (variants.py)
    dropout = float(overrides.get("input_dropout", 0.0)) if choose else 0.0
    probe = choose and dropout == 0  # networks trained only to decide the choice
    average = bool(overrides.get("average_last", one_level))
    on_val = bool(overrides.get("train_on_val", one_level and not choose and not kinds))
    n_seq, val_len = epoch_sizes(
        lengths.tolist(), [e.n_step for e in val], on_val=on_val, seq_len=seq_len, burn_in=window
    )
    cost = epoch_cost_s(n_seq, seq_len=seq_len, seq_batch=SEQ_BATCH, val_steps=val_len)
    asked = overrides.get("members")
    members = (
        int(asked)
        if asked
        else plan_members(cost * want_epochs(n_seq), budget_s, cpus=cpus, probe=probe, kinds=kinds)
    )
    workers = min(members, cpus)
    per_member = member_budget_s(members, budget_s, cpus=cpus, probe=probe, kinds=kinds)
    cap = training_cap_s(per_member)
    why.append(
        f"seed ensemble of {members} member(s), {workers} in parallel, at most {cap:.0f} s "
        f"each ({budget_s:.0f} s of training in all on {counted}, {POST_SHARE:.0%} of it "
        "held back for the choices after training)"
        + (
            ""
            if asked
            else "; as many members as the budget fits at the planned epochs, "
            f"{min_members(cpus)}-{max_members(cpus)}, with room for a computer "
            f"{MEMBER_HEADROOM:g}x slower than the reference to train each whole"
        )
    )
    if inputs and one_level and len(held) < len(inputs) and "exogenous" not in overrides:
        why.append(
            f"exogenous input(s) {', '.join(i for i in inputs if i not in held)} ignored "
            "without a trial: validation sits at one command level, which vouches for no "
            "input at the others (h1-dev's H/L condition, chosen at duty 50, lost 12-51 % "
            "per joint at duty 80 held out, where its trial also cost the validation runs as "
            "training data); the networks train as on the data without the columns, on the "
            'validation runs too (set exogenous = "choose" to try them)'
        )
    if inputs and all_mapped and len(held) < len(inputs) and "exogenous" not in overrides:
        why.append(
            f"exogenous input(s) {', '.join(i for i in inputs if i not in held)} ignored "
            "without a trial: validation spans every joint's commands, so the map-correcting "
            "networks drive every joint, and they never read an input chosen on validation "
            "(on the 10-minute loader log the throttle chosen there cost their boom 1.38x held "
            "out, and a trial that refused it still cost its epochs: the continuous log's "
            "boom 1.72x; docs/real-history.md); the networks train as on the data without the "
            'columns (set exogenous = "use" to let every network read them, "choose" to try '
            'giving them to single joints on plain networks, or prior_drive = "validation" to '
            "choose the kinds, and so the inputs, on validation)"
        )
    if held and "exogenous" not in overrides:
        why.append(
            f"exogenous input(s) {', '.join(f'{k} = {v:g}' for k, v in held.items())} never "
            "change in the training data: nothing to learn from them, so "
            + (
                "they are ignored without a trial and the budget plans as without them (each "
                "network trains as on the data without the columns)"
                if default_exogenous == "ignore"
                else "they add nothing to the inputs the choice below weighs"
            )
        )
    if choose and not probe:
        why.append(
            f"exogenous inputs {inputs} must not hurt: every network learns with and without "
            f"them ({dropout:.0%} of its training sub-sequences blanked) and runs both ways; "
            "they are kept only if the ensemble that uses them is better on validation, overall "
            "and on every joint, than the same networks with their input weights zeroed; where "
            "they help some joints only, those joints may take them alone (each network's two "
            "ways joint by joint, kept on the same terms); no training is spent on the losing "
            "way"
            + (
                "; the map-correcting networks of the kind choice learn the same way and follow "
                "the chosen way (if some joints take them: ignoring them)"
                if kinds
                else ""
            )
        )
    if probe:
        half = probe_members(members)
        why.append(
            f"exogenous inputs {inputs} must not hurt: {half} member(s) use them and {half} "
            f"ignore them (same seeds); they are kept only if better on validation, overall "
            f"and on every joint, and the other {members - half} member(s) train the chosen "
            f"way ({trainings(members, probe=True, kinds=kinds)} trainings in the budget)"
            + "; where they help some joints only, those joints may take them alone "
            "(each seed's two networks joint by joint, kept on the same terms)"
            + (
                "; the map-correcting networks of the kind choice ignore them, whichever "
                "way wins (the joints they drive never take an input chosen on validation)"
                if kinds
                else ""
            )
        )
    if kinds:
        rule = (
            "per joint, the kind whose ensemble validates better drives it, or the even blend "
            "of both"
            if drive == "validation"
            else "they drive every joint whose validation spans its commands, the plain ones "
            "the rest, without a comparison on validation (on the operator logs one validation "
            "segment misranked the kinds, and the map-correcting networks held better off the "
            "training's conditions)"
        )
        why.append(
            f"two kinds of network: beside the {members} plain member(s), "
            f"{prior_members(members)} correct the static valve map (same seeds); {rule} "
            f"({trainings(members, probe=probe, kinds=True)} trainings in the budget)"
        )
    elif spans is not None and not any(spanned) and "prior_choice" not in overrides:
        why.append(
            "one kind of network (plain): validation commands "
            f"{span_note(spans, dataset.spec, min_span=min_span)} of the training's command "
            f"range beyond the dead zone (below {100 * min_span:.0f} %), too little to choose the "
            "map-correcting networks or the map for any joint; the budget trains plain members"
        )
    n_val = len(val)
    if short_val:
        why.append(
            f"selection on {n_val or 'no'} validation episode(s) (short): only epochs after "
            f"{SELECT_AFTER:.0%} of the plan compete, each scored by the larger of its own "
            f"validation error and the median of the last {SELECT_SMOOTH + 1}"
        )
    elif on_val:
        why.append(
            f"the {n_val} validation episodes are trained on too, and the last epoch is the "
            "model (validation, now in-sample, only says whether its weight average or its "
            "raw weights run it better"
            + (", and that is averaged with the raw weights" if average else "")
            + "): at one command level validation vouches for no joint's other commands and "
            "only ranked the epochs, and its runs are data the training's levels lack (with "
            "h1-dev's duty 60, 80 or 90 held out: 8 joints' medians of 9 better, the bucket's "
            "at duty 80 worse; docs/real-history.md)"
        )
    else:
        why.append(
            f"selection: the epoch with the lowest free-run error on {n_val} validation episodes"
            + (
                ", its weights averaged with the last epoch's: validation spans too little of "
                "every joint's command range to pick the epoch for the other commands alone "
                "(at h1-dev's held-out duties 60 and 80 the average beat the selected epoch on "
                "every joint of every seed, the last epoch alone lost at 60)"
                if average
                else ""
            )
        )
    epochs, limit = plan_epochs(n_seq, cost, budget_s=per_member)
    why.append(
        f"{epochs} epochs planned: {n_seq} sub-sequences per epoch, about {epochs * cost:.0f} s "
        f"per member at the plan's prices on the reference machine (an upper bound: `--dry-run` "
        f"estimates the run; {limit}); the budget only caps it"
    )
    why.append("envelope: end stops and speed bounds from the spec, else from the training data")
    turning = [j.name for j in dataset.spec.joints if j.periodic]
    if turning:
        why.append(
            f"{', '.join(turning)} turned by a random offset per training sub-sequence: a "
            "machine on level ground moves alike in every direction, so the network must not "
            "tie its dynamics to where it points"
        )
    why.append(
        "static valve map as a candidate per joint: a joint follows the map (dead zone, gain "
        "per direction, delay) if its validation free run is within 5 % of the network's (a "
        "near tie goes to the simpler model; on one validation segment, on both its halves "
        "too), and any joint whose map with its fitted delay "
        f"alone runs the validation with angle R^2 >= {PERIODIC_MAP_R2:g} follows it; in "
        "parallel: the networks keep reading their own angles of the map joints, so no map "
        "joint moves the others; only on a joint whose validation commands span at least "
        f"{100 * min_span:.0f} % of its training command range beyond the dead zone (a "
        "valve's speed is not linear in its command: validation at one command level cannot "
        "vouch for the map at the others)"
    )
    why.append(
        "then validation's speed, the data nearest the test in time: a map joint's gains times "
        "validation's speed ratio (where several validation episodes each find it on the same "
        "side of 1, or one, a log's next stretch, finds it faster: the oil warms over a log), "
        "and a joint a network drives only where at least 2 validation episodes "
        "each measured its network more than 5 % too slow, or each too fast (one segment of a "
        "log cannot tell a day's speed from a network's error on it)"
    )
    cfg = TrainConfig(
        window=window,
        hidden=128,
        layers=2,
        head_hidden=128,
        mode="stateful",
        feedback="teacher",
        seq_len=seq_len,
        burn_in=window,
        tbptt=10,
        seq_batch=SEQ_BATCH,
        lr=1e-3,
        lr_schedule="cosine",
        min_lr=1e-5,
        epochs=epochs,
        patience=epochs,
        ema_decay=0.999,
        members=members,
        member_workers=workers,
        max_train_seconds=cap if capped else 0.0,
        end_stops=True,
        select_after=SELECT_AFTER if short_val else 0.0,
        select_smooth=SELECT_SMOOTH if short_val else 0,
        average_last=average,
        train_on_val=on_val,
        exogenous=default_exogenous,
        input_dropout=dropout,
        periodic_offsets=bool(turning),
        static_map=True,
        net_val_gain=True,
        prior_choice=kinds,
    )
    if overrides:
        if overrides.get("mode") in ("windowed", "stateful") and overrides["mode"] != cfg.mode:
            cfg = cfg.for_mode(str(overrides["mode"]))  # the other mode's knobs: defaults
        if "epochs" in overrides and "patience" not in overrides:
            overrides["patience"] = overrides["epochs"]
        merged = {**to_dict(cfg), **overrides}
        cfg = from_dict(TrainConfig, merged, where="[train]")
        why.append("overridden: " + ", ".join(f"{k} = {v!r}" for k, v in overrides.items()))
    return cfg, why


def held_inputs(dataset: Dataset) -> dict[str, float]:
    """The exogenous inputs whose value never changes over the training episodes, with it
    (``{name: value}``; e.g. a throttle left at full, a gear never shifted)."""
    spec = dataset.spec
    if not spec.n_input or not dataset.train:
        return {}
    u = np.concatenate([e.u[:, spec.n_joint :] for e in dataset.train])
    lo, hi = u.min(axis=0), u.max(axis=0)
    return {
        name: float(a)
        for name, a, b in zip(spec.u_names[spec.n_joint :], lo, hi)
        if np.isfinite(a) and a == b
    }


def recipe_table(why: list[str]) -> dict[str, Any]:
    """The ``[recipe]`` table of ``config.toml``: ``{"name": "auto", "why": [...]}``."""
    return {"name": "auto", "why": list(why)}
