"""Assigning source files to train/val/test.

Splits are made **per source file**: every episode cut from one file (segments split at
time gaps) lands in the same split, so no recording contributes windows to both
training and test.
"""

from __future__ import annotations

import fnmatch
import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ..data import SPLITS
from ..errors import ConfigError
from .mapping import SplitOptions


def assign_splits(
    files: Sequence[str | Path],
    sizes: Sequence[int],
    options: SplitOptions,
) -> tuple[dict[str, str], list[str]]:
    """Split of each file, plus warnings.

    Args:
        files: source files (as given on the command line); each a group of episodes.
        sizes: samples each file contributes (used by ``by = "fraction"``).
        options: the ``[split]`` options.

    Returns:
        ``({file: split}, warnings)``.

    Raises:
        ConfigError: a file matched by several splits, or not listed (``glob``/``file``).
    """
    keys = [str(f) for f in files]
    if not keys:
        return {}, []
    if options.by == "fraction":
        return _by_fraction(keys, list(sizes), options)
    return _by_pattern(keys, options)


def _by_fraction(
    keys: list[str], sizes: list[int], o: SplitOptions
) -> tuple[dict[str, str], list[str]]:
    order = sorted(range(len(keys)), key=lambda i: keys[i])
    perm = np.random.default_rng(o.seed).permutation(len(order))
    order = [order[i] for i in perm]
    total = float(sum(sizes)) or 1.0
    # each file (in shuffled order) goes to the split furthest below its share of samples
    target = {s: f * total for s, f in zip(SPLITS, o.fractions)}
    got = dict.fromkeys(SPLITS, 0.0)
    out: dict[str, str] = {}
    for i in order:
        s = max(SPLITS, key=lambda x: (target[x] - got[x], -SPLITS.index(x)))
        got[s] += sizes[i]
        out[keys[i]] = s
    # a split with a share but no file takes the smallest file of the biggest other split
    for s, f in zip(SPLITS, o.fractions):
        if f <= 0 or s in out.values():
            continue
        counts = {x: sum(1 for v in out.values() if v == x) for x in SPLITS}
        donor = max(SPLITS, key=lambda x: counts[x])
        if counts[donor] < 2:
            continue
        cand = [i for i in order if out[keys[i]] == donor]
        pick = min(cand, key=lambda i: (sizes[i], keys[i]))
        out[keys[pick]] = s
    warnings = [
        f"split '{s}' is empty: {len(keys)} file(s) are too few for fractions {list(o.fractions)}"
        for s, f in zip(SPLITS, o.fractions)
        if f > 0 and s not in out.values()
    ]
    return out, warnings


def _by_pattern(keys: list[str], o: SplitOptions) -> tuple[dict[str, str], list[str]]:
    exact = o.by == "file"
    pats = {"train": o.train, "val": o.val, "test": o.test}
    if not any(pats.values()):
        raise ConfigError(
            f"split by {o.by} needs file names or patterns for train/val/test "
            "([split] val = [...] or --val/--test/--train)"
        )

    def hit(key: str, pat: str) -> bool:
        name = Path(key).name
        if exact:
            return key == pat or name == pat or Path(key) == Path(pat)
        # the path as the user spells it (./logs/r0.csv, logs/../logs/r0.csv, absolute)
        norm, absolute = os.path.normpath, os.path.abspath
        return (
            fnmatch.fnmatch(norm(key), norm(pat))
            or fnmatch.fnmatch(absolute(key), absolute(pat))
            or fnmatch.fnmatch(name, pat)
        )

    out: dict[str, str] = {}
    warnings: list[str] = []
    for key in keys:
        matched = [s for s in SPLITS if any(hit(key, p) for p in pats[s])]
        if len(matched) > 1:
            raise ConfigError(
                f"{key}: matches the {' and '.join(matched)} split {'lists' if exact else 'patterns'}; "
                "a file may belong to one split only"
            )
        if matched:
            out[key] = matched[0]
        elif exact or pats["train"]:
            what = "listed in" if exact else "matched by"
            raise ConfigError(
                f"{key}: not {what} any split ({'train, val, test'}); "
                f"add it to [split] train/val/test or the split options"
            )
        else:
            out[key] = "train"
    for s in SPLITS:
        for p in pats[s]:
            if not any(hit(k, p) for k in keys):
                warnings.append(
                    f"split file lists '{p}' ({s}) but no such source was imported"
                    if exact
                    else f"split pattern '{p}' ({s}) matches no imported file"
                )
    for s in SPLITS:
        if s not in out.values():
            warnings.append(f"split '{s}' is empty")
    return out, warnings
