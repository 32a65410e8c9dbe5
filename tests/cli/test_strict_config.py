"""Issue 25 at the command line: a misspelled table, a knob that will not be read, a size that
cannot fit and a budget of zero are one-line errors before anything runs."""

from __future__ import annotations

import pytest

from excavator_surrogate.cli import main


def _fails(capsys: pytest.CaptureFixture[str], *argv: object) -> str:
    """Run ``exsur argv``; assert a non-zero exit with ONE error line; return that line."""
    try:
        rc = main([str(a) for a in argv])
    except SystemExit as e:  # argparse errors
        rc = e.code
    assert rc not in (0, None)
    err = capsys.readouterr().err.strip().splitlines()
    assert err and "Traceback" not in "\n".join(err)
    return err[-1]


def test_a_misspelled_table_in_a_preset_file_is_an_error(capsys, data_dir, tmp_path):
    preset = tmp_path / "typo.toml"
    preset.write_text((data_dir / "tiny.toml").read_text() + "\n[trian]\nepochs = 1\n")
    out = tmp_path / "m"
    line = _fails(capsys, "train", data_dir / "ds3", "--out", out, "--preset", preset)
    assert f"{preset}: unknown table [trian] (did you mean [train]?)" in line
    assert not out.exists()


def test_a_misspelled_nested_key_names_the_file_table_and_close_match(capsys, tmp_path):
    preset = tmp_path / "sim.toml"
    preset.write_text('extends = "tiny"\n[simulate.excitation.multisine]\nf_mx = 3.0\n')
    line = _fails(capsys, "simulate", "--preset", preset, "--out", tmp_path / "d")
    assert f"{preset} [simulate.excitation.multisine]: unknown key(s) ['f_mx'] for" in line
    assert "(did you mean 'f_max'?)" in line and "valid keys: n_component" in line


def test_a_typo_in_an_extended_preset_file_names_that_file(capsys, tmp_path):
    base = tmp_path / "base.toml"
    base.write_text("[simulate]\nn_trian = 2\n")
    top = tmp_path / "top.toml"
    top.write_text(f'extends = "{base}"\n[simulate]\nn_val = 1\n')
    line = _fails(capsys, "config", "show", top)
    assert (
        f"{base} [simulate]: unknown key(s) ['n_trian'] for SimulateConfig (did you mean 'n_train'?)"
        in line
    )


def test_clean_knobs_without_cleaning_are_refused(capsys, tmp_path):
    line = _fails(
        capsys, "run", "--preset", "tiny", "--out", tmp_path / "r", "--set", "clean.method=rts"
    )
    assert "--set clean.method: not read" in line and "run.clean = false" in line
    assert not (tmp_path / "r").exists()


def test_simulate_knobs_with_data_are_refused(capsys, data_dir, tmp_path):
    argv = ["run", "--preset", "tiny", "--data", data_dir / "ds3", "--out", tmp_path / "r"]
    line = _fails(capsys, *argv, "--set", "simulate.n_train=3")
    assert "--set simulate.n_train: not read, this run trains on --data" in line


def test_a_runs_evaluate_reference_is_refused_for_run_reference(capsys, data_dir, tmp_path):
    argv = ["run", "--preset", "tiny", "--data", data_dir / "ds3", "--out", tmp_path / "r"]
    line = _fails(capsys, *argv, "--set", 'evaluate.reference="true"')
    assert "--set evaluate.reference: not read, exsur run scores against run.reference" in line
    assert "--set run.reference=" in line and not (tmp_path / "r").exists()


def test_sensor_and_hydraulic_knobs_of_a_switched_off_model_are_refused(capsys, tmp_path):
    out = tmp_path / "d"
    line = _fails(
        capsys,
        "simulate",
        "--preset",
        "tiny",
        "--out",
        out,
        "--set",
        "simulate.sensor.theta_white_std=0.01",
    )
    assert "--set simulate.sensor.theta_white_std: not read, simulate.sensors = false" in line
    line = _fails(
        capsys,
        "simulate",
        "--preset",
        "tiny",
        "--out",
        out,
        "--set",
        "simulate.hydraulics.drift=true",
    )
    assert "--set simulate.hydraulics.drift: not read" in line and 'plant = "ideal"' in line
    assert not out.exists()


