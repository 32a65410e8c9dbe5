"""The output-folder rule (outdir.py) and the atomic writers that apply it (io_utils.py)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from excavator_surrogate.errors import ConfigError
from excavator_surrogate.io_utils import atomic_dir, mark_output, sweep_stale
from excavator_surrogate.outdir import (
    MARKER,
    check_out_dir,
    check_out_file,
    foreign_entry,
    is_exsur_file,
    is_exsur_output,
    read_marker,
    replace_allowed,
)


def _dataset(root: Path) -> Path:
    mark_output(root, "dataset")
    (root / "episodes").mkdir(parents=True)
    (root / "episodes" / "a.parquet").write_bytes(b"x")
    (root / "manifest.json").write_text("{}")
    (root / "config.toml").write_text("")
    return root


def _run(root: Path) -> Path:
    """A folder laid out like 'exsur run' output: report + nested dataset and model."""
    mark_output(root, "run")
    for name in ("report.md", "metrics.json", "table.md", "cbe.png", "config.toml"):
        (root / name).write_text("")
    _dataset(root / "data")
    (root / "model" / "tb").mkdir(parents=True)
    (root / "model" / "tb" / "events.out.tfevents.1.host").write_text("")
    (root / "model" / "best.pt").write_text("")
    return root


def test_recognises_exsur_outputs(tmp_path: Path) -> None:
    assert is_exsur_output(_dataset(tmp_path / "ds"))
    assert is_exsur_output(_run(tmp_path / "run"))
    (tmp_path / "empty").mkdir()
    assert is_exsur_output(tmp_path / "empty")
    assert not is_exsur_output(tmp_path / "missing")


@pytest.mark.parametrize(
    ("extra", "named"),
    [
        ("precious.txt", "precious.txt"),
        ("episodes/notes.txt", "episodes/notes.txt"),
        ("model/mine.csv", "model/mine.csv"),
        ("data/logs/run.csv", "data/logs"),
    ],
)
def test_a_foreign_file_anywhere_is_named(tmp_path: Path, extra: str, named: str) -> None:
    root = _run(tmp_path / "run")
    (root / extra).parent.mkdir(parents=True, exist_ok=True)
    (root / extra).write_text("mine")
    assert foreign_entry(root) is not None and foreign_entry(root).startswith(named)
    assert not is_exsur_output(root)


def test_exsur_names_without_a_marker_are_not_enough(tmp_path: Path) -> None:
    """Another project's best.pt / config.toml / manifest.json (a web app's) is not exsur's:
    only the marker exsur writes itself says so, by content."""
    for names in (["table.md"], ["best.pt", "last.pt", "config.toml"], ["manifest.json"]):
        d = tmp_path / "_".join(names)
        d.mkdir()
        for n in names:
            (d / n).write_text("theirs")
        assert foreign_entry(d) == MARKER and not is_exsur_output(d)
        with pytest.raises(
            ConfigError,
            match=r"which exsur did not write \(no exsur marker \.exsur\.json.*--overwrite",
        ):
            check_out_dir(d)
        with pytest.raises(ConfigError, match="no exsur marker"), atomic_dir(d) as tmp:
            (tmp / "manifest.json").write_text("{}")
        assert sorted(p.name for p in d.iterdir()) == sorted(names)  # untouched
        (d / MARKER).write_text('{"kind": "dataset"}')  # a look-alike: wrong content
        assert not is_exsur_output(d)


def test_an_unmarked_folder_of_temporary_files_only_names_one(tmp_path: Path) -> None:
    """An unmarked folder whose only entry is a temporary file of exsur's name (another
    writer's, mid-write) was refused as holding ``''``; the refusal names that file."""
    d = tmp_path / "out"
    d.mkdir()
    (d / ".exsur.json.123-abcd1234.tmp").write_text("{}")
    with pytest.raises(ConfigError, match=r"out: output folder holds '\.exsur\.json\.123-abcd"):
        check_out_dir(d, flag="output folder")
    (d / "notes.txt").write_text("mine")  # a file of the user's comes first
    with pytest.raises(ConfigError, match=r"holds 'notes\.txt'"):
        check_out_dir(d, flag="output folder")


