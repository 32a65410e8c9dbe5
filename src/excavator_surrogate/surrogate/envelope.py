"""The machine's physical envelope, completed from data where the spec leaves it open.

A free run must never leave what the machine can physically do.  The envelope is a pair of
bounds per joint (:func:`~.angles.envelope`): end stops ``[theta_min, theta_max]`` [rad] and
a speed bound ``omega_max`` [rad/s].  A mapping or a simulator spec may declare them; most
users' mappings do not.  :func:`fill_envelope` then takes them from the training data:

- end stops: the range of angles seen in training, widened on each side by ``limit_margin``
  times that range (real runs end against the end stops, so the range *is* the end stops up
  to the sensor's noise and the structure's give under load);
- speed bound: the largest ``|omega|`` seen in training (backward differences of the
  recorded angle) times ``1 + speed_margin``.

Declared bounds are never replaced; periodic joints get no end stops.  The result is stored in
the checkpoint's spec, so every runtime (closed loop, vector env, ONNX) applies the same bounds.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence

import numpy as np

from ..data.episode import Episode
from ..spec import MachineSpec
from .angles import omega_target, unwrap_periodic


def fill_envelope(
    spec: MachineSpec,
    episodes: Sequence[Episode],
    *,
    limit_margin: float,
    speed_margin: float,
) -> tuple[MachineSpec, dict[str, dict[str, float | str]]]:
    """``spec`` with the end stops and speed bounds it lacks taken from ``episodes``.

    Args:
        spec: the machine; its declared limits and ``omega_max`` are kept.
        episodes: the training episodes (``theta: (n_step, n_joint)`` [rad]).
        limit_margin: widen the observed angle range by this fraction of it on each side
            (negative: derive no end stops).
        speed_margin: the speed bound is ``(1 + speed_margin)`` times the largest observed
            ``|omega|`` (negative: derive no speed bound).

    Returns:
        The completed spec and, per joint, ``{"theta_min", "theta_max", "omega_max"}`` with
        each value's ``*_source`` (``"spec"``, ``"data"`` or ``"none"``), for reports.
    """
    if not episodes:
        return spec, {}
    th = np.concatenate([unwrap_periodic(e.theta, spec) for e in episodes])
    om = np.concatenate([omega_target(e.theta, spec)[1:] for e in episodes])
    lo, hi = np.nanmin(th, axis=0), np.nanmax(th, axis=0)
    w = np.nanmax(np.abs(om), axis=0)
    joints, info = [], {}
    for k, j in enumerate(spec.joints):
        span = float(hi[k] - lo[k])
        changes: dict[str, float] = {}
        rec: dict[str, float | str] = {}
        for key, value in (
            ("theta_min", float(lo[k]) - limit_margin * span),
            ("theta_max", float(hi[k]) + limit_margin * span),
        ):
            declared = getattr(j, key)
            if declared is not None:
                rec[key], rec[f"{key}_source"] = float(declared), "spec"
            elif j.periodic or limit_margin < 0 or not math.isfinite(value):
                rec[key], rec[f"{key}_source"] = math.nan, "none"
            else:
                changes[key] = value
                rec[key], rec[f"{key}_source"] = value, "data"
        bound = float(w[k]) * (1.0 + speed_margin)
        if j.omega_max is not None:
            rec["omega_max"], rec["omega_max_source"] = float(j.omega_max), "spec"
        elif speed_margin < 0 or not (math.isfinite(bound) and bound > 0):
            rec["omega_max"], rec["omega_max_source"] = math.nan, "none"
        else:
            changes["omega_max"] = bound
            rec["omega_max"], rec["omega_max_source"] = bound, "data"
        joints.append(dataclasses.replace(j, **changes) if changes else j)
        info[j.name] = rec
    return dataclasses.replace(spec, joints=tuple(joints)), info


def with_end_stops(
    spec: MachineSpec, lo: Sequence[float], hi: Sequence[float], *, joints: Sequence[bool]
) -> MachineSpec:
    """``spec`` with the end stops of ``joints`` set to ``lo`` / ``hi``.

    Args:
        spec: the machine.
        lo, hi: (n_joint,) end stops [rad]; an infinite value sets none.
        joints: (n_joint,) which joints take them; periodic joints keep none.
    """
    out = []
    for j, a, b, p in zip(spec.joints, lo, hi, joints):
        if p and not j.periodic:
            a, b = float(a), float(b)
            j = dataclasses.replace(
                j,
                theta_min=a if math.isfinite(a) else None,
                theta_max=b if math.isfinite(b) else None,
            )
        out.append(j)
    return dataclasses.replace(spec, joints=tuple(out))
