"""Exogenous inputs chosen on networks that learned both ways (``exogenous = "choose"`` with
``input_dropout`` > 0; an option, not the recipe's: docs/real-history.md, session 49).

Every member trains with the inputs, and on ``input_dropout`` of its sub-sequences with them
blanked (feature 0, their training mean: :meth:`~.modes.Stateful._blanked`).  Each network
then runs both ways: as trained, and :func:`blinded`, its input weights of the inputs
zeroed, so it cannot depend on them.  The choice of :mod:`.variants` is made on these two
ways of the same networks, under the same rule (:func:`~.input_choice.choose_inputs`: the
inputs are kept only if the ensemble that uses them is better on validation by
:data:`~.input_choice.INPUT_MARGIN` overall and no joint is worse by more; else, per joint,
:func:`~.input_choice.choose_input_joints`).  No network is trained only to lose the choice: the
budget's trainings all go to the ensemble, as many as without inputs (the probe of
:mod:`.variants` spent 2 of 6 on the losing way, and h1-dev's bucket with the H/L condition
scored as 4 members instead of 6).

With ``prior_choice`` the kind choice's map-correcting networks train the same way beside
the plain ones, and follow the chosen way: as trained where the inputs are kept, blinded
where they are refused or go to some joints only (there the plain networks' two ways are
the pairs, :func:`~.input_choice.paired`, as in :mod:`.variants`).

Layout: ``OUT/member_*`` (every network, as trained; with ``prior_choice`` the kind
choice's ``OUT/plain/member_*`` and ``OUT/prior/member_*``), ``OUT/best.pt`` (the chosen
model; ``metrics.training.exogenous`` says what was chosen and why, with ``"dual": true``),
``OUT/config.toml`` (``[exogenous]``).

Measured (session 49, h1-dev with its H/L condition and the 7-minute loader log with its
throttle): better on the validation the choices are made on, but not on held-out data: on
h1-dev's held-out duty 80 the bucket scored 9.89 against 8.49 deg for the probe, and on
the loader's test the boom 5.65 against 5.36 deg (medians of three seeds).
"""

from __future__ import annotations

import copy
import logging
import time
from collections.abc import Mapping, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import torch

from ..data.dataset import Dataset
from ..surrogate.ensemble import merge
from ..surrogate.model import Surrogate
from .batches import split_episodes
from .composite import plain_ensemble
from .config import TrainConfig
from .ensembles import member_configs, merge_members, open_run, train_groups, train_members
from .input_choice import decide_inputs, inputs_after_kinds
from .kinds import choice_joints, choice_options, choose_kinds, model_kind
from .plan import prior_members
from .records import write_config

_log = logging.getLogger(__name__)


def blinded(sur: Surrogate) -> Surrogate:
    """A copy of ``sur`` that cannot depend on its exogenous inputs: their columns of the
    first recurrent layer's input weights are zero (what a network trained with
    ``input_dropout`` saw on its blanked sub-sequences, feature 0)::

        W_ih[:, spec.input_features] = 0
    """
    net = copy.deepcopy(sur.net)
    with torch.no_grad():
        net.rnn.weight_ih_l0[:, sur.spec.input_features] = 0.0
    return replace(sur, net=net)


def train_dual_inputs(
    cfg: TrainConfig,
    dataset: Dataset,
    *,
    out: str | Path,
    show_progress: bool | None = None,
    notes: Mapping[str, Any] | None = None,
) -> Path:
    """Train ``cfg.members`` networks (and, with ``prior_choice``, the map-correcting ones)
    that learn both ways, then keep the exogenous inputs, refuse them or give them to some
    joints on validation (see the module docstring); returns ``OUT/best.pt``."""
    n_prior = prior_members(cfg.members) if cfg.prior_choice else 0
    val_eps, out, workers = open_run(
        cfg, dataset, out, notes=notes, trainings=cfg.members + n_prior
    )
    names = list(dataset.spec.u_names[dataset.spec.n_joint :])
    _log.info(
        f"exogenous inputs {names}: {cfg.members} member(s)"
        + (f" and {n_prior} network(s) correcting the static map" if n_prior else "")
        + f" learn with and without them ({cfg.input_dropout:.0%} of the sub-sequences "
        f"blanked), {workers} in parallel; then each way is scored on validation"
    )
    t0 = time.monotonic()
    base = replace(cfg, prior_choice=False, static_map=False, exogenous="use")
    cfgs = {"plain": member_configs(base)}
    if n_prior:  # the kind choice's layout: OUT/plain/member_*, OUT/prior/member_*
        cfgs["prior"] = member_configs(replace(base, prior=True, members=n_prior))
        nets = train_groups(cfgs, dataset, out=out, workers=workers, show_progress=show_progress)
        use, priors = nets["plain"], nets["prior"]
    else:  # a seed ensemble's: OUT/member_*
        use = train_members(
            cfgs["plain"], dataset, out=out, workers=workers, show_progress=show_progress
        )
        priors = []
    ignore = [blinded(s) for s in use]
    record, keep, joints, per_joint = decide_inputs(
        cfg,
        use,
        ignore,
        val_eps,
        dataset=dataset,
        n_prior=n_prior,
        pairs="each network",
        dual=True,
        input_dropout=cfg.input_dropout,
    )
    _log.info(f"exogenous inputs {names}: {record['why']}")
    way = "use" if keep else ("per joint" if joints is not None else "ignore")
    plains = use if keep else ignore
    prior_nets = priors if keep else [blinded(s) for s in priors]
    training: dict[str, Any] = {"exogenous": record}
    model: Surrogate | None = None
    if n_prior:  # the kinds, per joint, among the networks the chosen way (pairs per joint)
        if not per_joint:
            train_eps = split_episodes(cfg, dataset)[0]
            per_joint = choice_joints(cfg, plains[0], train_eps, val_eps)
        twins = {"twins": use, "twin_joints": joints} if joints is not None else {}
        model, kinds = choose_kinds(
            plains, prior_nets, val_eps, **twins, **per_joint, **choice_options(cfg)
        )
        _log.info(f"two kinds of network: {kinds['why']}")
        training["kinds"] = kinds
        if joints is not None:
            inputs_after_kinds(record, kinds)
    elif joints is not None:
        model = plain_ensemble(ignore, twins=use, twin_joints=joints)
    elif not keep:
        model = merge(ignore)
    column: tuple[str, Sequence[Any], Any] = (
        ("kind", ["plain"] * len(use) + ["prior"] * len(priors), model_kind(training["kinds"]))
        if n_prior
        else ("exogenous", [way] * len(use), way)
    )
    best = merge_members(
        replace(cfg, exogenous="use" if keep or joints is not None else "ignore"),
        cfgs["plain"] + cfgs.get("prior", []),
        use + priors,
        val_eps,
        out=out,
        t0=t0,
        training=training,
        merged=model,
        column=column,
    )
    write_config(out, cfg, notes={**(notes or {}), **training})
    return best
