"""Checkpoint writes that fail (full disk, permissions, a file where the folder belongs) and
tampered entries (spec, model sizes, mode, missing keys): one line naming the file and the fix,
and nothing half-written left behind."""

from __future__ import annotations

import errno
from pathlib import Path
from typing import Any

import pytest
import torch

from excavator_surrogate.errors import CheckpointError
from excavator_surrogate.surrogate import load_checkpoint, save_checkpoint
from excavator_surrogate.surrogate.checkpoint import checkpoint_dict, checkpoint_in, read_checkpoint
from tests.helpers.surrogates import make_surrogate

FIX = "re-train or copy the file again"


def _failing_save(exc: BaseException):
    def save(obj: Any, f: Any) -> None:
        f.write(b"PK\x03\x04 half a checkpoint")
        raise exc

    return save


@pytest.mark.parametrize(
    ("exc", "why"),
    [
        (OSError(errno.ENOSPC, "No space left on device"), "No space left on device; free disk"),
        (OSError(errno.EDQUOT, "Disk quota exceeded"), "Disk quota exceeded; free disk space"),
        (PermissionError(errno.EACCES, "Permission denied"), "Permission denied; check the folder"),
        (OSError("I/O failed"), "I/O failed; check the folder and its permissions"),
        (RuntimeError("[enforce fail] PytorchStreamWriter failed writing file"), "disk full?"),
    ],
    ids=["full", "quota", "denied", "no-errno", "stream-writer"],
)
def test_a_failed_write_is_one_line_and_keeps_the_old_file(
    tmp_path: Path, spec, episodes, monkeypatch: pytest.MonkeyPatch, exc: BaseException, why: str
) -> None:
    sur = make_surrogate(spec, episodes)
    path = save_checkpoint(tmp_path / "m.pt", sur)
    before = path.read_bytes()
    monkeypatch.setattr(torch, "save", _failing_save(exc))
    with pytest.raises(CheckpointError) as e:
        save_checkpoint(path, sur)
    msg = str(e.value)
    assert "\n" not in msg and msg.startswith(f"{path}: cannot write the checkpoint") and why in msg
    assert path.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["m.pt"]  # no temporary file left


def test_an_unrelated_runtime_error_is_not_reworded(
    tmp_path: Path, spec, episodes, monkeypatch: pytest.MonkeyPatch
) -> None:
    sur = make_surrogate(spec, episodes)
    monkeypatch.setattr(torch, "save", _failing_save(RuntimeError("a bug in exsur")))
    with pytest.raises(RuntimeError, match="^a bug in exsur$"):
        save_checkpoint(tmp_path / "m.pt", sur)
    assert list(tmp_path.iterdir()) == []


def test_a_file_where_the_folder_belongs(tmp_path: Path, spec, episodes) -> None:
    sur = make_surrogate(spec, episodes)
    f = tmp_path / "notes.txt"
    f.write_text("x")
    for path in (f / "m.pt", f / "sub" / "m.pt"):
        with pytest.raises(CheckpointError) as e:
            save_checkpoint(path, sur)
        assert str(e.value) == (
            f"{path}: cannot write the checkpoint ({f} is a file, not a folder; write the "
            "checkpoint elsewhere)"
        )
    assert [p.name for p in tmp_path.iterdir()] == ["notes.txt"]


def _tamper(path: Path, sur, edit) -> Path:
    ck = checkpoint_dict(sur)
    edit(ck)
    torch.save(ck, path)
    return path


