"""exsur info: a checkpoint's description (machine, network, training, validation) read back."""

from __future__ import annotations

import json
import math

import pytest

from excavator_surrogate.cli import main
from excavator_surrogate.data import write_dataset
from excavator_surrogate.data.dataset import load_dataset
from excavator_surrogate.errors import CheckpointError
from excavator_surrogate.evaluate.card import LOW_R2, card_markdown, model_card, public
from excavator_surrogate.spec import JointSpec, MachineSpec
from excavator_surrogate.surrogate.bands import calibrate_checkpoint
from excavator_surrogate.surrogate.checkpoint import save_checkpoint
from excavator_surrogate.surrogate.ensemble import merge
from excavator_surrogate.surrogate.synthetic import synthetic_spec, synthetic_split
from tests.helpers.surrogates import make_surrogate, tiny_surrogate


@pytest.fixture(scope="module")
def dataset_dir(tmp_path_factory):
    spec = synthetic_spec(2)
    items = synthetic_split(spec, n_train=2, n_val=1, n_test=1, n_step=120, noise=0.001)
    return write_dataset(tmp_path_factory.mktemp("ds") / "data", items)


def _training(*, cut: bool, n: int = 1) -> dict:
    member = {
        "epochs_planned": 12,
        "epochs_done": 5 if cut else 12,
        "stopped": "budget" if cut else "planned",
        "budget_cut": cut,
        "max_train_seconds": 30.0,
        "numerics": "native",
    }
    env = {"cpu": "Test CPU", "torch": "2.x", "torch_cpu_capability": "AVX2"}
    rec = {"epochs_planned": 12, "budget_cut": cut, "numerics": "native", "environment": env}
    if n > 1:
        rec["members"] = [dict(member) for _ in range(n)]
    else:
        rec.update(member)
    return rec


def test_a_cut_single_network_is_described_with_its_notes(tmp_path, dataset_dir):
    ds = load_dataset(dataset_dir)
    sur = make_surrogate(ds.spec, ds.train, mode="stateful", window=5, hidden=8, end_stops=True)
    sur.train_config = {"seed": 7, "epochs": 12, "feedback": "free", "lr": 0.002}
    sur.metrics = {
        "val": {
            "val_error": 0.5,
            "theta_r2": [0.99, 0.42],
            "theta_rmse": [0.01, math.pi / 180.0],
            "omega_rmse": [0.02, 0.03],
        },
        "training": _training(cut=True),
    }
    ckpt = save_checkpoint(tmp_path / "one.pt", sur)
    card = model_card(ckpt)
    assert card["machine"]["rate_hz"] == ds.spec.rate_hz
    assert [j["name"] for j in card["machine"]["joints"]] == list(ds.spec.names)
    net = card["network"]
    assert net["n_member"] == 1 and net["hidden"] == 8 and net["mode"] == "stateful"
    assert net["n_param"] == sum(p.numel() for p in sur.net.parameters())
    assert card["training"]["seed"] == 7 and card["training"]["budget_cut"]
    assert card["training"]["epochs_done"] == [5] and card["training"]["max_train_seconds"] == 30
    assert card["validation"]["theta_r2"] == {ds.spec.names[0]: 0.99, ds.spec.names[1]: 0.42}
    notes = card["warnings"]
    assert any("wall-time cap cut training short" in w for w in notes)
    assert any(f"below {LOW_R2}: {ds.spec.names[1]} 0.420" in w for w in notes)
    assert any("no coverage record" in w for w in notes)
    assert not any("end stops off" in w or "in-sample" in w for w in notes)
    text = card_markdown(card)
    for head in ("## Machine", "## Network", "## Training", "## Validation (free run)"):
        assert head in text
    assert "One 2 × 8 LSTM" in text and "Seed 7" in text and "trained on its own free run" in text
    assert "**Warning: the wall-time cap cut training short**" in text  # the report's line
    assert "Trained on Test CPU" in text
    # the second joint's angle RMSE of 1 degree, printed in degrees
    assert "| angle RMSE | 0.57 ° | 1.00 ° |" in text
    assert "No calibrated uncertainty bands" in text
    assert card["training"]["pace"] is None and "Time on this computer" not in text  # no logs
    # with its log beside it: how fast this computer trained it, against the cap
    rows = "epoch,time_s,epoch_s,val_s,ref_epoch_s\n" + "".join(
        f"{e},{6 * (e + 1)},5.0,1.0,4.0\n" for e in range(5)
    )
    (tmp_path / "log.csv").write_text(rows)
    card = model_card(ckpt)
    assert card["training"]["pace"]["pace"] == 1.25 and card["training"]["pace"]["longest_s"] == 30
    text = card_markdown(card)
    assert "their training steps took 25 s, 1.25x the reference machine's 20 s" in text
    assert "The longest network ran 30 s and its 30-s cap cut it." in text


