"""surrogate stage: LSTM/GRU surrogate model, training, closed-loop rollout, checkpoints, baselines.

Public API: :class:`TrainConfig`, :func:`train`, :func:`load_checkpoint`, :func:`save_checkpoint`,
:class:`Surrogate`, :class:`ClosedLoop`, :func:`rollout`, :func:`rollout_episodes`,
:func:`fit_arx`, :func:`omega_target`.
"""

from .baselines import fit_arx
from .checkpoint import load_checkpoint, read_checkpoint, save_checkpoint
from .features import Normalization, encode_np, omega_target, unwrap_periodic, wrap_angle
from .model import ARXNet, ModelConfig, Surrogate, SurrogateNet
from .rollout import ClosedLoop, EpisodeRollout, rollout, rollout_episodes, rollout_reference
from .train import TrainConfig, free_run_error, horizon_loss, train

__all__ = [
    "ARXNet",
    "ClosedLoop",
    "EpisodeRollout",
    "ModelConfig",
    "Normalization",
    "Surrogate",
    "SurrogateNet",
    "TrainConfig",
    "encode_np",
    "fit_arx",
    "free_run_error",
    "horizon_loss",
    "load_checkpoint",
    "omega_target",
    "read_checkpoint",
    "rollout",
    "rollout_episodes",
    "rollout_reference",
    "save_checkpoint",
    "train",
    "unwrap_periodic",
    "wrap_angle",
]
