"""Training data on the device and the episodes it comes from.

:class:`TrainData` holds the training episodes concatenated on the device (one global sample
index); :func:`windowed_indices` and :func:`sequence_starts` list the samples each mode draws
its batches from, each episode as many times as :func:`bootstrap_counts` says when a member
trains on a bootstrap resample; :func:`split_episodes` picks the training and validation
episodes long enough for a config.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
import torch

from ..data.dataset import Dataset
from ..data.episode import Episode
from ..errors import DataError
from ..surrogate.angles import omega_in_np, omega_target
from ..surrogate.features import Normalization
from .config import TrainConfig

_log = logging.getLogger(__name__)


@dataclass
class TrainData:
    """Training episodes concatenated on the device (global sample index)."""

    x: torch.Tensor
    """(T, n_feature) normalised recorded features."""
    theta: torch.Tensor
    """(T, n_joint) recorded angles [rad]."""
    u: torch.Tensor
    """(T, n_joint) commands."""
    z: torch.Tensor
    """(T, P, n_joint) play states after u (P = 0: no play features)."""
    w: torch.Tensor
    """(T, n_joint) recorded velocity feature [rad/s] (:func:`omega_in_np`, used or not)."""
    y: torch.Tensor
    """(T, n_joint) normalised targets (row 0 of each episode NaN)."""
    starts: np.ndarray
    """(n_episode,) global start index of each episode."""
    lengths: np.ndarray
    """(n_episode,) samples per episode."""


def make_data(episodes: list[Episode], norm: Normalization, device: torch.device) -> TrainData:
    """Normalise and concatenate ``episodes`` on ``device``."""
    spec = episodes[0].spec
    xs, ths, us, zs, ws, ys = [], [], [], [], [], []
    y_mean, y_std = norm.y_mean.double().numpy(), norm.y_std.double().numpy()
    for ep in episodes:
        z = norm.play_from_rest_np(ep.u, spec)
        w = omega_in_np(ep.theta, spec)
        xs.append(norm.encode_np(ep.theta, ep.u, spec, z, w))
        ws.append(w)
        ths.append(ep.theta)
        us.append(ep.u)
        zs.append(np.zeros((ep.n_step, 0, spec.n_joint)) if z is None else z)
        ys.append((omega_target(ep.theta, spec) - y_mean) / y_std)
    lengths = np.array([ep.n_step for ep in episodes])
    starts = np.concatenate([[0], np.cumsum(lengths)[:-1]])

    def t(parts: list[np.ndarray]) -> torch.Tensor:
        return torch.as_tensor(np.concatenate(parts), dtype=torch.float32, device=device)

    return TrainData(
        x=t(xs), theta=t(ths), u=t(us), z=t(zs), w=t(ws), y=t(ys), starts=starts, lengths=lengths
    )


BOOTSTRAP_STREAM = 0xB007
"""Second word of a bootstrap draw's seed ``(seed, BOOTSTRAP_STREAM)``: a stream of its own,
apart from the epochs' ``(seed, epoch)``."""


def bootstrap_counts(n_episode: int, seed: int) -> np.ndarray:
    """(n_episode,) how many times each training episode is in the bootstrap resample of the
    member with ``seed``: ``n_episode`` episodes drawn with replacement (a multinomial draw,
    about 37 % of the episodes left out, some twice or more), from ``seed`` alone, so the same
    on every run, machine and epoch, and different for every member (seeds ``seed + i``)."""
    rng = np.random.default_rng([seed, BOOTSTRAP_STREAM])
    return rng.multinomial(n_episode, np.full(n_episode, 1.0 / n_episode))


def _copies(data: TrainData, counts: np.ndarray | None) -> list[tuple[int, int]]:
    """``(start, length)`` of each episode, repeated ``counts`` times (None: once each)."""
    pairs = list(zip(data.starts.tolist(), data.lengths.tolist()))
    if counts is None:
        return pairs
    return [p for p, k in zip(pairs, counts.tolist()) for _ in range(k)]


