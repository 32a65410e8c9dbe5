"""Fixtures for the environment tests: tiny untrained checkpoints (no training needed)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import torch

from excavator_surrogate.spec import EXCAVATOR, MachineSpec
from excavator_surrogate.surrogate.checkpoint import save_checkpoint
from excavator_surrogate.surrogate.features import Normalization
from excavator_surrogate.surrogate.model import ModelConfig, Surrogate, build_net
from shared_helpers import drive_into_stops


def tiny_surrogate(
    *,
    mode: str = "stateful",
    cell: str = "lstm",
    spec: MachineSpec = EXCAVATOR,
    window: int = 6,
    hidden: int = 16,
    seed: int = 0,
    end_stops: bool = False,
    drive: float = 0.0,
    play: tuple[float, ...] = (),
) -> Surrogate:
    """An untrained small surrogate with a non-trivial normalisation (slow, bounded output).

    ``play``: half-widths of command play features (inputs widen by ``len(play) * n_joint``).

    ``drive`` adds +/- ``drive`` (alternating by joint, normalised units) to the output bias so
    that free runs reach the joint limits (end-stop tests)."""
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    n_feature = spec.n_feature + len(play) * spec.n_joint
    cfg = ModelConfig(
        n_feature=n_feature,
        n_joint=spec.n_joint,
        window=window,
        hidden=hidden,
        n_layer=2,
        cell=cell,
        head_hidden=hidden,
    )
    norm = Normalization.from_arrays(
        x_mean=rng.normal(size=n_feature) * 0.1,
        x_std=1.0 + rng.random(n_feature),
        y_mean=np.zeros(spec.n_joint),
        y_std=np.full(spec.n_joint, 0.05),
        spec=spec,
        play=play,
    )
    net = build_net(cfg).eval()
    drive_into_stops(net, drive, spec.n_joint)
    return Surrogate(
        net=net, spec=spec, norm=norm, model_cfg=cfg, mode=mode, name=cell, end_stops=end_stops
    )


@pytest.fixture(scope="session")
def make_surrogate() -> Callable[..., Surrogate]:
    """Factory of tiny untrained surrogates (see :func:`tiny_surrogate`)."""
    return tiny_surrogate


@pytest.fixture(scope="session")
def ckpt_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("ckpt")


@pytest.fixture(scope="session")
def stateful_ckpt(ckpt_dir: Path) -> Path:
    """Path of a tiny stateful LSTM checkpoint."""
    return save_checkpoint(ckpt_dir / "stateful.pt", tiny_surrogate(mode="stateful"))


@pytest.fixture(scope="session")
def windowed_ckpt(ckpt_dir: Path) -> Path:
    """Path of a tiny windowed LSTM checkpoint."""
    return save_checkpoint(ckpt_dir / "windowed.pt", tiny_surrogate(mode="windowed", seed=1))
