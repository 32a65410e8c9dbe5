"""What a folder, a file or a glob source imports (``ingest/readers.py``, ``expand_sources``),
and what it says about the logs a folder leaves out."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from excavator_surrogate.errors import DataError
from excavator_surrogate.ingest import expand_sources
from excavator_surrogate.ingest.readers import nested_logs
from tests.helpers.ingest import assert_nothing_written


@pytest.fixture
def tree(tmp_path: Path, arm3_dir: Path) -> Path:
    """logs/run01.csv, logs/day2/run02.csv, logs/day2/deep/run04.csv.gz, non-logs and hidden
    entries beside them."""
    logs = tmp_path / "logs"
    (logs / "day2" / "deep").mkdir(parents=True)
    (logs / ".cache").mkdir()
    src = arm3_dir / "logs"
    shutil.copy(src / "run01.csv", logs / "run01.csv")
    shutil.copy(src / "run02.csv", logs / "day2" / "run02.csv")
    shutil.copy(src / "run04.csv.gz", logs / "day2" / "deep" / "run04.csv.gz")
    shutil.copy(src / "run03.csv", logs / ".cache" / "run03.csv")
    (logs / "README.txt").write_text("notes")
    (logs / ".~lock.run01.csv#").write_text("lock")
    return logs


def test_a_folder_takes_its_own_logs_and_a_glob_goes_deeper(tree: Path) -> None:
    assert expand_sources([tree]) == [tree / "run01.csv"]
    assert expand_sources([f"{tree}/**/*.csv*"]) == [
        tree / "day2" / "deep" / "run04.csv.gz",
        tree / "day2" / "run02.csv",
        tree / "run01.csv",
    ]
    assert nested_logs(tree) == [
        tree / "day2" / "run02.csv",
        tree / "day2" / "deep" / "run04.csv.gz",
    ]


def test_the_logs_a_folder_leaves_out_are_a_warning(cli, tree: Path, arm3_dir: Path) -> None:
    out = tree.parent / "ds"
    rc, text, err = cli("import", tree, "--mapping", arm3_dir / "arm3.toml", "--out", out)
    assert rc == 0, err
    warning = (
        f"{tree}: its sub-folders hold 2 log(s) that were not imported (a folder is not searched "
        f'recursively); give the sub-folders too, or a quoted glob such as "{tree}/**/*.csv"'
    )
    assert warning in text
    assert warning in json.loads((out / "import_report.json").read_text())["warnings"]


def test_a_folder_with_logs_only_below_names_the_glob(cli, tree: Path, arm3_dir: Path) -> None:
    (tree / "run01.csv").unlink()
    out = tree.parent / "ds"
    rc, _, err = cli("import", tree, "--mapping", arm3_dir / "arm3.toml", "--out", out)
    assert rc == 2 and err.count("\n") == 1, err
    assert f"{tree}: folder holds no log files (its sub-folders hold 2 log(s)" in err
    assert f'a quoted glob such as "{tree}/**/*.csv")' in err
    assert_nothing_written(out)
    empty = tree.parent / "empty"
    empty.mkdir()
    with pytest.raises(DataError, match=r"folder holds no log files \(put "):
        expand_sources([empty])


def _bag(folder: Path) -> Path:
    """A rosbag2 folder as the detection sees it (metadata.yaml and a storage file); its
    contents are never read here."""
    folder.mkdir(parents=True)
    (folder / "metadata.yaml").write_text("rosbag2_bagfile_information: {}\n")
    (folder / "bag_0.db3").write_bytes(b"")
    return folder


def test_a_bag_folder_is_one_log_wherever_it_is_named(tree: Path) -> None:
    """Its storage file stands for the folder; below a folder source it is one nested log,
    not searched further."""
    top = _bag(tree / "bag")
    deep = _bag(tree / "day3" / "drive")
    (deep / "nested.csv").write_text("t\n")  # inside the bag: not a separate log
    assert expand_sources([top / "bag_0.db3", top]) == [top]
    assert nested_logs(tree) == [
        tree / "day2" / "run02.csv",
        tree / "day2" / "deep" / "run04.csv.gz",
        deep,
    ]
    assert nested_logs(tree, limit=1) == [tree / "day2" / "run02.csv"]


def test_a_glob_that_matches_no_log(tree: Path) -> None:
    with pytest.raises(DataError) as e:
        expand_sources([f"{tree}/**/*.parquet"])
    msg = str(e.value)
    assert msg.startswith(f"{tree}/**/*.parquet: glob pattern matches no log files"), msg
    assert "(check the pattern; supported: dSPACE" in msg and "\n" not in msg


def test_read_log_refuses_a_file_no_reader_takes(tree: Path, arm3_dir: Path) -> None:
    """The API's read_log (the CLI refuses such a file in expand_sources first)."""
    from excavator_surrogate.ingest import load_mapping
    from excavator_surrogate.ingest.readers import read_log

    with pytest.raises(DataError, match=r"README\.txt: unsupported log type \(give "):
        read_log(tree / "README.txt", load_mapping(arm3_dir / "arm3.toml"))
