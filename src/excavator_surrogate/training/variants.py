"""Exogenous inputs that must not hurt: ``[train] exogenous = "choose"``.

A throttle, a gear or a run condition (``spec.inputs``) may help one joint and hurt
another on held-out data.  With ``choose`` the ensemble's members are trained in two ways
on the same seeds: :func:`~.plan.probe_members` of them (2, at most half) use the inputs, as many
ignore them (trained without their columns, stored with zero weights for them,
:mod:`.ignored`).  Each half is
merged and scored by its validation free run; the inputs are kept only if that half is
better by :data:`~.input_choice.INPUT_MARGIN` overall and no joint's angle RMSE is worse by more than it.
The remaining members are then trained the chosen way and merged with the winning half, so
the result is an ensemble of ``members`` networks, as without inputs (the recipe plans the
epochs for the ``members + probe_members(members)`` trainings within the same budget).
With ``prior_choice`` the kind choice's map-correcting networks (:mod:`.kinds`) train
beside the rest, ignoring the inputs whichever way won, and the kinds are chosen per joint
on the result: the joints they drive never take an input chosen on validation (on the
10-minute loader log the throttle kept on its one validation segment cost their boom 1.38x
held out; ignoring it, 3 cells of 4 better; docs/real-history.md, session 96).  Where they
drive every joint the recipe does not run the trial at all (:mod:`.auto`); a forced one
there warns when no joint can take the inputs alone either (:func:`trial_reaches_no_joint`),
and a kept input's record drops the joints they drive alone.

**Per joint** (``[train] inputs_per_joint``, default true): an input can help one joint
and hurt another (the wheel loader's throttle and gear helped its boom and hurt its
bucket).  When the whole ``use`` half is refused, the joints on which it beats the
``ignore`` half by the margin (:func:`~.input_choice.input_joints`) are candidates to take the inputs
alone, but for a joint the static map choice will drive whatever the networks
(:func:`~.kinds.map_pinned`: its gain would not last).  Each seed's two networks, the one
that uses the inputs and the one that ignores them, become one (:func:`~.input_choice.paired`: joint ``j``
is the first's where ``j`` takes the inputs, the second's elsewhere), and the seeds' pairs
are merged as an ensemble.  The candidates together, and each alone, are scored by that
model's validation free run, and a set is kept under the same rule as the whole ``use``
half against the ``ignore`` half (:func:`~.input_choice.choose_inputs`: better by the margin overall, no
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
from ..surrogate.model import Surrogate
from .batches import split_episodes
from .config import TrainConfig
from .ensembles import member_configs, merge_members, open_run, train_groups, train_member
from .input_choice import decide_inputs, inputs_after_kinds, paired
from .jobs import TrainJob, run_jobs
from .kinds import choice_joints, choice_options, choose_kinds, model_kind, spanned_joints
from .plan import prior_members, probe_members
from .records import write_config

_log = logging.getLogger(__name__)


def more_pairs(members: int, half: int, n_prior: int) -> int | None:
    """Pairs to train after the choice's ``half``: as many as the rest of the budget buys
    (``(members - half) // 2``, each pair two trainings), with the kind choice's
    ``n_prior`` map-correcting networks as many fewer as it takes for them to divide the
    pairs evenly (:func:`~.composite.composite`); None if no count does."""
    limit = (members - half) // 2
    fits = [n for n in range(limit + 1) if not n_prior or (half + n) % n_prior == 0]
    return max(fits) if fits else None


def blind_priors(base: TrainConfig, n_prior: int) -> list[TrainConfig]:
    """The configs of the kind choice's ``n_prior`` map-correcting networks (of ``base``'s
    single networks): they ignore the exogenous inputs whichever way the choice went.  They
    drive every spanned joint without a comparison on validation, so nothing vouches for
    their use of an input the plain probe networks chose there (docs/real.md), and where
    the inputs go to some joints only, a tie keeps the model that cannot depend on them."""
    if not n_prior:
        return []
    return member_configs(replace(base, exogenous="ignore", prior=True, members=n_prior))


def trial_reaches_no_joint(
    cfg: TrainConfig, dataset: Dataset, val_eps: Sequence[Any], *, half: int, n_prior: int
) -> bool:
    """Whether the input trial can give the inputs to no joint: the kind choice's
    ``n_prior`` map-correcting networks, which ignore them (:func:`blind_priors`), drive
    every joint (``prior_drive = "spanned"`` and validation spans every joint's commands,
    :func:`~.kinds.spanned_joints`, as the kind choice reads them), and no joint can take
    them alone on its plain pairs
    (``inputs_per_joint`` off, or no pair count fits beside ``half``: :func:`more_pairs`).
    The recipe then runs no trial (:mod:`.auto`); a forced ``exogenous = "choose"`` does."""
    if not n_prior or cfg.prior_drive != "spanned":
        return False
    if cfg.inputs_per_joint and more_pairs(cfg.members, half, n_prior) is not None:
        return False
    train_eps = split_episodes(cfg, dataset)[0]
    return all(spanned_joints(cfg, dataset.spec, train_eps, val_eps))


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
    if trial_reaches_no_joint(cfg, dataset, val_eps, half=half, n_prior=n_prior):
        _log.warning(
            f"exogenous inputs {names}: this trial decides no joint: validation spans every "
            "joint's commands, so the map-correcting networks, which ignore the inputs, drive "
            "them all, and no joint can take the inputs alone (inputs_per_joint is off or no "
            'pair count fits); its probe networks only cost epochs. Set exogenous = "use" to '
            'let every network read them, prior_drive = "validation" to choose the kinds on '
            'validation too, or exogenous = "ignore"'
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
    priors = blind_priors(base, n_prior)
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
    if n_prior:  # the kinds, per joint: the plain networks the chosen way, the others blind
        if not per_joint:  # not found for the inputs per joint above
            per_joint = choice_joints(cfg, plains[0], split_episodes(cfg, dataset)[0], val_eps)
        model, kinds = choose_kinds(plains, prior_nets, val_eps, **per_joint, **choice_options(cfg))
        _log.info(f"two kinds of network: {kinds['why']}")
        training["kinds"] = kinds
        inputs_after_kinds(record, kinds)  # a kept input: the joints the blind ones drive alone
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
    """The inputs on some joints (:func:`~.input_choice.choose_input_joints`): the rest of the budget trains
    :func:`more_pairs` more pairs (each way, the same seeds) and, with ``prior_choice``, the
    kind choice's map-correcting networks (ignoring the inputs: a tie keeps the model that
    cannot depend on them).  The model is :func:`~.input_choice.paired` over every pair, or the kind
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
    priors = blind_priors(base, n_prior)
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
