"""The evaluation says whether the wall-time cap cut the model's training short."""

from __future__ import annotations

import json
import math

from excavator_surrogate.evaluate.cbe import evaluate_checkpoint
from excavator_surrogate.evaluate.training_report import environment_markdown, training_markdown
from excavator_surrogate.training import train
from excavator_surrogate.training.ensembles import ensemble_training
from tests.helpers.training import tiny_dataset, tiny_train_config


def test_a_cut_run_is_reported_in_metrics_json_and_the_table(tmp_path):
    ds = tiny_dataset(2, n_train=2, n_step=120)
    cut = train(tiny_train_config(epochs=50, max_train_seconds=1e-3), ds, out=tmp_path / "cut")
    res = evaluate_checkpoint(cut, ds, out=tmp_path / "ev_cut", arx=False, figure=False)
    assert res["training"]["budget_cut"] is True
    saved = json.loads((tmp_path / "ev_cut" / "metrics.json").read_text())
    assert saved["training"]["epochs_done"] == 1 and saved["training"]["epochs_planned"] == 50
    table = (tmp_path / "ev_cut" / "table.md").read_text()
    assert "wall-time cap cut training short" in table and "1 of 50" in table

    full = train(tiny_train_config(epochs=2), ds, out=tmp_path / "full")
    res = evaluate_checkpoint(full, ds, out=tmp_path / "ev_full", arx=False, figure=False)
    assert res["training"]["budget_cut"] is False
    table = (tmp_path / "ev_full" / "table.md").read_text()
    assert "planned 2 epochs ran" in table
    # how fast this computer trained it, from log.csv (the tiny network is not the one the
    # reference times were measured on: no ratio); nothing of it in best.pt
    pace = res["pace"]
    assert pace["networks"] == 1 and pace["epochs"] == 2 and math.isnan(pace["pace"])
    assert (
        "Time on this computer: 1 network(s), 2 epochs in all" in table
        and "no wall-time cap" in table
    )
    assert "reference machine" not in table.split("Time on this computer")[1].split("\n")[0]
    # the computer and libraries it trained with, in metrics.json and in the table
    env = res["training"]["environment"]
    assert env["torch"] and env["torch_cpu_capability"] and env["numerics"] == "native"
    head = f"Trained on {env['cpu']} with {env['cpus']}, torch {env['torch']}"
    assert f"{head} ({env['torch_cpu_capability']}" in table


def test_ensembles_report_the_members_that_were_cut_and_old_checkpoints_nothing():
    members = [
        {"epochs_planned": 30, "epochs_done": 30, "budget_cut": False},
        {"epochs_planned": 30, "epochs_done": 12, "budget_cut": True},
    ]
    text = training_markdown({"budget_cut": True, "epochs_planned": 30, "members": members})
    assert "1 of 2 network(s): 12 of 30 planned epochs" in text
    assert training_markdown(None) == ""


def test_network_joints_scaled_to_validations_speed_get_a_line_and_unscaled_none():
    scaled = {"joints": ["arm", "bucket"], "gain": [1.142, 0.913], "why": "every one agrees"}
    text = training_markdown({"epochs_planned": 3, "net_val_gain": scaled})
    assert "Network joints at validation's speed: arm x1.142, bucket x0.913 (every one" in text
    kept = {"joints": [], "gain": [], "why": "no joint a network drives has ..."}
    assert "validation's speed" not in training_markdown(
        {"epochs_planned": 3, "net_val_gain": kept}
    )


def test_the_environment_line_and_an_ensembles_record():
    env = {
        "numerics": "portable",
        "cpu": "AMD EPYC (family 26, model 2)",
        "torch": "2.13.0+cpu",
        "torch_cpu_capability": "AVX2",
        "numpy": "2.4.6",
        "numpy_simd": ["X86_V3"],
        "numpy_blas": "openblas 0.3.31.188.0 (Haswell kernels)",
        "mujoco": None,
    }
    assert environment_markdown(env) == (
        "Trained on AMD EPYC (family 26, model 2), torch 2.13.0+cpu (AVX2 kernels), "
        "NumPy 2.4.6 (X86_V3; openblas 0.3.31.188.0 (Haswell kernels)); portable numerics.\n"
    )
    older = {k: v for k, v in env.items() if k != "numpy_blas"}  # a record of session 59
    assert "NumPy 2.4.6 (X86_V3);" in environment_markdown(older)
    assert environment_markdown(None) == "" and environment_markdown({}) == ""
    members = [{"epochs_planned": 3, "environment": env}, {"epochs_planned": 3, "environment": env}]
    assert ensemble_training(members)["environment"] == env
    assert "environment" not in ensemble_training([{"epochs_planned": 3}])  # older members