def test_the_marker_is_written_first_and_kept(tmp_path: Path) -> None:
    with atomic_dir(tmp_path / "ds", kind="dataset") as tmp:
        assert read_marker(tmp)["kind"] == "dataset"  # before the first file
    m = read_marker(tmp_path / "ds")
    assert m["format"] == "exsur-output" and m["version"] and m["created"]
    assert is_exsur_output(tmp_path / "ds")
    mark_output(tmp_path / "ds", "model")  # a later writer keeps the folder's marker
    assert read_marker(tmp_path / "ds") == m
    with pytest.raises(ValueError, match="not one of"):
        mark_output(tmp_path / "x", "notes")


def test_exsur_folders_with_any_of_its_files_are_its_own(tmp_path: Path) -> None:
    """A control report (tracking.png), an ensemble killed after its first member, a sweep:
    marked, so a rerun into them is allowed."""
    ctl = mark_output(tmp_path / "ctl", "control")
    for n in ("tracking.png", "learning_curve.png", "trajectories.npz", "report.md"):
        (ctl / n).write_text("")
    ens = mark_output(tmp_path / "ens", "model")
    (ens / "config.toml").write_text("")
    mark_output(ens / "member_0", "model")
    (ens / "member_0" / "log.csv").write_text("")
    for d in (ctl, ens):
        assert is_exsur_output(d), foreign_entry(d)
        assert check_out_dir(d) == d


def test_symlink_is_foreign(tmp_path: Path) -> None:
    root = _dataset(tmp_path / "ds")
    (root / "link.pt").symlink_to(tmp_path)
    assert foreign_entry(root) == "link.pt"


def test_atomic_dir_refuses_a_foreign_folder_and_keeps_it(tmp_path: Path) -> None:
    d = tmp_path / "d"
    d.mkdir()
    (d / "precious.txt").write_text("x")
    with pytest.raises(ConfigError, match="precious.txt"), atomic_dir(d) as tmp:
        (tmp / "manifest.json").write_text("{}")
    assert (d / "precious.txt").read_text() == "x"
    assert [p.name for p in tmp_path.iterdir()] == ["d"]


def test_atomic_dir_replaces_its_own_output_or_with_consent(tmp_path: Path) -> None:
    ds = _dataset(tmp_path / "ds")
    with atomic_dir(ds) as tmp:
        (tmp / "manifest.json").write_text('{"new": 1}')
    assert sorted(p.name for p in ds.iterdir()) == [MARKER, "manifest.json"]
    d = tmp_path / "d"
    d.mkdir()
    (d / "precious.txt").write_text("x")
    with replace_allowed(d), atomic_dir(d) as tmp:
        (tmp / "manifest.json").write_text("{}")
    assert sorted(p.name for p in d.iterdir()) == [MARKER, "manifest.json"]


def test_atomic_dir_refuses_the_current_folder(tmp_path: Path, monkeypatch) -> None:
    sub = tmp_path / "sub"
    sub.mkdir()
    monkeypatch.chdir(sub)
    for p in (".", "..", str(tmp_path)):
        with pytest.raises(ConfigError, match="current folder"), atomic_dir(p):
            pass


def _dead_pid() -> int:
    p = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True)
    return int(p.stdout)


def test_stale_temp_folders_of_killed_runs_are_removed(tmp_path: Path) -> None:
    out = tmp_path / "ds"
    dead = mark_output(tmp_path / f".ds.{_dead_pid()}-abc123de.tmp", "dataset")
    legacy = tmp_path / ".ds.k2j4h5g6.tmp"  # no pid (exsur < 0.2, or the user's): kept
    alive = tmp_path / f".ds.{os.getpid()}-xyz45678.tmp"
    old = mark_output(tmp_path / f".ds.old-{_dead_pid()}", "dataset")
    nested = tmp_path / f".{dead.name}.{_dead_pid()}-q1234567.tmp"  # write_dataset in import's
    other = tmp_path / ".other.123-abcdefgh.tmp"
    for p in (legacy, alive, nested, other):
        p.mkdir()
    (dead / "episodes").mkdir()
    removed = sweep_stale(out)
    assert sorted(removed) == sorted([dead, old, nested])
    assert alive.exists() and other.exists() and legacy.exists()
    with atomic_dir(out) as tmp:  # a new run sweeps too, and leaves only its result
        (tmp / "manifest.json").write_text("{}")
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
        [".other.123-abcdefgh.tmp", alive.name, legacy.name, "ds"]
    )


