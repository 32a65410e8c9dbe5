"""Assigning source files to train/val/test (:func:`assign_splits`): the corners the import
tests do not reach."""

from __future__ import annotations

import os

import pytest

from excavator_surrogate.errors import ConfigError
from excavator_surrogate.ingest.options import SplitOptions
from excavator_surrogate.ingest.split import assign_splits


def test_no_files_no_splits() -> None:
    assert assign_splits([], [], SplitOptions()) == ({}, [])


def test_a_split_with_a_share_takes_a_file_from_the_biggest() -> None:
    """[0.9, 0.05, 0.05] of three equal files fills train first; val and test each take
    one of its files rather than stay empty."""
    files = ["a.csv", "b.csv", "c.csv"]
    out, warnings = assign_splits(files, [100, 100, 100], SplitOptions(fractions=(0.9, 0.05, 0.05)))
    assert sorted(out.values()) == ["test", "train", "val"] and warnings == []
    # two files: train keeps one, so test stays empty and says why
    out, warnings = assign_splits(files[:2], [100, 100], SplitOptions(fractions=(0.9, 0.05, 0.05)))
    assert sorted(out.values()) == ["train", "val"]
    assert warnings == [
        "split 'test' is empty: 2 file(s) are too few for fractions [0.9, 0.05, 0.05]"
    ]


def test_by_pattern_needs_patterns() -> None:
    with pytest.raises(ConfigError) as e:
        assign_splits(["a.csv"], [10], SplitOptions(by="glob"))
    msg = str(e.value)
    assert "split by glob needs file names or patterns for train/val/test" in msg
    assert "--val/--test/--train" in msg and "\n" not in msg


def test_a_listed_file_that_was_not_imported_is_a_warning() -> None:
    opts = SplitOptions(by="file", train=("logs/a.csv",), val=("b.csv",), test=("gone.csv",))
    out, warnings = assign_splits(["logs/a.csv", "logs/b.csv"], [10, 10], opts)
    assert out == {"logs/a.csv": "train", "logs/b.csv": "val"}
    assert warnings == [
        "split file lists 'gone.csv' (test) but no such source was imported",
        "split 'test' is empty",
    ]


def test_glob_patterns_match_the_path_however_it_is_spelled() -> None:
    """``./logs/r0.csv`` (and an absolute path) match the source ``logs/r0.csv``: the key had
    lost its ``./``, so the file the user named as test data went to train, silently (audit
    1, D8). A pattern that matches no imported file is a warning."""
    files = ["logs/r0.csv", "logs/r1.csv", "logs/r2.csv"]
    opts = SplitOptions(
        by="glob",
        test=("./logs/r0.csv", "logs/r9*.csv"),
        val=(os.path.abspath("logs/r1.csv"),),
    )
    out, warnings = assign_splits(files, [10, 10, 10], opts)
    assert out == {"logs/r0.csv": "test", "logs/r1.csv": "val", "logs/r2.csv": "train"}
    assert warnings == ["split pattern 'logs/r9*.csv' (test) matches no imported file"]
