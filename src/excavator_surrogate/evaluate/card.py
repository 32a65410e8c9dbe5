"""What a trained checkpoint is (``exsur info CKPT``): the machine it models, its network, how
its training ended and how it scored on validation.

A ``best.pt`` travels: a colleague sends one, a controller's repository pins one, a run
folder is months old.  Everything needed to tell what it is was stored when it was trained
(:mod:`excavator_surrogate.surrogate.checkpoint`); this module reads it back without running
the model.  :func:`model_card` gives a JSON-ready dict, :func:`card_markdown` the text a user
reads.
"""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from ..config import CAP_OPTIONS
from ..io_utils import json_ready
from ..spec import JointSpec, MachineSpec
from ..surrogate.checkpoint import read_checkpoint, surrogate_from_dict
from ..surrogate.ensemble import n_member
from ..surrogate.model import Surrogate
from ..surrogate.sizes import n_param
from .pace import pace_markdown, training_pace
from .training_report import training_markdown

LOW_R2 = 0.9
"""A validation angle R² below this on a joint is flagged: the free run drifts there."""


def model_card(path: str | Path) -> dict[str, Any]:
    """The description of the checkpoint at ``path`` (read with ``weights_only=True``).

    The checkpoint is checked as :func:`~excavator_surrogate.surrogate.load_checkpoint`
    checks it (format, sizes, finite weights), so a file this describes is one that loads.

    Returns:
        A dict of plain types: ``file``, ``machine`` (joints with their ranges in the stored
        unit: rad, rad/s, or m, m/s for a linear joint), ``network``, ``training``,
        ``validation`` (per-joint free-run scores, or None), ``members``, ``uncertainty``,
        ``coverage`` and ``warnings`` (one line each); ``training.pace``: how fast this
        computer trained it (:func:`~.pace.training_pace` of the logs beside the file).

    Raises:
        CheckpointError: a missing, corrupt or foreign file (one line naming it).
    """
    path = Path(path)
    ckpt = read_checkpoint(path)
    card = describe_surrogate(surrogate_from_dict(ckpt, where=str(path)), folder=path.parent)
    file = {
        "path": str(path),
        "bytes": path.stat().st_size,
        "exsur_version": ckpt.get("exsur_version"),
        "format_version": ckpt.get("format_version"),
    }
    return {"file": file, **card}


def describe_surrogate(sur: Surrogate, *, folder: str | Path | None = None) -> dict[str, Any]:
    """:func:`model_card` of a loaded surrogate, without the ``file`` entry (what an ONNX
    export embeds as its ``exsur_card`` metadata, :func:`full_json`).  ``folder``: where its
    checkpoint lies, whose training logs give ``training.pace`` (:func:`~.pace.training_pace`;
    None without the folder, its logs or a training record)."""
    spec, cfg, norm = sur.spec, sur.model_cfg, sur.norm
    metrics: Mapping[str, Any] = sur.metrics or {}
    tc: Mapping[str, Any] = sur.train_config or {}
    training = metrics.get("training") if isinstance(metrics.get("training"), Mapping) else {}
    ens = metrics.get("ensemble") if isinstance(metrics.get("ensemble"), Mapping) else {}
    smap = training.get("static_map") if isinstance(training.get("static_map"), Mapping) else {}
    card: dict[str, Any] = {
        "machine": {
            "name": spec.name,
            "class": spec.meta.get("class"),
            "data_source": spec.meta.get("data_source"),
            "rate_hz": spec.rate_hz,
            "joints": [_joint(j) for j in spec.joints],
            "inputs": [
                {"name": i.name, "u_min": i.u_min, "u_max": i.u_max, "unit": i.unit}
                for i in spec.inputs
            ],
        },
        "network": {
            "label": sur.name,
            "cell": cfg.cell,
            "n_layer": cfg.n_layer,
            "hidden": cfg.hidden,
            "head_hidden": cfg.head_hidden,
            "n_param": n_param(cfg),
            "n_feature": cfg.n_feature,
            "mode": sur.mode,
            "window": cfg.window,
            "n_member": n_member(sur),
            "member_hidden": list(ens.get("hidden") or []),
            # the recipe's kind choice: each member joins, per joint, several trained networks
            "composite": any(
                str(m.get("name", "")).endswith("-composite") for m in ens.get("members") or []
            ),
            "n_trained": len(training.get("members") or []) or None,
            "velocity_input": bool(norm.omega_in),
            "residual": bool(cfg.residual),
            "map_correcting": bool(cfg.prior),
            "play_operators": norm.n_play,
            "command_delays": list(norm.lags),
            "end_stops": bool(sur.end_stops),
            "map_joints": list(metrics.get("map_joints") or smap.get("chosen") or []),
        },
        "training": {
            "seed": tc.get("seed"),
            "epochs_planned": training.get("epochs_planned", tc.get("epochs")),
            "epochs_done": _epochs_done(training),
            "budget_cut": bool(training.get("budget_cut", False))
            or any(bool(m.get("budget_cut")) for m in training.get("members") or []),
            "max_train_seconds": _cap(training, tc),
            "feedback": tc.get("feedback"),
            "trained_on_validation": bool(tc.get("train_on_val", False)),
            "lr": tc.get("lr"),
            "numerics": training.get("numerics"),
            "parallel": training.get("parallel"),  # processes and global batch of a DDP run
            "environment": dict(training.get("environment") or {}),
            "pace": training_pace(folder) if folder is not None and training else None,
        },
        "validation": _validation(metrics, spec),
        "members": [
            {k: m.get(k) for k in ("seed", "epoch", "val_error", "kind") if k in m}
            for m in ens.get("members") or []
        ],
        "uncertainty": _uncertainty(metrics.get("uncertainty")),
        "coverage": _coverage(metrics.get("coverage")),
    }
    card["warnings"] = _warnings(card, merged=bool(ens.get("sources")))
    card["_training_record"] = dict(training)
    return card