def test_joints_on_the_static_map_are_named():
    rec = {"chosen": ["swing"], "why": "swing follow(s) the static map: validation error 0.19"}
    text = training_markdown({"epochs_planned": 30, "static_map": rec})
    assert "Static valve map: swing" in text and "gain spread over the training log" in text
    assert "Static valve map" not in training_markdown({"static_map": {"chosen": []}, "x": 1})
    assert "instead of the network" in text
    par = training_markdown({"static_map": {**rec, "composition": "parallel"}})
    assert "in parallel with the network, which keeps reading its own angles" in par


def test_a_map_pinned_where_the_networks_validated_far_better_is_called_out():
    from excavator_surrogate.evaluate.training_report import PINNED_COST

    rec = {
        "names": ["swing", "boom", "bucket"],
        "chosen": ["swing", "boom", "bucket"],
        "pinned": ["swing", "bucket"],  # boom: chosen by the 5 % tie, not pinned
        "composition": "parallel",
        "val_theta_rmse_network": [0.10, 0.05, 0.068],
        "val_theta_rmse_map": [0.12, 0.20, 0.2227],
        "why": "swing, bucket: the map alone runs validation with angle R^2 >= 0.95",
    }
    text = training_markdown({"static_map": rec})
    assert "**The map was kept where the networks validated better**" in text
    assert "networks'): bucket 3.3×." in text  # not the swing (1.2x), nor the unpinned boom
    assert "`--set train.map_periodic=false`" in text
    mild = {**rec, "val_theta_rmse_map": [0.12, 0.20, PINNED_COST * 0.068 * 0.99]}
    assert "kept where the networks validated better" not in training_markdown({"static_map": mild})
    older = {k: v for k, v in rec.items() if k != "val_theta_rmse_map"}  # a record without it
    assert "kept where the networks validated better" not in training_markdown(
        {"static_map": older}
    )


def test_the_note_says_whether_the_bits_hold_on_another_cpu():
    native = training_markdown({"epochs_planned": 3, "epochs_done": 3, "numerics": "native"})
    assert "of this computer" in native and "EXSUR_NUMERICS=portable" in native
    portable = training_markdown({"epochs_planned": 3, "epochs_done": 3, "numerics": "portable"})
    assert "any x86-64 CPU with AVX2" in portable and "of this computer" not in portable
    old = training_markdown({"epochs_planned": 3, "epochs_done": 3})  # before numerics existed
    assert "of this computer" in old


def test_a_delayed_map_says_its_delay():
    rec = {
        "chosen": ["swing"],
        "names": ["swing", "boom"],
        "map": {"delay_s": [0.65, 0.2]},
        "why": "swing follow(s) the static map",
    }
    text = training_markdown({"epochs_planned": 30, "static_map": rec})
    assert "gain per direction, delay swing 0.65 s)" in text and "boom 0.20" not in text