def test_a_calibrated_ensemble_lists_its_members_and_bands(tmp_path, dataset_dir):
    ds = load_dataset(dataset_dir)
    surs = [
        make_surrogate(ds.spec, ds.train, mode="stateful", window=5, hidden=8, seed=s)
        for s in (0, 1)
    ]
    for k, s in enumerate(surs):
        s.train_config = {"seed": k}
        s.metrics = {"training": _training(cut=False), "best_val_error": 0.1 + k, "epoch": 3}
    ckpt = save_checkpoint(tmp_path / "ens.pt", merge(surs))
    calibrate_checkpoint(ckpt, ds.val, ds.train)
    card = model_card(ckpt)
    assert card["training"]["trained_on_validation"] is False
    assert card["network"]["n_member"] == 2 and card["network"]["member_hidden"] == [8, 8]
    assert [m["seed"] for m in card["members"]] == [0, 1]
    assert card["uncertainty"]["levels"] == [0.5, 0.9]
    n_train = sum(len(e.theta) for e in ds.train)
    assert 0 < card["coverage"]["n_sample"] <= n_train  # (a sample per step with a successor)
    assert any("end stops off" in w for w in card["warnings"])
    text = card_markdown(card)
    assert "An ensemble of 2 LSTM networks of 8 units each, merged into one 2 × 16 LSTM" in text
    assert "| 1 | 1 |" in text and "Calibrated uncertainty bands at 50%, 90%" in text
    # where the calibration's free runs came from: training runs are in-sample, not
    # "validation steps" (all 570 of a tiny run's steps had been called validation steps)
    unc = card["uncertainty"]
    n_val, n_tr = unc["n_run"], unc["n_train_run"]
    assert n_val == len(ds.val) and n_tr > 0
    assert (
        f"(from {unc['n_step']:,} free-run steps of {n_val} validation and {n_tr} training runs)"
        in text
    )
    assert "Coverage record of" in text


def test_linear_joints_are_printed_in_their_own_unit(tmp_path):
    spec = MachineSpec(
        (
            JointSpec("swing", periodic=True),
            JointSpec("boom", kind="linear", unit="mm", theta_min=0.1, theta_max=1.6),
        ),
        name="stroke-rig",
    )
    sur = tiny_surrogate(spec, hidden=8)
    sur.train_config = {"train_on_val": True}  # the recipe's h1-dev way: validation in-sample
    sur.metrics = {
        "val": {"theta_r2": [0.97, 0.98], "theta_rmse": [0.01, 0.004], "omega_rmse": [0.1, 0.002]}
    }
    card = model_card(save_checkpoint(tmp_path / "lin.pt", sur))
    boom = card["machine"]["joints"][1]
    assert boom["kind"] == "linear" and boom["unit"] == "mm" and boom["theta_max"] == 1.6
    text = card_markdown(card)
    assert "| boom | linear | 100.0 … 1600.0 mm |" in text
    assert "4.000 mm" in text and "2.000 mm/s" in text  # stored in m, printed in mm
    assert "no validation scores" not in " ".join(card["warnings"])
    assert any("validation scores are in-sample" in w for w in card["warnings"])
    assert "## Validation (free run; in-sample)" in text


