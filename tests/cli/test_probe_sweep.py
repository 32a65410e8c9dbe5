"""Issue 25 probe: ``exsur sweep --trial-seconds -1`` failed every trial inside Optuna (one
traceback each) and still exited 0 with an empty report; now one line before any trial."""

from __future__ import annotations

from pathlib import Path

import pytest

from excavator_surrogate.cli import main
from excavator_surrogate.errors import ConfigError


def test_a_negative_trial_budget_is_refused_before_the_study(
    data_dir: Path, tmp_path: Path, capsys
) -> None:
    pytest.importorskip("optuna")
    from excavator_surrogate.scale.sweep import SweepConfig

    out = tmp_path / "sw"
    argv = ["sweep", data_dir / "ds3", "--trials", "1", "--trial-seconds", "-1", "--out", out]
    rc = main([str(a) for a in argv])
    err = capsys.readouterr().err
    assert rc == 2, err
    assert "Traceback" not in err and "Trial 0 failed" not in err, err
    assert err.rstrip("\n").split("\n")[-1] == (
        "exsur: error: [sweep] max_train_seconds = -1.0 must be >= 0 (0 = unlimited; "
        "--trial-seconds)"
    )
    assert not (out / "sweep.json").exists()
    with pytest.raises(ConfigError, match="max_train_seconds"):
        SweepConfig(max_train_seconds=-1.0)
    assert SweepConfig(max_train_seconds=0.0).max_train_seconds == 0.0
