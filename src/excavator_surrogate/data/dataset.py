"""A dataset: a folder of episode files plus ``manifest.json``.

Layout::

    DIR/
      manifest.json        # schema_version, spec, rate_hz, source, episodes[{file, split, n_step, ...}]
      config.toml          # the config that produced the dataset
      episodes/<name>.parquet

Splits are ``train``, ``val`` and ``test``.  An episode belongs to exactly one split, so no
episode contributes windows to both training and test.
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import ConfigError, DataError, need_path
from ..io_utils import atomic_dir, write_json, write_text
from ..spec import MachineSpec
from .episode import SCHEMA_VERSION, Episode, read_episode, write_episode

SPLITS = ("train", "val", "test")
MANIFEST = "manifest.json"
NEWER_FIX = "upgrade exsur: pip install -U excavator-surrogate"
"""What to do about a manifest whose ``schema_version`` is above :data:`SCHEMA_VERSION`."""


@dataclass
class Dataset:
    """Episodes grouped by split, with the machine spec they share."""

    spec: MachineSpec
    episodes: dict[str, list[Episode]] = field(default_factory=lambda: {s: [] for s in SPLITS})
    root: Path | None = None
    manifest: dict[str, Any] = field(default_factory=dict)

    def split(self, name: str) -> list[Episode]:
        """Episodes of one split (possibly empty)."""
        return self.episodes.get(name, [])

    def paths(self, name: str) -> list[Path | None]:
        """The file each episode of split ``name`` was read from, in :meth:`split`'s order
        (None for an episode not loaded from a manifest)."""
        eps = self.split(name)
        if self.root is None or not self.manifest.get("episodes"):
            return [None] * len(eps)
        files = [self.root / e["file"] for e in self.manifest["episodes"] if e["split"] == name]
        return list(files) if len(files) == len(eps) else [None] * len(eps)

    @property
    def train(self) -> list[Episode]:
        """Training episodes."""
        return self.split("train")

    @property
    def val(self) -> list[Episode]:
        """Validation episodes."""
        return self.split("val")

    @property
    def test(self) -> list[Episode]:
        """Test episodes."""
        return self.split("test")

    def n_samples(self, split: str | None = None) -> int:
        """Total samples in one split, or all splits."""
        names = SPLITS if split is None else (split,)
        return sum(ep.n_step for s in names for ep in self.split(s))


def write_dataset(
    out: str | Path,
    items: Iterable[tuple[Episode, str]],
    *,
    config: dict[str, Any] | None = None,
    extra: dict[str, Any] | None = None,
) -> Path:
    """Write episodes with their splits to folder ``out``, atomically (temp folder, then rename).

    Args:
        out: target folder; replaced only once the new dataset is complete.
        items: ``(episode, split)`` pairs; all episodes must be of one machine
            (:meth:`MachineSpec.mismatch`) and have unique names.
        config: plain-data config recorded as ``config.toml`` and in the manifest.
        extra: extra manifest entries (e.g. preset name).
    """
    from ..config import dumps_toml

    items = list(items)
    if not items:
        raise DataError(out, "no episodes to write", fix="check the generator or import settings")
    spec = items[0][0].spec
    entries = []
    names: set[str] = set()
    with atomic_dir(out, kind="dataset") as tmp:
        (tmp / "episodes").mkdir()
        for ep, split in items:
            if split not in SPLITS:
                raise DataError(
                    out,
                    f"unknown split '{split}' for episode {ep.name}",
                    fix=f"use one of {SPLITS}",
                )
            diff = spec.mismatch(ep.spec)
            if diff is not None:
                raise DataError(
                    out,
                    f"episode {ep.name} is of another machine than episode {items[0][0].name} "
                    f"({diff})",
                    fix="write one dataset per machine, rate and command scale",
                )
            if ep.name in names:
                raise DataError(
                    out, f"duplicate episode name '{ep.name}'", fix="give episodes unique names"
                )
            names.add(ep.name)
            rel = f"episodes/{ep.name}.parquet"
            write_episode(tmp / rel, ep)
            entries.append(
                {
                    "file": rel,
                    "split": split,
                    "n_step": ep.n_step,
                    "source": ep.source,
                    "condition": ep.condition,
                    "seed": ep.seed,
                }
            )
        manifest = {
            "schema_version": SCHEMA_VERSION,
            "spec": spec.to_dict(),
            "rate_hz": spec.rate_hz,
            "n_samples": {s: sum(e["n_step"] for e in entries if e["split"] == s) for s in SPLITS},
            "episodes": entries,
            "config": config or {},
            **(extra or {}),
        }
        write_json(tmp / MANIFEST, manifest)
        if config:
            write_text(tmp / "config.toml", dumps_toml(config))
    return Path(out)


def read_manifest(root: str | Path) -> dict[str, Any]:
    """Read and check ``root/manifest.json``."""
    root = Path(root)
    mpath = root / MANIFEST
    if root.is_file():
        raise DataError(
            root,
            "is a file, not a dataset folder",
            fix="give the folder that holds manifest.json; 'exsur validate' checks single episodes",
        )
    if not root.is_dir():
        raise DataError(
            root, "dataset folder not found", fix="run 'exsur simulate' or 'exsur import' first"
        )
    if not mpath.exists():
        raise DataError(
            mpath,
            "manifest.json is missing",
            fix="a dataset folder is written by 'exsur simulate' or 'exsur import'",
        )
    try:
        manifest = json.loads(mpath.read_text())
    except json.JSONDecodeError as e:
        raise DataError(
            mpath, f"invalid JSON at line {e.lineno}", fix="regenerate the dataset"
        ) from e
    if isinstance(manifest, dict):  # first: a newer manifest may be laid out differently
        _check_schema_version(mpath, manifest)
    if not isinstance(manifest, dict) or not isinstance(manifest.get("episodes"), list):
        raise DataError(mpath, "no 'episodes' list", fix="regenerate the dataset")
    for i, e in enumerate(manifest["episodes"]):
        if (
            not isinstance(e, dict)
            or not isinstance(e.get("file"), str)
            or e.get("split") not in SPLITS
        ):
            raise DataError(
                mpath,
                f"episode entry {i} needs 'file' and 'split' in {SPLITS}",
                fix="fix or regenerate the manifest",
            )
        n_step = e.get("n_step")
        if n_step is not None and (
            isinstance(n_step, bool) or not isinstance(n_step, int) or n_step < 0
        ):
            raise DataError(
                mpath,
                f"episode entry {i} ({e['file']}): n_step {n_step!r} is not a sample count",
                fix="fix or regenerate the manifest",
            )
    _check_entries_distinct(root, mpath, manifest["episodes"])
    return manifest


def _check_schema_version(mpath: Path, manifest: dict[str, Any]) -> None:
    """The manifest's ``schema_version`` (absent in old manifests) is the one this exsur reads."""
    if "schema_version" not in manifest:
        return
    version = manifest["schema_version"]
    if version == SCHEMA_VERSION and not isinstance(version, bool):
        return
    newer = isinstance(version, int) and not isinstance(version, bool) and version > SCHEMA_VERSION
    raise DataError(
        mpath,
        f"schema_version {version!r} is not supported (this exsur reads {SCHEMA_VERSION})"
        + (": written by a newer exsur" if newer else ""),
        fix=NEWER_FIX if newer else "re-create the dataset with this version of exsur",
    )


