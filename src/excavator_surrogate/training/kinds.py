"""Two kinds of network, chosen per joint: ``[train] prior_choice = true``.

A network trained from scratch and one that corrects the static valve map (``prior``: dead
zone, gain per direction, delay) generalise differently, and not alike on every joint: on
the stand-in sessions case the map-correcting networks drove the boom and the bucket better
on validation and on the test day, the plain ones the arm (docs/real-history.md).  With
``prior_choice`` the run trains the whole plain ensemble (``members`` networks, seeds
``seed, seed + 1, ...``, as without the option) and :func:`~.plan.prior_members` more that
correct the map (seeds ``seed, seed + 1, ...``): ``members + prior_members(members)``
trainings, which the recipe plans the epochs for within the same budget
(:func:`~.plan.trainings`).

**Which joints they drive** (``[train] prior_drive``).  With ``"spanned"`` (the default) the
map-correcting networks drive every joint whose validation commands span enough of the
training's (``spanned``, :mod:`.span`) and that takes no exogenous inputs its own way
(``twin_joints``), the plain networks the rest, with no comparison on validation: on the
four operator-log shapes (session 87, the same networks) the map-correcting ensemble ran the
test and the more test data better than the plain one on most joints and seeds, while the
choice on one validation segment or two sessions kept the plain networks where they lost
(the continuous log's arm 12.95 -> 8.36 deg on the test; the 10-minute loader's boom 5.01 ->
3.85; the sessions' worst bucket seed 2.47x -> 1.21x the median).  Both ensembles are still
scored on validation for the record.  With ``"validation"`` both ensembles are scored by
their validation free run, and:

1. a joint is a candidate for the map-correcting networks if their validation angle RMSE
   on it is below ``1 - margin`` times the plain ensemble's (``[train] prior_margin``,
   default :data:`PRIOR_MARGIN`: a near tie stays plain; a negative margin sends a near tie
   to the map-correcting networks).  With ``[train] prior_blend`` (default
   :data:`PRIOR_BLEND`) the even blend of both ensembles (:data:`BLEND`: each kind's omega
   weighted 1/2 on every joint) is scored too and is a candidate on the same terms; a joint
   takes the candidate with the lower RMSE.  The blend hedges where validation cannot tell
   the kinds apart: on the development shapes it repaired a seed whose bucket the plain kind
   drove at 2x the median, and bettered h1-dev's arm on every seed (docs/real-history.md);
2. for the candidates, and for each candidate alone, a **composite** ensemble is built
   (:func:`~.composite.composite`): group ``g`` of every ``P``-th plain network and map-correcting
   network ``g`` becomes one network whose joint ``j`` is ``a_j`` times the map-correcting
   network plus ``1 - a_j`` times the mean of its plain ones (``a_j``: 1 or 1/2 on a
   candidate, 0 elsewhere; :func:`~excavator_surrogate.surrogate.ensemble.merge` with
   ``joint_weights``), and the ``P`` groups are merged into the ensemble.  A plain joint is
   then exactly the plain ensemble's mean, a map joint the map-correcting ensemble's, a
   blended joint the mean of the two;
3. the best set whose validation error is at most :data:`SET_MARGIN` above the plain
   ensemble's overall, and on every joint within the static map choice's allowance
   (:func:`~excavator_surrogate.training.sets.joint_allowance`), is kept (a joint's
   choice changes the angles the others read); if none, or no candidate, the plain ensemble
   is the model, as without the option.  A joint the static map choice will put on the map
   whatever the networks (:func:`map_pinned`, ``[train] prior_skip_pinned``) cannot refuse
   a set on its own score; it still counts in the whole error (on the first continuous
   development log the networks' own swing, which the map drives, refused the
   map-correcting networks' boom in two seeds of three).

The static map choice (``static_map``) then runs on the result as on any model.

Layout: ``OUT/plain/member_*`` and ``OUT/prior/member_*`` (the trained networks),
``OUT/best.pt`` (the model; ``metrics.training.kinds`` says what was chosen and why),
``OUT/config.toml`` (``[kinds]``: the same), ``OUT/log.csv`` (one row per network).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Mapping, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

from ..data.dataset import Dataset
from ..spec import MachineSpec
from ..surrogate.ensemble import merge
from ..surrogate.model import Surrogate
from ..surrogate.validation import free_run_error
from .batches import split_episodes
from .composite import composite, plain_ensemble
from .config import TrainConfig
from .ensembles import member_configs, merge_members, open_run, train_groups
from .map_joints import map_options, pinned_joints
from .plan import prior_members
from .records import write_config
from .sets import SET_MARGIN, best_set
from .span import joint_spans

_log = logging.getLogger(__name__)

PRIOR_DRIVE = TrainConfig.prior_drive
"""Default: the map-correcting networks drive every spanned joint (``TrainConfig.prior_drive``)."""
PRIOR_MARGIN = TrainConfig.prior_margin
"""Default relative margin by which the map-correcting networks must beat the plain ones on a
joint's validation angle RMSE for the joint to be a candidate (a tie stays plain);
``TrainConfig.prior_margin`` sets it."""

PRIOR_BLEND = TrainConfig.prior_blend
"""Default: the even blend of both kinds is a candidate per joint (``TrainConfig.prior_blend``)."""

KINDS = ("plain", "prior")

BLEND = 0.5
"""The map-correcting networks' weight on a joint that the even blend of both kinds drives
(``[train] prior_blend``)."""


def model_kind(record: Mapping[str, Any]) -> str:
    """What :func:`choose_kinds`'s ``record`` made the model: ``"plain"`` (no joint chosen),
    ``"prior"`` (every joint, from the map-correcting networks alone) or ``"composite"``."""
    chosen = len(record["chosen"])
    if not chosen:
        return "plain"
    whole = chosen == len(record["names"]) and not record.get("blended")
    return "prior" if whole else "composite"


def map_pinned(
    cfg: TrainConfig, carrier: Surrogate, train: Sequence[Any], val: Sequence[Any]
) -> list[bool] | None:
    """The joints the static map choice that follows will put on the map whatever the networks
    (:func:`~.map_joints.pinned_joints` with ``cfg``'s options, on the run's ``carrier``
    network), when ``cfg.prior_skip_pinned`` and that choice pins any; else None."""
    if not (cfg.prior_skip_pinned and cfg.static_map and cfg.map_periodic):
        return None
    pinned = pinned_joints(carrier, train, val, **map_options(cfg))
    return pinned if any(pinned) else None


def spanned_joints(
    cfg: TrainConfig, spec: MachineSpec, train: Sequence[Any], val: Sequence[Any]
) -> list[bool]:
    """(n_joint,) the joints of ``spec`` whose validation commands span enough of the
    training's command range (:func:`~.span.joint_spans` at ``cfg.choice_min_span``): the
    data's alone, known before any network trains."""
    return list(joint_spans(train, val, spec, min_span=cfg.choice_min_span)[1])


