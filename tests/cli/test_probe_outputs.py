"""Issue 25 probe: outputs that would silently not be what was asked for, or never fit.

``exsur export --opset 3`` (or 999) used to write an opset-18 model and exit 0 (torch only
logged its converter's failure); ``exsur control --samples 1000000000`` ran into the kernel's
OOM killer.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from tests.helpers.cli import fails as _fails

from excavator_surrogate.cli import main


@pytest.mark.parametrize("opset", [3, 999])
def test_export_refuses_an_opset_it_did_not_write(
    opset: int, model3: Path, tmp_path: Path, capsys
) -> None:
    pytest.importorskip("onnx")
    out = tmp_path / "m.onnx"
    line = _fails(capsys, "export", model3 / "best.pt", "--opset", opset, "--out", out)
    assert f"{out}: the ONNX exporter cannot write opset {opset}" in line
    assert not out.exists()
    assert [p.name for p in tmp_path.iterdir()] == []  # no temporary file left either


def test_export_writes_the_opset_asked_for(model3: Path, tmp_path: Path) -> None:
    onnx = pytest.importorskip("onnx")
    out = tmp_path / "m.onnx"
    assert main(["export", str(model3 / "best.pt"), "--opset", "18", "--out", str(out)]) == 0
    versions = [o.version for o in onnx.load(str(out)).opset_import if o.domain in ("", "ai.onnx")]
    assert versions == [18]


def test_control_refuses_mppi_rollouts_that_cannot_fit(
    model3: Path, tmp_path: Path, capsys
) -> None:
    pytest.importorskip("mujoco")
    out = tmp_path / "ctl"
    line = _fails(
        capsys, "control", model3 / "best.pt", "--samples", 10**12, "--cpus", 1, "--out", out
    )
    assert "--samples 1000000000000 x --horizon 20 MPPI rollouts needs about" in line
    assert "lower --samples or --horizon" in line
    assert not out.exists()


def test_control_refuses_a_seed_ppo_cannot_take(model3: Path, tmp_path: Path, capsys) -> None:
    pytest.importorskip("mujoco")
    out = tmp_path / "ctl"
    line = _fails(capsys, "control", model3 / "best.pt", "--seed", 10**23, "--out", out)
    assert f"--seed {10**23}: must be < 2**32" in line
    assert not out.exists()


def test_the_api_refuses_a_folder_as_a_file_output(model3: Path, tmp_path: Path) -> None:
    """export_onnx(ckpt, folder) raised IsADirectoryError naming its temporary file."""
    pytest.importorskip("onnx")
    from excavator_surrogate.env.export import export_onnx
    from excavator_surrogate.errors import ConfigError

    folder = tmp_path / "exports"
    folder.mkdir()
    with pytest.raises(ConfigError, match=f"{folder}: is a folder; give a file name"):
        export_onnx(model3 / "best.pt", folder)
    assert list(folder.iterdir()) == [] and sorted(p.name for p in tmp_path.iterdir()) == [
        "exports"
    ]
