"""Users' logs end to end: ``exsur run --logs`` and ``exsur train`` without a preset."""

from __future__ import annotations

import json
import re
import tomllib
from pathlib import Path

import numpy as np

from excavator_surrogate.surrogate.angles import envelope
from excavator_surrogate.surrogate.checkpoint import load_checkpoint

# The data-driven recipe with a tiny network and one short epoch (the recipe itself is
# tested in tests/surrogate/test_auto.py).
TINY = """extends = "real"
[train]
hidden = 8
head_hidden = 8
layers = 1
epochs = 1
members = 1
max_train_seconds = 0.0
tensorboard = false
[evaluate]
max_figures = 1
"""


def _open_mapping(arm3_dir: Path, tmp_path: Path) -> Path:
    """arm3.toml without the declared limits (as most users' mappings are)."""
    text = re.sub(r"^limits = .*$", "", (arm3_dir / "arm3.toml").read_text(), flags=re.M)
    out = tmp_path / "open.toml"
    out.write_text(text)
    return out


def test_run_logs_writes_the_report_folder(arm3_dir: Path, tmp_path: Path, cli) -> None:
    preset = tmp_path / "tiny-real.toml"
    preset.write_text(TINY)
    out = tmp_path / "report"
    mapping = _open_mapping(arm3_dir, tmp_path)
    rc, _, err = cli(
        "run", "--logs", arm3_dir / "logs", "--mapping", mapping, "--preset", preset, "--out", out
    )
    assert rc == 0, err
    for f in ("report.md", "metrics.json", "table.md", "cbe.png", "config.toml", "model/best.pt"):
        assert (out / f).is_file(), f
    assert (out / "data" / "manifest.json").is_file()
    metrics = json.loads((out / "metrics.json").read_text())
    assert set(metrics["theta"]) == {"boom", "arm", "bucket"}
    assert "ARX" in json.dumps(metrics)
    # the imported dataset and the model are recorded relative to the run folder
    assert metrics["run"]["dataset"] == "data" and metrics["run"]["checkpoint"] == "model/best.pt"
    cfg = tomllib.loads((out / "config.toml").read_text())
    assert cfg["logs"]["mapping"] == str(mapping)
    assert cfg["train"]["hidden"] == 8 and cfg["train"]["mode"] == "stateful"
    assert any("sub-sequences" in w for w in cfg["recipe"]["why"])
    assert "simulate" not in cfg
    # the mapping declares no limits: the model's envelope comes from the training data
    sur = load_checkpoint(out / "model" / "best.pt")
    lo, hi, w = envelope(sur.spec)
    assert np.isfinite(lo).all() and np.isfinite(hi).all() and np.isfinite(w).all()
    assert "recipe" in err
    assert "planned work: " in err and err.index("recipe: ") < err.index("planned work: ")
    # the dry run of the same command: the same import, recipe and config.toml, in a moment
    rc, text, err = cli(
        "run", "--logs", arm3_dir / "logs", "--mapping", mapping, "--preset", preset, "--dry-run"
    )
    assert rc == 0, err
    assert text.startswith(f"preset: tiny-real\ndata: 4 log(s) imported with {mapping}: ")
    assert tomllib.loads(text[text.index("config.toml:\n") + 13 :]) == cfg
    assert "planned work of the surrogate" in text and "(1 plain member(s)" in text


def test_the_dry_run_imports_into_a_folder_it_removes(
    arm3_dir: Path, tmp_path: Path, cli, monkeypatch
) -> None:
    """``exsur run --logs --dry-run`` writes nothing: not ``--out``, no temporary folder left;
    a log the run would refuse, it refuses in the same words."""
    import tempfile

    temp = tmp_path / "temp"
    temp.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(temp))
    out = tmp_path / "never"
    mapping = _open_mapping(arm3_dir, tmp_path)
    argv = ["run", "--logs", arm3_dir / "logs", "--mapping", mapping, "--out", out]
    rc, text, err = cli(*argv, "--dry-run")
    assert rc == 0, err
    assert "recipe (docs/real.md):" in text and "evaluate: " in text
    assert not out.exists() and list(temp.iterdir()) == []
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "run01.csv").write_text(
        (arm3_dir / "logs" / "run01.csv").read_text().replace("0.", "x", 1)
    )
    argv[2] = bad
    rc_dry, _, err_dry = cli(*argv, "--dry-run")
    rc_run, _, err_run = cli(*argv)
    assert (
        rc_dry == rc_run != 0
        and err_dry.strip().splitlines()[-1] == err_run.strip().splitlines()[-1]
    )
    assert len(err_dry.strip().splitlines()) == 1 and "run01.csv" in err_dry
    assert not out.exists() and list(temp.iterdir()) == []


def test_run_logs_needs_the_mapping(arm3_dir: Path, tmp_path: Path, cli) -> None:
    rc, _, err = cli("run", "--logs", arm3_dir / "logs", "--out", tmp_path / "r")
    assert rc == 2 and "--mapping" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "r").exists()


def test_train_without_a_preset_uses_the_recipe(arm3_dir: Path, tmp_path: Path, cli) -> None:
    ds = tmp_path / "ds"
    assert (
        cli("import", arm3_dir / "logs", "--mapping", arm3_dir / "arm3.toml", "--out", ds)[0] == 0
    )
    out = tmp_path / "m"
    rc, stdout, err = cli("train", ds, "--out", out, "--epochs", "1", "--members", "1")
    assert rc == 0, err
    assert stdout.strip().endswith("best.pt")
    cfg = tomllib.loads((out / "config.toml").read_text())
    assert cfg["recipe"]["name"] == "auto" and cfg["train"]["mode"] == "stateful"
    assert "recipe: window" in err and "planned work: " in err
