"""A manifest that disagrees with itself or with its episode files is refused where the
dataset is loaded (so train, evaluate and validate all refuse it): an entry pointing at
another entry's file (leakage), an entry listed twice, a copied episode, a rate the episodes
do not have, a newer schema_version, an n_step that is not the file's row count."""

from __future__ import annotations

import json
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from excavator_surrogate.cli import main
from excavator_surrogate.data import load_dataset, read_manifest, write_dataset
from excavator_surrogate.errors import DataError
from tests.data.test_contract import make_episode


def _dataset(tmp_path: Path) -> Path:
    """Entries 0 a (train, 50 rows), 1 b (train, 60), 2 v (val, 40), 3 t (test, 50) at 20 Hz;
    the make_episode data of a and t are the same samples under other names."""
    return write_dataset(
        tmp_path / "ds",
        [
            (make_episode(name="a"), "train"),
            (make_episode(name="b", n=60), "train"),
            (make_episode(name="v", n=40), "val"),
            (make_episode(name="t"), "test"),
        ],
    )


def _edit(ds: Path, edit: Callable[[dict[str, Any]], None]) -> Path:
    mpath = ds / "manifest.json"
    m = json.loads(mpath.read_text())
    edit(m)
    mpath.write_text(json.dumps(m))
    return mpath


def _set_rates(m: dict[str, Any], top: float | None, spec: float | None) -> None:
    if top is not None:
        m["rate_hz"] = top
    if spec is not None:
        m["spec"]["rate_hz"] = spec


def _entry(i: int, **changes: Any) -> Callable[[dict[str, Any]], None]:
    return lambda m: m["episodes"][i].update(changes)


# case -> (manifest edit, file named first ("manifest.json" or an episode), what the line says)
CASES: dict[str, tuple[Callable[[dict[str, Any]], None], str, list[str]]] = {
    "test entry points at a train file": (
        _entry(3, file="episodes/a.parquet"),
        "manifest.json",
        [
            "episode entries 0 (train) and 3 (test) both name the file episodes/a.parquet: "
            "the test episode is also a train episode",
            "an episode belongs to one split only",
        ],
    ),
    "val entry points at a train file, spelled otherwise": (
        _entry(2, file="episodes/../episodes/./b.parquet"),
        "manifest.json",
        [
            "episode entries 1 (train) and 2 (val) both name the same file (episodes/b.parquet, "
            "episodes/../episodes/./b.parquet): the val episode is also a train episode"
        ],
    ),
    "an entry listed twice": (
        lambda m: m["episodes"].append(dict(m["episodes"][1])),
        "manifest.json",
        [
            "episode entries 1 and 4 both name the file episodes/b.parquet: "
            "the train episode is listed twice",
            "remove the repeated entry",
        ],
    ),
    "rate_hz and spec.rate_hz 10 Hz, episodes 20 Hz": (
        lambda m: _set_rates(m, 10.0, 10.0),
        "episodes/a.parquet",
        [
            "manifest entry 0: the episode is sampled at 20 Hz (its metadata and time column) "
            "but the manifest's rate_hz is 10 Hz"
        ],
    ),
    "spec.rate_hz alone 10 Hz": (
        lambda m: _set_rates(m, None, 10.0),
        "episodes/a.parquet",
        [
            "manifest entry 0: the episode is sampled at 20 Hz",
            "the manifest's spec.rate_hz is 10 Hz",
        ],
    ),
    "rate_hz alone 10 Hz": (
        lambda m: _set_rates(m, 10.0, None),
        "episodes/a.parquet",
        ["sampled at 20 Hz", "the manifest's rate_hz is 10 Hz"],
    ),
    "rate_hz not a number": (
        lambda m: _set_rates(m, "fast", None),  # type: ignore[arg-type]
        "manifest.json",
        ["rate_hz 'fast' is not a positive number"],
    ),
    "schema_version from the future": (
        lambda m: m.update(schema_version=7),
        "manifest.json",
        [
            "schema_version 7 is not supported (this exsur reads 1): written by a newer exsur",
            "upgrade exsur: pip install -U excavator-surrogate",
        ],
    ),
    "schema_version unknown": (
        lambda m: m.update(schema_version="1.0"),
        "manifest.json",
        ["schema_version '1.0' is not supported", "re-create the dataset"],
    ),
    "n_step is not the row count": (
        _entry(1, n_step=55),
        "episodes/b.parquet",
        ["manifest entry 1: n_step is 55 but the episode has 60 rows", "regenerate the dataset"],
    ),
    "n_step is not a count": (
        _entry(2, n_step="40"),
        "manifest.json",
        ["episode entry 2 (episodes/v.parquet): n_step '40' is not a sample count"],
    ),
}