CASES = {
    "no spec": (lambda c: c.pop("spec"), "checkpoint lacks entries ['spec']; re-train"),
    "no mode": (lambda c: c.pop("mode"), "checkpoint lacks entries ['mode']; re-train"),
    "spec not a dict": (lambda c: c.update(spec="abc"), "malformed joint spec"),
    "spec rate not a number": (lambda c: c["spec"].update(rate_hz="fast"), "malformed joint spec"),
    "spec joint not a dict": (lambda c: c["spec"].update(joints=["boom"]), "malformed joint spec"),
    "model n_feature": (
        lambda c: c["model"].update(n_feature=c["model"]["n_feature"] + 1),
        "model sizes",
    ),
    "model n_joint": (
        lambda c: c["model"].update(n_joint=c["model"]["n_joint"] + 1),
        "model sizes",
    ),
    "model hidden text": (lambda c: c["model"].update(hidden="big"), "model entry is malformed"),
    "model hidden fraction": (lambda c: c["model"].update(hidden=12.5), "model entry is malformed"),
    "model hidden negative": (lambda c: c["model"].update(hidden=-3), "model entry is malformed"),
    "model not a dict": (lambda c: c.update(model=[1, 2]), "model entry is malformed"),
    "norm not a dict": (lambda c: c.update(norm=None), "normalisation entry is malformed"),
    "mode": (lambda c: c.update(mode="online"), "unknown mode 'online' (windowed or stateful)"),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_tampered_entries(tmp_path: Path, spec, episodes, case: str) -> None:
    edit, what = CASES[case]
    path = _tamper(tmp_path / "t.pt", make_surrogate(spec, episodes), edit)
    with pytest.raises(CheckpointError) as e:
        load_checkpoint(path)
    msg = str(e.value)
    assert "\n" not in msg and msg.startswith(f"{path}: ") and what in msg, msg
    assert "re-train" in msg


def test_tampered_entries_through_the_cli(
    tmp_path: Path, spec, episodes, capsys: pytest.CaptureFixture[str]
) -> None:
    from excavator_surrogate.cli import main

    path = _tamper(tmp_path / "t.pt", make_surrogate(spec, episodes), lambda c: c.update(mode="x"))
    assert main(["info", str(path)]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and "unknown mode 'x'" in lines[0] and FIX in lines[0]


def test_a_folder_names_the_checkpoint_in_it(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    (tmp_path / "seed1").mkdir()
    (tmp_path / "seed1" / "best.pt").write_bytes(b"")
    assert checkpoint_in(tmp_path) == tmp_path / "seed1" / "best.pt"

    def unreadable(self: Path, pattern: str) -> Any:
        raise PermissionError(errno.EACCES, "Permission denied", str(self))

    monkeypatch.setattr(Path, "glob", unreadable)
    assert checkpoint_in(tmp_path) == tmp_path / "best.pt"  # a guess, still a path to name
    with pytest.raises(CheckpointError, match=r"is a folder, not a checkpoint file; give the file"):
        read_checkpoint(tmp_path)


@pytest.mark.parametrize(("suffix", "what"), [(".onnx", "an ONNX export"), (".csv", "a CSV file")])
def test_a_file_of_another_kind_is_named_as_such(tmp_path: Path, suffix: str, what: str) -> None:
    path = tmp_path / f"model{suffix}"
    path.write_bytes(b"\x08\x07onnx-or-text")
    with pytest.raises(CheckpointError, match=f"{what} .*, not a checkpoint; give the .pt") as e:
        load_checkpoint(path)
    assert "re-train" not in str(e.value)  # nothing is wrong with the model


def test_altered_weights_say_what_to_do(tmp_path: Path, spec, episodes) -> None:
    ck = checkpoint_dict(make_surrogate(spec, episodes))
    name = next(iter(ck["state_dict"]))
    ck["state_dict"][name] = torch.zeros(3, 3)  # another shape than the stored architecture
    path = tmp_path / "altered.pt"
    torch.save(ck, path)
    with pytest.raises(CheckpointError, match="do not fit the stored architecture .*re-train"):
        load_checkpoint(path)


def test_a_changed_weight_byte_fails_the_crc_check(tmp_path: Path, spec, episodes) -> None:
    import zipfile

    path = tmp_path / "best.pt"
    save_checkpoint(path, make_surrogate(spec, episodes))
    with zipfile.ZipFile(path) as z:  # a weight tensor's stored (uncompressed) bytes
        info = next(i for i in z.infolist() if "/data/" in i.filename and i.file_size >= 4)
    raw = bytearray(path.read_bytes())
    start = (
        info.header_offset
        + 30
        + int.from_bytes(raw[info.header_offset + 26 : info.header_offset + 28], "little")
    )
    start += int.from_bytes(raw[info.header_offset + 28 : info.header_offset + 30], "little")
    raw[start : start + 4] = torch.tensor([1000.0]).numpy().tobytes()  # a finite, wrong weight
    path.write_bytes(bytes(raw))
    with pytest.raises(
        CheckpointError, match=f"corrupt checkpoint \\(entry .*/data/.* CRC .*{FIX}"
    ):
        load_checkpoint(path)


def test_the_device_is_checked_in_one_line(
    tmp_path: Path, spec, episodes, monkeypatch: pytest.MonkeyPatch
) -> None:
    from excavator_surrogate import devices
    from excavator_surrogate.errors import ConfigError

    path = tmp_path / "best.pt"
    save_checkpoint(path, make_surrogate(spec, episodes))
    monkeypatch.setattr(devices, "cuda_usable", lambda: False)
    with pytest.raises(ConfigError, match="unknown device 'bogus'"):
        load_checkpoint(path, device="bogus")
    with pytest.raises(ConfigError, match="device 'cuda' is not available"):
        load_checkpoint(path, device="cuda")
    assert load_checkpoint(path, device="auto").device == torch.device("cpu")
