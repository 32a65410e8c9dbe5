"""The evaluation's table of the choices made after training: each option's validation score
per joint, the one that drives it, and the close calls."""

from __future__ import annotations

from excavator_surrogate.evaluate.training_report import (
    CLOSE_CALL,
    choices_markdown,
    training_markdown,
)
from excavator_surrogate.spec import JointSpec, MachineSpec

NAMES = ["swing", "boom", "arm", "bucket"]
KINDS = {
    "names": NAMES,
    "val_theta_rmse_plain": [0.24, 0.0826, 0.23, 0.1555],
    "val_theta_rmse_prior": [0.16, 0.0578, 0.21, 0.1925],
    "val_theta_rmse_blend": [0.19, 0.0695, 0.228, 0.1915],
    "weights": [1.0, 0.0, 0.5, 0.0],
    "chosen": ["swing", "arm"],
    "blended": ["arm"],
}
MAP = {"names": NAMES, "val_theta_rmse_map": [0.12, 0.104, 0.30, 0.2484], "chosen": ["swing"]}


def _row(text: str, label: str) -> list[str]:
    line = next(ln for ln in text.splitlines() if ln.startswith(f"| {label} |"))
    return [c.strip() for c in line.strip("|").split("|")][1:]


def test_each_option_per_joint_the_driver_in_bold_and_the_close_calls() -> None:
    text = choices_markdown({"kinds": KINDS, "static_map": MAP})
    assert "| Joint | plain networks | map-correcting networks | even blend | static map |" in text
    # the swing follows the map (it beats the kind choice's map-correcting networks by 1.33x)
    assert _row(text, "Swing") == ["0.2400", "0.1600", "0.1900", "**0.1200**", "1.33"]
    # the boom stays plain although the map-correcting networks validate better on it alone
    assert _row(text, "Boom") == ["**0.0826**", "0.0578", "0.0695", "0.1040", "0.70"]
    # the arm's blend: the map-correcting networks are 8 % better, within the close call
    assert _row(text, "Arm")[2] == "**0.2280**" and _row(text, "Arm")[-1] == "0.92"
    assert _row(text, "Bucket")[-1] == f"{0.1915 / 0.1555:.2f}"  # 1.23: not close
    close = next(ln for ln in text.splitlines() if ln.startswith("Close call"))
    assert "boom, arm:" in close and f"{CLOSE_CALL:.0%}" in close and "bucket" not in close
    # the swing on the map with a network 3 % behind: shown, not flagged (the same map in
    # every seed)
    near = {**MAP, "val_theta_rmse_map": [0.155, 0.104, 0.30, 0.2484]}
    text = choices_markdown({"kinds": KINDS, "static_map": near})
    assert _row(text, "Swing")[-1] == "1.03" and "Close call on boom, arm:" in text


def test_a_record_from_before_the_blend_takes_its_drivers_from_the_chosen_joints() -> None:
    gone = ("weights", "blended", "val_theta_rmse_blend")  # keys the blend added
    old = {k: v for k, v in KINDS.items() if k not in gone}
    text = choices_markdown({"kinds": {**old, "chosen": ["boom"]}})
    assert "even blend" not in text
    assert _row(text, "Boom") == ["0.0826", "**0.0578**", "1.43"]
    assert _row(text, "Arm") == ["**0.2300**", "0.2100", "0.91"]


def test_a_joint_validation_cannot_vouch_for_keeps_the_networks_and_no_close_call() -> None:
    names = ["boom", "arm"]
    smap = {
        "names": names,
        "val_theta_rmse_network": [0.0725, 0.2027],
        "val_theta_rmse_map": [0.0585, 0.2100],
        "chosen": [],
        "unspanned": ["boom"],
    }
    text = choices_markdown({"static_map": smap})
    assert "| Joint | network | static map |" in text
    assert _row(text, "Boom") == ["**0.0725**", "(0.0585)", "—"]  # the map was not an option
    assert _row(text, "Arm") == ["**0.2027**", "0.2100", "1.04"]
    # the map is the same in every seed: its near tie is shown, not flagged
    assert "Close call" not in text and "In parentheses: not an option" in text


def test_nothing_to_compare_gives_no_table_and_old_records_too() -> None:
    assert choices_markdown({}) == ""
    assert choices_markdown({"static_map": {"names": NAMES, "chosen": []}}) == ""
    short = {"names": NAMES, "val_theta_rmse_network": [0.1] * 3, "val_theta_rmse_map": [0.2] * 4}
    assert choices_markdown({"static_map": short}) == ""  # lengths disagree: not guessed
    no_blend = {k: v for k, v in KINDS.items() if k != "val_theta_rmse_blend"}
    assert choices_markdown({"kinds": no_blend}) == ""  # the arm's blend was not scored
    text = training_markdown({"kinds": KINDS, "epochs_planned": 3})
    assert "Validation angle RMSE [rad] of each option" in text


def test_linear_joints_print_in_their_own_unit() -> None:
    spec = MachineSpec(
        (JointSpec("swing", periodic=True), JointSpec("boom", kind="linear", unit="mm"))
    )
    kinds = {
        "names": ["swing", "boom"],
        "val_theta_rmse_plain": [0.13, 0.0547],
        "val_theta_rmse_prior": [0.12, 0.0431],
        "weights": [0.0, 1.0],
        "chosen": ["boom"],
    }
    text = choices_markdown({"kinds": kinds}, spec=spec)
    assert "in the joint's unit" in text
    assert _row(text, "Boom [mm]") == ["54.7000", "**43.1000**", "1.27"]
    assert _row(text, "Swing [rad]") == ["**0.1300**", "0.1200", "0.92"]


def test_a_map_refused_on_the_validation_halves_is_explained() -> None:
    """The map validated better over the whole segment yet the networks drive the boom: the
    table says why, with the halves' scores."""
    smap = {
        **MAP,
        "chosen": ["swing"],
        "blocks": {
            "what": "the validation episode's halves",
            "tie": 0.05,
            "checked": ["boom"],
            "val_theta_rmse_network": [[0.1, 0.0422, 0.2, 0.1], [0.1, 0.0449, 0.2, 0.1]],
            "val_theta_rmse_map": [[0.1, 0.0534, 0.3, 0.2], [0.1, 0.0260, 0.3, 0.2]],
            "refused": ["boom"],
        },
    }
    text = choices_markdown({"kinds": KINDS, "static_map": smap})
    assert "Not on the static map although it validated within 5% of the networks" in text
    assert "Boom (map against networks: 0.0534 against 0.0422 and 0.0260 against 0.0449)" in text
    assert "map_blocks=false" in text
    assert "Not on the static map" not in choices_markdown({"kinds": KINDS, "static_map": MAP})
