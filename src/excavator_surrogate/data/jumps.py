"""Sensor-fault metadata of an episode: the jump mask stored in ``extra["sensor"]``.

Part of the data contract: simulated episodes with sensor faults record where the angle
sensor jumped as compact runs ``extra["sensor"]["jump_runs"] = [[joint, start, stop), ...]``;
the cleaning stage scores its detector against them.
"""

from __future__ import annotations

import numpy as np

from ..errors import DataError
from .episode import Episode


def mask_to_runs(mask: np.ndarray) -> list[list[int]]:
    """Compact form of a (n_step, n_joint) bool mask: ``[[joint, start, stop), ...]`` runs of True."""
    mask = np.asarray(mask, dtype=bool)
    runs: list[list[int]] = []
    for j in range(mask.shape[1]):
        m = np.concatenate([[False], mask[:, j], [False]]).astype(np.int8)
        edges = np.flatnonzero(np.diff(m))
        runs.extend([j, int(a), int(b)] for a, b in zip(edges[0::2], edges[1::2]))
    return runs


def runs_to_mask(
    runs: list[list[int]], n_step: int, n_joint: int, *, name: str | None = None
) -> np.ndarray:
    """Inverse of :func:`mask_to_runs`: a (n_step, n_joint) bool mask.

    Raises:
        DataError: a run outside ``[0, n_step)`` or of a joint the episode does not have
            (``name``: the episode the runs belong to, for the message).
    """
    mask = np.zeros((n_step, n_joint), dtype=bool)
    for run in runs:
        j, a, b = (int(x) for x in run)
        if not (0 <= j < n_joint and 0 <= a < b <= n_step):
            raise DataError(
                name,
                f"sensor jump run [{j}, {a}, {b}) lies outside the episode's {n_joint} joints "
                f"x {n_step} samples",
                fix="re-run the simulation that wrote it, or drop extra['sensor']['jump_runs']",
            )
        mask[a:b, j] = True
    return mask


def jump_mask_of(ep: Episode) -> np.ndarray | None:
    """The (n_step, n_joint) jump mask stored by :func:`apply_sensors_episode`, or None."""
    sensor = (ep.extra or {}).get("sensor")
    if not isinstance(sensor, dict) or "jump_runs" not in sensor:
        return None
    return runs_to_mask(sensor["jump_runs"], ep.n_step, ep.spec.n_joint, name=ep.name)
