"""How far ahead a surrogate can be trusted: the angle error n seconds after a measured start.

The CBE free run (:mod:`.cbe`) starts once, at an episode's beginning, and runs to its end:
the paper's question, "does it stay with the machine for minutes?".  A planner asks another
one.  MPPI (``control/``) predicts 1 s ahead from the machine's measured state, again and
again; an operator assist or a safety monitor does the same.  Here every model is started
from many measured states along each episode (every ``stride`` seconds), warmed up on the
``W`` recorded samples before each, as ``exsur evaluate``'s free run and the env's
``options["history"]`` start are (:class:`~excavator_surrogate.surrogate.rollout.ClosedLoop`),
and driven by the recorded commands.  The angle error at each horizon is pooled over all
starts into an RMSE per joint.

The baseline **hold** predicts that the machine stays where it is (``θ[k+n] = θ[k]``); a
model that is no better than it at some horizon has nothing to tell a planner there.
Errors of periodic joints are wrapped to ``[-π, π)``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any, Literal

import numpy as np
import torch

from ..data.episode import Episode
from ..errors import ConfigError
from ..plotting.horizon import HOLD
from ..spec import JointSpec, MachineSpec
from ..surrogate.angles import wrap_periodic
from ..surrogate.model import Surrogate
from ..surrogate.rollout import ClosedLoop, reference_theta

HORIZONS_S = (0.5, 1.0, 2.0, 5.0)
"""Default horizons [s]: MPPI's 1 s, and around it."""

CHUNK = 1024
"""Starts rolled out in one batch (bounds the memory on long logs)."""


def check_horizons(horizons_s: Sequence[float], stride_s: float) -> None:
    """One-line errors for the ``[evaluate]`` horizon options."""
    if any(not (math.isfinite(h) and h > 0) for h in horizons_s):
        raise ConfigError(f"[evaluate] horizons must be seconds > 0, got {list(horizons_s)}")
    if not (math.isfinite(stride_s) and stride_s > 0):
        raise ConfigError(f"[evaluate] horizon_stride must be seconds > 0, got {stride_s}")


