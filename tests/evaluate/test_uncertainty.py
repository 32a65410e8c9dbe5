"""exsur evaluate reports the ensemble's bands (coverage, width) and the out-of-distribution share."""

from __future__ import annotations

import json

import pytest

from excavator_surrogate.data import write_dataset
from excavator_surrogate.data.dataset import load_dataset
from excavator_surrogate.evaluate import evaluate_checkpoint
from excavator_surrogate.evaluate.uncertainty import uncertainty_markdown
from excavator_surrogate.surrogate.bands import calibrate_checkpoint
from excavator_surrogate.surrogate.checkpoint import save_checkpoint
from excavator_surrogate.surrogate.ensemble import merge
from excavator_surrogate.surrogate.synthetic import synthetic_spec, synthetic_split
from excavator_surrogate.surrogate.uncertainty import NO_MEMBERS
from tests.helpers.surrogates import make_surrogate


@pytest.fixture(scope="module")
def dataset_dir(tmp_path_factory):
    spec = synthetic_spec(2)
    items = synthetic_split(spec, n_train=2, n_val=2, n_test=2, n_step=120, noise=0.001)
    return write_dataset(tmp_path_factory.mktemp("ds") / "data", items)


def _checkpoint(path, ds, *, members: int):
    kw = dict(mode="stateful", window=5)
    surs = [make_surrogate(ds.spec, ds.train, seed=s, hidden=8, **kw) for s in range(members)]
    sur = merge(surs) if members > 1 else surs[0]
    save_checkpoint(path, sur)
    calibrate_checkpoint(path, ds.val, ds.train)
    return path


def test_evaluate_reports_band_coverage_width_and_flags(tmp_path, dataset_dir):
    ds = load_dataset(dataset_dir)
    ckpt = _checkpoint(tmp_path / "ens.pt", ds, members=2)
    res = evaluate_checkpoint(ckpt, ds, out=tmp_path / "ev", arx=False, max_figures=1)
    unc = json.loads((tmp_path / "ev" / "metrics.json").read_text())["uncertainty"]
    assert unc == json.loads(json.dumps(res["uncertainty"]))
    assert unc["available"] and unc["levels"] == [0.5, 0.9] and not unc["notes"]
    for q in ("theta", "omega"):
        for n in ds.spec.names:
            d = unc[q][n]
            assert 0.0 <= d["coverage_50"] <= d["coverage_90"] <= 1.0
            assert 0.0 < d["width_50"] <= d["width_90"]
    assert set(unc["ood"]) == {*ds.spec.names, "any"}
    table = (tmp_path / "ev" / "table.md").read_text()
    assert "## Uncertainty and out-of-distribution" in table and "90 % band coverage" in table
    assert (tmp_path / "ev" / "cbe.png").stat().st_size > 0


def test_evaluate_says_a_single_network_has_no_uncertainty(tmp_path, dataset_dir):
    ds = load_dataset(dataset_dir)
    ckpt = _checkpoint(tmp_path / "one.pt", ds, members=1)
    res = evaluate_checkpoint(ckpt, ds, out=tmp_path / "ev", arx=False, figure=False)
    unc = res["uncertainty"]
    assert not unc["available"] and unc["notes"] == [NO_MEMBERS]
    assert "theta" not in unc and unc["ood"] is not None  # the flags need no members
    assert NO_MEMBERS in (tmp_path / "ev" / "table.md").read_text()