def test_check_out_dir_rules(tmp_path: Path, monkeypatch) -> None:
    f = tmp_path / "file.txt"
    f.write_text("x")
    with pytest.raises(ConfigError, match="exists and is a file; give a folder"):
        check_out_dir(f)
    with pytest.raises(ConfigError, match=r"file.txt is a file, not a folder"):
        check_out_dir(f / "sub")
    ds = _dataset(tmp_path / "ds")
    (ds / "map.toml").write_text("")
    with pytest.raises(ConfigError, match="map.toml: this input lies inside --out"):
        check_out_dir(ds, inputs=[ds / "map.toml"], overwrite=True)
    with pytest.raises(ConfigError, match="which exsur did not write.*--overwrite"):
        check_out_dir(ds)
    assert check_out_dir(ds, overwrite=True) == ds
    assert check_out_dir(tmp_path / "new" / "deeper") == tmp_path / "new" / "deeper"
    real_access = os.access
    monkeypatch.setattr(os, "access", lambda p, m: Path(p) != tmp_path and real_access(p, m))
    with pytest.raises(ConfigError, match="is not writable"):
        check_out_dir(tmp_path / "new")


def test_check_out_file_rules(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="is a folder; give a file name such as m.onnx"):
        check_out_file(tmp_path, example="m.onnx")
    a = tmp_path / "a.pt"
    a.write_text("")
    with pytest.raises(ConfigError, match="one of the inputs"):
        check_out_file(a, inputs=[a], example="e.pt")
    assert check_out_file(tmp_path / "b.pt", inputs=[a], example="e.pt") == tmp_path / "b.pt"


def _identity_onnx(path: Path, *, exsur: bool) -> Path:
    """A one-node ONNX file at ``path``; with ``exsur``, the metadata exsur's exports carry."""
    from onnx import TensorProto, helper, save

    graph = helper.make_graph(
        [helper.make_node("Identity", ["x"], ["y"])],
        "g",
        [helper.make_tensor_value_info("x", TensorProto.FLOAT, [1])],
        [helper.make_tensor_value_info("y", TensorProto.FLOAT, [1])],
    )
    model = helper.make_model(graph)
    if exsur:
        helper.set_model_props(model, {"exsur_spec": "{}"})
    save(model, path)
    return path


def test_file_outputs_by_content(tmp_path: Path) -> None:
    pytest.importorskip("onnx")
    theirs = _identity_onnx(tmp_path / "theirs.onnx", exsur=False)
    ours = _identity_onnx(tmp_path / "ours.onnx", exsur=True)
    assert is_exsur_file(ours) and not is_exsur_file(theirs)
    with pytest.raises(ConfigError, match="exists and exsur did not write it.*--overwrite"):
        check_out_file(theirs, example="m.onnx")
    assert check_out_file(theirs, example="m.onnx", overwrite=True) == theirs
    assert check_out_file(ours, example="m.onnx") == ours
    with pytest.raises(ConfigError, match=r"must end in \.onnx"):
        check_out_file(tmp_path / "notes.txt", example="m.onnx")
    torch = pytest.importorskip("torch")
    torch.save({"format": "exsur-surrogate"}, tmp_path / "a.pt")
    torch.save({"format": "other"}, tmp_path / "b.pt")
    (tmp_path / "c.pt").write_bytes(b"not a checkpoint")
    assert [is_exsur_file(tmp_path / n) for n in ("a.pt", "b.pt", "c.pt")] == [True, False, False]


def test_file_outputs_by_content_whatever_the_suffix_case(tmp_path: Path) -> None:
    """``--out M1.ONNX`` was written (the suffix check ignores case) and then called "not
    written by exsur" (the content check compared the suffix case-sensitively)."""
    pytest.importorskip("onnx")
    ours = _identity_onnx(tmp_path / "M1.ONNX", exsur=True)
    assert is_exsur_file(ours)
    assert check_out_file(ours, example="m.onnx") == ours
    torch = pytest.importorskip("torch")
    torch.save({"format": "exsur-surrogate"}, tmp_path / "A.Pt")
    assert is_exsur_file(tmp_path / "A.Pt")