def choice_joints(
    cfg: TrainConfig, carrier: Surrogate, train: Sequence[Any], val: Sequence[Any]
) -> dict[str, Any]:
    """The per-joint keyword options of :func:`choose_kinds` that the data and ``cfg`` set:
    ``spanned`` (:func:`spanned_joints`) and ``pinned`` (:func:`map_pinned`; only the
    validation rule reads it, so under ``prior_drive = "spanned"`` it is None and the map's
    validation free run is not paid for)."""
    reads_pinned = cfg.prior_drive == "validation"
    return {
        "pinned": map_pinned(cfg, carrier, train, val) if reads_pinned else None,
        "spanned": spanned_joints(cfg, carrier.spec, train, val),
    }


def choice_options(cfg: TrainConfig) -> dict[str, Any]:
    """The keyword options of :func:`choose_kinds` that ``cfg`` sets (the validation cap, the
    margin, the blend): every caller makes the choice as ``exsur train`` does."""
    return {
        "max_steps": cfg.val_steps or None,
        "drive": cfg.prior_drive,
        "margin": cfg.prior_margin,
        "blend": cfg.prior_blend,
    }


def choose_kinds(
    plains: Sequence[Surrogate],
    priors: Sequence[Surrogate],
    val: Sequence[Any],
    *,
    max_steps: int | None = None,
    drive: str = PRIOR_DRIVE,
    margin: float = PRIOR_MARGIN,
    blend: bool = PRIOR_BLEND,
    pinned: Sequence[bool] | None = None,
    spanned: Sequence[bool] | None = None,
    twins: Sequence[Surrogate] | None = None,
    twin_joints: Sequence[bool] | None = None,
) -> tuple[Surrogate, dict[str, Any]]:
    """The model of the two ensembles (see the module docstring) and the record of the choice.

    Args:
        plains: the K plain networks; priors: the P map-correcting ones (P divides K).
        val: the validation episodes.
        max_steps: validation free-run length cap (as the epoch selection's).
        drive: ``"spanned"``: the map-correcting networks drive every ``spanned`` joint
            that is not in ``twin_joints``, without a comparison (both ensembles are still
            scored on validation, for the record); ``"validation"``: the choice below.
        margin: a joint is a candidate for the map-correcting networks when their
            validation angle RMSE is below ``1 - margin`` times the plain ensemble's.
        blend: the even blend of both kinds (:data:`BLEND`) is a candidate on the same terms;
            a joint takes the candidate with the lower validation angle RMSE.
        pinned: (n_joint,) joints the static map choice will drive whatever the networks
            (:func:`map_pinned`): they cannot refuse a set (``best_set``'s ``ignore``).
        spanned: (n_joint,) joints whose validation commands span enough of the training's
            command range (:func:`~.span.joint_spans`); the others stay plain (default: all).
        twins, twin_joints: the plain side as pairs (:func:`~.composite.plain_ensemble`): the joints
            ``twin_joints`` take the exogenous inputs, from ``twins`` (:mod:`.variants`).

    Returns:
        ``(model, record)``; ``record`` holds both ensembles' validation scores, the
        candidate joints, the sets tried and what was chosen, with a one-line ``why``.
    """
    names = list(plains[0].spec.names)
    n_joint = len(names)
    sides: dict[str, Any] = {"twins": twins, "twin_joints": twin_joints}  # the pairs, if any
    merged = {"plain": plain_ensemble(plains, **sides), "prior": merge(list(priors))}
    if blend and drive != "spanned":
        merged["blend"] = composite(plains, priors, [BLEND] * n_joint, **sides)
    vals = {k: free_run_error(m, list(val), max_steps=max_steps) for k, m in merged.items()}
    spanned = list(spanned) if spanned is not None else [True] * n_joint
    if drive == "spanned":
        return _drive_spanned(plains, priors, merged, vals, spanned=spanned, **sides)
    base = vals["plain"]
    # per joint, the map-correcting networks' weight: the option (1 = their ensemble, 1/2 =
    # the even blend) with the lowest validation angle RMSE among those below (1 - margin)
    # times the plain ensemble's; 0 (plain) if none is
    scored = {1.0: vals["prior"]} | ({BLEND: vals["blend"]} if blend else {})
    weights = []
    for j, plain in enumerate(base["theta_rmse"]):
        ok = [
            (v["theta_rmse"][j], -w)
            for w, v in scored.items()
            if v["theta_rmse"][j] < (1 - margin) * plain
        ]
        weights.append(-min(ok)[1] if ok and spanned[j] else 0.0)
    cand = [w > 0 for w in weights]
    record: dict[str, Any] = {
        **_scores_record(names, vals, spanned),
        "candidates": [n for n, c in zip(names, cand) if c],
        "margin": margin,
        "blend": blend,
        "chosen": [],
        "weights": [0.0] * n_joint,
        "pinned": [n for n, p in zip(names, pinned or []) if p],
    }
    if blend:
        record["val_theta_rmse_blend"] = vals["blend"]["theta_rmse"]
        record["val_error_blend"] = vals["blend"]["val_error"]
    options_said = "nor the even blend of both kinds is" if blend else "are not"
    if not any(cand):
        record["why"] = (
            f"the map-correcting networks {options_said} below {1 - margin:.0%} of the plain "
            "ones' validation angle RMSE on any joint"
            + (
                f" whose validation commands span enough of its command range (not "
                f"{', '.join(record['unspanned'])})"
                if record["unspanned"]
                else ""
            )
            + ": the plain networks drive every joint"
        )
        return merged["plain"], record

    def weights_of(joints: Sequence[bool]) -> list[float]:
        return [w if p else 0.0 for w, p in zip(weights, joints)]

    def build(joints: Sequence[bool]) -> Surrogate:  # joints -> the composite taking them
        return composite(plains, priors, weights_of(joints), **sides)

    # the set of every joint at one weight is an ensemble scored above: not run again
    uniform = len(set(weights)) == 1 and weights[0] in scored
    known = {(True,) * n_joint: scored[weights[0]]} if uniform else {}
    best = best_set(
        cand, build, base, val, record=record, max_steps=max_steps, known=known, ignore=pinned
    )
    if best is None:
        record["why"] = (
            "every set of joints on the map-correcting networks"
            + (" (or on the even blend of both kinds)" if blend else "")
            + f" is worse than the plain networks' validation error {base['val_error']:.4g} "
            "by more than "
            f"{SET_MARGIN:.0%} overall, or on a joint by more than the whole gains: the plain "
            "networks drive every joint"
        )
        return merged["plain"], record
    model, got, joints = best
    record["weights"] = weights_of(joints)
    record["chosen"] = [n for n, p in zip(names, joints) if p]
    record["blended"] = [n for n, w in zip(names, record["weights"]) if 0.0 < w < 1.0]
    whole = [n for n in record["chosen"] if n not in record["blended"]]
    who = [f"{', '.join(whole)} from the map-correcting networks"] if whole else []
    if record["blended"]:
        who.append(f"{', '.join(record['blended'])} from the even blend of both kinds")
    record["why"] = (
        f"{'; '.join(who)}: validation error {got['val_error']:.4g} against the plain "
        f"networks' {base['val_error']:.4g}"
    )
    return model, record


