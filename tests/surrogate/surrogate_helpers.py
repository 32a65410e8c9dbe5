"""Test helpers: untrained tiny surrogates and in-memory synthetic datasets."""

from __future__ import annotations

from excavator_surrogate.data import Dataset, Episode
from excavator_surrogate.spec import MachineSpec
from excavator_surrogate.surrogate import Normalization, Surrogate, TrainConfig
from excavator_surrogate.surrogate.synthetic import synthetic_episode, synthetic_spec
from shared_helpers import tiny_net


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
    net, cfg = tiny_net(
        spec, cell=cell, window=window, hidden=hidden, seed=seed, drive=drive, play=play
    )
    norm = Normalization.fit([e.theta for e in episodes], [e.u for e in episodes], spec, play=play)
    return Surrogate(
        net=net, spec=spec, norm=norm, model_cfg=cfg, mode=mode, name=cell, end_stops=end_stops
    )


def tiny_stateful_config(**overrides) -> TrainConfig:
    """A tiny stateful training config (window 5, 8 units, 40-sample sequences, no
    TensorBoard) for fast tests; keyword arguments override its fields."""
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
    return TrainConfig(**{**kw, **overrides})


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