def test_an_output_of_another_kind_is_refused(tmp_path: Path) -> None:
    """A mistyped --out naming another kind of exsur output (a trained model, a dataset) is
    neither replaced nor written into without --overwrite, by the CLI's check or by
    atomic_dir; a model and its evaluation may share a folder."""
    model = mark_output(tmp_path / "model", "model")
    (model / "best.pt").write_text("")
    ds = _dataset(tmp_path / "ds")
    for out, kind in ((model, "dataset"), (model, "compare"), (ds, "model"), (ds, "run")):
        with pytest.raises(ConfigError) as e:
            check_out_dir(out, kind=kind)
        found = read_marker(out)["kind"]
        assert str(e.value) == (
            f"{out}: --out is an exsur {found} output (.exsur.json), and this command writes "
            f"a {kind} output; give another --out, or pass --overwrite"
        )
        assert check_out_dir(out, kind=kind, overwrite=True) == out
    assert check_out_dir(model, kind="evaluation") == model
    assert check_out_dir(ds, kind="dataset") == ds
    with pytest.raises(ConfigError, match="exsur model output"), atomic_dir(model, kind="dataset"):
        pass
    assert sorted(p.name for p in model.iterdir()) == [MARKER, "best.pt"]
    with replace_allowed(model), atomic_dir(model, kind="dataset"):
        pass
    assert read_marker(model)["kind"] == "dataset"


def test_an_out_inside_an_input_dataset_is_refused(tmp_path: Path) -> None:
    """A command does not write into the exsur output it reads (train DS --out DS/model), not
    even with --overwrite; a new dataset inside a folder of logs stays fine."""
    ds = _dataset(tmp_path / "ds")
    for out in (ds / "model", ds / "episodes" / "ev"):
        with pytest.raises(ConfigError) as e:
            check_out_dir(out, inputs=[ds], overwrite=True)
        assert str(e.value) == (
            f"{out}: --out lies inside {ds}, an exsur output this command reads; "
            "give a --out outside it"
        )
    logs = tmp_path / "logs"
    logs.mkdir()
    (logs / "a.csv").write_text("t\n0\n")
    assert check_out_dir(logs / "ds", inputs=[logs / "a.csv", logs]) == logs / "ds"


def test_an_output_inside_another_is_not_part_of_it(tmp_path: Path) -> None:
    """A model trained into a dataset folder is not part of the dataset: replacing the
    dataset would delete it.  A run holds its data and models, a model its members."""
    ds = _dataset(tmp_path / "ds")
    mark_output(ds / "model", "model")
    (ds / "model" / "best.pt").write_text("")
    assert foreign_entry(ds) == "model"
    with pytest.raises(ConfigError, match=r"holds 'model', another exsur output \(a model\)"):
        check_out_dir(ds, kind="dataset")
    run = _run(tmp_path / "run")
    mark_output(run / "model" / "member_0", "model")
    mark_output(run / "eval_cleaned", "evaluation")
    assert foreign_entry(run) is None
    mark_output(run / "data" / "model", "model")
    assert foreign_entry(run) == "data/model"


def test_an_output_written_whole_records_what_exsur_wrote(tmp_path: Path) -> None:
    """Files a user adds to a dataset under names exsur writes (a colleague's model, notes in
    report.md, a field log among the episodes) are the user's: the marker lists what exsur
    wrote, so replacing the folder needs --overwrite."""
    with atomic_dir(tmp_path / "ds", kind="dataset") as tmp:
        (tmp / "episodes").mkdir()
        (tmp / "episodes" / "test_000.parquet").write_bytes(b"x")
        (tmp / "manifest.json").write_text("{}")
    ds = tmp_path / "ds"
    assert read_marker(ds)["files"] == ["episodes", "episodes/test_000.parquet", "manifest.json"]
    assert foreign_entry(ds) is None
    for added in ("colleague_model.pt", "report.md", "episodes/my_field_log.parquet"):
        (ds / added).write_text("mine")
        assert foreign_entry(ds) == added
        with pytest.raises(ConfigError, match=f"holds '{added}', which exsur did not write"):
            check_out_dir(ds, kind="dataset")
        with pytest.raises(ConfigError, match="which exsur did not write"):
            with atomic_dir(ds, kind="dataset") as tmp:
                pass
        assert (ds / added).read_text() == "mine"
        (ds / added).unlink()