def _scores_record(
    names: Sequence[str], vals: Mapping[str, Mapping[str, Any]], spanned: Sequence[bool]
) -> dict[str, Any]:
    """The part of :func:`choose_kinds`'s record that both ways of giving the joints their
    kind share: both ensembles' validation scores and the unspanned joints (no set tried, no
    joint blended yet)."""
    return {
        "names": list(names),
        "val_theta_rmse_plain": vals["plain"]["theta_rmse"],
        "val_theta_rmse_prior": vals["prior"]["theta_rmse"],
        "val_error_plain": vals["plain"]["val_error"],
        "val_error_prior": vals["prior"]["val_error"],
        "tried": [],
        "blended": [],
        "unspanned": [n for n, sp in zip(names, spanned) if not sp],
    }


def _drive_spanned(
    plains: Sequence[Surrogate],
    priors: Sequence[Surrogate],
    merged: Mapping[str, Surrogate],
    vals: Mapping[str, Mapping[str, Any]],
    *,
    spanned: Sequence[bool],
    twins: Sequence[Surrogate] | None,
    twin_joints: Sequence[bool] | None,
) -> tuple[Surrogate, dict[str, Any]]:
    """:func:`choose_kinds` with ``drive = "spanned"``: the map-correcting networks drive every
    spanned joint that takes no exogenous inputs of its own (``twin_joints``), the plain
    networks the rest; both ensembles' validation scores (``vals`` of ``merged``) go in the
    record, unused."""
    names = list(plains[0].spec.names)
    own_inputs = list(twin_joints) if twin_joints is not None else [False] * len(names)
    joints = [bool(s) and not bool(t) for s, t in zip(spanned, own_inputs)]
    weights = [1.0 if p else 0.0 for p in joints]
    record: dict[str, Any] = {
        **_scores_record(names, vals, spanned),
        "drive": "spanned",
        "candidates": [n for n, p in zip(names, joints) if p],
        "chosen": [n for n, p in zip(names, joints) if p],
        "weights": weights,
        "pinned": [],
        "own_inputs": [n for n, t in zip(names, own_inputs) if t],
    }
    rest = []  # why the other joints stay plain
    if record["unspanned"]:
        rest.append(
            f"{', '.join(record['unspanned'])}: validation commands span too little of the "
            "training's"
        )
    if record["own_inputs"]:
        rest.append(f"{', '.join(record['own_inputs'])}: takes the exogenous inputs its own way")
    if not any(joints):
        record["why"] = "the plain networks drive every joint (" + "; ".join(rest) + ")"
        return merged["plain"], record
    if all(joints):
        model = merged["prior"]
    else:
        model = composite(plains, priors, weights, twins=twins, twin_joints=twin_joints)
    record["why"] = (
        f"{', '.join(record['chosen'])}: validation spans their commands"
        + (f"; plain: {'; '.join(rest)}" if rest else "")
        + f"; validation error {vals['prior']['val_error']:.4g} for the map-correcting networks "
        f"and {vals['plain']['val_error']:.4g} for the plain ones, not compared"
    )
    return model, record


