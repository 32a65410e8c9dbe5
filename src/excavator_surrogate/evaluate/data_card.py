"""What a dataset holds (``exsur info DATASET``): its machine, its splits, and per joint how far
each split moves it and commands it, with notes on what selection and the test can vouch for.

A surrogate is only as good as the ground its data cover.  Before training, a user wants to
know how long each split runs, whether validation drives every joint over the commands the
training drives it (selection cannot vouch for the rest, :mod:`..training.span`), and
whether the test leaves the angles the training saw (a free run there extrapolates).  This
module reads the dataset through :func:`~excavator_surrogate.data.load_dataset` (so a
dataset it describes is one that trains) and computes those numbers; :func:`dataset_card`
gives a JSON-ready dict and :func:`dataset_card_markdown` the text.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..data.dataset import SPLITS, Dataset, load_dataset
from ..data.episode import Episode
from ..spec import JointSpec, MachineSpec
from ..training.config import TrainConfig
from ..training.span import command_span

MIN_SPAN = TrainConfig.choice_min_span
"""Validation command spans below this are noted (the recipe's own line for trusting a
choice made on validation, ``[train] choice_min_span``)."""

OUTSIDE = 0.05
"""A test angle beyond the training's range by more than this share of that range is noted."""


def dataset_card(path: str | Path) -> dict[str, Any]:
    """The description of the dataset folder ``path`` (every episode validated on load).

    Returns:
        A dict of plain types: ``path``, ``machine`` (name, rate, joints, inputs),
        ``splits`` (per split: episodes, samples, duration [s], sources, conditions, whether
        it holds ground truth or cleaning flags), ``joints`` (per joint and split: position
        range and speed in the stored unit, rad or m, and the command range used in the
        command's unit), ``val_span`` (per joint, the share of the training's command range
        validation reaches, :func:`~excavator_surrogate.training.span.command_span`; None
        without both splits) and ``warnings`` (one line each).

    Raises:
        DataError: a missing folder, manifest or an episode that breaks the data contract.
    """
    return describe_dataset(load_dataset(path), path=path)


def describe_dataset(ds: Dataset, *, path: str | Path | None = None) -> dict[str, Any]:
    """:func:`dataset_card` of a loaded dataset (``path``: the folder it is named by; default
    its ``root``)."""
    groups = {name: ds.split(name) for name in SPLITS if ds.split(name)}
    card = _describe(groups, ds.spec, path=path if path is not None else ds.root)
    spans = None
    if ds.train and ds.val:
        spans = dict(zip(ds.spec.names, command_span(ds.train, ds.val, ds.spec), strict=True))
    card["val_span"] = spans
    card["warnings"] = _warnings(card)
    return card


def episode_card(path: str | Path) -> dict[str, Any]:
    """The description of one episode file (``exsur info EPISODE.parquet``): the keys of
    :func:`dataset_card`, its one "split" named after the episode, no ``val_span``, and
    ``episode`` (name, source, condition, start time, seed, the generator's or the import's
    record).

    Raises:
        DataError: a missing or unreadable file, or one that breaks the data contract.
    """
    from ..data.episode import read_episode

    ep = read_episode(path)
    card = _describe({ep.name: [ep]}, ep.spec, path=path)
    card["kind"] = "episode"
    card["episode"] = {
        "name": ep.name,
        "source": ep.source,
        "condition": ep.condition,
        "t0_s": float(ep.time[0]),
        "seed": ep.seed,
        "generator": dict(ep.generator),
    }
    card["val_span"] = None
    card["warnings"] = []
    return card