def test_the_kind_and_input_choices_are_named():
    kinds = {"names": ["swing", "boom"], "chosen": ["boom"], "why": "boom from the map..."}
    text = training_markdown({"epochs_planned": 30, "kinds": kinds})
    assert "correct the static valve map drive boom, the plain networks the other" in text
    none = training_markdown({"epochs_planned": 30, "kinds": {**kinds, "chosen": []}})
    assert "the plain networks drive every joint" in none
    every = training_markdown({"epochs_planned": 30, "kinds": {**kinds, "chosen": kinds["names"]}})
    assert "static valve map drive every joint" in every
    mixed = {**kinds, "chosen": kinds["names"], "blended": ["swing"]}
    text = training_markdown({"epochs_planned": 30, "kinds": mixed})
    assert "static valve map drive boom, the even blend of both kinds drives swing, chosen" in text
    assert "the plain networks" not in text
    some = {**kinds, "blended": ["boom"]}
    text = training_markdown({"epochs_planned": 30, "kinds": some})
    assert "the even blend of both kinds drives boom, the plain networks the other" in text
    assert "static valve map drive" not in text
    rec = {"inputs": ["u_throttle"], "kept": False, "why": "validation error 0.41 with"}
    text = training_markdown({"epochs_planned": 30, "exogenous": rec})
    assert "Exogenous inputs (u_throttle): ignored by the model" in text and "0.41" in text
    some = {**rec, "kept": True, "per_joint": True, "joints": ["boom"]}
    text = training_markdown({"epochs_planned": 30, "exogenous": some})
    assert "Exogenous inputs (u_throttle): used by boom only (the other joints ignore" in text
    assert "so do the networks that correct" not in text
    both = training_markdown({"epochs_planned": 30, "exogenous": some, "kinds": kinds})
    assert "ignore them; so do the networks that correct the static valve map)" in both
    whole = {**rec, "kept": True, "per_joint": False, "joints": ["swing", "boom"]}
    assert "used by the model" in training_markdown({"epochs_planned": 30, "exogenous": whole})
    # kept whole, then the static map took the swing: the line names the joint that reads them
    part = {**whole, "joints": ["boom"], "dropped": ["swing"]}
    text_part = training_markdown({"epochs_planned": 30, "exogenous": part})
    assert "used by boom only (the parts of the model that drive the other joints" in text_part
    assert "used by the model" not in text_part
    assert "Two kinds" not in text and "Exogenous" not in training_markdown({"epochs_planned": 3})


def test_a_cut_names_the_cap_option_of_each_command():
    """The advice after a cut named ``--max-seconds``, which ``exsur run`` (its option is
    ``--max-train-seconds``) and ``exsur sweep`` (``--trial-seconds``) refuse: the log line,
    the report and the model card name each command's option."""
    from excavator_surrogate.evaluate.card import _warnings
    from excavator_surrogate.training.records import budget_cut_message

    cut = {"epochs_planned": 200, "epochs_done": 6, "stopped": "budget", "budget_cut": True}
    card = {
        "training": {"budget_cut": True},
        "network": {"end_stops": True},
        "validation": None,
        "coverage": None,
    }
    for text in (
        budget_cut_message(1.0, 6, 200),
        training_markdown(cut),
        _warnings(card)[0],
    ):
        assert "6 of 200" in text or "cut training short" in text
        for option in ("--max-seconds", "--max-train-seconds of exsur run", "--trial-seconds"):
            assert option in text, text


def test_a_compared_checkpoint_the_cap_cut_is_recorded_and_shown(tmp_path):
    """``exsur run`` compares its surrogate with a GRU trained under the same cap; a cut GRU
    was compared without a word (``compare.GRU`` held omega and theta only)."""
    ds = tiny_dataset(2, n_train=2, n_step=120)
    full = train(tiny_train_config(epochs=1), ds, out=tmp_path / "full", show_progress=False)
    gru = tiny_train_config(epochs=50, max_train_seconds=1e-3, cell="gru")
    cut = train(gru, ds, out=tmp_path / "gru", show_progress=False)
    out = tmp_path / "ev"
    evaluate_checkpoint(full, ds, out=out, compare={"GRU": cut}, arx=False, figure=False)
    saved = json.loads((out / "metrics.json").read_text())
    assert saved["compare"]["GRU"]["training"]["budget_cut"] is True
    assert saved["compare"]["GRU"]["training"]["epochs_done"] == 1
    table = (out / "table.md").read_text()
    assert "the wall-time cap cut the training of GRU short** (1 of 50 planned epochs)" in table
    assert "planned 1 epochs ran" in table  # the surrogate's own was not cut


def test_an_early_stop_says_how_many_epochs_ran() -> None:
    """A single network early stopping after 4 of 20 epochs was reported as 'the planned 20
    epochs ran' (the per-member count was printed for ensembles only)."""
    one = {"epochs_planned": 20, "epochs_done": 4, "stopped": "early-stop", "budget_cut": False}
    text = training_markdown(one)
    assert "4 of the planned 20 epochs ran (early stop)" in text
    assert "Training: the planned" not in text
    two = {"epochs_planned": 20, "members": [dict(one), {**one, "epochs_done": 20}]}
    assert "or fewer where early stopping ended a network (epochs done per member: 4, 20)" in (
        training_markdown(two)
    )
    full = {**one, "epochs_done": 20, "stopped": "planned"}
    assert "Training: the planned 20 epochs ran;" in training_markdown(full)
