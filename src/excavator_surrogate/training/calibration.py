"""After training: record what the data covered and calibrate the ensemble's bands.

Runs once ``best.pt`` is final (:func:`~.api.train`, for one network and for a merged seed
ensemble alike): the training split's coverage record always, the band scales when the
checkpoint has ensemble members (:mod:`excavator_surrogate.surrogate.uncertainty`).
"""

from __future__ import annotations

import logging
from pathlib import Path

from ..data.dataset import Dataset
from ..surrogate.bands import calibrate_checkpoint
from .batches import split_episodes
from .config import TrainConfig

_log = logging.getLogger(__name__)


def calibrate_best(cfg: TrainConfig, dataset: Dataset, best: str | Path) -> None:
    """Add the coverage record and (ensembles) the band calibration to ``best`` in place.

    The bands are fitted on whole episodes (the long free runs they are for), validation and
    training ones (:data:`~excavator_surrogate.surrogate.bands.RULE`); the coverage record on
    the training episodes ``cfg`` trains on.
    """
    train_eps, val_eps = split_episodes(cfg, dataset)
    cal, _ = calibrate_checkpoint(best, val_eps, train_eps)
    if cal is None:
        _log.info(f"{best}: coverage record stored (single network: no uncertainty bands)")
    else:
        k90 = ", ".join(f"{v:.2g}" for v in cal.theta[-1])
        _log.info(
            f"{best}: ensemble bands calibrated on {cal.n_step} steps of {cal.n_run} validation "
            f"and {cal.n_train_run} training runs "
            f"(angle {round(100 * cal.levels[-1])} % scale per joint: {k90}) and coverage stored"
        )