def test_exsur_info_prints_text_or_json_and_refuses_bad_files(tmp_path, dataset_dir, capsys):
    ds = load_dataset(dataset_dir)
    sur = make_surrogate(ds.spec, ds.train, mode="stateful", window=5, hidden=8)
    sur.metrics = {"val": {"theta_r2": [float("nan"), None]}}  # diverged; not recorded
    ckpt = save_checkpoint(tmp_path / "m" / "best.pt", sur)
    assert main(["info", str(ckpt)]) == 0
    text = capsys.readouterr().out
    assert text.startswith(f"# {ckpt}\n") and "| angle R² | — | — |" in text
    assert main(["info", str(ckpt), "--json"]) == 0
    got = json.loads(capsys.readouterr().out)
    assert got == json.loads(json.dumps(public(model_card(ckpt))))
    assert got["validation"]["theta_r2"][ds.spec.names[0]] is None  # NaN: null, not an error
    assert "_training_record" not in got
    # a folder names the checkpoint inside it; a corrupt file is one line, exit code 2
    assert main(["info", str(tmp_path / "m")]) == 2
    err = capsys.readouterr().err
    assert f"is not a dataset; give a checkpoint file, e.g. {ckpt}, or a dataset folder" in err
    run = tmp_path / "run"  # an exsur run folder: the model is in model/
    save_checkpoint(run / "model" / "best.pt", sur)
    assert main(["info", str(run)]) == 2
    assert f"e.g. {run / 'model' / 'best.pt'}" in capsys.readouterr().err
    with pytest.raises(CheckpointError, match="is a folder, not a checkpoint file"):
        model_card(run)  # the Python API names the file inside too
    bad = tmp_path / "bad.pt"
    bad.write_bytes(b"not a checkpoint")
    assert main(["info", str(bad)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "not a readable exsur checkpoint" in err[0]
    # a file not named as a checkpoint: what info reads instead
    notes = tmp_path / "notes.txt"
    notes.write_text("hello")
    assert main(["info", str(notes)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].endswith(
        "notes.txt: not a file exsur info reads; it describes a checkpoint (.pt), an ONNX "
        "export (.onnx), a dataset folder, an episode file (.parquet) or a raw log exsur "
        "import reads"
    )


def test_a_linear_joints_card_holds_its_whole_linkage():
    """The card alone turns strokes into angles: a, b, phi and the stroke offset l0."""
    from excavator_surrogate.evaluate.card import _joint
    from excavator_surrogate.spec import Linkage

    link = Linkage(a=1.2, b=0.4, phi=0.1, l0=0.9)
    j = JointSpec("boom", kind="linear", unit="mm", theta_min=0.0, theta_max=0.5, linkage=link)
    assert _joint(j)["linkage"] == {"a": 1.2, "b": 0.4, "phi": 0.1, "l0": 0.9}


def test_a_merged_checkpoint_says_the_merge_scored_nothing(tmp_path, dataset_dir):
    """``exsur merge`` stores no validation scores; the card said the model was "trained
    without a validation split", which its members were not."""
    ds = load_dataset(dataset_dir)
    paths = []
    for s in (0, 1):
        sur = make_surrogate(ds.spec, ds.train, mode="stateful", window=5, hidden=8, seed=s)
        sur.metrics = {"val_error": 0.5, "epoch": 3}
        paths.append(str(save_checkpoint(tmp_path / f"m{s}.pt", sur)))
    assert main(["merge", *paths, "--out", str(tmp_path / "ens.pt"), "-q"]) == 0
    warnings = model_card(tmp_path / "ens.pt")["warnings"]
    assert (
        "no validation scores stored (merged by exsur merge, which scores nothing; "
        "exsur evaluate CKPT DATASET scores the merged model)"
    ) in warnings
    assert not any("trained without a validation split" in w for w in warnings)
    # a single network without validation scores keeps its reason
    assert (
        "no validation scores stored (trained without a validation split)"
        in (model_card(paths[0])["warnings"])
    )
