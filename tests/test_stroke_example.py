"""The stroke-sensing excavator end to end: simulate (tiny) -> strokes in mm -> exsur import ->
train -> evaluate -> validate -> export, with every printed unit the mapping's (mm), never deg.

``examples/stroke_make_logs.py`` turns the hydraulic stand-in's boom, arm and bucket angles
into cylinder strokes through a made-up linkage; the swing stays an angle (in deg in the logs).
"""

from __future__ import annotations

import importlib.util
import json
import re
import sys
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest

from excavator_surrogate.cli import main
from excavator_surrogate.data import load_dataset
from excavator_surrogate.surrogate import load_checkpoint
from excavator_surrogate.surrogate.rollout import rollout_episodes

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "stroke_make_logs.py"


def _example() -> ModuleType:
    spec = importlib.util.spec_from_file_location("stroke_make_logs", EXAMPLE)
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    sys.modules["stroke_make_logs"] = mod
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    work = tmp_path_factory.mktemp("stroke")
    mapping = _example().make_logs(work, seed=0, preset="tiny")
    ds, model, ev = work / "dataset", work / "model", work / "eval"
    argv = ["import", work / "logs", "--mapping", mapping, "--out", ds, "-q"]
    assert main([str(a) for a in argv]) == 0
    argv = ["train", ds, "--out", model, "--preset", "tiny", "--seed", "0", "-q"]
    assert main([str(a) for a in argv]) == 0
    assert main([str(a) for a in ["evaluate", model / "best.pt", ds, "--out", ev, "-q"]]) == 0
    return {"work": work, "mapping": mapping, "dataset": ds, "model": model, "eval": ev}


def test_the_mapping_declares_strokes_in_mm(run: dict[str, Path]) -> None:
    spec = load_dataset(run["dataset"]).spec
    assert [(j.kind, j.unit) for j in spec.joints] == [
        ("revolute", "rad"),
        ("linear", "mm"),
        ("linear", "mm"),
        ("linear", "mm"),
    ]
    assert all(j.linkage is not None for j in spec.joints[1:])


def test_report_prints_mm_not_deg(run: dict[str, Path]) -> None:
    table = (run["eval"] / "table.md").read_text()
    for joint in ("Boom", "Arm", "Bucket"):
        assert f"| {joint} [mm] |" in table and f"| {joint} [mm/s] |" in table
    # strokes never in degrees: only the revolute swing's prediction-horizon row is in °
    assert "deg" not in table
    lines = table.splitlines()
    (verdict,) = [line for line in lines if line.startswith("**Free-run position RMSE of ")]
    assert [line for line in lines if "°" in line and line != verdict] == [
        line for line in lines if line.startswith("| Swing [°] |")
    ]
    # the verdict's joints each in their own unit: the swing in °, the strokes in mm
    for joint, a, b in re.findall(r"the (\w+): ([^,;)]+) against ([^,;)]+)", verdict):
        unit = "°" if joint == "swing" else " mm"
        assert a.endswith(unit) and b.endswith(unit), (joint, a, b)
    assert "| Boom [mm] | " in table.split("## Prediction horizon")[1]
    assert "Paper RMSE" not in table  # the paper's machine senses angles
    assert "Joint angles through the linkage" in table
    m = json.loads((run["eval"] / "metrics.json").read_text())
    assert m["run"]["units"]["boom"] == {"theta": "m", "display": "mm"}
    assert set(m["linkage"]) == {"boom", "arm", "bucket"}


def test_the_free_run_stays_within_the_stroke_limits(run: dict[str, Path]) -> None:
    ds = load_dataset(run["dataset"])
    sur = load_checkpoint(run["model"] / "best.pt")
    runs = rollout_episodes(sur, ds.split("test"))
    theta = np.concatenate([r.theta_hat for r in runs])
    assert np.isfinite(theta).all()
    for k, j in enumerate(ds.spec.joints):
        if not j.linear:
            continue
        span = j.theta_max - j.theta_min
        tol = 1e-6 * span  # float32 rounding of the end stops
        assert theta[:, k].min() >= j.theta_min - tol, j.name
        assert theta[:, k].max() <= j.theta_max + tol, j.name


def test_validate_prints_no_degrees(run: dict[str, Path], capsys: pytest.CaptureFixture) -> None:
    assert main(["validate", str(run["dataset"])]) == 0
    out = capsys.readouterr()
    assert "ok" in out.out and "deg" not in out.out + out.err


def test_onnx_metadata_carries_the_units(run: dict[str, Path]) -> None:
    onnx = pytest.importorskip("onnx")
    pytest.importorskip("onnxruntime")
    path = run["work"] / "stroke.onnx"
    assert main(["export", str(run["model"] / "best.pt"), "--out", str(path), "-q"]) == 0
    meta = {p.key: p.value for p in onnx.load(str(path)).metadata_props}
    units = json.loads(meta["exsur_units"])
    assert units["boom"]["display"] == "mm" and units["boom"]["theta"] == "m"
    assert units["swing"]["display"] == "rad"
    assert json.loads(meta["exsur_spec"])["joints"][1]["unit"] == "mm"


def test_import_summary_names_the_unit(run: dict[str, Path]) -> None:
    text = (run["dataset"] / "import_report.md").read_text()
    assert "boom (linear, mm)" in text and "swing (periodic)" in text


def test_the_mujoco_plant_refuses_a_stroke_checkpoint(
    run: dict[str, Path], capsys: pytest.CaptureFixture
) -> None:
    """The built-in plant is revolute: comparing (or controlling) through it is refused in
    one line, not run on strokes taken for angles."""
    from tests.helpers.cli import fails

    ckpt = run["model"] / "best.pt"
    line = fails(capsys, "compare", ckpt, "--commands", "steps:seed=1,n_step=50")
    assert "joint 'boom' linear vs revolute" in line


def test_the_shipped_mapping_is_the_generated_one() -> None:
    """examples/stroke_excavator.toml (for reading) is what make_logs writes at 20 Hz."""
    shipped = EXAMPLE.with_name("stroke_excavator.toml").read_text()
    assert shipped == _example().mapping_toml(20.0)


def test_clean_prints_the_strokes_in_mm(
    run: dict[str, Path], capsys: pytest.CaptureFixture
) -> None:
    out = run["work"] / "cleaned"
    assert main(["clean", str(run["dataset"]), "--out", str(out)]) == 0
    lines = {ln.split(":")[0].strip(): ln for ln in capsys.readouterr().out.splitlines()}
    assert lines["boom"].endswith(" mm") and lines["swing"].endswith(" rad"), lines
    assert load_dataset(out).spec.joints[1].unit == "mm"  # cleaning keeps the spec