def _check_entries_distinct(root: Path, mpath: Path, entries: list[dict[str, Any]]) -> None:
    """No two manifest entries name the same episode file (also through ``..`` or a link):
    an episode listed twice would weigh double, and one listed in two splits leaks test (or
    validation) data into training."""
    seen: dict[str, int] = {}
    for i, e in enumerate(entries):
        key = os.path.realpath(root / e["file"])
        j = seen.setdefault(key, i)
        if j == i:
            continue
        first = entries[j]
        same = first["file"] == e["file"]
        what = f"the file {e['file']}" if same else f"the same file ({first['file']}, {e['file']})"
        if first["split"] == e["split"]:
            problem = (
                f"episode entries {j} and {i} both name {what}: "
                f"the {e['split']} episode is listed twice"
            )
            fix = "remove the repeated entry, or regenerate the dataset"
        else:
            problem = (
                f"episode entries {j} ({first['split']}) and {i} ({e['split']}) both name "
                f"{what}: the {e['split']} episode is also a {first['split']} episode"
            )
            fix = (
                "an episode belongs to one split only: give each entry its own file, "
                "or regenerate the dataset"
            )
        raise DataError(mpath, problem, fix=fix)


def load_dataset(
    root: str | Path,
    *,
    splits: Sequence[str] = SPLITS,
    min_steps: int = 1,
) -> Dataset:
    """Load and validate every episode of the requested splits.

    Besides each file's contract (:func:`read_episode`), every episode must be of the
    manifest's machine (:meth:`MachineSpec.mismatch`: joints, periodic flags, kinds, command
    ranges, rate, exogenous inputs; without a manifest spec, the first episode's), have its
    entry's rate and ``n_step``, and carry a name no other loaded episode has.  These compare
    specs and names, not samples (only two files of one name are compared sample by sample).

    Raises:
        DataError: for the first file that breaks the contract.
        ConfigError: ``root`` is not a path (None, a number).
    """
    root = need_path(root, "dataset")
    manifest = read_manifest(root)
    try:
        spec = MachineSpec.from_dict(manifest["spec"]) if "spec" in manifest else None
    except ConfigError as e:
        raise DataError(
            root / MANIFEST, f"'spec' is malformed ({e})", fix="regenerate the dataset"
        ) from e
    rates = _declared_rates(root / MANIFEST, manifest, spec)
    spec_of = "the manifest's"
    ds_eps: dict[str, list[Episode]] = {s: [] for s in SPLITS}
    by_name: dict[str, tuple[int, Episode]] = {}
    for i, e in enumerate(manifest["episodes"]):
        if e["split"] not in splits:
            continue
        path = root / e["file"]
        ep = read_episode(path, min_steps=min_steps)
        if spec is None:  # an old manifest without a spec: the first episode's machine
            spec, spec_of = ep.spec, f"the first episode's ({e['file']})"
        if not rates:  # an old manifest without spec or rate_hz: the first episode's rate
            rates = [("the first episode's rate", ep.spec.rate_hz)]
        _check_entry(path, i, e, ep, rates)
        _check_machine(path, i, ep, spec, spec_of)
        _check_unique_name(path, i, e, ep, by_name, manifest["episodes"])
        ds_eps[e["split"]].append(ep)
    if spec is None:
        raise DataError(
            root / MANIFEST, "dataset has no episodes and no spec", fix="regenerate the dataset"
        )
    if len(rates) > 1 and not _same_rate(rates[0][1], rates[1][1]):  # no episode was read
        (k1, r1), (k2, r2) = rates[0], rates[1]
        raise DataError(
            root / MANIFEST,
            f"{k1} {r1:g} Hz disagrees with {k2} {r2:g} Hz",
            fix="fix or regenerate the manifest",
        )
    return Dataset(spec=spec, episodes=ds_eps, root=root, manifest=manifest)