def test_a_dataset_too_large_for_memory_is_refused_before_simulating(capsys, tmp_path):
    out = tmp_path / "d"
    line = _fails(
        capsys, "simulate", "--preset", "tiny", "--out", out, "--set", "simulate.n_train=100000000"
    )
    assert line.startswith("exsur: error: [simulate]") and "samples" in line and "available" in line
    assert not out.exists()


@pytest.mark.parametrize("value", ["0", "-1", "nan"])
def test_a_time_budget_must_be_positive(capsys, data_dir, tmp_path, value):
    line = _fails(
        capsys, "train", data_dir / "ds3", "--out", tmp_path / "m", f"--max-seconds={value}"
    )
    assert f"--max-seconds {value}: give a finite number > 0 [s]" in line
    line = _fails(capsys, "run", "--out", tmp_path / "r", f"--max-train-seconds={value}")
    assert f"--max-train-seconds {value}: give a finite number > 0" in line


@pytest.mark.parametrize(
    ("knob", "says"),
    [
        ("train.hidden=100000000", "[train] hidden = 100000000"),
        ("train.seed=-5", "[train] seed = -5 must be >= 0"),
        ("train.lr=1e308", "[train] lr = 1e+308 must be in (0, 1]"),
    ],
)
def test_out_of_range_train_knobs_are_one_line(capsys, data_dir, tmp_path, knob, says):
    argv = ["train", data_dir / "ds3", "--out", tmp_path / "m", "--preset", data_dir / "tiny.toml"]
    line = _fails(capsys, *argv, "--set", knob)
    assert says in line
    assert not (tmp_path / "m").exists()


def test_merge_refuses_the_same_file_twice_and_a_member_with_nan_weights(capsys, model3, tmp_path):
    import torch

    ckpt = model3 / "best.pt"
    link = tmp_path / "same.pt"
    link.symlink_to(ckpt)
    line = _fails(capsys, "merge", ckpt, link, "--out", tmp_path / "e.pt")
    assert f"{link}: given twice (also as {ckpt})" in line
    raw = torch.load(ckpt, weights_only=True)
    name = next(k for k in raw["state_dict"] if k.endswith("weight_hh_l0"))
    raw["state_dict"][name] = torch.full_like(raw["state_dict"][name], float("nan"))
    bad = tmp_path / "nan.pt"
    torch.save(raw, bad)
    line = _fails(capsys, "merge", ckpt, bad, "--out", tmp_path / "e.pt")
    assert f"{bad}: non-finite weights" in line
    assert not (tmp_path / "e.pt").exists()


def test_a_checkpoint_too_large_to_build_is_refused_before_allocating(capsys, model3, tmp_path):
    import torch

    raw = torch.load(model3 / "best.pt", weights_only=True)
    raw["model"]["hidden"] = 300_000  # crafted: ~3e12 parameters, the weights stay small
    crafted = tmp_path / "huge.pt"
    torch.save(raw, crafted)
    line = _fails(capsys, "merge", crafted, model3 / "best.pt", "--out", tmp_path / "e.pt")
    assert f"{crafted}: the stored network (hidden = 300000" in line and "available" in line


def test_exsur_run_names_an_undefined_r2_instead_of_printing_minus_inf():
    from excavator_surrogate.evaluate.metrics import worst_r2_text
    from excavator_surrogate.evaluate.run_report import ReportContext, render_run_report

    m = {"theta": {"swing": {"r2": 0.9}, "boom": {"r2": None}, "arm": {"r2": 0.5}}}
    text = worst_r2_text(m, "theta")
    assert text.startswith("0.5000 (undefined for boom")
    assert worst_r2_text({"theta": {"a": {"r2": None}}}, "theta").startswith("undefined")
    # the report's headline says the same (it dropped the boom, and crashed with no R² at all)
    idle = {k: {"a": {"rmse": 0.0, "mae": 0.0, "r2": None}} for k in ("theta", "omega")}
    ctx = ReportContext(name="t", spec_names=("a",), table_md="")
    assert "worst-joint angle R² undefined (undefined for a" in render_run_report(idle, ctx)
    m = {**m, "omega": m["theta"]}
    ctx = ReportContext(name="t", spec_names=("swing", "boom", "arm"), table_md="")
    assert "R² 0.5000 (undefined for boom" in render_run_report(m, ctx)


def test_config_show_still_reads_every_shipped_preset(capsys):
    from excavator_surrogate.config import preset_names

    for name in preset_names():
        assert main(["config", "show", name]) == 0
    capsys.readouterr()
