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
    the training episodes ``cfg`` trains on.  Where the validation episodes are trained on
    (``cfg.train_on_val``) they count as training runs, not held-out ones: the scales are the
    training runs' alone (rule ``"train"``), in-sample, and the log says so.
    """
    train_eps, val_eps = split_episodes(cfg, dataset)
    held_out = [] if cfg.train_on_val else val_eps
    cal, _ = calibrate_checkpoint(best, held_out, train_eps)
    if cal is None:
        _log.info(f"{best}: coverage record stored (single network: no uncertainty bands)")
    else:
        k90 = ", ".join(f"{v:.2g}" for v in cal.theta[-1])
        runs = (
            f"{cal.n_train_run} training runs (validation is trained on: no held-out run, the "
            "bands are in-sample and likely too narrow off the training's commands)"
            if cfg.train_on_val
            else f"{cal.n_run} validation and {cal.n_train_run} training runs"
        )
        _log.info(
            f"{best}: ensemble bands calibrated on {cal.n_step} steps of {runs} "
            f"(angle {round(100 * cal.levels[-1])} % scale per joint: {k90}) and coverage stored"
        )
