"""``exsur control`` runs the machine check of ``exsur compare`` before any run: another
machine or another plant than the checkpoint's is refused in one line naming both, and the
plant defaults to the checkpoint's."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import pytest

from excavator_surrogate.cli import main
from excavator_surrogate.spec import EXCAVATOR, JointSpec, MachineSpec
from excavator_surrogate.surrogate.checkpoint import save_checkpoint
from tests.helpers.surrogates import tiny_surrogate


def _ckpt(path: Path, spec: MachineSpec, source: str | None) -> Path:
    meta = {**spec.meta, **({"data_source": source} if source else {})}
    return save_checkpoint(path, tiny_surrogate(replace(spec, meta=meta)))


def _control(ckpt: Path, out: Path, *extra: str) -> int:
    return main(["control", str(ckpt), "--out", str(out), "--no-rl", "--no-oracle", *extra])


@pytest.fixture
def no_run(monkeypatch: pytest.MonkeyPatch) -> list[dict]:
    """Replace the (minutes-long) control run; the calls' keyword arguments are recorded."""
    calls: list[dict] = []

    def fake_run(sur, out, **kw):
        calls.append(kw)
        out.mkdir()
        (out / "report.md").write_text("report\n")
        return {}

    monkeypatch.setattr("excavator_surrogate.control.report.run_control", fake_run)
    return calls


def test_control_refuses_an_imported_machine_with_the_same_joint_names(
    tmp_path: Path, capsys, no_run: list[dict]
) -> None:
    # the case: same joint names, a non-periodic swing, data imported from logs
    joints = (JointSpec("swing", theta_min=-1.5, theta_max=1.5), *EXCAVATOR.joints[1:])
    ckpt = _ckpt(tmp_path / "imp.pt", replace(EXCAVATOR, joints=joints, name="site7"), "import")
    assert _control(ckpt, tmp_path / "o") == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "built-in MuJoCo excavator" in err[0] and "periodic" in err[0]
    # the same machine description as the excavator, but imported data: refused too
    ckpt = _ckpt(tmp_path / "imp2.pt", EXCAVATOR, "import")
    assert _control(ckpt, tmp_path / "o") == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "'import' data" in err[0] and "built-in MuJoCo excavator" in err[0]
    assert not no_run and not (tmp_path / "o").exists()


def test_control_follows_and_enforces_the_checkpoints_plant(
    tmp_path: Path, capsys, no_run: list[dict]
) -> None:
    ideal = _ckpt(tmp_path / "ideal.pt", EXCAVATOR, "mujoco-ideal")
    assert _control(ideal, tmp_path / "a") == 0
    assert no_run[-1]["plant"] == "ideal"  # was: hydraulic whatever the checkpoint
    assert _control(ideal, tmp_path / "b", "--plant", "hydraulic") == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "ideal MuJoCo plant" in err[0] and "hydraulic" in err[0]
    assert len(no_run) == 1
    # a checkpoint that does not record its data keeps the old default
    old = _ckpt(tmp_path / "old.pt", EXCAVATOR, None)
    assert _control(old, tmp_path / "c") == 0 and no_run[-1]["plant"] == "hydraulic"


def test_run_control_checks_the_machine_itself(tmp_path: Path) -> None:
    from excavator_surrogate.control.report import run_control
    from excavator_surrogate.errors import CheckpointError

    sur = tiny_surrogate(replace(EXCAVATOR, meta={"data_source": "mujoco-hydraulic"}))
    with pytest.raises(CheckpointError, match="hydraulic MuJoCo plant.*not on the ideal plant"):
        run_control(sur, tmp_path / "o", plant="ideal", do_rl=False)
    assert not (tmp_path / "o").exists()
