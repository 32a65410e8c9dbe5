"""Split one long recording in time: train | validation | test.

A machine logged in one continuous session (a wheel loader's 7-minute operator log) cannot
be split by file.  It is split in time instead: the last ``test_s`` seconds are the test,
the ``val_s`` seconds before them the validation, and everything earlier the training data,
so the model is always scored on what comes *after* what it learnt from::

    |<------------- train ------------->|<-- val_s -->|<--- test_s --->|

Each part is a separate episode (its own warm-up at its start), named ``<name>``,
``<name>_val`` and ``<name>_test``.  :func:`split_in_time` cuts one episode,
:func:`split_dataset_in_time` every episode of a dataset's ``train`` split (``exsur
simulate`` does it with ``[simulate] val_s / test_s``).
"""

from __future__ import annotations

from pathlib import Path

from ..errors import ConfigError, DataError
from .dataset import Dataset, load_dataset, write_dataset
from .episode import Episode

MIN_PART = 60
"""Fewest samples of each part (a 30-sample warm-up and as many to score or train on)."""


def split_in_time(
    episode: Episode, *, val_s: float, test_s: float, min_part: int = MIN_PART
) -> list[tuple[Episode, str]]:
    """Cut ``episode`` into ``(train, val, test)`` parts by time (a part of 0 s is left out).

    Args:
        episode: one long recording (``n_step`` samples at ``spec.rate_hz``).
        val_s: length of the validation part before the test part [s].
        test_s: length of the test part at the end [s].
        min_part: fewest samples of any part that is made.

    Returns:
        ``[(episode_part, split), ...]`` in time order, ready for :func:`write_dataset`.

    Raises:
        ConfigError: a negative length.
        DataError: the episode is too short for the parts.
    """
    rate = episode.spec.rate_hz
    ends = {"train": "", "val": "_val", "test": "_test"}  # the parts' name suffixes
    made = [
        (n, s, ends[s])
        for n, s in time_split_sizes(episode.n_step, rate_hz=rate, val_s=val_s, test_s=test_s)
    ]
    if any(n < min_part for n, _, _ in made):
        raise DataError(
            episode.name,
            f"is {episode.n_step / rate:.1f} s long, too short to split into train | "
            f"{val_s:g} s val | {test_s:g} s test with at least {min_part} samples each",
            fix="give shorter val_s / test_s, or a longer recording",
        )
    out: list[tuple[Episode, str]] = []
    start = 0
    for n, split, suffix in made:
        part = episode.slice(start, start + n)
        part = part.replace(
            name=f"{episode.name}{suffix}",
            extra={
                **part.extra,
                "time_split": {"from": episode.name, "start": start, "stop": start + n},
            },
        )
        out.append((part, split))
        start += n
    return out


def time_split_sizes(
    n_step: int, *, rate_hz: float, val_s: float, test_s: float
) -> list[tuple[int, str]]:
    """The parts :func:`split_in_time` cuts an ``n_step``-sample episode into, without the
    episode: ``[(n_samples, split), ...]`` in time order (a part of 0 s left out; the lengths
    not checked against :data:`MIN_PART`)::

        n_val = round(val_s * rate_hz),  n_test = round(test_s * rate_hz)
        n_train = n_step - n_val - n_test

    Raises:
        ConfigError: a negative length.
    """
    if not (val_s >= 0 and test_s >= 0):
        raise ConfigError(
            f"split in time: val_s and test_s must be >= 0 [s], got {val_s}, {test_s}"
        )
    n_val, n_test = round(val_s * rate_hz), round(test_s * rate_hz)
    parts = [(n_step - n_val - n_test, "train"), (n_val, "val"), (n_test, "test")]
    return [(n, s) for n, s in parts if n > 0 or s == "train"]


def split_dataset_in_time(
    src: str | Path | Dataset, out: str | Path, *, val_s: float, test_s: float
) -> Path:
    """Write a copy of dataset ``src`` whose ``train`` episodes are split in time.

    Episodes already in ``val`` or ``test`` keep their split.

    Args:
        src: dataset folder or loaded :class:`Dataset`.
        out: the new dataset folder (written atomically).
        val_s: validation part of each training episode [s].
        test_s: test part of each training episode [s].

    Returns:
        ``out`` as a Path.
    """
    ds = src if isinstance(src, Dataset) else load_dataset(src)
    items: list[tuple[Episode, str]] = []
    for ep in ds.train:
        items += split_in_time(ep, val_s=val_s, test_s=test_s)
    items += [(ep, s) for s in ("val", "test") for ep in ds.split(s)]
    extra = {"time_split": {"val_s": val_s, "test_s": test_s, "from": str(ds.root)}}
    return write_dataset(out, items, config=ds.manifest.get("config") or None, extra=extra)
