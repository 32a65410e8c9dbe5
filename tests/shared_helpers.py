"""Helpers shared by the test folders (``tests/`` is on ``sys.path`` through its conftest)."""

from __future__ import annotations

import numpy as np
import torch
from torch import nn

from excavator_surrogate.spec import EXCAVATOR, MachineSpec
from excavator_surrogate.surrogate.features import Normalization
from excavator_surrogate.surrogate.model import ModelConfig, Surrogate, build_net


def drive_into_stops(net: nn.Module, drive: float, n_joint: int) -> None:
    """Add ``+/- drive`` (alternating by joint, normalised units) to the output bias of an
    untrained surrogate network so that its free runs reach the joint limits (end-stop tests)."""
    if not drive:
        return
    last = net.linear if hasattr(net, "linear") else net.head[-1]
    with torch.no_grad():
        last.bias += drive * torch.tensor([(-1.0) ** j for j in range(n_joint)])


def tiny_net(
    spec: MachineSpec,
    *,
    cell: str,
    window: int,
    hidden: int,
    seed: int,
    drive: float = 0.0,
    play: tuple[float, ...] = (),
) -> tuple[nn.Module, ModelConfig]:
    """An untrained 2-layer network (eval mode) for ``spec`` (inputs widen by
    ``len(play) * n_joint`` play features) and its config; ``drive``: see
    :func:`drive_into_stops`."""
    torch.manual_seed(seed)
    cfg = ModelConfig(
        n_feature=spec.n_feature + len(play) * spec.n_joint,
        n_joint=spec.n_joint,
        window=window,
        hidden=hidden,
        n_layer=2,
        cell=cell,
        head_hidden=hidden,
    )
    net = build_net(cfg).eval()
    drive_into_stops(net, drive, spec.n_joint)
    return net, cfg


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
    net, cfg = tiny_net(
        spec, cell=cell, window=window, hidden=hidden, seed=seed, drive=drive, play=play
    )
    rng = np.random.default_rng(seed)
    n_feature = cfg.n_feature
    norm = Normalization.from_arrays(
        x_mean=rng.normal(size=n_feature) * 0.1,
        x_std=1.0 + rng.random(n_feature),
        y_mean=np.zeros(spec.n_joint),
        y_std=np.full(spec.n_joint, 0.05),
        spec=spec,
        play=play,
    )
    return Surrogate(
        net=net, spec=spec, norm=norm, model_cfg=cfg, mode=mode, name=cell, end_stops=end_stops
    )
