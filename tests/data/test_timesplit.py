"""Splitting one long recording in time: train | val | test."""

from __future__ import annotations

import numpy as np
import pytest

from excavator_surrogate.data import Episode, load_dataset, write_dataset
from excavator_surrogate.data.timesplit import (
    split_dataset_in_time,
    split_in_time,
    time_split_sizes,
)
from excavator_surrogate.errors import ConfigError, DataError
from excavator_surrogate.spec import JointSpec, MachineSpec

SPEC = MachineSpec(joints=(JointSpec("boom"), JointSpec("bucket")), rate_hz=20.0)


def _log(n_step: int = 2000, name: str = "shift") -> Episode:
    t = np.arange(n_step) * SPEC.dt
    theta = np.stack([np.sin(0.1 * t), np.cos(0.2 * t)], axis=1)
    return Episode(
        spec=SPEC,
        time=t,
        u=np.zeros((n_step, 2)),
        theta=theta,
        omega=np.vstack([np.zeros((1, 2)), np.diff(theta, axis=0) / SPEC.dt]),
        name=name,
    )


def test_parts_follow_each_other_in_time():
    ep = _log()
    parts = split_in_time(ep, val_s=20.0, test_s=30.0)
    assert [s for _, s in parts] == ["train", "val", "test"]
    assert [p.n_step for p, _ in parts] == [2000 - 400 - 600, 400, 600]
    assert [p.name for p, _ in parts] == ["shift", "shift_val", "shift_test"]
    # the parts are the recording, in order, without gaps or overlap
    np.testing.assert_array_equal(np.concatenate([p.theta for p, _ in parts]), ep.theta)
    assert parts[1][0].time[0] == pytest.approx(parts[0][0].time[-1] + SPEC.dt)
    assert parts[2][0].extra["time_split"] == {"from": "shift", "start": 1400, "stop": 2000}


@pytest.mark.parametrize(("val_s", "test_s"), [(20.0, 30.0), (0.0, 30.0), (12.34, 0.0), (0.0, 0.0)])
def test_the_sizes_alone_are_the_parts_lengths(val_s, test_s):
    """What a dry run plans from (no episode) is what the cut makes."""
    parts = split_in_time(_log(), val_s=val_s, test_s=test_s)
    sizes = time_split_sizes(2000, rate_hz=SPEC.rate_hz, val_s=val_s, test_s=test_s)
    assert sizes == [(p.n_step, s) for p, s in parts]


def test_a_zero_length_part_is_left_out():
    parts = split_in_time(_log(), val_s=0.0, test_s=30.0)
    assert [s for _, s in parts] == ["train", "test"]


def test_too_short_or_negative_is_one_clear_error():
    with pytest.raises(DataError, match="too short to split"):
        split_in_time(_log(300), val_s=10.0, test_s=10.0)  # 15 s: leaves 100 training samples
    with pytest.raises(DataError, match="too short to split"):
        split_in_time(_log(2000), val_s=2.0, test_s=30.0)  # a 40-sample validation part
    with pytest.raises(ConfigError, match="must be >= 0"):
        split_in_time(_log(), val_s=-1.0, test_s=10.0)


def test_dataset_split_keeps_existing_val_and_test(tmp_path):
    other = _log(500, name="other")
    write_dataset(tmp_path / "src", [(_log(), "train"), (other, "test")])
    out = split_dataset_in_time(tmp_path / "src", tmp_path / "out", val_s=20.0, test_s=30.0)
    ds = load_dataset(out)
    assert [e.name for e in ds.train] == ["shift"]
    assert [e.name for e in ds.val] == ["shift_val"]
    assert sorted(e.name for e in ds.test) == ["other", "shift_test"]
    assert ds.manifest["time_split"]["val_s"] == 20.0


def test_parts_carry_their_own_sensor_jump_runs():
    """The sensor model's jump runs are indexed on samples: each part keeps the runs inside
    it, counted from its first sample (a part used to keep the whole recording's runs, so
    cleaning scored its detector against the wrong samples)."""
    from excavator_surrogate.data.jumps import jump_mask_of, runs_to_mask

    ep = _log()
    runs = [[0, 10, 20], [1, 1390, 1410], [0, 1500, 1505], [1, 1990, 2000]]
    ep = ep.replace(extra={"sensor": {"model": "m", "jump_runs": runs}})
    full = runs_to_mask(runs, ep.n_step, 2)
    start = 0
    for part, _ in split_in_time(ep, val_s=20.0, test_s=30.0):
        np.testing.assert_array_equal(jump_mask_of(part), full[start : start + part.n_step])
        assert part.extra["sensor"]["model"] == "m"
        start += part.n_step
    _, val, test = (
        p.extra["sensor"]["jump_runs"] for p, _ in split_in_time(ep, val_s=20.0, test_s=30.0)
    )
    assert val == [[1, 390, 400]]  # samples 1000-1399
    assert test == [[1, 0, 10], [0, 100, 105], [1, 590, 600]]  # samples 1400-1999


def test_a_jump_run_outside_the_episode_is_one_clear_error():
    from excavator_surrogate.data.jumps import jump_mask_of

    ep = _log(n_step=100).replace(extra={"sensor": {"jump_runs": [[0, 90, 120]]}})
    with pytest.raises(DataError, match=r"shift: sensor jump run \[0, 90, 120\) lies outside"):
        jump_mask_of(ep)