@torch.no_grad()
def _squared_errors(
    sur: Surrogate | None,
    theta: np.ndarray,
    u: np.ndarray,
    *,
    window: int,
    stride: int,
    n_max: int,
    periodic: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Summed squared angle errors ``(n_max, n_joint)`` and start counts ``(n_max,)`` of one
    episode (``theta``: (n_step, n_joint) [rad], ``u``: (n_step, n_u)) at horizons 1..n_max
    samples; ``sur`` None: the hold baseline."""
    n_step, n_joint = theta.shape
    sq = np.zeros((n_max, n_joint))
    count = np.zeros(n_max, dtype=np.int64)
    starts = np.arange(window - 1, n_step - 1, stride)  # k: the last warm-up sample
    for lo in range(0, len(starts), CHUNK):
        k = starts[lo : lo + CHUNK]
        n_run = min(n_max, n_step - 1 - int(k[0]))  # the earliest start reaches farthest
        if sur is not None:
            loop = ClosedLoop(sur)
            loop.reset_at(theta, u, k, n_hist=window)
        for j in range(n_run):
            t = k + j + 1  # the predicted sample
            ok = t <= n_step - 1
            t = np.minimum(t, n_step - 1)
            if sur is None:
                pred = theta[k]
            else:
                pred = loop.step(u[np.minimum(k + j, n_step - 1)])[0].double().cpu().numpy()
            err = wrap_periodic(pred - theta[t], periodic)[ok]
            sq[j] += (err**2).sum(axis=0)
            count[j] += int(ok.sum())
    return sq, count


def horizon_errors(
    models: Mapping[str, Surrogate],
    episodes: Sequence[Episode],
    *,
    spec: MachineSpec,
    reference: Literal["measured", "true"] = "measured",
    horizons_s: Sequence[float] = HORIZONS_S,
    stride_s: float = 0.5,
    max_steps: int | None = None,
) -> dict[str, Any]:
    """The angle RMSE of every model (and of :data:`HOLD`) ``horizons_s`` after measured starts.

    Args:
        models: label -> surrogate; all start at the same moments, warmed up on the
            longest window ``W`` among them (a windowed model reads its own last ``W``).
        episodes: the scored episodes.
        spec: the machine (joint names, periodic joints, sample period).
        reference: ``measured`` or ``true`` angles to start from and compare with.
        horizons_s: horizons [s], rounded to whole samples.
        stride_s: seconds between two starts.
        max_steps: truncate the episodes.

    Returns:
        ``{"horizons_s", "steps", "stride_s", "n_start", "rmse": {label: {joint: [per
        horizon, None where no start reaches it]}}, "curve": {"seconds": (n,), "rmse":
        {label: {joint: (n,)}}}, "display", "warmup"}``, RMSE in stored units (rad; m for
        a linear joint), the labels in the order of ``models``, then :data:`HOLD`; the curve
        holds every sample up to the longest horizon.
    """
    check_horizons(horizons_s, stride_s)
    if HOLD in models:
        raise ConfigError(f"'{HOLD}' names the no-motion baseline: give the model another label")
    dt = spec.dt
    steps = [max(1, round(h / dt)) for h in horizons_s]
    n_max = max(steps)
    stride = max(1, round(stride_s / dt))
    periodic = np.asarray(spec.periodic, dtype=bool)
    window = max(m.window for m in models.values())  # one set of starts for every model
    labels = [*models, HOLD]
    sq = {label: np.zeros((n_max, spec.n_joint)) for label in labels}
    count = np.zeros(n_max, dtype=np.int64)
    n_start = 0
    for ep in episodes:
        theta = np.asarray(reference_theta(ep, reference)[:max_steps], dtype=np.float64)
        u = np.asarray(ep.u[:max_steps], dtype=np.float64)
        n_start += len(range(window - 1, len(u) - 1, stride))
        for label in labels:
            sur = models.get(label)
            s, c = _squared_errors(
                sur, theta, u, window=window, stride=stride, n_max=n_max, periodic=periodic
            )
            sq[label] += s
            if label == HOLD:
                count += c
    with np.errstate(invalid="ignore", divide="ignore"):
        rmse = {label: np.sqrt(sq[label] / count[:, None]) for label in labels}

    def listed(a: np.ndarray) -> list[float | None]:
        return [None if not np.isfinite(v) else float(v) for v in a]

    return {
        "horizons_s": [float(h) for h in horizons_s],
        "steps": steps,
        "stride_s": stride * dt,
        "n_start": n_start,
        "warmup": window,
        "display": {j.name: display_unit(j) for j in spec.joints},
        "rmse": {
            label: {name: listed(r[[s - 1 for s in steps], i]) for i, name in enumerate(spec.names)}
            for label, r in rmse.items()
        },
        "curve": {
            "seconds": [float((j + 1) * dt) for j in range(n_max)],
            "rmse": {
                label: {name: listed(r[:, i]) for i, name in enumerate(spec.names)}
                for label, r in rmse.items()
            },
        },
    }


def display_unit(joint: JointSpec) -> dict[str, Any]:
    """``{"unit", "factor"}`` a joint's angle error is shown in: degrees, or a linear joint's
    display unit (mm)."""
    if joint.linear:
        return {"unit": joint.display_unit, "factor": joint.display_factor}
    return {"unit": "°", "factor": math.degrees(1.0)}


def horizon_markdown(result: Mapping[str, Any]) -> str:
    """The table of :func:`horizon_errors`: a row per joint and model (in its order: the
    evaluated model first, the hold baseline last), a column per horizon, in the display
    units (°, mm)."""
    if not result or not result.get("n_start"):
        return ""
    hs = result["horizons_s"]
    head = "| Joint | Model | " + " | ".join(f"{h:g} s" for h in hs) + " |"
    rule = "|---|---|" + "---:|" * len(hs)
    lines = [
        "## Prediction horizon",
        "",
        f"Angle RMSE n seconds after {result['n_start']} measured starts (every "
        f"{result['stride_s']:g} s, each warmed up on the {result['warmup']} samples before "
        "it), driven by the recorded commands. *hold*: the machine stays where it is.",
        "",
        head,
        rule,
    ]
    labels = list(result["rmse"])
    for joint, shown_in in result["display"].items():
        f = shown_in["factor"]
        for k, label in enumerate(labels):
            vals = result["rmse"][label][joint]
            cells = " | ".join("—" if v is None else f"{v * f:.3g}" for v in vals)
            name = f"{joint.capitalize()} [{shown_in['unit']}]" if k == 0 else ""
            shown = f"*{label}*" if label == HOLD else label
            lines.append(f"| {name} | {shown} | {cells} |")
    return "\n".join(lines) + "\n"
