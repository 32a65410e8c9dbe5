"""Tiny datasets and training configs for the training tests."""

from __future__ import annotations

from pathlib import Path

from excavator_surrogate.data import Dataset
from excavator_surrogate.surrogate.checkpoint import load_checkpoint
from excavator_surrogate.surrogate.model import Surrogate
from excavator_surrogate.surrogate.synthetic import synthetic_episode, synthetic_spec
from excavator_surrogate.training import TrainConfig, train
from excavator_surrogate.training.config import MODE_FIELDS


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


def train_tiny_free_run(out: Path, mode: str, **overrides) -> tuple[Dataset, Surrogate]:
    """Train two epochs (the first teacher-forced, then free run) of a tiny config in
    ``mode`` on a tiny 2-joint dataset, with extra config fields ``overrides`` (the input
    features under test); returns the dataset and the loaded best checkpoint."""
    ds = tiny_dataset(2, n_train=2, n_step=120)
    cfg = tiny_train_config(
        mode=mode,
        horizon=3,
        burn_in=10,
        seq_batch=2,
        batch_size=16,
        epochs=2,
        feedback="free",
        teacher_epochs=1,
        **overrides,
    )
    return ds, load_checkpoint(train(cfg, ds, out=out, show_progress=False))
