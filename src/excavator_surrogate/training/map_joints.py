"""Joints that follow the static valve map: ``[train] static_map = true``.

A network trained on a few minutes of one machine can fit them better than any simple model
and still generalise worse: on a test that drives the machine harder, or on another day, a
joint's free run drifts where the structured model's does not (``docs/real-history.md``).  So after
training (and merging), the recipe puts a simple model next to the network as a candidate
per joint, chosen on the validation free run like an epoch is:

1. fit the static valve map (dead zone, gain per direction, delay up to
   :data:`~excavator_surrogate.surrogate.structured.MAX_DELAY_S` and the window:
   :func:`~excavator_surrogate.surrogate.structured.fit_prior`) on the training split, as the
   structured baseline is fitted; a joint whose speed lags its command (a heavy swing's
   inertia, a slow pump) reads its command that many samples back.  If some joint's fitted
   delay is not 0, the map with delay 0 is fitted too;
2. free-run the validation episodes with every joint on the map (on each map, if two); each
   joint takes the map that drives it better there, and the joints whose angle RMSE on it is
   at most :data:`MAP_TIE` above the network's, on one validation episode on both its halves
   too (:mod:`.map_blocks`), are the candidates (a near tie goes to the simpler model);
3. try them together, then each alone (:func:`~..surrogate.series.with_map_joints`:
   those joints follow the map, the others keep the network's output exactly);
4. keep the best set whose validation error is at most :data:`SET_MARGIN` above the
   network's overall, and on no joint more than :data:`SET_MARGIN` above it, or more than the
   share by which the whole fell (:func:`~.sets.joint_allowance`); else the network stays as it was.

A **periodic joint** (the swing) is the exception (``periodic``, ``[train] map_periodic``): no
end stop ever resets its free-run error, so every speed error adds up for the whole run, and a
validation split of a few minutes does not show how far a network's drifts.  Where the map
with its fitted delay alone runs such a joint's validation free run with angle R^2 of at least
:data:`PERIODIC_MAP_R2` (the map is a good model of it), the joint follows that map without a
comparison with the network, and steps 2-4 choose among the other joints with it on the map.

**In parallel** (``parallel``, ``[train] map_parallel``, the recipe's since session 30): the
joints steps 2-4 keep, and every joint whose delayed map alone validates with angle R^2 >=
:data:`PERIODIC_MAP_R2` (periodic or not), follow the map while the network keeps reading its
own angles of them (:func:`~excavator_surrogate.surrogate.parallel.with_parallel_map`), so
no map joint moves the others (:func:`choose_parallel`).

**End stops** (``end_stops``, ``[train] map_end_stops``): a joint on the map stops at the
training data's angle range, as the structured baseline does
(:func:`.map_fit.map_end_stops`), where the network's end stops leave ``[train]
limit_margin`` beyond it.  The map integrates its command with no angle to correct it, and
an end stop is its only reset: on the simulated operator logs and h1-dev, every map clipped
at the training range scored at least as well on the more test data as with the margin, by
up to 9 % (docs/real-history.md).  In parallel the network's own angles keep the network's
end stops.

**After the choice** (:mod:`.map_fit`): the joints on the map take its gains scaled to
validation's speed, the data nearest the test in time (``val_gain``, ``[train]
map_val_gain``, the recipe's since session 109), after a refit on both splits where one is
due (``refit_share``).

The choice and both scores are recorded in ``best.pt`` (``metrics.training.static_map``),
in the log and in ``metrics.json`` (:func:`.map_apply.apply_map_choice`, which applies the
choice to a run's checkpoint).  On a joint on the map, the ensemble's members drive it
with gains spread like the map's stretch-wise gain over the training log
(:func:`~excavator_surrogate.surrogate.structured.gain_spread`), so its band grows with the
distance the map moved it.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

from ..data.episode import Episode
from ..surrogate.model import Surrogate
from ..surrogate.parallel import with_parallel_map
from ..surrogate.series import with_map_joints
from ..surrogate.structured import fit_prior, max_map_delay
from ..surrogate.validation import free_run_error, with_val_scores
from .config import TrainConfig
from .map_blocks import all_on_map, check_blocks
from .map_fit import map_end_stops, refit_due, refit_map, say_changes, scale_gains
from .sets import SET_MARGIN, best_set
from .span import joint_spans, span_note

MAP_TIE = 0.05
"""A joint is a candidate when the map's validation angle RMSE is at most this share above
the network's: on the continuous case a swing whose network tied the map on validation
(7.6 against 7.2 deg) drifted 2x the map's error on the test."""
MIN_SPAN = TrainConfig.choice_min_span
"""Default: the share of the training's command range a joint's validation commands must
span for the joint to be a candidate (:mod:`.span`)."""