def windowed_indices(
    data: TrainData, window: int, horizon: int, counts: np.ndarray | None = None
) -> np.ndarray:
    """Global indices t of window ends with targets t+1..t+H inside the episode (episode i's
    ``counts[i]`` times: a bootstrap resample; None: once each)."""
    idx = [
        s + np.arange(window - 1, n - horizon)
        for s, n in _copies(data, counts)
        if n - horizon > window - 1
    ]
    return np.concatenate(idx) if idx else np.zeros(0, dtype=np.int64)


def sequence_starts(
    data: TrainData,
    seq_len: int,
    burn_in: int,
    rng: np.random.Generator,
    counts: np.ndarray | None = None,
) -> np.ndarray:
    """Global starts s of sub-sequences (steps s..s+L-1, targets up to s+L) tiling each episode
    (episode i's ``counts[i]`` times, each copy from its own random offset: a bootstrap
    resample; None: once each)."""
    stride = seq_len - burn_in + 1
    out = []
    for s0, n in _copies(data, counts):
        last = n - 1 - seq_len  # local start must satisfy s + L <= n - 1
        if last < 0:
            continue
        off = int(rng.integers(0, min(stride, last + 1)))
        out.append(s0 + np.arange(off, last + 1, stride))
    return np.concatenate(out) if out else np.zeros(0, dtype=np.int64)


def sequence_cap(epoch_samples: int, *, seq_len: int, burn_in: int) -> int | None:
    """Most sub-sequences an epoch trains under a cap of ``epoch_samples`` target samples
    (None: no cap, ``epoch_samples`` 0), each sub-sequence holding ``seq_len - burn_in + 1``
    targets; at least one."""
    if epoch_samples <= 0:
        return None
    return max(1, epoch_samples // (seq_len - burn_in + 1))


def global_batches(order: np.ndarray, size: int) -> list[np.ndarray]:
    """``order`` cut into consecutive batches of ``size`` (the last one may be short)."""
    return [order[b : b + size] for b in range(0, len(order), size)]


def val_min_steps(window: int) -> int:
    """The fewest samples a validation episode needs to be free-run after a ``window``-sample
    warm-up (shorter ones are skipped)."""
    return window + 2


def _usable(episodes: list[Episode], n_min: int, split: str) -> list[Episode]:
    keep = [e for e in episodes if e.n_step >= n_min]
    if len(keep) < len(episodes):
        _log.info(
            f"{split}: skipping {len(episodes) - len(keep)} episode(s) shorter than {n_min} samples"
        )
    return keep


def split_episodes(cfg: TrainConfig, dataset: Dataset) -> tuple[list[Episode], list[Episode]]:
    """The training and validation episodes long enough for ``cfg`` (validation falls back to
    the training episodes, with a warning); with ``cfg.train_on_val`` the validation episodes
    long enough to train on are training episodes too (after the training split's).

    Raises:
        DataError: no training episode is long enough.
    """
    n_min = cfg.window + cfg.horizon + 1 if cfg.mode == "windowed" else cfg.seq_len + 1
    train_eps = _usable(dataset.train, n_min, "train")
    if cfg.mode == "stateful" and not train_eps and dataset.train:
        longest = max(e.n_step for e in dataset.train)
        raise DataError(
            dataset.root,
            f"every training episode is shorter than seq_len + 1 = {n_min} (longest {longest})",
            fix="lower [train] seq_len",
        )
    if not train_eps:
        raise DataError(
            dataset.root,
            f"no training episode with at least {n_min} samples",
            fix="add training episodes or lower window/horizon",
        )
    val_eps = _usable(dataset.val, val_min_steps(cfg.window), "val")
    if not val_eps:
        _log.warning(
            "no usable validation episodes: validating on the training episodes "
            "(model selection is optimistic)"
        )
        return train_eps, train_eps
    if cfg.train_on_val:  # they still score the epochs (cfg.train_on_val's doc)
        train_eps = train_eps + [e for e in val_eps if e.n_step >= n_min]
    return train_eps, val_eps
