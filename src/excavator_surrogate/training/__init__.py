"""training stage: fit a :class:`~excavator_surrogate.surrogate.model.SurrogateNet` to a dataset.

One idea per module:

- :mod:`.config` - :class:`TrainConfig` (the ``[train]`` table) and which knobs each mode reads;
- :mod:`.loss` - the loss passed into the loop (:func:`horizon_loss`, paper III-B);
- :mod:`.batches` - training data on the device, episode selection;
- :mod:`.modes` - ``windowed`` / ``stateful`` strategies (``batches()``, ``predict()``);
- :mod:`.parallel` - the :class:`Parallel` interface, :class:`SingleProcess`, the NaN rule;
- :mod:`.optim` - optimiser, learning-rate schedules, weight average;
- :mod:`.loop` - the one epoch loop (:func:`train_network`);
- :mod:`.selection` - free-run validation and best-epoch selection;
- :mod:`.resume` - starting fresh or from a checkpoint;
- :mod:`.records` - ``config.toml``, ``log.csv``, TensorBoard;
- :mod:`.jobs` - independent trainings side by side in processes (:class:`TrainJob`);
- :mod:`.ensembles` - seed ensembles (:func:`train_ensemble`);
- :mod:`.api` - :func:`train`, :func:`train_parallel`.
"""

from ..surrogate.validation import free_run_error
from .api import train, train_parallel
from .config import TrainConfig
from .ensembles import member_configs, train_ensemble
from .jobs import TrainJob
from .loop import EpochCallback, train_network
from .loss import LossFn, horizon_loss
from .parallel import Parallel, SingleProcess, clip_and_step

__all__ = [
    "EpochCallback",
    "LossFn",
    "Parallel",
    "SingleProcess",
    "TrainConfig",
    "TrainJob",
    "clip_and_step",
    "free_run_error",
    "horizon_loss",
    "member_configs",
    "train",
    "train_ensemble",
    "train_network",
    "train_parallel",
]