PERIODIC_MAP_R2 = 0.95
"""A periodic joint follows the static map with its fitted delay when that map alone runs its
validation free run with angle R^2 at least this (the demo's quality line).  On the four
simulated operator logs the swing's map scored 0.97-0.99 there and was the best swing model on
their more test data, or within 10 % of it, where networks validated up to 2.3x better than it
and drifted up to 4.9x further; on the stroke case's lab runs it scored 0.02
(docs/real-history.md)."""


def map_options(cfg: TrainConfig) -> dict[str, Any]:
    """The keyword options of :func:`choose_map_joints`, :func:`.map_apply.apply_map_choice` and
    :func:`pinned_joints` that ``cfg`` sets: every caller makes the map choice, or predicts
    its pinned joints, as ``exsur train`` does."""
    return {
        "max_steps": cfg.val_steps or None,
        "periodic": cfg.map_periodic,
        "parallel": cfg.map_parallel,
        "end_stops": cfg.map_stops_at_range,
        "min_span": cfg.choice_min_span,
        "refit_share": cfg.map_refit_share,
        "blocks": cfg.map_blocks,
        "val_gain": cfg.map_val_gain,
    }


def _delayed_map(
    sur: Surrogate,
    train: Sequence[Episode],
    val: Sequence[Episode],
    *,
    max_steps: int | None,
    end_stops: bool,
) -> tuple[dict[str, Any], tuple[Any, Any] | None, dict[str, Any]]:
    """``(fit, stops, run)``: the map fitted on ``train`` with delays up to ``sur``'s window,
    the end stops a map joint gets (:func:`.map_fit.map_end_stops`, or ``sur``'s without
    ``end_stops``), and the validation free run of every joint on that map alone."""
    fit = fit_prior(train, sur.spec, max_delay=max_map_delay(sur.window, sur.spec))
    stops = map_end_stops(train) if end_stops and sur.end_stops else None
    return fit, stops, all_on_map(sur, fit, val, stops=stops, max_steps=max_steps)


def _runs_well(run: Mapping[str, Any], *, periodic: bool, spanned: Sequence[bool]) -> list[bool]:
    """Per joint, whether its map alone ran ``run`` with angle R^2 >= :data:`PERIODIC_MAP_R2`
    (never without ``periodic``, nor on a joint validation does not span: :mod:`.span`): such
    a joint follows the map without a comparison with the network (a periodic one in series;
    any in parallel)."""
    return [
        bool(periodic and s and r2 >= PERIODIC_MAP_R2) for r2, s in zip(run["theta_r2"], spanned)
    ]


def pinned_joints(
    sur: Surrogate,
    train: Sequence[Episode],
    val: Sequence[Episode],
    *,
    max_steps: int | None = None,
    periodic: bool = True,
    parallel: bool = False,
    end_stops: bool = True,
    min_span: float = MIN_SPAN,
    refit_share: float = 0.0,
    blocks: bool = True,
    val_gain: bool = True,
) -> list[bool]:
    """The joints that :func:`choose_map_joints` (with the same options) puts on the map
    whatever the network: with ``periodic``, a joint (a periodic one; with ``parallel``, any)
    whose delayed map alone runs the validation free run with angle R^2 >=
    :data:`PERIODIC_MAP_R2`.  A map joint's angle depends on its own command only, so this
    reads nothing of ``sur`` but its window, spec and end stops: the kind choice, which runs
    before the map choice on other networks of the same run, gets the same joints
    (``record["pinned"]`` of the map choice; ``refit_share`` and ``val_gain`` change the map
    after the choice and ``blocks`` checks the other candidates: none changes which joints it
    pins)."""
    del refit_share, blocks, val_gain
    if not periodic:
        return [False] * sur.spec.n_joint
    _, spanned = joint_spans(train, val, sur.spec, min_span=min_span)
    if not any(spanned):
        return [False] * sur.spec.n_joint
    _, _, run = _delayed_map(sur, train, val, max_steps=max_steps, end_stops=end_stops)
    good = _runs_well(run, periodic=periodic, spanned=spanned)
    return [g and (parallel or js.periodic) for g, js in zip(good, sur.spec.joints)]


