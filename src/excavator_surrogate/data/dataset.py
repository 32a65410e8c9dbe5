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
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..errors import ConfigError, DataError
from ..io_utils import atomic_dir, write_json, write_text
from ..spec import MachineSpec
from .episode import SCHEMA_VERSION, Episode, read_episode, write_episode

SPLITS = ("train", "val", "test")
MANIFEST = "manifest.json"


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
        items: ``(episode, split)`` pairs; all episodes must share one spec.
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
            if ep.spec.names != spec.names or ep.spec.rate_hz != spec.rate_hz:
                raise DataError(
                    out,
                    f"episode {ep.name} has a different joint spec or rate",
                    fix="write one dataset per machine and rate",
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
    return manifest


def load_dataset(
    root: str | Path,
    *,
    splits: Sequence[str] = SPLITS,
    min_steps: int = 1,
) -> Dataset:
    """Load and validate every episode of the requested splits.

    Raises:
        DataError: for the first file that breaks the contract.
    """
    root = Path(root)
    manifest = read_manifest(root)
    try:
        spec = MachineSpec.from_dict(manifest["spec"]) if "spec" in manifest else None
    except ConfigError as e:
        raise DataError(
            root / MANIFEST, f"'spec' is malformed ({e})", fix="regenerate the dataset"
        ) from e
    ds_eps: dict[str, list[Episode]] = {s: [] for s in SPLITS}
    for e in manifest["episodes"]:
        if e["split"] not in splits:
            continue
        ep = read_episode(root / e["file"], min_steps=min_steps, spec=spec)
        if spec is None:
            spec = ep.spec
        ds_eps[e["split"]].append(ep)
    if spec is None:
        raise DataError(
            root / MANIFEST, "dataset has no episodes and no spec", fix="regenerate the dataset"
        )
    return Dataset(spec=spec, episodes=ds_eps, root=root, manifest=manifest)