def public(card: Mapping[str, Any]) -> dict[str, Any]:
    """``card`` for JSON: without the raw training record :func:`card_markdown` reads, and
    with a non-finite number (a score of a diverged run) as None."""
    return {k: json_ready(v) for k, v in card.items() if not k.startswith("_")}


def full_json(card: Mapping[str, Any]) -> str:
    """``card`` as JSON with everything :func:`card_markdown` reads (the raw training record
    too), non-finite numbers as null: what an export embeds to print the same card later."""
    return json.dumps(json_ready(dict(card)), allow_nan=False)


def _joint(j: JointSpec) -> dict[str, Any]:
    """One joint's kind, unit, position range, speed bound and command range (stored units)."""
    d: dict[str, Any] = {
        "name": j.name,
        "kind": j.kind,
        "unit": j.unit,
        "periodic": j.periodic,
        "theta_min": j.theta_min,
        "theta_max": j.theta_max,
        "omega_max": j.omega_max,
        "u_min": j.u_min,
        "u_max": j.u_max,
        "u_unit": j.u_unit,
    }
    if j.linkage is not None:
        d["linkage"] = dataclasses.asdict(j.linkage)  # a, b, phi, l0: all it takes to get angles
    return d


def _epochs_done(training: Mapping[str, Any]) -> list[int]:
    """Epochs each network ran (one entry per member; one for a single network)."""
    members = list(training.get("members") or ([training] if training else []))
    return [int(m["epochs_done"]) for m in members if "epochs_done" in m]


def _cap(training: Mapping[str, Any], tc: Mapping[str, Any]) -> float | None:
    """The wall-time cap per network [s] (0 or None: none)."""
    members = list(training.get("members") or [])
    caps = [m["max_train_seconds"] for m in members if "max_train_seconds" in m]
    cap = caps[0] if caps else training.get("max_train_seconds", tc.get("max_train_seconds"))
    return float(cap) if cap else None


def _validation(metrics: Mapping[str, Any], spec: MachineSpec) -> dict[str, Any] | None:
    """The selected model's free-run scores on the validation split, per joint."""
    val = metrics.get("val")
    if not isinstance(val, Mapping) or "theta_r2" not in val:
        return None
    out: dict[str, Any] = {"val_error": val.get("val_error", metrics.get("val_error"))}
    for key in ("theta_r2", "theta_rmse", "omega_rmse"):
        v = val.get(key)
        if isinstance(v, Sequence) and len(v) == spec.n_joint:
            out[key] = dict(zip(spec.names, (_float(x) for x in v), strict=True))
    return out


def _float(x: Any) -> float | None:
    """A stored score as a float (None: missing, or not a number)."""
    return float(x) if isinstance(x, int | float) and not isinstance(x, bool) else None


