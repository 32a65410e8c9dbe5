"""A bare free-run result for the metrics' tests: what ``evaluate.metrics`` reads of one."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class Run:
    """The fields of :class:`~excavator_surrogate.surrogate.rollout.EpisodeRollout` that the
    CBE metrics read (``RunLike``), each ``(n_step, n_joint)``."""

    theta_hat: np.ndarray
    omega_hat: np.ndarray
    theta_ref: np.ndarray
    omega_ref: np.ndarray
    warmup: int
