"""``exsur run``: the report folder of Stage I and Stage II runs, and no half-written output."""

from __future__ import annotations

import json
import tomllib
from pathlib import Path

import pytest

from excavator_surrogate.cli import main
from excavator_surrogate.stages import build_configs, load_preset

TINY_TRAIN = """
[train]
mode = "stateful"
hidden = 16
layers = 1
head_hidden = 16
seq_len = 60
burn_in = 30
tbptt = 10
epochs = 2
tensorboard = false
max_train_seconds = 0.0
[evaluate]
max_figures = 1
"""


def _preset(tmp_path: Path, base: str, extra: str = "") -> Path:
    p = tmp_path / f"{base}-test.toml"
    p.write_text(f'extends = "{base}"\n' + extra + TINY_TRAIN)
    return p


def _not_json(name: str) -> None:
    raise ValueError(f"{name} is not JSON")


def test_run_stage1_report(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "run"
    assert main(["run", "--preset", str(_preset(tmp_path, "tiny")), "--out", str(out)]) == 0
    for f in (
        "report.md",
        "metrics.json",
        "table.md",
        "cbe.png",
        "horizon.png",
        "config.toml",
        "model/best.pt",
        "model_gru/best.pt",
        "data/manifest.json",
    ):
        assert (out / f).exists(), f
    # strict JSON: a pace the cost model does not cover is null, not NaN (other readers refuse it)
    m = json.loads((out / "metrics.json").read_text(), parse_constant=_not_json)
    joints = ["swing", "boom", "arm", "bucket"]
    assert list(m["omega"]) == joints and list(m["theta"]) == joints
    assert set(m["theta"]["boom"]) >= {"rmse", "mae", "r2"}
    assert set(m["compare"]) == {"GRU", "ARX", "Structured"}
    assert m["run"]["preset"] == "tiny-test" and "total" in m["run"]["timings_s"]
    # Paths inside the run folder are relative to it: right after the temporary build folder
    # is renamed into place, and after the folder is moved.
    assert m["run"]["checkpoint"] == "model/best.pt" and m["run"]["dataset"] == "data"
    assert m["run"]["out"] == str(out.resolve())
    report = (out / "report.md").read_text()
    assert "- checkpoint: model/best.pt" in report and "- dataset: data" in report
    assert report.rstrip().endswith("load_checkpoint`), `data/`.")  # the folders it wrote
    assert ".tmp" not in json.dumps(m) and ".tmp" not in report
    # the data the model trained on: its splits, and the command to see each joint
    assert "## Data" in report and "| train | 2 |" in report and "| test | 1 |" in report
    # how far ahead it can be trusted: every model and the hold baseline, with the figure
    assert set(m["horizon"]["rmse"]) == {"LSTM", "GRU", "ARX", "Structured", "hold"}
    # the summary's one line against every model of the comparison
    assert "**Free-run angle RMSE of the surrogate:** lower than GRU on" in report
    assert "; lower than Structured on" in report
    assert "## Prediction horizon" in report and "![prediction horizon](horizon.png)" in report
    assert f"`exsur info {out.resolve() / 'data'}`" in report
    cfg = tomllib.loads((out / "config.toml").read_text())
    assert cfg["train"]["hidden"] == 16 and cfg["simulate"]["n_train"] == 2
    # the dry run of the same command: the data's sizes before simulating, the same record
    assert main(["run", "--preset", str(_preset(tmp_path, "tiny")), "--dry-run", "-q"]) == 0
    text = capsys.readouterr().out
    assert "data: simulated on the ideal stand-in (nothing simulated now): 2 train" in text
    assert tomllib.loads(text[text.index("config.toml:\n") + 13 :]) == cfg
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]
    moved = tmp_path / "moved"
    out.rename(moved)
    assert (moved / m["run"]["checkpoint"]).is_file()
    assert (moved / m["run"]["dataset"] / "manifest.json").is_file()
    # a run on a dataset of the user's writes no data/, and its report lists none
    again = tmp_path / "again"
    argv = ["run", "--preset", str(_preset(tmp_path, "tiny")), "--data", str(moved / "data")]
    assert main([*argv, "--out", str(again), "-q"]) == 0
    assert not (again / "data").exists()
    assert (again / "report.md").read_text().rstrip().endswith("load_checkpoint`).")