def _uncertainty(rec: Any) -> dict[str, Any] | None:
    """The calibrated bands' levels, and the free-run steps and runs (validation, training)
    that calibrated them."""
    if not isinstance(rec, Mapping) or not rec.get("levels"):
        return None
    return {
        "levels": list(rec["levels"]),
        "n_step": rec.get("n_step"),
        "n_run": int(rec.get("n_run") or 0),
        "n_train_run": int(rec.get("n_train_run") or 0),
    }


def _calibrated_from(unc: Mapping[str, Any]) -> str:
    """``" (from 570 free-run steps of 1 validation and 2 training runs)"``; empty when the
    record has no step count."""
    if not unc.get("n_step"):
        return ""
    counts = {"validation": unc.get("n_run") or 0, "training": unc.get("n_train_run") or 0}
    runs = " and ".join(f"{n} {kind}" for kind, n in counts.items() if n)
    plural = "s" if sum(counts.values()) > 1 else ""
    return f" (from {unc['n_step']:,} free-run steps" + (
        f" of {runs} run{plural})" if runs else ")"
    )


def _coverage(rec: Any) -> dict[str, Any] | None:
    """The training data's coverage record (for the out-of-distribution flags)."""
    if not isinstance(rec, Mapping) or "n_sample" not in rec:
        return None
    return {"n_sample": int(rec["n_sample"]), "channels": list(rec.get("channels") or [])}


def _warnings(card: Mapping[str, Any], *, merged: bool = False) -> list[str]:
    """What a user should know before relying on the model, one line each (``merged``: an
    ``exsur merge`` of checkpoints, which scores nothing)."""
    out = []
    tr, net = card["training"], card["network"]
    if tr["budget_cut"]:
        out.append(
            "the wall-time cap cut training short: this model depends on the computer's speed "
            f"and load; retrain with a larger cap ({CAP_OPTIONS}) for the planned model"
        )
    val = card["validation"]
    if val is not None and tr["trained_on_validation"]:
        out.append(
            "the networks also trained on the validation runs, so the validation scores are "
            "in-sample, not an estimate for new data: score it on held-out runs with exsur "
            "evaluate"
        )
    if val and "theta_r2" in val:
        rmse = val.get("theta_rmse") or {}
        low = [
            f"{n} {r:.3f}"
            for n, r in val["theta_r2"].items()
            # NaN with a finite RMSE: a joint still in every validation run (no R²)
            if r is not None
            and not r >= LOW_R2
            and not (math.isnan(r) and math.isfinite(rmse.get(n) or math.inf))
        ]
        if low:
            out.append(
                f"validation angle R² below {LOW_R2}: {', '.join(low)}; its free run drifts "
                "there (more or more varied training data on those joints)"
            )
    if val is None and merged:
        out.append(
            "no validation scores stored (merged by exsur merge, which scores nothing; "
            "exsur evaluate CKPT DATASET scores the merged model)"
        )
    elif val is None:
        out.append("no validation scores stored (trained without a validation split)")
    if not net["end_stops"]:
        out.append("end stops off: free-run angles are not kept inside the joint limits")
    if card["coverage"] is None:
        out.append(
            "no coverage record: no out-of-distribution flags (exsur calibrate CKPT DATASET "
            "records one)"
        )
    return out


def _num(v: float | None, unit: str, f: float = 1.0, digits: int = 1) -> str:
    """``v * f`` with ``digits`` decimals and ``unit`` (``—`` for None or a non-finite value)."""
    if v is None or not math.isfinite(float(v)):
        return "—"
    return f"{float(v) * f:.{digits}f} {unit}".strip()


def _range(j: Mapping[str, Any], f: float, unit: str) -> str:
    if j["periodic"]:
        return "periodic (no limits)"
    lo, hi = j["theta_min"], j["theta_max"]
    if lo is None and hi is None:
        return "—"
    lo_s = "−∞" if lo is None else f"{lo * f:.1f}"
    hi_s = "+∞" if hi is None else f"{hi * f:.1f}"
    return f"{lo_s} … {hi_s} {unit}"


