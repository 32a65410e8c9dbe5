"""CLI: exsur train + exsur evaluate on a tiny synthetic dataset written with write_dataset."""

from __future__ import annotations

import json

import pytest

from excavator_surrogate.cli import main
from excavator_surrogate.data import write_dataset
from excavator_surrogate.surrogate.synthetic import synthetic_spec, synthetic_split


@pytest.fixture(scope="module")
def dataset_dir(tmp_path_factory):
    spec = synthetic_spec(3)
    items = synthetic_split(spec, n_train=2, n_val=1, n_test=2, n_step=160, noise=0.001)
    return write_dataset(tmp_path_factory.mktemp("ds") / "data", items)


def test_train_then_evaluate(tmp_path, dataset_dir, capsys):
    preset = tmp_path / "p.toml"
    preset.write_text(
        "[train]\nwindow = 6\nhidden = 8\nhead_hidden = 8\nbatch_size = 64\ntensorboard = false\n"
        "seq_len = 40\nburn_in = 6\ntbptt = 10\n[evaluate]\nmax_figures = 1\n"
    )
    run = tmp_path / "run"
    rc = main(
        [
            "train",
            str(dataset_dir),
            "--out",
            str(run),
            "--preset",
            str(preset),
            "--epochs",
            "2",
            "--mode",
            "stateful",
        ]
    )
    assert rc == 0
    assert capsys.readouterr().out.strip().endswith("best.pt")
    rc = main(
        [
            "evaluate",
            str(run / "best.pt"),
            str(dataset_dir),
            "--out",
            str(tmp_path / "ev"),
            "--preset",
            str(preset),
            "--reference",
            "true",
        ]
    )
    assert rc == 0
    out = capsys.readouterr().out
    assert "| Type | Joint | RMSE | MAE | R² |" in out and "ARX" in out
    m = json.loads((tmp_path / "ev" / "metrics.json").read_text())
    assert set(m["omega"]) == {"swing", "boom", "arm"} and set(m["omega"]["arm"]) == {
        "rmse",
        "mae",
        "r2",
    }
    assert (
        m["run"]["reference"] == "true"
        and m["run"]["n_episode"] == 2
        and m["run"]["mode"] == "stateful"
    )
    assert list(m["compare"]) == ["ARX", "Structured"]
    # the checkpoint and the dataset lie outside --out: recorded absolute
    assert m["run"]["checkpoint"] == str((run / "best.pt").resolve())
    assert m["run"]["dataset"] == str(dataset_dir.resolve())
    assert (tmp_path / "ev" / "table.md").exists() and (tmp_path / "ev" / "cbe.png").exists()
    assert not (tmp_path / "ev" / "cbe_step_0201.png").exists()  # max_figures = 1
    # a second model in the table
    rc = main(
        [
            "evaluate",
            str(run / "best.pt"),
            str(dataset_dir),
            "--out",
            str(tmp_path / "ev2"),
            "--compare",
            f"LAST={run / 'last.pt'}",
            "--no-arx",
            "--no-structured",
        ]
    )
    assert rc == 0
    m2 = json.loads((tmp_path / "ev2" / "metrics.json").read_text())
    assert list(m2["compare"]) == ["LAST"]


def test_cli_errors_are_one_line(tmp_path, dataset_dir, capsys):
    bad = tmp_path / "bad.pt"
    bad.write_bytes(b"junk")
    rc = main(["evaluate", str(bad), str(dataset_dir), "--out", str(tmp_path / "e")])
    err = capsys.readouterr().err
    assert rc != 0 and err.startswith("exsur: error:") and err.count("\n") == 1
    rc = main(["train", str(tmp_path / "missing"), "--out", str(tmp_path / "r")])
    assert rc != 0 and "dataset folder not found" in capsys.readouterr().err
    rc = main(
        ["train", str(dataset_dir), "--out", str(tmp_path / "r"), "--preset", "no-such-preset"]
    )
    assert rc != 0 and "unknown preset" in capsys.readouterr().err
