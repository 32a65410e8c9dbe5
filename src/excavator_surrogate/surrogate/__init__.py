"""surrogate stage: LSTM/GRU surrogate model, closed-loop rollout, validation, checkpoints, baselines.

Public API: :func:`load_checkpoint`, :func:`save_checkpoint`, :class:`Surrogate`,
:class:`ClosedLoop`, :func:`rollout`, :func:`rollout_episodes`, :func:`free_run_error`,
:func:`fit_arx`, :func:`omega_target`.  Training lives one layer up, in
:mod:`excavator_surrogate.training`.
"""

from .angles import omega_target, unwrap_periodic, wrap_angle
from .baselines import fit_arx
from .checkpoint import load_checkpoint, read_checkpoint, save_checkpoint
from .features import Normalization
from .features_np import encode_np
from .model import ARXNet, ModelConfig, Surrogate, SurrogateNet
from .reference import rollout_reference
from .rollout import ClosedLoop, EpisodeRollout, rollout, rollout_episodes
from .validation import free_run_error

__all__ = [
    "ARXNet",
    "ClosedLoop",
    "EpisodeRollout",
    "ModelConfig",
    "Normalization",
    "Surrogate",
    "SurrogateNet",
    "encode_np",
    "fit_arx",
    "free_run_error",
    "load_checkpoint",
    "omega_target",
    "read_checkpoint",
    "rollout",
    "rollout_episodes",
    "rollout_reference",
    "save_checkpoint",
    "unwrap_periodic",
    "wrap_angle",
]