def _declared_rates(
    mpath: Path, manifest: dict[str, Any], spec: MachineSpec | None
) -> list[tuple[str, float]]:
    """The sample rates the manifest declares: ``[(key, Hz)]`` for ``rate_hz`` and
    ``spec.rate_hz`` (either may be absent in an old manifest)."""
    out: list[tuple[str, float]] = []
    if "rate_hz" in manifest:
        rate = manifest["rate_hz"]
        if isinstance(rate, bool) or not isinstance(rate, int | float) or not rate > 0:
            raise DataError(
                mpath,
                f"rate_hz {rate!r} is not a positive number",
                fix="fix or regenerate the manifest",
            )
        out.append(("rate_hz", float(rate)))
    if spec is not None:
        out.append(("spec.rate_hz", float(spec.rate_hz)))
    return out


def _rate_label(key: str) -> str:
    return key if key.startswith("the ") else f"the manifest's {key}"


def _same_rate(a: float, b: float) -> bool:
    return abs(a - b) <= 1e-9 * max(abs(a), abs(b))


def _check_entry(
    path: Path, i: int, entry: dict[str, Any], ep: Episode, rates: list[tuple[str, float]]
) -> None:
    """The episode read from ``path`` is what manifest entry ``i`` says: the dataset's rate
    (the episode's own rate is checked against its time column by :func:`read_episode`) and
    ``n_step`` rows."""
    for key, rate in rates:
        if not _same_rate(ep.spec.rate_hz, rate):
            raise DataError(
                path,
                f"manifest entry {i}: the episode is sampled at {ep.spec.rate_hz:g} Hz (its "
                f"metadata and time column) but {_rate_label(key)} is {rate:g} Hz",
                fix="a dataset holds one rate: fix the manifest's rate, or regenerate the dataset",
            )
    n_step = entry.get("n_step")
    if n_step is not None and n_step != ep.n_step:
        raise DataError(
            path,
            f"manifest entry {i}: n_step is {n_step} but the episode has {ep.n_step} rows",
            fix="the file or the manifest was changed after writing: regenerate the dataset",
        )


