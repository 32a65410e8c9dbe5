"""The input choice's rule (``training/input_choice.py``): keep the inputs only if better on
validation overall and on every joint; else the joints they help, as a set kept on the same
terms.  Training through both ways of the choice: ``test_variants.py``, ``test_dual.py``."""

from __future__ import annotations

import math

from excavator_surrogate.spec import InputSpec, JointSpec, MachineSpec
from excavator_surrogate.training import input_choice
from excavator_surrogate.training.input_choice import (
    INPUT_MARGIN,
    choose_inputs,
    inputs_after_kinds,
)

THREE = MachineSpec(
    joints=(JointSpec("boom"), JointSpec("arm"), JointSpec("bucket")),
    rate_hz=20.0,
    inputs=(InputSpec("gear", u_min=-1.0, u_max=1.0),),
)
"""A machine with an exogenous input; the rule reads only its joint names."""


def _val(err, rmse):
    return {"val_error": err, "theta_rmse": rmse}


def test_inputs_are_kept_only_if_better_overall_and_on_every_joint():
    m = INPUT_MARGIN
    assert choose_inputs(_val(0.5, [1.0, 1.0]), _val(1.0, [2.0, 2.0]))[0]
    # a tie (within the margin) keeps the model that cannot depend on them
    assert not choose_inputs(_val(1.0 - m / 2, [1.0, 1.0]), _val(1.0, [1.0, 1.0]))[0]
    # better overall, but one joint worse: they would hurt that joint
    keep, why = choose_inputs(_val(0.5, [0.2, 2.2]), _val(1.0, [2.0, 2.0]))
    assert not keep and "[1]" in why
    assert not choose_inputs(_val(math.inf, [math.nan, 1.0]), _val(1.0, [1.0, 1.0]))[0]


def test_choose_input_joints_keeps_the_best_set_that_passes_the_whole_rule(monkeypatch):
    """The candidates together and each alone are scored; a set must beat the half that
    ignores the inputs as the whole half must (better overall, no joint worse)."""
    monkeypatch.setattr(input_choice, "paired", lambda use, ignore, joints: tuple(joints))
    scores: dict = {}
    monkeypatch.setattr(input_choice, "free_run_error", lambda model, val, max_steps: scores[model])
    ignore = _val(1.0, [1.0, 1.0, 1.0])
    use = [type("S", (), {"spec": THREE})()]
    # the inputs help the first two joints and hurt the third
    vals = {"use": _val(0.9, [0.5, 0.8, 1.5]), "ignore": ignore}
    scores[(True, True, False)] = _val(0.7, [0.5, 0.8, 1.02])
    scores[(True, False, False)] = _val(0.8, [0.5, 1.0, 1.0])
    scores[(False, True, False)] = _val(0.9, [1.0, 0.8, 1.0])
    joints, tried = input_choice.choose_input_joints(use, use, vals, [])
    assert joints == [True, True, False]
    assert [t["joints"] for t in tried] == [["boom", "arm"], ["boom"], ["arm"]]
    assert [t["kept"] for t in tried] == [True, True, True]
    # together they hurt the bucket (it reads their angles): the best single one wins
    scores[(True, True, False)] = _val(0.6, [0.5, 0.8, 1.2])
    joints, tried = input_choice.choose_input_joints(use, use, vals, [])
    assert joints == [True, False, False] and [t["kept"] for t in tried] == [False, True, True]
    # a joint the static map drives anyway is no candidate
    joints, tried = input_choice.choose_input_joints(
        use, use, vals, [], pinned=[True, False, False]
    )
    assert joints == [False, True, False] and [t["joints"] for t in tried] == [["arm"]]
    # no set beats the ignoring half by the margin: none
    for k in list(scores):
        scores[k] = _val(1.0 - INPUT_MARGIN / 2, [1.0, 1.0, 1.0])
    assert input_choice.choose_input_joints(use, use, vals, [])[0] is None
    # better on every joint: the whole half (refused by the caller) is no set of its own
    vals_all = {"use": _val(0.9, [0.5, 0.8, 0.9]), "ignore": ignore}
    scores[(False, False, True)] = _val(0.9, [1.0, 1.0, 0.9])
    joints, tried = input_choice.choose_input_joints(use, use, vals_all, [])
    assert [t["joints"] for t in tried] == [["boom"], ["arm"], ["bucket"]]


def test_a_joint_the_map_correcting_networks_drive_alone_reads_no_input():
    def record(joints):
        return {"joints": list(joints), "kept": True, "why": "boom, arm take them alone"}

    names = ["swing", "boom", "arm"]
    rec = record(["boom", "arm"])
    inputs_after_kinds(rec, {"names": names, "weights": [1.0, 1.0, 0.5]})
    assert rec["joints"] == ["arm"] and rec["kept"]
    assert rec["why"].endswith("drive swing, boom: arm read them")
    rec = record(["boom"])
    inputs_after_kinds(rec, {"names": names, "weights": [0.0, 1.0, 0.0]})
    assert rec["joints"] == [] and not rec["kept"] and rec["why"].endswith("no joint reads them")
    rec = record(["boom", "arm"])  # a blend, or the plain networks: unchanged
    inputs_after_kinds(rec, {"names": names, "weights": [1.0, 0.5, 0.0]})
    assert rec == record(["boom", "arm"])
