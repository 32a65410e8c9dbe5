"""The input record after a later choice hands joints to parts of the model that ignore the
inputs."""

from __future__ import annotations

from excavator_surrogate.training.input_readers import drop_readers

BY = "the static valve map, which ignores them, drives"


def _record(joints):
    return {"inputs": ["gear"], "joints": list(joints), "kept": True, "why": "kept"}


def test_joints_the_blind_part_drives_leave_the_record_and_the_rest_stay():
    rec = _record(["swing", "boom", "arm"])
    assert drop_readers(rec, ["boom", "bucket"], by=BY)
    assert rec["joints"] == ["swing", "arm"] and rec["kept"] and rec["dropped"] == ["boom"]
    assert rec["why"] == f"kept; {BY} boom, bucket: swing, arm read them"
    # a second choice adds to what the first dropped
    assert drop_readers(rec, ["swing", "arm"], by="the map-correcting networks drive")
    assert rec["joints"] == [] and rec["kept"] is False
    assert rec["dropped"] == ["boom", "swing", "arm"]
    assert rec["why"].endswith(
        "; the map-correcting networks drive swing, arm: no joint reads them"
    )


def test_a_record_whose_readers_the_choice_does_not_touch_is_left_as_it_was():
    for rec, alone in (
        (_record(["boom"]), ["arm"]),
        (_record([]), ["arm"]),
        (_record(["boom"]), []),
    ):
        before = dict(rec)
        assert not drop_readers(rec, alone, by=BY)
        assert rec == before
    refused = {"inputs": ["gear"], "kept": False, "why": "ignored"}  # no "joints" at all
    assert not drop_readers(refused, ["boom"], by=BY) and "dropped" not in refused
