"""Exogenous inputs that must not hurt: ``[train] exogenous = "choose"``.

A throttle, a gear or a run condition (``spec.inputs``) may help one joint and hurt
another on held-out data.  With ``choose`` the ensemble's members are trained in two ways
on the same seeds: :func:`probe_members` of them (2, at most half) use the inputs, as many
ignore them (their input weights held at zero, :func:`~.loop.blind_inputs`).  Each half is
merged and scored by its validation free run; the inputs are kept only if that half is
better by :data:`INPUT_MARGIN` overall and no joint's angle RMSE is worse by more than it.
The remaining members are then trained the chosen way and merged with the winning half, so
the result is an ensemble of ``members`` networks, as without inputs (the recipe plans the
epochs for the ``members + probe_members(members)`` trainings within the same budget).
With ``prior_choice`` the kind choice's map-correcting networks (:mod:`.kinds`) train
beside the rest, the chosen way, and the kinds are chosen per joint on the result.

**Per joint** (``[train] inputs_per_joint``, default true): an input can help one joint
and hurt another (the wheel loader's throttle and gear helped its boom and hurt its
bucket).  When the whole ``use`` half is refused, the joints on which it beats the
``ignore`` half by the margin (:func:`input_joints`) are candidates to take the inputs
alone, but for a joint the static map choice will drive whatever the networks
(:func:`~.kinds.map_pinned`: its gain would not last).  Each seed's two networks, the one
that uses the inputs and the one that ignores them, become one (:func:`paired`: joint ``j``
is the first's where ``j`` takes the inputs, the second's elsewhere), and the seeds' pairs
are merged as an ensemble.  The candidates together, and each alone, are scored by that
model's validation free run, and a set is kept under the same rule as the whole ``use``
half against the ``ignore`` half (:func:`choose_inputs`: better by the margin overall, no
joint worse by more; a joint's choice moves the angles the others read).  The lowest kept set wins; the rest of the budget
then trains pairs (one network each way, the same seed), so the model is an ensemble of
``half + (members - half) // 2`` pairs.  With ``prior_choice`` the map-correcting networks
train instead of some of those pairs (they ignore the inputs, and must divide the pairs
evenly: :func:`more_pairs`; 4 members: the choice's 2 pairs and 2 map-correcting networks),
and the kind choice runs with the pairs as its plain side (:func:`~.kinds.choose_kinds`'s
``twins``).

Layout: ``OUT/member_*`` (the ensemble's members, as for any ensemble: the winning half,
then the rest), ``OUT/use/member_*`` or ``OUT/ignore/member_*`` (the losing half),
``OUT/prior/member_*`` (with ``prior_choice``), ``OUT/best.pt`` (the merged ensemble,
``metrics.training.exogenous`` and ``kinds`` say what was chosen and why),
``OUT/config.toml`` (``[exogenous]``, ``[kinds]``: the same).  With the inputs on some
joints: ``OUT/use/member_*`` and ``OUT/ignore/member_*``, the pairs' two networks (and
``OUT/prior/member_*`` with ``prior_choice``).
"""

from __future__ import annotations

import logging
import os
import time
from collections.abc import Mapping, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

from ..data.dataset import Dataset
from ..surrogate.checkpoint import load_checkpoint
from ..surrogate.ensemble import merge
from ..surrogate.model import Surrogate
from ..surrogate.validation import free_run_error
from .batches import split_episodes
from .config import TrainConfig
from .ensembles import member_configs, merge_members, open_run, train_groups, train_member
from .jobs import TrainJob, run_jobs
from .kinds import (
    choice_joints,
    choice_options,
    choose_kinds,
    map_pinned,
    model_kind,
    plain_ensemble,
    prior_members,
    spanned_joints,
)
from .records import write_config

_log = logging.getLogger(__name__)