def train_choosing_kinds(
    cfg: TrainConfig,
    dataset: Dataset,
    *,
    out: str | Path,
    show_progress: bool | None = None,
    notes: Mapping[str, Any] | None = None,
) -> Path:
    """Train the plain ensemble of ``cfg.members`` networks and :func:`~.plan.prior_members` more
    that correct the static map, and keep per joint the kind (or their blend) that validates
    better (see the module docstring); returns ``OUT/best.pt``."""
    n_plain, n_prior = cfg.members, prior_members(cfg.members)
    val_eps, out, workers = open_run(cfg, dataset, out, notes=notes, trainings=n_plain + n_prior)
    _log.info(
        f"two kinds of network: {n_plain} plain and {n_prior} correcting the static map (seeds "
        f"from {cfg.seed}), {workers} in parallel; "
        + (
            "the map-correcting networks drive every joint whose validation spans its commands"
            if cfg.prior_drive == "spanned"
            else "per joint, the kind that validates better"
            + (" (or the even blend of both)" if cfg.prior_blend else "")
        )
    )
    t0 = time.monotonic()
    # the members are single networks: the static map choice runs on the model they make
    base = replace(cfg, prior_choice=False, static_map=False)
    cfgs = {
        "plain": member_configs(base),
        "prior": member_configs(replace(base, prior=True, members=n_prior)),
    }
    nets = train_groups(cfgs, dataset, out=out, workers=workers, show_progress=show_progress)
    train_eps, _ = split_episodes(cfg, dataset)
    model, record = choose_kinds(
        nets["plain"],
        nets["prior"],
        val_eps,
        **choice_joints(cfg, nets["plain"][0], train_eps, val_eps),
        **choice_options(cfg),
    )
    _log.info(f"two kinds of network: {record['why']}")
    kind = model_kind(record)
    best = merge_members(
        cfg,
        cfgs["plain"] + cfgs["prior"],
        nets["plain"] + nets["prior"],
        val_eps,
        out=out,
        t0=t0,
        training={"kinds": record},
        merged=model,
        column=("kind", [k for k in KINDS for _ in cfgs[k]], kind),
    )
    write_config(out, cfg, notes={**(notes or {}), "kinds": record})
    return best