def _joint_rows(joints: Sequence[Mapping[str, Any]]) -> list[str]:
    """The machine table: revolute joints in degrees, linear ones in their own unit."""
    rows = [
        "| Joint | Kind | Position range | Speed bound | Command range |",
        "|---|---|---|---:|---|",
    ]
    for j in joints:
        if j["kind"] == "linear":
            spec = JointSpec.from_dict(j)
            f, unit = spec.display_factor, spec.display_unit
            kind = "linear" + (", linkage given" if "linkage" in j else "")
        else:
            f, unit, kind = 180.0 / math.pi, "°", "revolute"
        rows.append(
            f"| {j['name']} | {kind} | {_range(j, f, unit)} | {_num(j['omega_max'], f'{unit}/s', f)} | "
            f"{j['u_min']:g} … {j['u_max']:g} {j['u_unit']} |"
        )
    return rows


def _network_lines(net: Mapping[str, Any]) -> list[str]:
    cell = net["cell"].upper()
    each = net["member_hidden"]
    size = f" of {each[0]} units each" if each and len(set(each)) == 1 else ""
    merged = (
        f"merged into one {net['n_layer']} × {net['hidden']} {cell} (the members' mean ω), "
        f"head {net['head_hidden']}"
    )
    if net.get("composite"):
        trained = f" of the {net['n_trained']} trained" if net.get("n_trained") else ""
        what = (
            f"- {net['n_member']} composite {cell} members{size}, each joining per joint "
            f"networks{trained} (plain and map-correcting, weighted by the kind choice), {merged}"
        )
    elif net["n_member"] > 1:
        what = f"- An ensemble of {net['n_member']} {cell} networks{size}, {merged}"
    else:
        what = f"- One {net['n_layer']} × {net['hidden']} {cell}, head {net['head_hidden']}"
    lines = [what + f"; {net['n_param']:,} parameters, {net['n_feature']} input features."]
    mode = (
        "stateful: the state is carried sample by sample"
        if net["mode"] == "stateful"
        else "windowed: a fresh state per window"
    )
    lines.append(f"- Runs {mode}; {net['window']}-sample window (the warm-up of a free run).")
    extras = []
    if net["velocity_input"]:
        extras.append("reads the previous velocity")
    if net["residual"]:
        extras.append("predicts the change of ω")
    if net["play_operators"]:
        extras.append(f"{net['play_operators']} play operator(s) per command (hysteresis)")
    if net["command_delays"]:
        delays = ", ".join(map(str, net["command_delays"]))
        extras.append(f"reads delayed commands ({delays} samples)")
    if net["map_correcting"]:
        extras.append("corrects a static valve map (dead zone, gain per direction)")
    if extras:
        lines.append("- It " + "; ".join(extras) + ".")
    if net["map_joints"]:
        lines.append(f"- Joints on the static valve map: {', '.join(net['map_joints'])}.")
    lines.append(
        "- End stops: on (free-run angles and speeds stay inside the joint limits)."
        if net["end_stops"]
        else "- End stops: off."
    )
    return lines


def machine_phrase(machine: Mapping[str, Any]) -> str:
    """``A surrogate of **name** (class, data: source) at 20 Hz`` for a card's ``machine``."""
    what = ", ".join(
        str(x)
        for x in (machine["class"], machine["data_source"] and f"data: {machine['data_source']}")
        if x
    )
    return (
        f"A surrogate of **{machine['name']}**"
        + (f" ({what})" if what else "")
        + f" at {machine['rate_hz']:g} Hz"
    )