def choose_map_joints(
    sur: Surrogate,
    train: Sequence[Episode],
    val: Sequence[Episode],
    *,
    max_steps: int | None = None,
    periodic: bool = True,
    parallel: bool = False,
    end_stops: bool = True,
    min_span: float = MIN_SPAN,
    refit_share: float = 0.0,
    blocks: bool = True,
    val_gain: bool = True,
) -> tuple[Surrogate | None, dict[str, Any]]:
    """The surrogate with the chosen joints on the static map, or None to keep ``sur``.

    Args:
        sur: the trained network or merged ensemble (LSTM/GRU, no prior, no residual head).
        train: the training episodes (the map is fitted on them).
        val: the validation episodes (the choice is made on their free run).
        max_steps: validation free-run length cap (as the epoch selection's).
        periodic: a periodic joint (with ``parallel``, any joint) whose delayed map alone
            validates with angle R^2 >= :data:`PERIODIC_MAP_R2` follows it without a
            comparison with the network.
        parallel: compose in parallel (:func:`.parallel.with_parallel_map`, the network
            reads its own angles; :func:`choose_parallel`) instead of in series.
        end_stops: a joint on the map stops at :func:`map_end_stops` (else, or when ``sur``
            runs without end stops, at ``sur``'s); every map free run of the choice is scored
            so.
        min_span: a joint whose validation commands span less than this share of the
            training's command range (:func:`~.span.command_span`) keeps the network.
        refit_share: when the validation episodes hold at least this share of the training's
            samples (0: never), the joints on the map take it fitted again on both splits
            after the choice (:func:`.map_fit.refit_map`; each keeps its variant), and their
            end stops from both; the model's validation scores are then in-sample on those
            joints.
        blocks: on a single validation episode, a candidate (one not pinned by the R^2 rule
            in parallel) must also be within :data:`MAP_TIE` of the network on both of its
            halves (:mod:`.map_blocks`).
        val_gain: after the choice (and a refit), the joints on the map take its gains
            scaled to validation's speed (:mod:`.map_fit`); their validation scores are
            then in-sample.

    Returns:
        ``(new or None, record)``; ``record`` holds the map, both validation scores, the
        candidates, the sets tried and what was chosen, with a one-line ``why``.
    """
    spec = sur.spec
    names = list(spec.names)
    delayed, stops, run = _delayed_map(sur, train, val, max_steps=max_steps, end_stops=end_stops)
    fits, runs = [delayed], [run]
    if any(delayed["delay"]):  # the same map without delays: chosen per joint on validation
        fits.append(fit_prior(train, spec))
        runs.append(all_on_map(sur, fits[1], val, stops=stops, max_steps=max_steps))
    net = free_run_error(sur, list(val), max_steps=max_steps)
    scores = [r["theta_rmse"] for r in runs]
    spans, spanned = joint_spans(train, val, spec, min_span=min_span)
    good = _runs_well(runs[0], periodic=periodic, spanned=spanned)
    pinned = [g and js.periodic for g, js in zip(good, spec.joints)]
    pick = [
        0 if good[j] else min(range(len(fits)), key=lambda v: scores[v][j])
        for j in range(spec.n_joint)
    ]
    fit = {k: [fits[v][k][j] for j, v in enumerate(pick)] for k in fits[0]}
    map_rmse = [scores[v][j] for j, v in enumerate(pick)]
    cand = [
        bool(not p and s and m <= (1 + MAP_TIE) * e)
        for p, s, m, e in zip(pinned, spanned, map_rmse, net["theta_rmse"])
    ]
    check = [bool(blocks and c and not (parallel and g)) for c, g in zip(cand, good)]
    checked = check_blocks(
        sur, fits, pick, val, check, stops=stops, max_steps=max_steps, names=names, tie=MAP_TIE
    )
    if checked is not None:
        cand = [c and n not in checked["refused"] for c, n in zip(cand, names)]
    record: dict[str, Any] = {
        "names": names,
        "map": {
            **{k: fit[k] for k in ("a_pos", "a_neg", "k_pos", "k_neg", "delay")},
            "delay_s": [d * spec.dt for d in fit["delay"]],
        },
        "fitted_delay": fits[0]["delay"],
        "val_theta_rmse_network": net["theta_rmse"],
        "val_theta_rmse_map": map_rmse,
        "val_theta_rmse_maps": {
            ("delayed" if v == 0 and len(fits) > 1 else "undelayed"): sc
            for v, sc in enumerate(scores)
        },
        "candidates": [n for n, c in zip(names, cand) if c],
        "val_theta_r2_map_delayed": runs[0]["theta_r2"],
        "end_stops": (
            "the network's"
            if stops is None
            else {
                k: [float(v) if math.isfinite(v) else None for v in a]
                for k, a in zip(("theta_min", "theta_max"), stops)
            }
        ),
        "pinned": [n for n, p in zip(names, pinned) if p],
        **({"blocks": checked} if checked is not None else {}),
        "span": spans,
        "min_span": min_span,
        "unspanned": [n for n, s in zip(names, spanned) if not s],
        "tried": [],
        "chosen": [],
    }

    def build(joints: Sequence[bool]) -> Surrogate:
        """The model with ``joints`` and the pinned joints on the map."""
        on = [bool(a or b) for a, b in zip(joints, pinned)]
        return with_map_joints(sur, fit, on, map_stops=stops)

    def pinned_only() -> tuple[Surrogate | None, Mapping[str, Any]]:
        """The pinned joints alone on the map (None without any: the network) and its
        validation scores."""
        if not any(pinned):
            return None, net
        base_model = build([False] * spec.n_joint)
        return base_model, free_run_error(base_model, list(val), max_steps=max_steps)

    lead = (
        f"{', '.join(record['pinned'])} follow(s) the static map with its fitted delay (a "
        f"periodic joint that the map alone runs with validation angle R^2 >= "
        f"{PERIODIC_MAP_R2:g}: no end stop resets its drift); "
        if any(pinned)
        else ""
    )
    if spans is not None and not all(spanned):
        lead += (
            f"validation commands {span_note(spans, spec, min_span=min_span)} of the "
            f"training's command range beyond the dead zone, below {100 * min_span:.0f} %: the "
            f"network keeps {'them' if spanned.count(False) > 1 else 'it'}; "
        )
    lead += _refused_note(record, "; ")
    # the series choice: which joints it keeps on the map, its model (None: the network) and
    # its validation scores (None: not run yet; in parallel neither is needed)
    kept: list[bool] = list(pinned)
    model: Surrogate | None = None
    got: Mapping[str, Any] | None = None
    if not any(spanned):
        record["why"] = lead + "no joint follows the map"
    elif not any(cand):
        record["chosen"] = list(record["pinned"])
        record["why"] = lead + (
            f"the network beats the static map by more than {MAP_TIE:.0%} on every "
            f"{'other ' if lead else ''}joint's validation free run: "
            f"{'no other' if lead else 'no'} joint follows the map"
        )
    else:
        model, base = pinned_only()  # the base: best_set's sets add to it
        got = base
        # every joint on one map is the all-map free run above: best_set need not run it again
        known = (
            {tuple(cand): runs[pick[0]]}
            if all(c or p for c, p in zip(cand, pinned)) and len(set(pick)) == 1
            else None
        )
        best = best_set(cand, build, base, val, record=record, max_steps=max_steps, known=known)
        if best is None:
            record["chosen"] = list(record["pinned"])
            record["why"] = lead + (
                f"every set of {'other ' if lead else ''}map joints is worse than the validation "
                f"error {base['val_error']:.4g} without them by more than {SET_MARGIN:.0%} "
                "overall, or on a joint by more than the whole gains: the network keeps them"
            )
        else:
            model, got, joints = best
            kept = [bool(p or q) for p, q in zip(joints, pinned)]
            record["chosen"] = [n for n, k in zip(names, kept) if k]
            record["why"] = lead + (
                f"{', '.join(n for n, p in zip(names, joints) if p)} follow(s) the static map: "
                f"validation error {got['val_error']:.4g} against {base['val_error']:.4g} "
                f"without {'them' if sum(joints) > 1 else 'it'}"
                + ("" if lead else " (the network's)")
            )
    on_map = [bool(k or (parallel and g)) for k, g in zip(kept, good)]
    ratio = refit_due(train, val, share=refit_share) if any(on_map) else None
    if ratio is not None:
        fit, stops = refit_map(
            pick,
            train,
            val,
            max_delay=max_map_delay(sur.window, spec),
            end_stops=stops is not None,
        )
        record["refit"] = {
            "val_share": ratio,
            "map": {k: fit[k] for k in ("a_pos", "a_neg", "k_pos", "k_neg", "delay")},
        }
    if val_gain:
        fit = scale_gains(fit, val, on_map, record=record)
    if parallel:
        chosen = choose_parallel(
            sur, fit, net, kept, good, val, record=record, max_steps=max_steps, map_stops=stops
        )
        say_changes(record)
        return chosen
    if ratio is not None or "val_gain" in record:  # the chosen joints, on the map as changed
        model = with_map_joints(sur, fit, kept, map_stops=stops)
        got = free_run_error(model, list(val), max_steps=max_steps)
        say_changes(record)
    if got is None:  # no candidate: the network, or the pinned joints on the map
        model, got = pinned_only()
    return _chosen(model, got), record