def _describe(
    groups: Mapping[str, Sequence[Episode]], spec: MachineSpec, *, path: str | Path | None
) -> dict[str, Any]:
    """The card's machine, per-group and per-joint parts of named groups of episodes."""
    splits: dict[str, Any] = {}
    for name, eps in groups.items():
        n = sum(e.n_step for e in eps)
        splits[name] = {
            "episodes": len(eps),
            "samples": n,
            "duration_s": n * spec.dt,
            "longest_s": max(e.n_step for e in eps) * spec.dt,
            "sources": sorted({e.source for e in eps}),
            "conditions": sorted({e.condition for e in eps}),
            "truth": all(e.theta_true is not None for e in eps),
            "cleaned": all(e.trusted is not None for e in eps),
        }
    joints = []
    for j, js in enumerate(spec.joints):
        per = {name: _joint_stats(groups[name], j, js) for name in splits}
        joints.append({"name": js.name, "kind": js.kind, "unit": js.unit, "splits": per})
    return {
        "kind": "dataset",
        "path": str(path),
        "machine": {
            "name": spec.name,
            "rate_hz": spec.rate_hz,
            "data_source": sorted({s for v in splits.values() for s in v["sources"]}),
            "joints": [js.to_dict() for js in spec.joints],
            "inputs": [i.name for i in spec.inputs],
        },
        "splits": splits,
        "joints": joints,
    }


def _joint_stats(eps: Sequence[Episode], j: int, js: JointSpec) -> dict[str, Any] | None:
    """One joint over one split: its position range (a periodic joint: the angle it travels,
    unwrapped), the 99th percentile of |speed|, and the 1st / 99th percentiles of its
    command."""
    if not eps:
        return None
    theta = np.concatenate([e.theta[:, j] for e in eps])
    omega = np.concatenate([e.omega[:, j] for e in eps])
    u = np.concatenate([e.u[:, j] for e in eps])
    travel = None
    if js.periodic:  # sum |d theta| over each episode, unwrapped as the CBE scores it
        travel = float(sum(np.abs(np.diff(np.unwrap(e.theta[:, j]))).sum() for e in eps))
    return {
        "theta_min": None if js.periodic else float(np.min(theta)),
        "theta_max": None if js.periodic else float(np.max(theta)),
        "travel": travel,
        "omega_p99": float(np.percentile(np.abs(omega), 99.0)),
        "u_p01": float(np.percentile(u, 1.0)),
        "u_p99": float(np.percentile(u, 99.0)),
    }


def _warnings(card: Mapping[str, Any]) -> list[str]:
    """What a user should know before training on or scoring against this dataset."""
    out = []
    splits = card["splits"]
    if "train" not in splits:
        out.append("no training split: nothing to train on")
    if "val" not in splits:
        out.append(
            "no validation split: training cannot select an epoch or a model on held-out data"
        )
    if "test" not in splits:
        out.append("no test split: exsur evaluate needs one (or --split val)")
    spans = card["val_span"]
    if spans:
        low = [f"{n} {100 * s:.0f} %" for n, s in spans.items() if s < MIN_SPAN]
        if low:
            out.append(
                f"validation commands {', '.join(low)} of the training's command range beyond "
                f"the dead zone (below {MIN_SPAN:.0%}): a choice made on validation cannot "
                "vouch for the rest there, so the recipe keeps the networks on those joints"
            )
    outside = []
    for jt, js in zip(card["joints"], card["machine"]["joints"], strict=True):
        tr, te = jt["splits"].get("train"), jt["splits"].get("test")
        if not tr or not te or tr["theta_min"] is None:
            continue
        width = max(tr["theta_max"] - tr["theta_min"], 1e-9)
        below = (tr["theta_min"] - te["theta_min"]) / width
        above = (te["theta_max"] - tr["theta_max"]) / width
        if max(below, above) > OUTSIDE:
            f, unit = _display(js)
            outside.append(
                f"{jt['name']} ({te['theta_min'] * f:.1f} … {te['theta_max'] * f:.1f} {unit} "
                f"against {tr['theta_min'] * f:.1f} … {tr['theta_max'] * f:.1f})"
            )
    if outside:
        out.append(
            "the test moves beyond the training's positions on "
            + ", ".join(outside)
            + ": a free run there extrapolates"
        )
    return out


def _display(js: Mapping[str, Any]) -> tuple[float, str]:
    """Factor and unit a joint is printed in: degrees for revolute joints, else its own."""
    spec = JointSpec.from_dict(dict(js))
    return (spec.display_factor, spec.display_unit) if spec.linear else (180.0 / math.pi, "°")