def _check_machine(path: Path, i: int, ep: Episode, spec: MachineSpec, spec_of: str) -> None:
    """The episode read from ``path`` (manifest entry ``i``) is of the dataset's machine
    ``spec`` (``spec_of`` says whose it is, for the message): a dataset is one machine, and
    the model scales every episode's commands by the dataset's ranges and reads its inputs."""
    diff = spec.mismatch(ep.spec)
    if diff is None:
        return
    raise DataError(
        path,
        f"manifest entry {i}: the episode is of another machine than {spec_of} spec "
        f"({diff}, dataset vs episode)",
        fix="a dataset holds one machine: give the episode and the manifest one spec (re-import "
        "with one mapping), or put the episode in a dataset of its own",
    )


def _check_unique_name(
    path: Path,
    i: int,
    entry: dict[str, Any],
    ep: Episode,
    by_name: dict[str, tuple[int, Episode]],
    entries: list[dict[str, Any]],
) -> None:
    """No two files of one dataset hold episodes of one stored name (the dataset writer keeps
    names unique; reports name episodes by it): a copy under another file name (the same
    samples) is named as such, any other pair as a name clash."""
    prev = by_name.setdefault(ep.name, (i, ep))
    if prev[0] == i:
        return
    j, other = prev
    first = entries[j]
    if not (
        other.n_step == ep.n_step
        and np.array_equal(other.time, ep.time)
        and np.array_equal(other.u, ep.u)
        and np.array_equal(other.theta, ep.theta)
        and np.array_equal(other.omega, ep.omega)
    ):
        raise DataError(
            path,
            f"manifest entry {i} ({entry['split']}): the episode is named '{ep.name}' (its "
            f"metadata), as is entry {j} ({first['split']}, {first['file']}): reports would "
            "show two episodes under one name",
            fix="give each episode its own name (Episode.name) and write the dataset again "
            "with write_dataset",
        )
    where = (
        f"the {entry['split']} episode is also a {first['split']} episode"
        if first["split"] != entry["split"]
        else f"the {entry['split']} episode is listed twice"
    )
    raise DataError(
        path,
        f"manifest entry {i} ({entry['split']}) holds the same episode '{ep.name}' as entry "
        f"{j} ({first['split']}, {first['file']}): {where}",
        fix="remove the copy and its manifest entry, or regenerate the dataset",
    )
