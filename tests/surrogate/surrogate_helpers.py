"""Test helpers: untrained tiny surrogates and in-memory synthetic datasets."""

from __future__ import annotations

import torch

from excavator_surrogate.data import Dataset, Episode
from excavator_surrogate.spec import MachineSpec
from excavator_surrogate.surrogate import ModelConfig, Normalization, Surrogate
from excavator_surrogate.surrogate.model import build_net
from excavator_surrogate.surrogate.synthetic import synthetic_episode, synthetic_spec
from excavator_surrogate.training import TrainConfig
from excavator_surrogate.training.config import MODE_FIELDS
from shared_helpers import drive_into_stops


def make_surrogate(
    spec: MachineSpec,
    episodes: list[Episode],
    *,
    cell: str = "lstm",
    mode: str = "windowed",
    window: int = 8,
    hidden: int = 12,
    seed: int = 0,
    end_stops: bool = False,
    drive: float = 0.0,
    play: tuple[float, ...] = (),
) -> Surrogate:
    """An untrained tiny surrogate with normalisation fitted on ``episodes``.

    ``play``: half-widths of command play features.  ``drive`` adds +/- ``drive`` (alternating by joint, normalised units) to the output bias,
    so that the free run runs into the joint limits (for end-stop tests)."""
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
    norm = Normalization.fit([e.theta for e in episodes], [e.u for e in episodes], spec, play=play)
    return Surrogate(
        net=net, spec=spec, norm=norm, model_cfg=cfg, mode=mode, name=cell, end_stops=end_stops
    )


def tiny_train_config(**overrides) -> TrainConfig:
    """A tiny training config (stateful unless ``mode`` is given; window 5, 8 units, 40-sample sequences, no
    TensorBoard) for fast tests; keyword arguments override its fields, and knobs of the mode
    not trained are dropped."""
    kw = dict(
        window=5,
        hidden=8,
        head_hidden=8,
        mode="stateful",
        seq_len=40,
        burn_in=5,
        tbptt=10,
        tensorboard=False,
    )
    kw = {**kw, **overrides}
    # knobs of the other mode are dropped (setting them would be an error)
    other = {n for m, names in MODE_FIELDS.items() if m != kw["mode"] for n in names}
    kw = {k: v for k, v in kw.items() if k not in other}
    return TrainConfig(**kw)


def tiny_dataset(
    n_joint: int = 3, *, n_train: int = 3, n_step: int = 300, seed: int = 0
) -> Dataset:
    """In-memory synthetic dataset (train sine, val sine, test step)."""
    spec = synthetic_spec(n_joint)
    ds = Dataset(spec=spec)
    for i in range(n_train):
        ds.episodes["train"].append(
            synthetic_episode(spec, kind="sine", n_step=n_step, seed=seed * 100 + i)
        )
    ds.episodes["val"].append(
        synthetic_episode(spec, kind="sine", n_step=n_step, seed=seed * 100 + 50)
    )
    ds.episodes["test"].append(
        synthetic_episode(spec, kind="step", n_step=n_step, seed=seed * 100 + 60)
    )
    return ds
