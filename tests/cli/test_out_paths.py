"""Issue 25: output paths. One writer per folder, unusable --out paths, full disks and file
outputs that are not exsur's are one-line errors; nothing half-written is left."""

from __future__ import annotations

import errno
import shutil
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
from tests.helpers.cli import fails

from excavator_surrogate.cli import main
from excavator_surrogate.outdir import MARKER, is_exsur_output, read_marker

HOLD = (  # what a running exsur writer holds: an flock on .NAME.lock next to its --out
    "import fcntl, os, sys; from pathlib import Path; p = Path(sys.argv[1]); "
    "f = open(p.parent / f'.{p.name}.lock', 'w'); fcntl.flock(f, fcntl.LOCK_EX); "
    "f.write(str(os.getpid())); f.flush(); print('locked', flush=True); sys.stdin.read()"
)


def _leftovers(out: Path) -> list[str]:
    """Temporary siblings of ``out`` and temporary files anywhere inside it."""
    near = [p.name for p in out.parent.iterdir() if p.name.startswith(f".{out.name}.")]
    inside = [p.name for p in out.rglob(".*") if p.name != MARKER] if out.is_dir() else []
    return near + inside


@pytest.fixture
def held(tmp_path: Path) -> Iterator[Path]:
    """An output folder whose writer lock another process holds (as a running train would)."""
    out = tmp_path / "M"
    proc = subprocess.Popen(
        [sys.executable, "-c", HOLD, str(out)],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert proc.stdout is not None and proc.stdout.readline().strip() == "locked"
        yield out
    finally:
        proc.kill()
        proc.wait()


def test_a_second_writer_is_refused(
    held: Path, data_dir: Path, model3: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    tiny = data_dir / "tiny.toml"
    for argv in (
        ["train", data_dir / "ds3", "--preset", tiny, "--epochs", "1"],
        ["evaluate", model3 / "best.pt", data_dir / "ds3"],
        ["clean", data_dir / "ds3"],
        ["simulate", "--preset", "tiny"],
    ):
        err = fails(capsys, *argv, "--out", held)
        assert f"{held}: another exsur process (pid " in err and "is writing this --out" in err
    assert not held.exists()


def test_the_lock_dies_with_its_process(tmp_path: Path, data_dir: Path) -> None:
    """A killed writer leaves no stale lock: the next command runs."""
    out = tmp_path / "M"
    proc = subprocess.Popen(
        [sys.executable, "-c", HOLD, str(out)], stdin=subprocess.PIPE, stdout=subprocess.PIPE
    )
    assert proc.stdout is not None and proc.stdout.readline().strip() == b"locked"
    proc.kill()
    proc.wait()
    assert main(["clean", str(data_dir / "ds3"), "--out", str(out)]) == 0
    assert read_marker(out)["kind"] == "dataset"
    assert _leftovers(out) == []


@pytest.mark.parametrize(
    "argv",
    [
        ["simulate", "--preset", "tiny", "--out", "/proc/x"],
        ["train", "DS", "--out", "/proc/x"],
        ["evaluate", "CKPT", "DS", "--out", "/proc/x"],
        ["import", "DS", "--mapping", "MAP", "--out", "/proc/x"],
        ["clean", "DS", "--out", "/proc/x"],
        ["export", "CKPT", "--out", "/proc/x.onnx"],
        ["merge", "CKPT", "CKPT2", "--out", "/proc/x.pt"],
    ],
    ids=lambda a: a[0],
)
def test_an_unusable_out_is_one_line(
    argv: list[str], tmp_path: Path, data_dir: Path, model3: Path, capsys
) -> None:
    if not Path("/proc/self").exists():
        pytest.skip("needs /proc")
    _other_model(model3 / "best.pt", tmp_path / "b.pt")
    subst = {
        "DS": data_dir / "ds3",
        "CKPT": model3 / "best.pt",
        "CKPT2": tmp_path / "b.pt",
        "MAP": tmp_path / "map.toml",
    }
    err = fails(capsys, *[subst.get(a, a) for a in argv])
    assert "/proc" in err


def test_disk_full_while_saving_a_checkpoint(
    tmp_path: Path, data_dir: Path, monkeypatch, capsys
) -> None:
    """torch.save reports a full disk as 'unexpected pos': one line, no partial checkpoint."""
    import torch

    def full(obj, f, *a, **k):
        raise RuntimeError(
            "[enforce fail at inline_container.cc:603] . unexpected pos 1536 vs 1468"
        )

    monkeypatch.setattr(torch, "save", full)
    out = tmp_path / "M"
    tiny = data_dir / "tiny.toml"
    err = fails(capsys, "train", data_dir / "ds3", "--out", out, "--preset", tiny, "--epochs", "1")
    assert ".pt: cannot write the checkpoint" in err and "free disk space" in err
    assert not list(out.rglob("*.pt")) and _leftovers(out) == []


def test_disk_full_during_evaluate_writes_nothing(
    tmp_path: Path, data_dir: Path, model3: Path, monkeypatch, capsys
) -> None:
    """All or nothing: metrics.json and table.md are not left without the figure."""
    import excavator_surrogate.plotting.cbe as plots

    def full(path, **kw):
        Path(path).write_bytes(b"\x89PNG half")
        raise OSError(errno.ENOSPC, "No space left on device", str(path))

    monkeypatch.setattr(plots, "plot_cbe", full)
    out = tmp_path / "E"
    err = fails(capsys, "evaluate", model3 / "best.pt", data_dir / "ds3", "--out", out)
    assert "cbe.png: No space left on device (free disk space and rerun)" in err
    assert not out.exists() and _leftovers(out) == []
    # into an existing exsur folder (the model's): its files stay, none is added
    before = sorted(p.name for p in model3.iterdir())
    fails(capsys, "evaluate", model3 / "best.pt", data_dir / "ds3", "--out", model3)
    assert sorted(p.name for p in model3.iterdir()) == before and _leftovers(model3) == []


def _other_model(ckpt: Path, path: Path) -> Path:
    """A copy of checkpoint ``ckpt`` with other weights (a second ensemble member)."""
    import torch

    d = torch.load(ckpt, weights_only=True)
    d["state_dict"] = {
        k: v + 0.01 if v.is_floating_point() else v for k, v in d["state_dict"].items()
    }
    torch.save(d, path)
    return path


def test_file_outputs_replace_only_exsur_files(tmp_path: Path, model3: Path, capsys) -> None:
    ckpt, other = model3 / "best.pt", _other_model(model3 / "best.pt", tmp_path / "b.pt")
    notes = tmp_path / "notes.txt"
    notes.write_text("mine")
    assert "must end in .onnx" in fails(capsys, "export", ckpt, "--out", notes)
    thesis = tmp_path / "thesis.tex"
    thesis.write_text("mine")
    assert "must end in .pt" in fails(capsys, "merge", ckpt, other, "--out", thesis)
    assert notes.read_text() == thesis.read_text() == "mine"
    fake = tmp_path / "model.onnx"
    fake.write_text("another tool's model")
    err = fails(capsys, "export", ckpt, "--out", fake)
    assert "exists and exsur did not write it" in err and "--overwrite" in err
    theirs = tmp_path / "theirs.pt"
    theirs.write_bytes(b"another project's weights")
    assert "exsur did not write it" in fails(capsys, "merge", ckpt, other, "--out", theirs)
    assert fake.read_text() == "another tool's model"
    # exsur's own checkpoint is replaced; another one only with --overwrite
    mine = tmp_path / "ens.pt"
    shutil.copy(ckpt, mine)
    assert main(["merge", str(ckpt), str(other), "--out", str(mine)]) == 0
    assert main(["merge", str(ckpt), str(other), "--out", str(theirs), "--overwrite"]) == 0
    capsys.readouterr()


def test_train_marks_the_folder_and_every_member(tmp_path: Path, data_dir: Path) -> None:
    """An ensemble killed after its first member is still recognised as exsur's."""
    out = tmp_path / "E"
    argv = ["train", data_dir / "ds3", "--out", out, "--preset", data_dir / "tiny.toml"]
    extra = ["--epochs", "1", "--members", "2", "--set", "train.member_workers=1"]
    assert main([str(a) for a in [*argv, *extra]]) == 0
    for d in (out, out / "member_0", out / "member_1"):
        assert read_marker(d)["kind"] == "model", d
    assert (out / "learning_curve.png").is_file()  # both members' epoch logs, one figure
    (out / "best.pt").unlink()  # as if killed while training member 1
    (out / "log.csv").unlink()
    shutil.rmtree(out / "member_1")
    assert is_exsur_output(out)
    assert main([str(a) for a in [*argv, *extra]]) == 0
    assert (out / "best.pt").is_file() and _leftovers(out) == []


def test_plot_replaces_only_its_own_images(tmp_path: Path, data_dir: Path, capsys) -> None:
    from PIL import Image

    ep = sorted((data_dir / "ds3" / "episodes").glob("*.parquet"))[0]
    png = tmp_path / "ep.png"
    for _ in range(2):  # the second run replaces the first one's image
        assert main(["plot", str(ep), "--out", str(png)]) == 0
    photo = tmp_path / "photo.png"
    Image.new("RGB", (4, 4)).save(photo)
    before = photo.read_bytes()
    assert "exsur did not write it" in fails(capsys, "plot", ep, "--out", photo)
    notes = tmp_path / "notes.txt"
    assert "must end in .png" in fails(capsys, "plot", ep, "--out", notes)
    assert photo.read_bytes() == before and not notes.exists()
    assert main(["plot", str(ep), "--out", str(photo), "--overwrite"]) == 0
    capsys.readouterr()


def test_control_reruns_into_its_own_folder(tmp_path: Path, capsys) -> None:
    """'exsur control' twice into one folder: the second run replaces its own report (it was
    refused: 'holds tracking.png, which exsur did not write'); a foreign folder is refused
    before any run."""
    from tests.helpers.surrogates import tiny_surrogate

    from excavator_surrogate.surrogate.checkpoint import save_checkpoint

    ckpt = save_checkpoint(tmp_path / "tiny.pt", tiny_surrogate())
    out = tmp_path / "ctl"
    argv = ["control", ckpt, "--out", out, "--samples", "2", "--horizon", "2", "--no-rl"]
    argv += ["--no-oracle", "--time-scale", "0.05", "--cpus", "1"]
    for _ in range(2):
        assert main([str(a) for a in argv]) == 0, capsys.readouterr().err
    assert read_marker(out)["kind"] == "control" and (out / "tracking.png").is_file()
    (out / "notes.txt").write_text("mine")
    assert "holds 'notes.txt', which exsur did not write" in fails(capsys, *argv)
    assert (out / "notes.txt").read_text() == "mine"


def test_an_out_of_another_kind_or_inside_the_input_is_refused(
    tmp_path: Path, data_dir: Path, model3: Path, capsys
) -> None:
    """``simulate --out MODEL``, ``train DS --out OTHER_DS``, ``compare --out MODEL`` and
    ``train DS --out DS/model`` are refused before any work, in one line, with nothing
    touched."""
    model = tmp_path / "mymodel"
    shutil.copytree(model3, model)
    before = sorted(p.name for p in model.iterdir())
    err = fails(capsys, "simulate", "--preset", "tiny", "--out", model)
    assert "is an exsur model output" in err and "writes a dataset output" in err
    err = fails(capsys, "compare", model / "best.pt", "--commands", "steps", "--out", model)
    assert "is an exsur model output" in err and "writes a compare output" in err
    assert sorted(p.name for p in model.iterdir()) == before
    ds = tmp_path / "ds"
    shutil.copytree(data_dir / "ds3", ds)
    tiny = data_dir / "tiny.toml"
    err = fails(capsys, "train", data_dir / "ds4", "--preset", tiny, "--out", ds)
    assert "is an exsur dataset output" in err
    err = fails(capsys, "train", ds, "--preset", tiny, "--out", ds / "model")
    assert f"--out lies inside {ds}, an exsur output this command reads" in err
    assert not (ds / "model").exists() and is_exsur_output(ds)


def test_files_a_user_adds_to_an_exsur_output_are_kept(
    tmp_path: Path, data_dir: Path, model3: Path, capsys
) -> None:
    """A colleague's checkpoint, notes in report.md and a field log among the episodes of a
    dataset exsur wrote: the next simulate into it is refused (it replaced them silently)."""
    ds = tmp_path / "ds"
    shutil.copytree(data_dir / "ds3", ds)
    ep = sorted((ds / "episodes").glob("*.parquet"))[0]
    added = {
        ds / "colleague_model.pt": model3 / "best.pt",
        ds / "report.md": None,
        ds / "episodes" / "my_field_log.parquet": ep,
    }
    for path, src in added.items():
        shutil.copy(src, path) if src else path.write_text("my notes")
        err = fails(capsys, "simulate", "--preset", "tiny", "--out", ds)
        assert f"holds '{path.relative_to(ds).as_posix()}', which exsur did not write" in err
        assert path.is_file()
        path.unlink()
    assert main(["plot", str(ep)]) == 0  # exsur's own figure beside the episode is recorded
    assert is_exsur_output(ds) and ep.with_suffix(".png").is_file()


def test_a_locale_that_is_not_utf8_writes_and_prints(
    tmp_path: Path, data_dir: Path, model3: Path
) -> None:
    """Under an ASCII locale (``LC_ALL=C`` without Python's UTF-8 mode) ``exsur evaluate``
    wrote its table with the locale's codec and failed on R² with a traceback: its files are
    UTF-8 now, and what it prints is escaped where the terminal cannot show it."""
    import os

    env = {**os.environ, "LC_ALL": "C", "LANG": "C", "PYTHONUTF8": "0"}
    env["PYTHONPATH"] = os.pathsep.join(p for p in sys.path if p)
    for quiet in ([], ["-q"]):
        out = tmp_path / f"ev{len(quiet)}"
        argv = ["evaluate", model3 / "best.pt", data_dir / "ds3", "--out", out, "--no-arx"]
        proc = subprocess.run(
            [sys.executable, "-m", "excavator_surrogate", *map(str, argv + quiet)],
            capture_output=True,
            env=env,
        )
        assert proc.returncode == 0, proc.stderr.decode()
        assert "R²" in (out / "table.md").read_text(encoding="utf-8")
        assert (b"R\\xb2" in proc.stdout) != bool(quiet)


def test_a_failed_file_output_leaves_no_folder(tmp_path: Path, model3: Path, capsys) -> None:
    """merge, export and plot created --out's missing parent folders in their first check
    and left them when they then failed on their input; a written file keeps them."""
    notckpt = tmp_path / "notckpt.pt"
    notckpt.write_text("not a checkpoint")
    bad = tmp_path / "bad.parquet"
    bad.write_text("not parquet")
    fails(capsys, "merge", model3 / "best.pt", "--out", tmp_path / "new1" / "deep" / "e.pt")
    fails(capsys, "export", notckpt, "--out", tmp_path / "new2" / "deep" / "m.onnx")
    fails(capsys, "plot", bad, "--out", tmp_path / "new3" / "deep" / "p.png")
    fails(capsys, "merge", notckpt, model3 / "best.pt", "--out", tmp_path / "new5" / "e.pt")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.parquet", "notckpt.pt"]
    other = _other_model(model3 / "best.pt", tmp_path / "b.pt")
    out = tmp_path / "new6" / "deep" / "e.pt"
    assert main(["merge", str(model3 / "best.pt"), str(other), "--out", str(out)]) == 0
    assert out.is_file()
    capsys.readouterr()
