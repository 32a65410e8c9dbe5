"""``exsur control --risk``: plumbed to the planner and the report, refused without members."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from excavator_surrogate.cli import main
from excavator_surrogate.surrogate.checkpoint import save_checkpoint
from excavator_surrogate.surrogate.ensemble import merge
from tests.helpers.surrogates import tiny_surrogate

FAST = ["--samples", "4", "--horizon", "3", "--time-scale", "0.1", "--no-rl", "--cpus", "1"]


def test_control_risk_reaches_the_planner_and_the_report(tmp_path: Path) -> None:
    ckpt = save_checkpoint(tmp_path / "ens.pt", merge([tiny_surrogate(seed=s) for s in range(2)]))
    out = tmp_path / "ctl"
    assert main(["control", str(ckpt), "--out", str(out), *FAST, "--risk", "0.5"]) == 0
    m = json.loads((out / "metrics.json").read_text())
    assert m["mppi_config"]["risk"] == 0.5
    assert "risk weight 0.5 (the surrogate's member spread" in (out / "report.md").read_text()
    assert m["mppi"]["runs"]["mppi_oracle"]["n_control_steps"] > 10  # the oracle: risk 0


@pytest.mark.parametrize(("risk", "word"), [("-1", "--risk must be >= 0"), ("1", "single network")])
def test_control_risk_errors_are_one_line(
    risk: str, word: str, tiny_ckpt: Path, tmp_path: Path, capsys
) -> None:
    rc = main(["control", str(tiny_ckpt), "--out", str(tmp_path / "o"), *FAST, "--risk", risk])
    assert rc == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and word in err[0]
    assert not (tmp_path / "o").exists()