def dataset_card_markdown(card: Mapping[str, Any]) -> str:
    """The card of :func:`dataset_card` as Markdown (what ``exsur info DATASET`` prints)."""
    m = card["machine"]
    total = sum(s["samples"] for s in card["splits"].values())
    kind = card.get("kind", "dataset")
    lines = [
        f"# {card['path']}",
        "",
        f"{'An episode' if kind == 'episode' else 'A dataset'} of **{m['name']}** at "
        f"{m['rate_hz']:g} Hz: {total:,} samples "
        f"({_minutes(total / m['rate_hz'])}), from {', '.join(m['data_source']) or 'unknown'}"
        + (f"; exogenous inputs {', '.join(m['inputs'])}" if m["inputs"] else "")
        + ".",
    ]
    if card["warnings"]:
        lines += ["", *notes_lines(card)]
    if kind == "episode":
        e = card["episode"]
        lines += [
            "",
            f"Episode `{e['name']}`, condition `{e['condition']}`, starting at "
            f"{e['t0_s']:g} s" + (f", seed {e['seed']}" if e["seed"] is not None else "") + ".",
            "",
            "## Joints",
            "",
            *joint_lines(card),
        ]
        return "\n".join(lines) + "\n"
    lines += ["", "## Splits", "", *splits_lines(card), "", "## Joints", "", *joint_lines(card)]
    lines += reach_lines(card)
    return "\n".join(lines) + "\n"


def notes_lines(card: Mapping[str, Any]) -> list[str]:
    """The card's notes, one bold-labelled paragraph each."""
    lines: list[str] = []
    for w in card["warnings"]:
        lines += ["", f"**Note:** {w}."] if lines else [f"**Note:** {w}."]
    return lines


def splits_lines(card: Mapping[str, Any]) -> list[str]:
    """The splits table: episodes, samples, duration, conditions, truth, cleaning."""
    lines = [
        "| Split | Episodes | Samples | Duration | Longest episode | Conditions | Ground truth "
        "| Cleaned |",
        "|---|---:|---:|---:|---:|---|---|---|",
    ]
    for name, s in card["splits"].items():
        lines.append(
            f"| {name} | {s['episodes']} | {s['samples']:,} | {_minutes(s['duration_s'])} | "
            f"{_minutes(s['longest_s'])} | {', '.join(s['conditions'])} | "
            f"{'yes' if s['truth'] else 'no'} | {'yes' if s['cleaned'] else 'no'} |"
        )
    return lines


def joint_lines(card: Mapping[str, Any]) -> list[str]:
    """Per joint and split (an episode card: the episode): position range (or travel),
    speed, commands used."""
    group = "Episode" if card.get("kind") == "episode" else "Split"
    lines = [
        f"Per {group.lower()}: the position range (a periodic joint: the angle it travels), the "
        "99th percentile of |speed|, and the commands used (1st … 99th percentile).",
        "",
        f"| Joint | {group} | Position | Speed | Command |",
        "|---|---|---|---:|---|",
    ]
    for jt, js in zip(card["joints"], card["machine"]["joints"], strict=True):
        f, unit = _display(js)
        for k, (name, st) in enumerate(jt["splits"].items()):
            if st["theta_min"] is None:
                pos = f"{st['travel'] * f:,.0f} {unit} travelled"
            else:
                pos = f"{st['theta_min'] * f:.1f} … {st['theta_max'] * f:.1f} {unit}"
            lines.append(
                f"| {jt['name'] if k == 0 else ''} | {name} | {pos} | "
                f"{st['omega_p99'] * f:.1f} {unit}/s | {st['u_p01']:.0f} … {st['u_p99']:.0f} |"
            )
    return lines


def reach_lines(card: Mapping[str, Any]) -> list[str]:
    """How much of the training's command range validation reaches, per joint (or nothing)."""
    spans = card["val_span"]
    if not spans:
        return []
    return [
        "",
        "Validation reaches "
        + ", ".join(f"{n} {100 * s:.0f} %" for n, s in spans.items())
        + " of the training's command range beyond the dead zone (in the direction it "
        "reaches less).",
    ]


def _minutes(seconds: float) -> str:
    """``12.5 s``, ``3.2 min`` or ``4.1 h``."""
    if seconds < 120:
        return f"{seconds:.1f} s"
    if seconds < 7200:
        return f"{seconds / 60:.1f} min"
    return f"{seconds / 3600:.1f} h"