def choose_parallel(
    sur: Surrogate,
    fit: Mapping[str, Any],
    net: Mapping[str, Any],
    kept: Sequence[bool],
    good: Sequence[bool],
    val: Sequence[Episode],
    *,
    record: dict[str, Any],
    max_steps: int | None = None,
    map_stops: tuple[Any, Any] | None = None,
) -> tuple[Surrogate | None, dict[str, Any]]:
    """The static map choice composed in parallel (:func:`.parallel.with_parallel_map`): the
    joints the series choice ``kept`` and every joint whose delayed map alone validates with
    angle R^2 >= :data:`PERIODIC_MAP_R2` (``good``) follow the map, and the network keeps
    reading its own angles of them.

    In parallel the network's free run is its own and a map joint's angle depends on its own
    command only, so every joint scores as its source does alone: a joint the map runs that
    well is pinned to it, periodic or not (on the first continuous dev log the bucket's map
    validated 19 % worse than the network and drifted 4.7x less on the test, and in series
    the arm, reading the map's bucket, drifted 1.6x further; docs/real-history.md).  The other
    candidates still pass the series set rule first (``kept``): in parallel no joint would
    pay for them, but the rule is the stricter evidence (the same log's boom map validated
    6-25 % better than the network in two seeds, the set with it was refused, and it was
    1.6x worse on the test).  The result's validation free run is scored once, for its
    record.
    """
    names = record["names"]
    joints = [bool(k or g) for k, g in zip(kept, good)]
    record["composition"] = "parallel"
    record["pinned"] = [n for n, g in zip(names, good) if g]
    record["chosen"] = [n for n, j in zip(names, joints) if j]
    if not any(joints):
        return None, record  # the series ``why`` stands: nothing follows the map
    model = with_parallel_map(sur, fit, joints, map_stops=map_stops)
    got = free_run_error(model, list(val), max_steps=max_steps)
    parts = []
    if any(good):
        parts.append(
            f"{', '.join(n for n, g in zip(names, good) if g)}: the map alone runs validation "
            f"with angle R^2 >= {PERIODIC_MAP_R2:g}"
        )
    rest = [n for n, k, g in zip(names, kept, good) if k and not g]
    if rest:
        parts.append(f"{', '.join(rest)}: within {MAP_TIE:.0%} of the network, kept as a set")
    if refused := _refused_note(record):
        parts.append(refused)
    record["why"] = (
        f"{', '.join(record['chosen'])} follow(s) the static map in parallel (the network "
        f"reads its own angles): {'; '.join(parts)}; validation error {got['val_error']:.4g} "
        f"against the network's {net['val_error']:.4g}"
        + (
            f"; {', '.join(record['unspanned'])} keep(s) the network: validation commands "
            f"less than {100 * record['min_span']:.0f} % of the training's command range"
            if record.get("unspanned")
            else ""
        )
    )
    record["parallel"] = {"val_error": got["val_error"], "val_theta_rmse": got["theta_rmse"]}
    return _chosen(model, got), record


def _refused_note(record: Mapping[str, Any], end: str = "") -> str:
    """The ``why`` of the candidates the block check refused (``record["blocks"]``), or ""."""
    refused = (record.get("blocks") or {}).get("refused") or []
    if not refused:
        return ""
    return (
        f"{', '.join(refused)}: the map within {MAP_TIE:.0%} of the network or better on the "
        f"whole validation free run, not on both of {record['blocks']['what']}: the "
        f"network keeps {'them' if len(refused) > 1 else 'it'}{end}"
    )


def _chosen(model: Surrogate | None, got: Mapping[str, Any]) -> Surrogate | None:
    """``model`` (if any) with its validation scores ``got`` in its metrics."""
    return None if model is None else with_val_scores(model, got)