@pytest.mark.parametrize("case", list(CASES))
def test_inconsistent_manifest_is_refused(
    tmp_path: Path, case: str, capsys: pytest.CaptureFixture[str]
) -> None:
    edit, named, says = CASES[case]
    ds = _dataset(tmp_path)
    _edit(ds, edit)
    with pytest.raises(DataError) as e:
        load_dataset(ds)
    msg = str(e.value)
    assert "\n" not in msg and msg.startswith(f"{ds / named}: "), msg
    for part in says:
        assert part in msg, msg
    assert main(["validate", str(ds)]) == 2
    cap = capsys.readouterr()
    assert cap.out == ""
    lines = cap.err.strip().splitlines()
    assert len(lines) == 1 and lines[0] == f"exsur: error: {msg}", lines


def test_leakage_is_refused_when_only_train_and_val_are_read(tmp_path: Path) -> None:
    """Training reads train and val only: a test entry on a training file is still refused,
    and so is a future schema_version when only the manifest is read."""
    ds = _dataset(tmp_path)
    _edit(ds, _entry(3, file="episodes/a.parquet"))
    with pytest.raises(DataError, match=r"the test episode is also a train episode"):
        load_dataset(ds, splits=("train", "val"))
    with pytest.raises(DataError, match=r"the test episode is also a train episode"):
        read_manifest(ds)
    _edit(ds, lambda m: m.update(schema_version=2))
    with pytest.raises(DataError, match=r"written by a newer exsur \(upgrade exsur"):
        load_dataset(ds, splits=())


def test_rates_that_disagree_with_no_episode_read(tmp_path: Path) -> None:
    """The manifest alone (``splits=()``, as ``exsur train`` reads it first): its two rates
    must agree."""
    ds = _dataset(tmp_path)
    mpath = _edit(ds, lambda m: _set_rates(m, 10.0, None))
    with pytest.raises(DataError) as e:
        load_dataset(ds, splits=())
    assert str(e.value).startswith(
        f"{mpath}: rate_hz 10 Hz disagrees with spec.rate_hz 20 Hz (fix or regenerate"
    )


def test_a_copied_episode_file_is_refused(tmp_path: Path) -> None:
    """The train episode copied over the test one (manifest untouched): the test file holds
    train episode 'a', sample for sample."""
    ds = _dataset(tmp_path)
    shutil.copy(ds / "episodes" / "a.parquet", ds / "episodes" / "t.parquet")
    with pytest.raises(DataError) as e:
        load_dataset(ds)
    assert str(e.value).startswith(
        f"{ds / 'episodes' / 't.parquet'}: manifest entry 3 (test) holds the same episode 'a' "
        "as entry 0 (train, episodes/a.parquet): the test episode is also a train episode"
    )


def test_a_consistent_dataset_loads(tmp_path: Path) -> None:
    """What write_dataset writes passes, episodes of equal samples under their own names
    (a and t) too; so does an old manifest without schema_version, rate_hz or n_step."""
    ds = _dataset(tmp_path)
    loaded = load_dataset(ds)
    assert [len(loaded.split(s)) for s in ("train", "val", "test")] == [2, 1, 1]
    assert loaded.n_samples() == 200

    def old(m: dict[str, Any]) -> None:
        for k in ("schema_version", "rate_hz"):
            m.pop(k)
        for e in m["episodes"]:
            e.pop("n_step")

    _edit(ds, old)
    assert load_dataset(ds).n_samples() == 200


def test_train_refuses_a_leaky_dataset(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    ds = _dataset(tmp_path)
    _edit(ds, _entry(3, file="episodes/a.parquet"))
    out = tmp_path / "model"
    assert main(["train", str(ds), "--out", str(out), "--epochs", "1", "-q"]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and "the test episode is also a train episode" in lines[0], lines
    assert not out.exists()