def test_exsurs_later_writes_into_a_recorded_output_are_recorded(tmp_path: Path) -> None:
    """A PNG that ``exsur plot`` writes beside an episode of a run's dataset (in the
    dataset's own record), a figure written into the run: recorded, so the run is still
    exsur's.  A file copied in beside them is not, nor a new file in an output inside the run
    that keeps no record of its own (its model folder)."""
    from excavator_surrogate.io_utils import write_text

    with atomic_dir(tmp_path / "run", kind="run") as tmp:
        with atomic_dir(tmp / "data", kind="dataset") as d:
            (d / "episodes").mkdir()
            (d / "episodes" / "a.parquet").write_bytes(b"x")
        mark_output(tmp / "model", "model")
        (tmp / "model" / "best.pt").write_text("")
        (tmp / "table.md").write_text("")
    run = tmp_path / "run"
    write_text(run / "data" / "episodes" / "a.png", "figure")
    write_text(run / "figures" / "b.png", "figure")
    write_text(run / "model" / "best.pt", "re-trained")  # a name the run recorded
    assert "episodes/a.png" in read_marker(run / "data")["files"]
    assert {"figures", "figures/b.png"} <= set(read_marker(run)["files"])
    assert foreign_entry(run) is None
    for theirs in ("model/colleague.pt", "data/notes.txt", "figures/c.png"):
        (run / theirs).write_text("theirs")
        assert foreign_entry(run) == theirs
        (run / theirs).unlink()
    write_text(run / "model" / "last.pt", "new")  # the model folder keeps no record
    assert foreign_entry(run) == "model/last.pt"
    (run / "model" / "last.pt").unlink()
    with atomic_dir(run / "data2", kind="dataset") as d:  # another output built inside
        write_text(d / "manifest.json", "{}")
        assert "files" not in read_marker(d)  # recorded when complete, not file by file
    assert not any("data2" in n for n in read_marker(run)["files"])
    assert foreign_entry(run) == "data2"


def test_a_marker_without_a_record_keeps_the_name_rule(tmp_path: Path) -> None:
    """An output of exsur before the record (and a folder commands write into) is judged by
    the names exsur writes, as before."""
    ds = _dataset(tmp_path / "ds")
    assert "files" not in read_marker(ds)
    (ds / "report.md").write_text("")
    assert foreign_entry(ds) is None and check_out_dir(ds, kind="dataset") == ds


def test_the_api_check_follows_the_rule_unless_the_cli_checked_under_its_lock(
    tmp_path: Path,
) -> None:
    from excavator_surrogate.outdir import check_api_out_dir
    from excavator_surrogate.outlock import release_locks

    out = tmp_path / "mine"
    out.mkdir()
    (out / "notes.txt").write_text("my notes")
    with pytest.raises(ConfigError, match="'notes.txt', which exsur did not write"):
        check_api_out_dir(out, overwrite=False, kind="model")
    assert check_api_out_dir(out, overwrite=True, kind="model") == out
    with pytest.raises(ConfigError, match="out: a path is needed, got NoneType"):
        check_api_out_dir(None, overwrite=False, kind="model")  # type: ignore[arg-type]
    cli = tmp_path / "cli"
    try:
        check_out_dir(cli, lock=True, kind="model")  # the CLI, before it loads anything
        (cli / "x").mkdir(parents=True)  # nothing of exsur's writes it under the lock
        assert check_api_out_dir(cli, overwrite=False, kind="model") == cli  # not again
    finally:
        release_locks()
    with pytest.raises(ConfigError, match="'x', which exsur did not write"):
        check_api_out_dir(cli, overwrite=False, kind="model")  # the lock is gone: checked