def test_uncertainty_table_lists_every_joint_and_band():
    unc = {
        "available": True,
        "notes": [],
        "levels": [0.5, 0.9],
        "theta": {"a": {"coverage_50": 0.5, "width_50": 0.1, "coverage_90": 0.9, "width_90": 0.3}},
        "omega": {"a": {"coverage_50": 0.4, "width_50": 0.2, "coverage_90": 0.8, "width_90": 0.5}},
        "ood": {"a": 0.02, "any": 0.02},
    }
    md = uncertainty_markdown(unc, ["a"])
    rows = [r for r in md.splitlines() if r.startswith("| θ") or r.startswith("| ω")]
    assert rows == [
        "| θ [rad] | a | 50 % | 0.1000 | 90 % | 0.3000 |",
        "| ω [rad/s] | a | 40 % | 0.2000 | 80 % | 0.5000 |",
    ]
    assert "any joint 2 %" in md
    # a few steps of a long run are not "0 %" beside the figure's red marks
    few = {**unc, "ood": {"a": 6 / 1770, "any": 6 / 1770}}
    assert "a 0.3 %; any joint 0.3 %." in uncertainty_markdown(few, ["a"])
    rare = {**unc, "ood": {"a": 0.0, "any": 1 / 5000}}
    assert "a 0 %; any joint < 0.1 %." in uncertainty_markdown(rare, ["a"])
    # a stroke (stored in m) in its mapping's unit, as the CBE table prints it
    md = uncertainty_markdown(unc, ["a"], units={"a": (1000.0, "mm")})
    rows = [r for r in md.splitlines() if r.startswith("| θ") or r.startswith("| ω")]
    assert rows == [
        "| θ | a [mm] | 50 % | 100.0000 | 90 % | 300.0000 |",
        "| ω | a [mm/s] | 40 % | 200.0000 | 80 % | 500.0000 |",
    ]


def test_run_report_shows_the_uncertainty_section_only_when_scored():
    from excavator_surrogate.evaluate.run_report import ReportContext, render_run_report

    base = {
        "theta": {"a": {"rmse": 0.1, "mae": 0.1, "r2": 0.9}},
        "omega": {"a": {"rmse": 0.1, "mae": 0.1, "r2": 0.8}},
        "run": {"split": "test"},
    }
    ctx = ReportContext(name="tiny", spec_names=("a",), table_md="")
    assert "Uncertainty" not in render_run_report(base, ctx)
    unc = {"available": False, "notes": [NO_MEMBERS], "ood": {"a": 0.25, "any": 0.25}}
    text = render_run_report({**base, "uncertainty": unc}, ctx)
    assert "## Uncertainty and out-of-distribution" in text and NO_MEMBERS in text
    assert "any joint 25 %" in text


def test_run_report_shows_the_uncertainty_section_once_beside_the_table_md_that_holds_it():
    from excavator_surrogate.evaluate.run_report import ReportContext, render_run_report
    from excavator_surrogate.evaluate.uncertainty import UNCERTAINTY_HEADING, uncertainty_markdown

    unc = {"available": False, "notes": [NO_MEMBERS], "ood": {"a": 0.25, "any": 0.25}}
    # table.md as evaluate_checkpoint writes it: the CBE table, then the uncertainty section
    table_md = (
        "# Closed-loop behavioural equivalence (CBE)\n\n| Type | Joint |\n|---|---|\n"
        "| θ | a |\n\n" + uncertainty_markdown(unc, ["a"])
    )
    base = {
        "theta": {"a": {"rmse": 0.1, "mae": 0.1, "r2": 0.9}},
        "omega": {"a": {"rmse": 0.1, "mae": 0.1, "r2": 0.8}},
        "run": {"split": "test"},
        "uncertainty": unc,
    }
    text = render_run_report(base, ReportContext(name="tiny", spec_names=("a",), table_md=table_md))
    assert text.count(UNCERTAINTY_HEADING) == 1
    assert text.count("any joint 25 %") == 1
    assert "| θ | a |" in text.split("## CBE table")[1]  # the table itself is still there