def card_markdown(card: Mapping[str, Any], *, header: Sequence[str] | None = None) -> str:
    """The card of :func:`model_card` as Markdown (what ``exsur info`` prints); ``header``:
    the lines to open with instead of the checkpoint file's (an ONNX export's)."""
    m, net = card["machine"], card["network"]
    spec = MachineSpec.from_dict(
        {"name": m["name"], "rate_hz": m["rate_hz"], "joints": m["joints"], "inputs": m["inputs"]}
    )
    if header is None:
        f = card["file"]
        header = [
            f"# {f['path']}",
            "",
            machine_phrase(m) + f"; {f['bytes'] / 1e6:.1f} MB, written by exsur "
            f"{f['exsur_version']} (checkpoint format {f['format_version']}).",
        ]
    lines = list(header)
    if card["warnings"]:
        for w in card["warnings"]:
            lines += ["", f"**Note:** {w}."]
    lines += ["", "## Machine", "", *_joint_rows(m["joints"])]
    if m["inputs"]:
        lines += [
            "",
            "Exogenous inputs: "
            + ", ".join(
                f"{i['name']} ({i['u_min']:g} … {i['u_max']:g} {i['unit']})" for i in m["inputs"]
            )
            + ".",
        ]
    lines += ["", "## Network", "", *_network_lines(net)]
    lines += ["", "## Training", ""]
    tr = card["training"]
    done = tr["epochs_done"]
    run = (
        (
            f"{done[0]} of {tr['epochs_planned']} planned epochs"
            if len(set(done)) == 1
            else f"{', '.join(map(str, done))} of {tr['epochs_planned']} planned epochs (per network)"
        )
        if done
        else f"{tr['epochs_planned']} planned epochs"
    )
    cap = f", capped at {tr['max_train_seconds']:g} s a network" if tr["max_train_seconds"] else ""
    loss = {"free": "on its own free run", "teacher": "teacher-forced"}.get(tr["feedback"] or "")
    record = card.get("_training_record")
    lines.append(
        f"Seed {tr['seed']}"
        + ("" if record else f", {run}")
        + cap
        + (f"; trained {loss}" if loss else "")
        + (f", learning rate {tr['lr']:g}" if tr["lr"] is not None else "")
        + "."
    )
    if record:
        text = training_markdown(record, spec=spec).strip("\n")
        text = text.replace("Training: ", "", 1)
        lines.append(text[:1].upper() + text[1:])
        if tr.get("pace"):
            lines += ["", pace_markdown(tr["pace"], record).strip("\n")]
    if card["members"] and card["network"].get("composite"):
        lines += [
            "",
            f"The model's {len(card['members'])} members are compositions of the trained "
            "networks, not networks of their own: each network's epochs are above, and which "
            "kind drives each joint is in the table of options.",
        ]
    elif card["members"]:
        lines += [
            "",
            "The members merged into the model:",
            "",
            "| Member | Seed | Selected epoch | Validation error |",
            "|---:|---:|---:|---:|",
        ]
        for k, mem in enumerate(card["members"]):
            err = mem.get("val_error")
            lines.append(
                f"| {k} | {mem.get('seed', '—')} | {mem.get('epoch', '—')} | "
                + ("—" if err is None else f"{err:.4f}")
                + " |"
            )
    in_sample = card["training"]["trained_on_validation"]
    lines += ["", "## Validation (free run" + ("; in-sample" if in_sample else "") + ")", ""]
    val = card["validation"]
    if val is None:
        lines.append("No validation scores were stored.")
    else:
        lines += _validation_rows(val, spec)
    lines += ["", "## Uncertainty and coverage", ""]
    unc, cov = card["uncertainty"], card["coverage"]
    lines.append(
        "Calibrated uncertainty bands at "
        + ", ".join(f"{lvl:.0%}" for lvl in unc["levels"])
        + _calibrated_from(unc)
        + "."
        if unc
        else "No calibrated uncertainty bands (a single network, or not calibrated)."
    )
    lines.append(
        f"Coverage record of {cov['n_sample']:,} training samples: free runs flag the steps "
        "outside the training data."
        if cov
        else "No coverage record: free runs cannot flag steps outside the training data."
    )
    return "\n".join(lines) + "\n"


def _validation_rows(val: Mapping[str, Any], spec: MachineSpec) -> list[str]:
    names = list(spec.names)
    head = "| | " + " | ".join(names) + " |"
    rows = [head, "|---|" + "---:|" * len(names)]
    r2 = val.get("theta_r2") or {}
    if r2:
        cells = [
            "—" if r2[n] is None or not math.isfinite(r2[n]) else f"{r2[n]:.4f}" for n in names
        ]
        rows.append("| angle R² | " + " | ".join(cells) + " |")
    for key, label in (("theta_rmse", "angle RMSE"), ("omega_rmse", "speed RMSE")):
        v = val.get(key) or {}
        if not v:
            continue
        cells = []
        for j, n in zip(spec.joints, names, strict=True):
            if j.linear:
                unit = j.display_unit if key == "theta_rmse" else j.rate_unit
                cells.append(_num(v[n], unit, j.display_factor, 3))
            else:
                unit = "°" if key == "theta_rmse" else "°/s"
                cells.append(_num(v[n], unit, 180.0 / math.pi, 2))
        rows.append(f"| {label} | " + " | ".join(cells) + " |")
    if val.get("val_error") is not None:
        rows += ["", f"Selection error (what chose the epoch): {val['val_error']:.4f}."]
    return rows