INPUT_PROBE = 2
"""Networks per way (using the inputs, ignoring them) that decide the input choice, at most
half the members (:func:`probe_members`): the losing way's networks are the choice's cost,
so it stays the same however many members the budget buys."""

INPUT_MARGIN = 0.05
"""Relative margin by which the members that use the exogenous inputs must beat those that
ignore them on validation (overall, and no joint worse by more): a tie keeps the model that
cannot depend on them."""


def probe_members(members: int) -> int:
    """Networks per way that decide the input choice of an ensemble of ``members``:
    :data:`INPUT_PROBE`, at most half of them, at least 1."""
    return max(1, min(INPUT_PROBE, members // 2))


def choose_inputs(use: Mapping[str, Any], ignore: Mapping[str, Any]) -> tuple[bool, str]:
    """Keep the inputs? From the two halves' validation free runs
    (:func:`~excavator_surrogate.surrogate.validation.free_run_error` results).

    Returns:
        ``(keep, reason)``, the reason one line with both scores.
    """
    m = INPUT_MARGIN
    worse = [
        j
        for j, (a, b) in enumerate(zip(use["theta_rmse"], ignore["theta_rmse"]))
        if not a <= (1 + m) * b  # NaN: worse
    ]
    better = use["val_error"] < (1 - m) * ignore["val_error"]
    keep = bool(better and not worse)
    why = (
        f"validation error {use['val_error']:.4g} with the inputs, {ignore['val_error']:.4g} "
        f"without: {'kept' if keep else 'ignored'}"
    )
    if not keep:
        why += (
            f" (joint(s) {worse} worse by more than {m:.0%})"
            if worse
            else f" (not better by {m:.0%})"
        )
    return keep, why


def input_joints(use: Mapping[str, Any], ignore: Mapping[str, Any]) -> list[bool]:
    """Per joint: does the half that uses the inputs beat the half that ignores them by
    :data:`INPUT_MARGIN` on its validation angle RMSE?  (A NaN is no.)"""
    m = INPUT_MARGIN
    return [bool(a < (1 - m) * b) for a, b in zip(use["theta_rmse"], ignore["theta_rmse"])]


def paired(
    use: Sequence[Surrogate], ignore: Sequence[Surrogate], joints: Sequence[bool]
) -> Surrogate:
    """The ensemble of the seeds' pairs: pair ``i`` is one network whose joint ``j`` is
    ``use[i]``'s where ``joints[j]``, else ``ignore[i]``'s (a composite,
    :func:`~excavator_surrogate.surrogate.ensemble.merge` with ``joint_weights``); the pairs
    are merged as the ensemble's members.

    Args:
        use, ignore: as many networks each, trained with the inputs used and ignored (pair
            ``i`` on the same seed).
        joints: (n_joint,) the joints that take the inputs.
    """
    return plain_ensemble(ignore, twins=use, twin_joints=joints)


def more_pairs(members: int, half: int, n_prior: int) -> int | None:
    """Pairs to train after the choice's ``half``: as many as the rest of the budget buys
    (``(members - half) // 2``, each pair two trainings), with the kind choice's
    ``n_prior`` map-correcting networks as many fewer as it takes for them to divide the
    pairs evenly (:func:`~.kinds.composite`); None if no count does."""
    limit = (members - half) // 2
    fits = [n for n in range(limit + 1) if not n_prior or (half + n) % n_prior == 0]
    return max(fits) if fits else None


def choose_input_joints(
    use: Sequence[Surrogate],
    ignore: Sequence[Surrogate],
    vals: Mapping[str, Mapping[str, Any]],
    val: Sequence[Any],
    *,
    max_steps: int | None = None,
    pinned: Sequence[bool] | None = None,
) -> tuple[list[bool] | None, list[dict[str, Any]]]:
    """The joints that take the inputs alone (see the module docstring), or None.

    Args:
        use, ignore: the two halves' networks (pair ``i`` on the same seed).
        vals: ``{"use": ..., "ignore": ...}``, each half's merged validation free run.
        val: the validation episodes.
        max_steps: validation free-run length cap.
        pinned: (n_joint,) joints the static map choice will drive whatever the networks
            (:func:`~.kinds.map_pinned`): no candidates, since their own gain would not last.

    Returns:
        ``(joints or None, tried)``: the kept set of lowest validation error, and one entry
        per set tried (its joints' names, validation error and angle RMSE, kept or not).
    """
    cand = input_joints(vals["use"], vals["ignore"])
    if pinned is not None:
        cand = [c and not p for c, p in zip(cand, pinned)]
    n_joint = len(cand)
    sets = [cand] if 0 < sum(cand) < n_joint else []  # all joints: the whole half, refused
    if sum(cand) > 1:
        sets += [[k == j for k in range(n_joint)] for j, c in enumerate(cand) if c]
    names = list(use[0].spec.names)
    tried: list[dict[str, Any]] = []
    best: tuple[float, list[bool]] | None = None
    for joints in sets:
        got = free_run_error(paired(use, ignore, joints), list(val), max_steps=max_steps)
        ok, _ = choose_inputs(got, vals["ignore"])
        tried.append(
            {
                "joints": [n for n, p in zip(names, joints) if p],
                "val_error": got["val_error"],
                "val_theta_rmse": got["theta_rmse"],
                "kept": ok,
            }
        )
        if ok and (best is None or got["val_error"] < best[0]):
            best = (got["val_error"], joints)
    return (None if best is None else best[1]), tried


def decide_inputs(
    cfg: TrainConfig,
    use: Sequence[Surrogate],
    ignore: Sequence[Surrogate],
    val_eps: list[Any],
    *,
    dataset: Dataset,
    n_prior: int,
    pairs: str,
    per_joint: bool = True,
    **extra: Any,
) -> tuple[dict[str, Any], bool, list[bool] | None, dict[str, Any]]:
    """The input choice on validation: the whole way (:func:`choose_inputs`), then, where it
    is refused, ``cfg.inputs_per_joint`` and ``per_joint`` allow and some joint is a
    candidate, the joints that take the inputs alone (:func:`choose_input_joints`).

    Args:
        use, ignore: networks with the inputs used and ignored (network ``i`` of each on the
            same seed, or the same network both ways).
        val_eps: the validation episodes; ``dataset``: the run's (its training split).
        n_prior: the kind choice's map-correcting networks (0: no kind choice).
        pairs, extra: for the record (:func:`choice_record`).

    Returns:
        ``(record, keep, joints, options)``: the choice's record (:func:`choice_record`),
        :func:`choose_inputs`'s verdict, :func:`choose_input_joints`'s joints (None where
        not tried), and the kind choice's per-joint options found on the way
        (``pinned``: :func:`~.kinds.map_pinned`, which the input choice reads too, and with
        ``n_prior`` ``spanned``: :func:`~.kinds.spanned_joints`; empty where not needed).
    """
    max_steps = cfg.val_steps or None
    vals = {
        "use": free_run_error(merge(list(use)), val_eps, max_steps=max_steps),
        "ignore": free_run_error(merge(list(ignore)), val_eps, max_steps=max_steps),
    }
    keep, why = choose_inputs(vals["use"], vals["ignore"])
    joints: list[bool] | None = None
    tried: list[dict[str, Any]] = []
    # the kind choice's options per joint, found once (they read the data and the networks'
    # window, spec and end stops only: the same for every network of the run)
    options: dict[str, Any] = {}
    # the pinned joints cost a map free run: only where some joint is a candidate at all
    if (
        not keep
        and cfg.inputs_per_joint
        and per_joint
        and any(input_joints(vals["use"], vals["ignore"]))
    ):
        train_eps = split_episodes(cfg, dataset)[0]
        carrier = ignore[0]
        # the input choice reads the pinned joints under either kind rule
        options = {"pinned": map_pinned(cfg, carrier, train_eps, val_eps)}
        if n_prior:
            options["spanned"] = spanned_joints(cfg, carrier, train_eps, val_eps)
        joints, tried = choose_input_joints(
            use, ignore, vals, val_eps, max_steps=max_steps, pinned=options["pinned"]
        )
    spec = dataset.spec
    record = choice_record(
        spec.u_names[spec.n_joint :],
        spec.names,
        vals,
        keep=keep,
        why=why,
        joints=joints,
        tried=tried,
        pairs=pairs,
        **extra,
    )
    return record, keep, joints, options


def choice_record(
    names: Sequence[str],
    joint_names: Sequence[str],
    vals: Mapping[str, Mapping[str, Any]],
    *,
    keep: bool,
    why: str,
    joints: Sequence[bool] | None,
    tried: list[dict[str, Any]],
    pairs: str,
    **extra: Any,
) -> dict[str, Any]:
    """The input choice's record (``metrics.training.exogenous``, ``[exogenous]``).

    Args:
        names: the exogenous inputs; ``joint_names``: the machine's joints.
        vals: ``{"use": ..., "ignore": ...}``, each way's merged validation free run.
        keep: the inputs kept on every joint; ``why``: :func:`choose_inputs`'s reason.
        joints: (n_joint,) the joints that take them alone (:func:`choose_input_joints`), or
            None; ``tried``: its sets.
        pairs: what each joint-by-joint network is made of, for the reason.
        extra: more entries (how the ways were trained).
    """
    record = {
        "inputs": list(names),
        "kept": keep or joints is not None,
        "joints": list(joint_names) if keep else [],
        "per_joint": joints is not None,
        "why": why,
        "val_error_use": vals["use"]["val_error"],
        "val_error_ignore": vals["ignore"]["val_error"],
        "theta_rmse_use": vals["use"]["theta_rmse"],
        "theta_rmse_ignore": vals["ignore"]["theta_rmse"],
        **extra,
        "tried": tried,
    }
    if joints is not None:
        taken = [n for n, p in zip(joint_names, joints) if p]
        got = next(t for t in tried if t["joints"] == taken)
        record["joints"] = taken
        record["why"] = (
            f"{why}; {', '.join(taken)} take them alone: validation error "
            f"{got['val_error']:.4g} ({pairs} with and without them, joint by joint)"
        )
    return record


def train_choosing_inputs(
    cfg: TrainConfig,
    dataset: Dataset,
    *,
    out: str | Path,
    show_progress: bool | None = None,
    notes: Mapping[str, Any] | None = None,
) -> Path:
    """Train ``cfg.members`` networks with the exogenous inputs used or ignored, whichever
    validates better (see the module docstring); returns ``OUT/best.pt``."""
    half = probe_members(cfg.members)
    n_prior = prior_members(cfg.members) if cfg.prior_choice else 0
    val_eps, out, workers = open_run(cfg, dataset, out, notes=notes, trainings=2 * half)
    names = list(dataset.spec.u_names[dataset.spec.n_joint :])
    _log.info(
        f"exogenous inputs {names}: {half} member(s) use them, {half} ignore them "
        f"(same seeds), {workers} in parallel; the better way trains the rest"
        + (f" and {n_prior} network(s) correcting the static map" if n_prior else "")
    )
    t0 = time.monotonic()
    ways = ("use", "ignore")
    base = replace(cfg, prior_choice=False, static_map=False)  # single networks
    cfgs = {w: member_configs(replace(base, exogenous=w))[:half] for w in ways}
    halves = train_groups(cfgs, dataset, out=out, workers=workers, show_progress=show_progress)
    fits = more_pairs(cfg.members, half, n_prior) is not None
    record, keep, joints, per_joint = decide_inputs(
        cfg,
        halves["use"],
        halves["ignore"],
        val_eps,
        dataset=dataset,
        n_prior=n_prior,
        pairs="each seed's networks",
        per_joint=fits,
        members_per_way=half,
    )
    why = record["why"]
    if joints is not None:
        _log.info(f"exogenous inputs {names}: {why}")
        return _train_pairs(
            cfg,
            dataset,
            halves,
            cfgs,
            joints,
            record,
            per_joint=per_joint,
            val_eps=val_eps,
            out=out,
            t0=t0,
            workers=workers,
            show_progress=show_progress,
            notes=notes,
        )
    way = "use" if keep else "ignore"
    _log.info(f"exogenous inputs {names}: {why}")
    for i in range(half):  # the winning half becomes the ensemble's first members
        os.replace(out / way / f"member_{i}", out / f"member_{i}")
    (out / way).rmdir()
    rest = member_configs(replace(base, exogenous=way))[half:]
    # the kind choice's map-correcting networks treat the inputs the chosen way too
    priors = (
        member_configs(replace(base, exogenous=way, prior=True, members=n_prior)) if n_prior else []
    )
    rest_jobs = [
        TrainJob(
            cfg=c, dataset=dataset, out=out / f"member_{half + i}", tag=f"exsur member {half + i}"
        )
        for i, c in enumerate(rest)
    ] + [
        TrainJob(cfg=c, dataset=dataset, out=out / "prior" / f"member_{i}", tag=f"exsur prior {i}")
        for i, c in enumerate(priors)
    ]
    more = run_jobs(
        train_member,
        rest_jobs,
        workers=min(workers, max(1, len(rest_jobs))),
        show_progress=show_progress,
    )
    training: dict[str, Any] = {"exogenous": record}
    lost = "ignore" if keep else "use"
    if any((m.metrics or {}).get("training", {}).get("budget_cut") for m in halves[lost]):
        training["budget_cut"] = True  # the choice itself depended on the clock: say so
    final_cfg = replace(cfg, exogenous=way)
    final_cfgs = cfgs[way] + rest
    nets = [load_checkpoint(p) for p in more]
    plains, prior_nets = halves[way] + nets[: len(rest)], nets[len(rest) :]
    model, column = None, ("exogenous", [c.exogenous for c in final_cfgs], way)
    if n_prior:  # the kinds, per joint, among the networks trained the chosen way
        if not per_joint:  # not found for the inputs per joint above
            per_joint = choice_joints(cfg, plains[0], split_episodes(cfg, dataset)[0], val_eps)
        model, kinds = choose_kinds(plains, prior_nets, val_eps, **per_joint, **choice_options(cfg))
        _log.info(f"two kinds of network: {kinds['why']}")
        training["kinds"] = kinds
        column = ("kind", ["plain"] * len(plains) + ["prior"] * len(prior_nets), model_kind(kinds))
    best = merge_members(
        final_cfg,
        final_cfgs + priors,
        plains + prior_nets,
        val_eps,
        out=out,
        t0=t0,
        training=training,
        merged=model,
        column=column,
    )
    chosen = {k: training[k] for k in ("exogenous", "kinds") if k in training}  # the records
    write_config(out, cfg, notes={**(notes or {}), **chosen})
    return best


def inputs_after_kinds(record: dict[str, Any], kinds: Mapping[str, Any]) -> None:
    """Update the input choice's ``record`` in place after the kind choice (``kinds``, its
    record): a joint that the map-correcting networks, which ignore the inputs, drive alone
    (weight 1) no longer reads them; with none left the inputs are not ``kept``."""
    alone = [n for n, w in zip(kinds["names"], kinds["weights"]) if w >= 1.0]
    if not any(n in alone for n in record["joints"]):
        return
    record["joints"] = [n for n in record["joints"] if n not in alone]
    record["kept"] = bool(record["joints"])
    record["why"] += (
        f"; the map-correcting networks, which ignore them, drive {', '.join(alone)}"
        + (
            f": {', '.join(record['joints'])} read them"
            if record["joints"]
            else ": no joint reads them"
        )
    )


def _train_pairs(
    cfg: TrainConfig,
    dataset: Dataset,
    halves: Mapping[str, list[Surrogate]],
    cfgs: Mapping[str, list[TrainConfig]],
    joints: Sequence[bool],
    record: dict[str, Any],
    *,
    per_joint: Mapping[str, Any],
    val_eps: list[Any],
    out: Path,
    t0: float,
    workers: int,
    show_progress: bool | None,
    notes: Mapping[str, Any] | None,
) -> Path:
    """The inputs on some joints (:func:`choose_input_joints`): the rest of the budget trains
    :func:`more_pairs` more pairs (each way, the same seeds) and, with ``prior_choice``, the
    kind choice's map-correcting networks (ignoring the inputs: a tie keeps the model that
    cannot depend on them).  The model is :func:`paired` over every pair, or the kind
    choice's model with the pairs as its plain side (``per_joint``: its
    :func:`~.kinds.choice_joints` options); returns ``OUT/best.pt``."""
    half = len(halves["use"])
    n_prior = prior_members(cfg.members) if cfg.prior_choice else 0
    n_more = more_pairs(cfg.members, half, n_prior) or 0
    base = replace(cfg, prior_choice=False, static_map=False)
    rest = {
        w: member_configs(replace(base, exogenous=w))[half : half + n_more]
        for w in ("use", "ignore")
    }
    priors = (
        member_configs(replace(base, exogenous="ignore", prior=True, members=n_prior))
        if n_prior
        else []
    )
    if n_prior and n_more < (cfg.members - half) // 2:
        _log.info(
            f"exogenous inputs: {n_more} more pair(s) and {n_prior} map-correcting network(s): "
            f"{n_prior} must divide the {half + n_more} pairs, so "
            f"{2 * ((cfg.members - half) // 2 - n_more)} planned training(s) are not run"
        )
    jobs = [
        TrainJob(
            cfg=c, dataset=dataset, out=out / w / f"member_{half + i}", tag=f"exsur {w} {half + i}"
        )
        for w, cs in rest.items()
        for i, c in enumerate(cs)
    ] + [
        TrainJob(cfg=c, dataset=dataset, out=out / "prior" / f"member_{i}", tag=f"exsur prior {i}")
        for i, c in enumerate(priors)
    ]
    paths = (
        run_jobs(
            train_member, jobs, workers=min(workers, max(1, len(jobs))), show_progress=show_progress
        )
        if jobs
        else []
    )
    more = [load_checkpoint(p) for p in paths]
    use = list(halves["use"]) + more[:n_more]
    ignore = list(halves["ignore"]) + more[n_more : 2 * n_more]
    prior_nets = more[2 * n_more :]
    final_cfgs = list(cfgs["use"]) + rest["use"] + list(cfgs["ignore"]) + rest["ignore"]
    training: dict[str, Any] = {"exogenous": record}
    if not n_prior:
        model = paired(use, ignore, joints)
    else:  # the kinds, per joint, with the pairs as the plain side
        model, kinds = choose_kinds(
            ignore,
            prior_nets,
            val_eps,
            twins=use,
            twin_joints=joints,
            **per_joint,
            **choice_options(cfg),
        )
        _log.info(f"two kinds of network: {kinds['why']}")
        training["kinds"] = kinds
        inputs_after_kinds(record, kinds)
    best = merge_members(
        replace(cfg, exogenous="use"),
        final_cfgs + priors,
        use + ignore + prior_nets,
        val_eps,
        out=out,
        t0=t0,
        training=training,
        merged=model,
        column=(
            "exogenous",
            [c.exogenous for c in final_cfgs] + ["ignore (map-correcting)"] * n_prior,
            "per joint",
        ),
    )
    write_config(out, cfg, notes={**(notes or {}), **training})
    return best