def test_exsur_calibrate_stores_the_records_and_refuses_other_machines(
    tmp_path, dataset_dir, capsys
):
    from excavator_surrogate.cli import main
    from excavator_surrogate.surrogate.checkpoint import load_checkpoint
    from excavator_surrogate.surrogate.uncertainty import stored_calibration, stored_coverage

    ds = load_dataset(dataset_dir)
    surs = [make_surrogate(ds.spec, ds.train, mode="stateful", window=5, seed=s) for s in (0, 1)]
    ckpt = save_checkpoint(tmp_path / "ens.pt", merge(surs))
    assert main(["calibrate", str(ckpt), str(dataset_dir), "--design", "independent"]) == 0
    out = capsys.readouterr().out
    assert "bands calibrated on" in out and f"{len(ds.val)} validation and " in out
    back = load_checkpoint(ckpt)
    assert stored_calibration(back).design == "independent" and stored_coverage(back) is not None
    assert stored_calibration(back).n_train_run == len(ds.train)
    # --train-runs 0: the validation runs alone (the first rule); a negative count is one line
    assert main(["calibrate", str(ckpt), str(dataset_dir), "--train-runs", "0"]) == 0
    assert "0 training runs" in capsys.readouterr().out
    assert stored_calibration(load_checkpoint(ckpt)).rule == "val"
    assert main(["calibrate", str(ckpt), str(dataset_dir), "--train-runs", "-1"]) == 2
    assert "--train-runs must be >= 0" in capsys.readouterr().err
    other = write_dataset(
        tmp_path / "other", synthetic_split(synthetic_spec(3), n_train=1, n_val=1, n_test=1)
    )
    assert main(["calibrate", str(ckpt), str(other)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("exsur: error:") and "Traceback" not in err


def test_bands_that_covered_far_less_than_their_level_are_named():
    from excavator_surrogate.evaluate.uncertainty import SHORTFALL, undercovered

    def band(c50: float, c90: float) -> dict:
        return {"coverage_50": c50, "width_50": 0.1, "coverage_90": c90, "width_90": 0.3}

    unc = {
        "available": True,
        "notes": [],
        "levels": [0.5, 0.9],
        # a: both bands fine; b: only its 90 % band short; c: its 50 % band short
        "theta": {"a": band(0.55, 0.88), "b": band(0.45, 0.61), "c": band(0.2, 0.95)},
        "omega": {"a": band(0.5, 0.9), "b": band(0.5, 0.9), "c": band(0.5, 0.9 - SHORTFALL / 2)},
        "ood": None,
    }
    assert undercovered(unc, ["a", "b", "c"]) == [
        ("theta", "b", 90, 0.61),
        ("theta", "c", 50, 0.2),
    ]
    md = uncertainty_markdown(unc, ["a", "b", "c"])
    assert "**The bands were too narrow on these runs** (coverage of the 50 % / 90 % bands): " in md
    assert "θ b 45 % / 61 %, θ c 20 % / 95 %. They were calibrated on other runs" in md
    assert "θ a" not in md.split("too narrow")[1] and "ω" not in md.split("too narrow")[1]
    fine = {**unc, "theta": {n: band(0.5, 0.9) for n in "abc"}}
    assert "too narrow" not in uncertainty_markdown(fine, ["a", "b", "c"])
    assert undercovered({"available": False, "notes": ["single network"]}, ["a"]) == []


def test_run_report_prints_a_strokes_bands_in_its_unit():
    from excavator_surrogate.evaluate.run_report import ReportContext, render_run_report

    unc = {
        "available": True,
        "notes": [],
        "levels": [0.5],
        "theta": {"a": {"coverage_50": 0.5, "width_50": 0.002}},
        "omega": {"a": {"coverage_50": 0.4, "width_50": 0.01}},
        "ood": None,
    }
    metrics = {
        "theta": {"a": {"rmse": 0.001, "mae": 0.001, "r2": 0.9}},
        "omega": {"a": {"rmse": 0.01, "mae": 0.01, "r2": 0.8}},
        "run": {"split": "test", "units": {"a": {"display": "mm"}}},
        "uncertainty": unc,
    }
    text = render_run_report(metrics, ReportContext(name="s", spec_names=("a",), table_md=""))
    assert "| θ | a [mm] | 50 % | 2.0000 |" in text and "| ω | a [mm/s] | 40 % | 10.0000 |" in text
