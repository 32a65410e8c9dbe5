"""Issue 17: never delete a user's files, never use a checkpoint on the wrong machine or rate.

Every case: exit code 2, ONE line naming the file/field and the fix, nothing written, nothing
of the user's deleted.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from excavator_surrogate.cli import main
from excavator_surrogate.config import from_dict
from excavator_surrogate.errors import CheckpointError, ConfigError
from excavator_surrogate.surrogate.checkpoint import read_checkpoint
from excavator_surrogate.training import TrainConfig


def fails(capsys: pytest.CaptureFixture[str], *argv: object) -> str:
    """Run exsur; assert exit code 2 and a one-line error; return it."""
    rc = main([str(a) for a in argv])
    err = capsys.readouterr().err
    assert rc == 2, err
    assert err.startswith("exsur: error: ") and err.count("\n") == 1, err
    return err


def _precious(tmp_path: Path) -> Path:
    d = tmp_path / "D"
    d.mkdir()
    (d / "precious.txt").write_text("x")
    return d


def _untouched(d: Path) -> None:
    assert [p.name for p in d.parent.iterdir() if p.name.startswith(f".{d.name}")] == []
    assert [p.name for p in d.iterdir()] == ["precious.txt"]
    assert (d / "precious.txt").read_text() == "x"


# --- B3: simulate, clean and run never replace a folder exsur did not write ------------------


@pytest.mark.parametrize("cmd", ["simulate", "clean", "run"])
def test_b3_foreign_out_is_refused(cmd: str, tmp_path: Path, data_dir: Path, capsys) -> None:
    d = _precious(tmp_path)
    argv = {
        "simulate": ["simulate", "--preset", "tiny", "--out", d],
        "clean": ["clean", data_dir / "ds3", "--out", d],
        "run": ["run", "--preset", "tiny", "--out", d],
    }[cmd]
    err = fails(capsys, *argv)
    assert f"{d}: --out holds 'precious.txt', which exsur did not write" in err
    assert "--overwrite" in err
    _untouched(d)


@pytest.mark.parametrize("cmd", ["train", "evaluate", "compare"])
def test_b3_foreign_out_is_refused_by_writers_too(
    cmd: str, tmp_path: Path, data_dir: Path, model3: Path, capsys
) -> None:
    d = _precious(tmp_path)
    argv = {
        "train": ["train", data_dir / "ds3", "--out", d, "--epochs", "1"],
        "evaluate": ["evaluate", model3 / "best.pt", data_dir / "ds3", "--out", d],
        "compare": ["compare", model3 / "best.pt", "--commands", "steps", "--out", d],
    }[cmd]
    assert "which exsur did not write" in fails(capsys, *argv)
    _untouched(d)


def test_b3_clean_replaces_its_own_output(tmp_path: Path, data_dir: Path, capsys) -> None:
    out = tmp_path / "clean"
    for _ in range(2):  # the second run replaces the dataset the first one wrote
        assert main(["clean", str(data_dir / "ds3"), "--out", str(out)]) == 0
    assert (out / "manifest.json").is_file()
    d = _precious(tmp_path)
    assert main(["clean", str(data_dir / "ds3"), "--out", str(d), "--overwrite"]) == 0
    assert not (d / "precious.txt").exists() and (d / "manifest.json").is_file()
    capsys.readouterr()


@pytest.mark.parametrize("cmd", ["clean", "train", "evaluate", "sweep"])
def test_b3_a_dataset_read_is_never_the_out(cmd: str, data_dir: Path, model3: Path, capsys) -> None:
    ds = data_dir / "ds3"
    before = {p.name: p.read_bytes() for p in ds.iterdir() if p.is_file()}
    argv = {
        "clean": ["clean", ds, "--out", ds, "--overwrite"],
        "train": ["train", ds, "--out", ds, "--epochs", "1"],  # its config.toml was rewritten
        "evaluate": ["evaluate", model3 / "best.pt", ds, "--out", ds],
        "sweep": ["sweep", ds, "--out", ds, "--trials", "1"],
    }[cmd]
    assert "this input lies inside --out" in fails(capsys, *argv)
    assert {p.name: p.read_bytes() for p in ds.iterdir() if p.is_file()} == before


# --- W8 / W3: wrong or unusable output paths -------------------------------------------------


@pytest.mark.parametrize("out", [".", ".."])
def test_w8_current_folder_is_never_an_output(
    out: str, tmp_path: Path, monkeypatch, capsys
) -> None:
    sub = tmp_path / "sub"
    sub.mkdir()
    monkeypatch.chdir(sub)
    err = fails(capsys, "simulate", "--preset", "tiny", "--out", out, "--overwrite")
    assert "is the current folder or one of its parents" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["sub"]


def test_w8_file_outputs_and_folder_outputs(tmp_path: Path, model3: Path, data_dir, capsys) -> None:
    ckpt = model3 / "best.pt"
    assert "is a folder; give a file name such as model.onnx" in fails(
        capsys, "export", ckpt, "--out", tmp_path
    )
    assert "is a folder; give a file name such as ensemble.pt" in fails(
        capsys, "merge", ckpt, ckpt, "--out", tmp_path
    )
    assert "is one of the inputs" in fails(capsys, "merge", ckpt, ckpt, "--out", ckpt)
    f = tmp_path / "f.txt"
    f.write_text("x")
    err = fails(capsys, "train", data_dir / "ds3", "--out", f)
    assert "exists and is a file; give a folder" in err and f.read_text() == "x"


def test_w3_unwritable_out_is_one_line(tmp_path: Path, monkeypatch, capsys) -> None:
    import os

    ro = tmp_path / "ro"
    ro.mkdir()
    real = os.access
    monkeypatch.setattr(os, "access", lambda p, m: Path(p) != ro and real(p, m))
    err = fails(capsys, "simulate", "--preset", "tiny", "--out", ro / "D")
    assert "is not writable" in err and not (ro / "D").exists()


def test_w3_os_errors_are_one_line(tmp_path: Path, monkeypatch, capsys) -> None:
    """An OS error the pre-checks cannot foresee (root ignores permission bits, a full disk)."""
    import excavator_surrogate.simulate.generate as gen

    def denied(*a, **k):
        raise PermissionError(13, "Permission denied", str(tmp_path / "D" / "x"))

    monkeypatch.setattr(gen, "simulate_dataset", denied)
    err = fails(capsys, "simulate", "--preset", "tiny", "--out", tmp_path / "D")
    assert f"{tmp_path / 'D' / 'x'}: Permission denied" in err


# --- B6 / W2: NaN and inf -------------------------------------------------------------------


def test_b6_nan_option_is_refused(tmp_path: Path, data_dir: Path, capsys) -> None:
    out = tmp_path / "X"
    err = fails(capsys, "train", data_dir / "ds3", "--out", out, "--max-seconds", "nan")
    assert "--max-seconds nan: give a finite number" in err
    assert "--epochs" not in err and not out.exists()
    assert "give a finite number" in fails(
        capsys, "run", "--out", out, "--max-train-seconds", "inf"
    )


def test_b6_nan_in_config_fields(tmp_path: Path, data_dir: Path, capsys) -> None:
    with pytest.raises(ConfigError, match=r"\[train\].max_train_seconds: expected a finite number"):
        from_dict(TrainConfig, {"max_train_seconds": float("nan")}, where="[train]")
    with pytest.raises(ConfigError, match="lr: expected a finite number"):
        from_dict(TrainConfig, {"lr": float("inf")})
    from excavator_surrogate.clean import CleanConfig

    assert from_dict(CleanConfig, {"tau_cons": float("inf")}).tau_cons == float("inf")
    preset = tmp_path / "p.toml"
    preset.write_text("[train]\nmax_train_seconds = nan\n")
    out = tmp_path / "X"
    err = fails(capsys, "train", data_dir / "ds3", "--out", out, "--preset", preset)
    assert "max_train_seconds: expected a finite number, got nan" in err and not out.exists()


# --- B5 / W5 / W9 / W6: a checkpoint of another machine or rate -----------------------------


def test_b5_evaluate_on_another_rate(tmp_path: Path, data_dir: Path, model3: Path, capsys) -> None:
    out = tmp_path / "E"
    err = fails(capsys, "evaluate", model3 / "best.pt", data_dir / "ds3_10hz", "--out", out)
    assert "best.pt: the checkpoint does not fit" in err and "rate 20 Hz vs 10 Hz" in err
    assert not out.exists()


def test_w5_evaluate_on_other_joints_before_the_arx_fit(
    tmp_path: Path, data_dir: Path, model3: Path, capsys
) -> None:
    out = tmp_path / "E"
    err = fails(capsys, "evaluate", model3 / "best.pt", data_dir / "ds4", "--out", out)
    assert "joints ['swing', 'boom', 'arm'] vs ['swing', 'boom', 'arm', 'bucket']" in err
    assert not out.exists()


def test_b5_resume_on_another_rate_writes_nothing(
    tmp_path: Path, data_dir: Path, model3: Path, capsys
) -> None:
    out = tmp_path / "R"
    err = fails(
        capsys, "train", data_dir / "ds3_10hz", "--out", out, "--resume", model3 / "last.pt"
    )
    assert "last.pt: the checkpoint does not fit" in err and "rate 20 Hz vs 10 Hz" in err
    assert not out.exists()


@pytest.mark.parametrize("resume", ["missing.pt", "garbage.pt"])
def test_w6_bad_resume_leaves_no_out_folder(
    resume: str, tmp_path: Path, data_dir: Path, capsys
) -> None:
    (tmp_path / "garbage.pt").write_bytes(b"PK\x03\x04 not a zip at all " * 20)
    out = tmp_path / "R"
    err = fails(capsys, "train", data_dir / "ds3", "--out", out, "--resume", tmp_path / resume)
    assert resume in err and not out.exists()


def test_w9_compare_refuses_another_machine(tmp_path: Path, model3: Path, capsys) -> None:
    out = tmp_path / "C"
    err = fails(capsys, "compare", model3 / "best.pt", "--commands", "steps:seed=1", "--out", out)
    assert "does not fit the built-in MuJoCo excavator" in err and "joints" in err
    assert not out.exists()


def test_cosmetic_checkpoint_error_is_not_cut_mid_word(tmp_path: Path) -> None:
    bad = tmp_path / "bad.pt"
    bad.write_text("not a checkpoint " * 50)
    with pytest.raises(CheckpointError) as e:
        read_checkpoint(bad)
    inner = str(e.value).split("(", 1)[1].rsplit(")", 1)[0]
    assert inner.endswith(("...", ".")) or len(inner) < 120, inner
    assert not inner.endswith(tuple("abcdefghijklmnopqrstuvwxyz")), inner


@pytest.mark.parametrize(
    ("argv", "msg"),
    [
        (["simulate", "--preset", "tiny", "--seed", "-1"], "--seed -1: a seed must be >= 0"),
        (["train", "DS", "--seed", "-1"], "--seed -1: a seed must be >= 0"),
        (["evaluate", "CKPT", "DS", "--max-steps", "-5"], "max_steps must be >= 0, got -5"),
    ],
)
def test_b6_other_bad_numbers_are_one_line(
    argv: list[str], msg: str, tmp_path: Path, data_dir: Path, model3: Path, capsys
) -> None:
    out = tmp_path / "O"
    subst = {"DS": data_dir / "ds3", "CKPT": model3 / "best.pt"}
    err = fails(capsys, *[subst.get(a, a) for a in argv], "--out", out)
    assert msg in err and not out.exists()


@pytest.mark.parametrize("cmd", ["sweep", "train", "clean", "evaluate"])
def test_w6_missing_dataset_creates_no_out(cmd: str, tmp_path: Path, model3: Path, capsys) -> None:
    out, missing = tmp_path / "O", tmp_path / "nope"
    argv = {
        "sweep": ["sweep", missing, "--trials", "1"],
        "train": ["train", missing],
        "clean": ["clean", missing],
        "evaluate": ["evaluate", model3 / "best.pt", missing],
    }[cmd]
    assert "dataset folder not found" in fails(capsys, *argv, "--out", out)
    assert not out.exists()


def test_w6_a_failed_train_leaves_no_out_folder(tmp_path: Path, data_dir: Path, capsys) -> None:
    out = tmp_path / "never"
    argv = ["train", data_dir / "ds3", "--out", out, "--preset", "tiny"]
    assert main([str(a) for a in [*argv, "--set", "train.window=100000"]]) == 2
    last = capsys.readouterr().err.strip().splitlines()[-1]
    assert last.startswith("exsur: error: ") and "warm-up of 100000" in last
    assert not out.exists()  # no marker, config.toml or TensorBoard folder left behind
    out.mkdir()  # an empty folder of the user's stays, empty
    assert main([str(a) for a in [*argv, "--set", "train.window=100000"]]) == 2
    assert out.is_dir() and not any(out.iterdir())