def test_run_stage2_cleaning_section(tmp_path: Path) -> None:
    sim = """
[simulate]
n_train = 2
n_val = 1
n_test = 1
steps_train = 300
steps_val = 300
steps_test = 300
"""
    out = tmp_path / "run2"
    assert (
        main(
            [
                "run",
                "--preset",
                str(_preset(tmp_path, "quick-noload", sim)),
                "--out",
                str(out),
                "--members",
                "2",
            ]
        )
        == 0
    )
    m = json.loads((out / "metrics.json").read_text())
    clean = m["cleaning"]
    assert set(clean) >= {"swing", "boom", "arm", "bucket"}
    for j in ("swing", "boom", "arm", "bucket"):
        assert clean[j]["rmse_fused"] <= 0.5 * clean[j]["rmse_raw"]
        assert {"jump_precision", "jump_recall"} <= set(clean[j])
    assert set(m["against_cleaned"]) == {"omega", "theta"}
    assert set(m["cleaning_effect"]) == {"trained on cleaned", "trained on raw"}
    assert m["run"]["reference"] == "true"
    report = (out / "report.md").read_text()
    assert "Table III (noload)" in report and "Effect of cleaning" in report
    assert report.rstrip().endswith("`data/`, `data_clean/`.")
    assert (out / "fusion_bucket.png").exists() and (out / "model_raw" / "best.pt").exists()
    # --members 2: every trained model is a two-seed ensemble, scored next to its members
    assert set(m["ensemble_members"]) == {"ensemble", "member 0", "member 1"}
    assert "Seed ensemble: the merged network vs its members" in report
    assert report.count("## Uncertainty and out-of-distribution") == 1  # not again in the table
    # cleaned runs train on the cleaned data: that is the dataset the Data section describes
    assert "| yes | yes |" in report.split("## Data")[1].split("## Learning")[0]
    for model in ("model", "model_raw"):  # each trained model's learning curves, in the report
        assert (out / model / "member_1" / "best.pt").exists()
        assert (out / model / "learning_curve.png").is_file()
        assert f"]({model}/learning_curve.png)" in report
    assert tomllib.loads((out / "config.toml").read_text())["train"]["members"] == 2
    # the evaluation against the cleaned data records its own config, which loads back
    record = out / "eval_cleaned" / "config.toml"
    ev = build_configs(load_preset(record), sections=["evaluate"])["evaluate"]
    assert ev.reference == "measured" and not ev.arx and not ev.structured
    assert tomllib.loads(record.read_text())["command"]["checkpoint"] == "model/best.pt"


def test_run_failure_leaves_nothing(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text('extends = "tiny"\n[train]\nwindoww = 3\n')
    out = tmp_path / "never"
    assert main(["run", "--preset", str(bad), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "windoww" in err[0]
    assert not out.exists()
    assert main(["run", "--preset", "no-such-preset", "--out", str(out)]) == 2
    assert "unknown preset 'no-such-preset'" in capsys.readouterr().err


def test_a_dataset_outside_the_run_is_named_by_its_absolute_path(tmp_path, monkeypatch) -> None:
    """``exsur run --data rel/data``: the report's ``exsur info`` command must resolve from
    anywhere (it read RUN/rel/data, a folder that does not exist)."""
    from excavator_surrogate.pipeline import _in_run

    monkeypatch.chdir(tmp_path)
    (tmp_path / "rel" / "data").mkdir(parents=True)
    run = tmp_path / "runs" / ".r1.tmp"
    (run / "data").mkdir(parents=True)
    assert _in_run(Path("rel/data"), run) == str(tmp_path.resolve() / "rel" / "data")
    assert _in_run(run / "data", run) == "data"  # inside the run: relative to it
