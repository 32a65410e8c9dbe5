"""What a run's training did, in markdown: how it ended against its plan, the computer it
ran on, and each choice made after training, joint by joint (``best.pt`` metrics
``training``).  The report, the model card and ``exsur info`` print it."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from ..config import CAP_OPTIONS
from ..spec import MachineSpec
from .report import format_value, row_label

CLOSE_CALL = 0.10
"""A joint that networks drive is a close call when another kind of network (the plain
networks, the map-correcting ones, their blend) validates less than this share above the
driver, or below it (a set rule kept the driver): another seed, whose networks differ, may
choose otherwise.  The static map is the same in every seed, so its near ties are shown
but not flagged (on the development logs the joints it drove scored alike over the seeds,
and half the joints flagged so spread 1.2x or more: docs/real.md)."""


def training_markdown(
    training: Mapping[str, Any] | None, *, spec: MachineSpec | None = None
) -> str:
    """One paragraph on how the model's training ended against its plan (``best.pt`` metrics
    ``training``; empty for checkpoints that do not record it), the choices made after
    training, and how close each joint's choice was on validation (:func:`choices_markdown`;
    ``spec`` prints linear joints in their own unit).

    A model the wall-time cap cut short depends on the computer's speed and load: the report
    says so, so nobody takes it for the planned (reproducible) model.
    """
    if not training:
        return ""
    return (
        _budget_markdown(training)
        + _parallel_markdown(training.get("parallel"))
        + environment_markdown(training.get("environment"))
        + _inputs_markdown(training.get("exogenous"), kinds="kinds" in training)
        + _kinds_markdown(training.get("kinds"))
        + _map_markdown(training.get("static_map"))
        + _net_gain_markdown(training.get("net_val_gain"))
        + choices_markdown(training, spec=spec)
    )


def choices_markdown(training: Mapping[str, Any], *, spec: MachineSpec | None = None) -> str:
    """Per joint, each option's validation angle RMSE (the plain networks, the map-correcting
    ones, their even blend, the static map: those the run scored), which one drives the
    joint, and whether that was a close call between kinds of network (:data:`CLOSE_CALL`).
    Empty when the run compared fewer than two options.

    The kind choice scores each kind's whole ensemble, and the map choice the map against
    the network the kind choice built; the set rules (``training/sets.py``) may keep an
    option that is not the lowest on its own joint, because the other joints read its
    angle.  Values in the stored unit (rad, or a linear joint's unit through ``spec``)."""
    kinds = training.get("kinds") if isinstance(training.get("kinds"), Mapping) else None
    smap = training.get("static_map")
    smap = smap if isinstance(smap, Mapping) else None
    names = list((kinds or smap or {}).get("names") or [])
    cols: dict[str, list[float]] = {}
    if kinds and kinds.get("val_theta_rmse_plain") and kinds.get("val_theta_rmse_prior"):
        cols["plain networks"] = list(kinds["val_theta_rmse_plain"])
        cols["map-correcting networks"] = list(kinds["val_theta_rmse_prior"])
        if kinds.get("val_theta_rmse_blend"):
            cols["even blend"] = list(kinds["val_theta_rmse_blend"])
    elif smap and smap.get("val_theta_rmse_network"):
        cols["network"] = list(smap["val_theta_rmse_network"])
    if smap and smap.get("val_theta_rmse_map"):
        cols["static map"] = list(smap["val_theta_rmse_map"])
    if len(cols) < 2 or not names or any(len(v) != len(names) for v in cols.values()):
        return ""
    # which kind drives a joint, read as _kinds_markdown reads it (records before the blend
    # have no "blended")
    chosen = set((kinds or {}).get("chosen") or [])
    blended = set((kinds or {}).get("blended") or [])
    on_map = set((smap or {}).get("chosen") or [])
    # joints whose validation spans too little of their commands: only the networks compete
    unspanned = set((kinds or {}).get("unspanned") or []) | set((smap or {}).get("unspanned") or [])
    simple = {"map-correcting networks", "even blend", "static map"}
    # prior_drive = "spanned": the kinds are scored for the record, not compared
    fixed = bool(kinds) and kinds.get("drive") == "spanned"
    kind_cols = {"plain networks", "map-correcting networks", "even blend"}
    lines = [
        "",
        (
            "Validation position RMSE of each option, per joint, in the joint's unit"
            if spec is not None and spec.any_linear
            else "Validation angle RMSE [rad] of each option, per joint"
        )
        + " (the bold one drives the joint):",
        "",
        "| Joint | " + " | ".join(cols) + " | next best / driver |",
        "|---|" + "---:|" * len(cols) + "---:|",
    ]
    close = []
    for j, name in enumerate(names):
        if name in on_map:
            driver = "static map"
        elif "network" in cols:
            driver = "network"
        elif name in blended:
            driver = "even blend"
        elif name in chosen:
            driver = "map-correcting networks"
        else:
            driver = "plain networks"
        if driver not in cols:  # a record that lacks its driver's scores: nothing to show
            return ""
        # the kind of network the joint has under the fixed rule (under the map too)
        own_kind = "map-correcting networks" if name in chosen else "plain networks"
        label, f = row_label(spec, "theta", name)
        allowed = [
            k
            for k in cols
            if not (name in unspanned and k in simple)
            and not (fixed and k in kind_cols and k != own_kind)
        ]
        mine = cols[driver][j]
        others = [cols[k][j] for k in allowed if k != driver]
        ratio = min(others) / mine if others and mine > 0 else None
        nets = [k for k in allowed if k != "static map" and k != driver]
        if (
            driver != "static map"
            and nets
            and min(cols[k][j] for k in nets) < (1.0 + CLOSE_CALL) * mine
        ):
            close.append(name)
        cells = [
            f"**{format_value(v[j], f)}**"
            if k == driver
            else format_value(v[j], f)
            if k in allowed
            else f"({format_value(v[j], f)})"
            for k, v in cols.items()
        ]
        tail = "—" if ratio is None else f"{ratio:.2f}"
        lines.append(f"| {label} | " + " | ".join(cells) + f" | {tail} |")
    if unspanned & set(names):
        lines += [
            "",
            "(In parentheses: not an option there. The joint's validation commands span too "
            "little of its training command range to vouch for a simpler model, so the "
            "networks drive it.)",
        ]
    if fixed:
        lines += [
            "",
            "The map-correcting networks drive every joint whose validation spans its commands "
            "(not one that takes exogenous inputs its own way), the plain networks the rest: "
            "the two kinds are scored on validation for the record, not compared (in "
            "parentheses), as one validation segment misranked them off the training's "
            "conditions (`--set train.prior_drive=validation` compares them).",
        ]
    lines += _halves_note(smap, spec)
    if close:
        lines += [
            "",
            f"Close call on {', '.join(close)}: another kind of network validated within "
            f"{CLOSE_CALL:.0%} of the one that drives it, or better (a near tie stays with the "
            "plain networks, and a joint keeps what the joints reading its angle need). Another "
            "seed may choose otherwise there; compare seeds, or add validation data that "
            "drives those joints.",
        ]
    return "\n".join(lines) + "\n"


def _halves_note(smap: Mapping[str, Any] | None, spec: MachineSpec | None) -> list[str]:
    """The lines on the joints the static map validated as well as the networks over the
    whole validation segment but not on both halves (``static_map.blocks``), or none."""
    if not smap:
        return []
    blocks, names = smap.get("blocks") or {}, list(smap.get("names") or [])
    refused = [n for n in blocks.get("refused") or [] if n in names]
    if not refused:
        return []
    net, amap = blocks["val_theta_rmse_network"], blocks["val_theta_rmse_map"]
    parts = []
    for name in refused:
        j = names.index(name)
        label, f = row_label(spec, "theta", name)
        halves = " and ".join(
            f"{format_value(m[j], f)} against {format_value(n[j], f)}" for n, m in zip(net, amap)
        )
        parts.append(f"{label} (map against networks: {halves})")
    return [
        "",
        f"Not on the static map although it validated within {blocks['tie']:.0%} of "
        f"the networks, or better, over the whole segment: {'; '.join(parts)}, on the two "
        "halves of the one validation episode. On one segment a single excursion can make "
        "that tie, so the map must hold on both halves (`--set train.map_blocks=false` lets "
        "the whole segment decide).",
    ]


def _inputs_markdown(record: Mapping[str, Any] | None, *, kinds: bool = False) -> str:
    """One line on the exogenous-input choice (``training.exogenous``; ``kinds``: the run
    chose the kinds too, whose map-correcting networks ignore inputs taken per joint)."""
    if not isinstance(record, Mapping) or "kept" not in record:
        return ""
    names = ", ".join(record.get("inputs") or []) or "the exogenous inputs"
    joints = list(record.get("joints") or [])
    if not record["kept"]:
        how = "ignored by the model"
    elif record.get("per_joint") and joints:
        how = f"used by {', '.join(joints)} only (the other joints ignore them" + (
            "; so do the networks that correct the static valve map)" if kinds else ")"
        )
    elif record.get("dropped") and joints:  # kept whole, then joints went to blind parts
        how = (
            f"used by {', '.join(joints)} only (the parts of the model that drive the other "
            "joints ignore them)"
        )
    else:
        how = "used by the model"
    return (
        f"\nExogenous inputs ({names}): {how}, chosen on the validation free run "
        f"({record.get('why', '')}).\n"
    )


def _kinds_markdown(record: Mapping[str, Any] | None) -> str:
    """One line on which joints the map-correcting networks drive (``training.kinds``)."""
    if not isinstance(record, Mapping) or "chosen" not in record:
        return ""
    chosen = list(record["chosen"])
    blended = [n for n in record.get("blended") or [] if n in chosen]
    whole = [n for n in chosen if n not in blended]
    if not chosen:
        who = "the plain networks drive every joint"
    elif not blended and len(chosen) == len(record.get("names") or chosen):
        who = "the networks that correct the static valve map drive every joint"
    else:
        parts = []
        if whole:
            parts.append(f"the networks that correct the static valve map drive {', '.join(whole)}")
        if blended:
            parts.append(f"the even blend of both kinds drives {', '.join(blended)}")
        rest = len(chosen) < len(record.get("names") or chosen)
        who = ", ".join(parts) + (", the plain networks the other joints" if rest else "")
    how = (
        "by the rule for joints whose validation spans their commands"
        if record.get("drive") == "spanned"
        else "chosen on the validation free run"
    )
    return f"\nTwo kinds of network: {who}, {how} ({record.get('why', '')}).\n"


def _map_markdown(record: Mapping[str, Any] | None) -> str:
    """One line on the joints that follow the static valve map (``training.static_map``)."""
    if not isinstance(record, Mapping) or not record.get("chosen"):
        return ""
    names = list(record.get("names") or [])
    lags = [
        f"{n} {s:.2f} s"
        for n, s in zip(names, (record.get("map") or {}).get("delay_s") or [])
        if n in record["chosen"] and s > 0
    ]
    delay = f", delay {', '.join(lags)}" if lags else ""
    how = (
        "in parallel with the network, which keeps reading its own angles of them"
        if record.get("composition") == "parallel"
        else "instead of the network"
    )
    return (
        f"\nStatic valve map: {', '.join(record['chosen'])} follow(s) the map (dead zone, gain "
        f"per direction{delay}) {how}, chosen on the validation free run "
        f"({record.get('why', '')}); its band comes from the map's gain spread over the "
        "training log, not from the members.\n" + _pinned_cost(record)
    )


def _net_gain_markdown(record: Mapping[str, Any] | None) -> str:
    """One line on the network joints scaled to validation's speed
    (``training.net_val_gain``), or "" where none was."""
    if not isinstance(record, Mapping) or not record.get("joints"):
        return ""
    each = ", ".join(f"{n} x{g:.3f}" for n, g in zip(record["joints"], record["gain"]))
    return f"\nNetwork joints at validation's speed: {each} ({record.get('why', '')}).\n"


PINNED_COST = 1.5
"""A joint pinned to the static map (it runs validation with angle R² >= 0.95) whose map
validated this many times worse than the networks gets a note on what the pin trades."""


def _pinned_cost(record: Mapping[str, Any]) -> str:
    """A paragraph on the joints pinned to the map although the networks validated
    :data:`PINNED_COST` times better there, and how to let the networks drive them."""
    names = list(record.get("names") or [])
    net = record.get("val_theta_rmse_network") or []
    amap = record.get("val_theta_rmse_map") or []
    costly = [
        f"{n} {m / v:.1f}×"
        for n, v, m in zip(names, net, amap)
        if n in (record.get("pinned") or []) and v > 0 and m > PINNED_COST * v
    ]
    if not costly:
        return ""
    return (
        "\n**The map was kept where the networks validated better** (the map's validation "
        f"angle RMSE over the networks'): {', '.join(costly)}. A map that runs validation with angle R² ≥ 0.95 "
        "is kept whatever the networks score, because on logs whose test leaves the training's "
        "conditions (another throttle, another day) such maps drifted less than the networks "
        "(docs/real.md). Where the runs you will use the model on are like the validation runs, "
        "`--set train.map_periodic=false` lets the networks drive those joints.\n"
    )


def environment_markdown(env: Mapping[str, Any] | None, *, lead: str = "Trained on") -> str:
    """One line naming the computer and libraries a run computed with
    (:func:`excavator_surrogate.numerics.environment`; empty for records without it): where
    two runs of the same data and seed differ, compare these first.  ``lead`` opens it
    (``exsur info --computer``: "Computes on")."""
    if not env:
        return ""
    parts = [
        str(env.get("cpu", "an unknown CPU")) + (f" with {env['cpus']}" if env.get("cpus") else "")
    ]
    if env.get("torch"):
        cap = env.get("torch_cpu_capability")
        parts.append(f"torch {env['torch']}" + (f" ({cap} kernels)" if cap else ""))
    if env.get("numpy"):
        kinds = [", ".join(env.get("numpy_simd") or []), env.get("numpy_blas") or ""]
        inner = "; ".join(k for k in kinds if k)
        parts.append(f"NumPy {env['numpy']}" + (f" ({inner})" if inner else ""))
    if env.get("mujoco"):
        parts.append(f"MuJoCo {env['mujoco']}")
    numerics = env.get("numerics", "native")
    return f"{lead} {', '.join(parts)}; {numerics} numerics.\n"


def computer_markdown(env: Mapping[str, Any]) -> str:
    """``exsur info --computer``: this computer's record
    (:func:`excavator_surrogate.numerics.environment`) as a short Markdown card: the line a
    report prints, each key, and what the figures of another computer mean here."""

    def cell(v: Any) -> str:
        return "-" if v is None else ", ".join(map(str, v)) if isinstance(v, list) else str(v)

    rows = "\n".join(f"| `{k}` | {cell(v)} |" for k, v in env.items())
    return (
        "# This computer\n\n"
        + environment_markdown(env, lead="Computes on")
        + "\n| Key | Value |\n|---|---|\n"
        + rows
        + "\n\nThe same data and seed train the same model on any load of this computer. "
        "Another CPU's kernels round differently and train another draw of the same recipe "
        "(docs/computers.md lists which CPUs give which of the README's columns), and the "
        "data-driven recipe plans from the CPU count: the README's real-machine figures are "
        "2-CPU plans (`--cpus 2` or `EXSUR_CPUS=2` on a larger computer).\n"
    )


def _cut_members(training: Mapping[str, Any]) -> tuple[list[Any], list[Any]]:
    """The networks of a ``training`` record, and those the wall-time cap cut short."""
    members = list(training.get("members") or [training])
    return members, [m for m in members if m.get("budget_cut")]


def _epochs_done(cut: list[Any]) -> str:
    """``"6 of 200"`` per cut network."""
    return ", ".join(f"{m.get('epochs_done', '?')} of {m.get('epochs_planned', '?')}" for m in cut)


def compared_budget_markdown(compare: Mapping[str, Any]) -> str:
    """A warning per compared model (``metrics.json`` ``compare``, each with the
    ``training`` record of its checkpoint) that the wall-time cap cut short: the comparison
    with it depends on the computer's speed and load.  Empty when none was cut."""
    text = ""
    for label, m in compare.items():
        cut = _cut_members(m.get("training") or {})[1]
        if cut:
            text += (
                f"\n**Warning: the wall-time cap cut the training of {label} short** "
                f"({_epochs_done(cut)} planned epochs): the comparison with it depends on the "
                f"computer's speed and load; rerun with a larger cap ({CAP_OPTIONS}).\n"
            )
    return text


def _parallel_markdown(rec: Any) -> str:
    """A data-parallel run's processes and global batch (``training.parallel``; empty for
    a run in one process): its ``config.toml`` trains the model again only with both."""
    if not isinstance(rec, Mapping) or int(rec.get("world_size", 1)) < 2:
        return ""
    n, batch, glob = int(rec["world_size"]), rec["batch"], int(rec["global_batch"])
    return (
        f"\nData parallel: {n} processes × {batch} {rec['per_rank']} = global batch {glob}; "
        f"its config.toml trains this model again on {n} processes (or with {batch} {glob} "
        "in one, up to rounding).\n"
    )


def _budget_markdown(training: Mapping[str, Any]) -> str:
    """How training ended against its plan (see :func:`training_markdown`)."""
    members, cut = _cut_members(training)
    planned = training.get("epochs_planned") or max(
        (int(m.get("epochs_planned", 0)) for m in members), default=0
    )
    if not cut:
        done = [m.get("epochs_done", "?") for m in members]
        if all(d == planned for d in done):
            ran = f"the planned {planned} epochs ran"
        elif len(members) == 1:
            ran = f"{done[0]} of the planned {planned} epochs ran (early stop)"
        else:
            ran = (
                f"the planned {planned} epochs ran, or fewer where early stopping ended a network "
                f"(epochs done per member: {', '.join(map(str, done))})"
            )
        return (
            f"\nTraining: {ran}"
            + "; the same data and seed give the same model on any load"
            + (
                " and on any x86-64 CPU with AVX2 (portable numerics).\n"
                if training.get("numerics") == "portable"
                else " of this computer (another CPU's kernels train another one; "
                "`EXSUR_NUMERICS=portable` gives the same bits on any x86-64 CPU with AVX2).\n"
            )
        )
    return (
        f"\n**Warning: the wall-time cap cut training short** ({len(cut)} of {len(members)} "
        f"network(s): {_epochs_done(cut)} planned epochs). This model depends on the computer's speed and "
        f"load; rerun with a larger cap ({CAP_OPTIONS}) for the planned, reproducible model.\n"
    )
