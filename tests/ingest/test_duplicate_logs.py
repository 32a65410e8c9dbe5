"""One recording given twice (``run.csv`` and ``run.csv.gz``, a copy in another folder) is
refused: split per file, its twin could land in training and its other copy in val/test.
The same file given twice (also spelled otherwise, or through a link) is imported once."""

from __future__ import annotations

import gzip
import os
import shutil
from pathlib import Path

import numpy as np
import pytest

from excavator_surrogate.data import load_dataset
from excavator_surrogate.errors import DataError
from excavator_surrogate.ingest import import_logs, load_mapping
from tests.helpers import arm3_plant
from tests.helpers.ingest import assert_nothing_written


@pytest.fixture(scope="module")
def logs(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """one.csv, two.csv (two 10 s recordings) and arm3.toml."""
    root = tmp_path_factory.mktemp("twins")
    for i, name in enumerate(("one", "two")):
        cols = arm3_plant.simulate(duration_s=10.0, seed=20 + i)
        arm3_plant.write_csv(root / f"{name}.csv", cols)
    (root / "arm3.toml").write_text(arm3_plant.MAPPING_TOML)
    return root


def _gzip(src: Path, dst: Path) -> Path:
    dst.write_bytes(gzip.compress(src.read_bytes()))
    return dst


def _refused(cli, argv, first: Path, second: Path, out: Path) -> None:
    rc, _, err = cli(*argv)
    lines = err.strip().splitlines()
    assert rc == 2 and len(lines) == 1, err
    assert lines[0] == (
        f"exsur: error: {second}: holds the same samples as {first}: one recording imported "
        "twice can land in both training and test (remove one of the two files, or pass only "
        "one of them)"
    )
    assert "Traceback" not in err
    assert_nothing_written(out)


def test_csv_and_its_gzip_are_refused(cli, logs: Path, tmp_path: Path) -> None:
    d = tmp_path / "logs"
    d.mkdir()
    for name in ("one", "two"):
        shutil.copy(logs / f"{name}.csv", d)
    _gzip(d / "one.csv", d / "one.csv.gz")
    out = tmp_path / "ds"
    argv = ("import", d, "--mapping", logs / "arm3.toml", "--out", out, "--quiet")
    _refused(cli, argv, d / "one.csv", d / "one.csv.gz", out)
    # neither --on-error skip nor a dry run lets it pass
    _refused(cli, (*argv, "--on-error", "skip"), d / "one.csv", d / "one.csv.gz", out)
    rc, _, err = cli("import", d, "--mapping", logs / "arm3.toml", "--dry-run", "--quiet")
    assert rc == 2 and "one.csv.gz: holds the same samples as" in err


def test_a_copy_in_another_folder_is_refused(cli, logs: Path, tmp_path: Path) -> None:
    a, b = tmp_path / "a", tmp_path / "b"
    a.mkdir(), b.mkdir()
    shutil.copy(logs / "one.csv", a / "run.csv")
    shutil.copy(logs / "two.csv", a / "other.csv")
    _gzip(logs / "one.csv", b / "renamed.csv.gz")
    out = tmp_path / "ds"
    argv = ("import", a, b, "--mapping", logs / "arm3.toml", "--out", out, "--quiet")
    _refused(cli, argv, a / "run.csv", b / "renamed.csv.gz", out)


def test_python_api_refuses_twins(logs: Path, tmp_path: Path) -> None:
    twin = shutil.copy(logs / "two.csv", tmp_path / "two_again.csv")
    with pytest.raises(DataError, match=r"two_again.csv: holds the same samples as .*two.csv"):
        import_logs(
            [logs / "two.csv", twin], load_mapping(logs / "arm3.toml"), out=None, quiet=True
        )


def test_the_same_file_twice_is_imported_once(cli, logs: Path, tmp_path: Path) -> None:
    """The same path, another spelling of it and a symbolic link to it: one log."""
    link = tmp_path / "link.csv"
    os.symlink(logs / "one.csv", link)
    rel = Path(os.path.relpath(logs / "one.csv"))
    out = tmp_path / "ds"
    rc, _, err = cli(
        "import",
        logs / "one.csv",
        logs / "one.csv",
        logs / "." / "one.csv",
        rel,
        link,
        logs / "two.csv",
        "--mapping",
        logs / "arm3.toml",
        "--out",
        out,
        "--quiet",
    )
    assert rc == 0, err
    ds = load_dataset(out)
    assert sorted(e.name for e in ds.train + ds.val + ds.test) == ["one", "two"]


def test_different_recordings_of_equal_length_pass(cli, logs: Path, tmp_path: Path) -> None:
    """A single changed sample makes another recording (no false twin)."""
    cols = arm3_plant.simulate(duration_s=10.0, seed=20)
    cols["boom_deg"] = np.array(cols["boom_deg"], dtype=np.float64)
    cols["boom_deg"][500] += 0.01
    arm3_plant.write_csv(tmp_path / "one_edited.csv", cols)
    rc, _, err = cli(
        "import",
        logs / "one.csv",
        tmp_path / "one_edited.csv",
        "--mapping",
        logs / "arm3.toml",
        "--dry-run",
        "--quiet",
    )
    assert rc == 0, err
