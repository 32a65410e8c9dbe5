"""clean stage: consistency-aware adaptive Kalman filtering of joint angles and gyro rates.

See docs/cleaning.md.  Entry points: :func:`clean_episode`, :func:`clean_dataset`,
:func:`cleaning_metrics`, and the array-level :func:`fuse`.
"""

from .api import (
    clean_dataset,
    clean_episode,
    clean_episodes,
    cleaning_metrics,
    pooled_cleaning_metrics,
)
from .config import METHODS, CleanConfig
from .filters import integrate_gyro
from .kalman import FusionResult, backward_difference, fuse

__all__ = [
    "METHODS",
    "CleanConfig",
    "FusionResult",
    "backward_difference",
    "clean_dataset",
    "clean_episode",
    "clean_episodes",
    "cleaning_metrics",
    "fuse",
    "integrate_gyro",
    "pooled_cleaning_metrics",
]
