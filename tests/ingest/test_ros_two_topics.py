"""A valve's two directions on two ROS topics: ``up = { topic, field }``, ``down = { ... }``."""

from __future__ import annotations

import dataclasses
import tomllib
from pathlib import Path

import numpy as np
import pytest

from excavator_surrogate.errors import ConfigError, DataError
from excavator_surrogate.ingest import convert_log, load_mapping
from excavator_surrogate.ingest.mapping_toml import parse_mapping
from tests.helpers import arm3_plant
from tests.helpers.ros_bags import write_bag

pytest.importorskip("rosbags")

HEAD = """
[machine]
name = "arm3-ros"
rate_hz = 10.0
[import]
min_steps = 20
"""


def _mapping(two_topics: bool) -> str:
    text = HEAD
    for i, j in enumerate(arm3_plant.JOINTS):
        if two_topics:
            cmd = (
                f'up = {{ topic = "/{j}/up", field = "data" }}, '
                f'down = {{ topic = "/{j}/down", field = "data" }}'
            )
        else:
            cmd = f'topic = "/valves", up = "data[{2 * i}]", down = "data[{2 * i + 1}]"'
        text += f"""
[[joints]]
name = "{j}"
angle = {{ topic = "/joint_states", field = "position[{j}_joint]", unit = "rad" }}
command = {{ {cmd}, unit = "%" }}
"""
    return text


@pytest.fixture(scope="module")
def logs(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, np.ndarray]]:
    root = tmp_path_factory.mktemp("two_topics")
    cols = arm3_plant.simulate(duration_s=12.0, seed=3, log_rate_hz=50.0)
    n = cols["t_ms"].size
    every = np.arange(n)
    write_bag(root / "array.mcap", cols, storage="mcap")
    write_bag(root / "same.mcap", cols, storage="mcap", split_valves=(every, every))
    # up at 25 Hz, down at 50/3 Hz and 3 ms late: no message of one shares the other's time
    up, down = np.arange(0, n, 2), np.arange(1, n, 3)
    write_bag(
        root / "apart.mcap", cols, storage="mcap", split_valves=(up, down), down_delay_ns=3_000_000
    )
    (root / "array.toml").write_text(_mapping(False))
    (root / "topics.toml").write_text(_mapping(True))
    return root, cols


def test_same_times_as_one_array(logs):
    """Duties on two topics at the array's times give the array's commands."""
    root, _ = logs
    ref = convert_log(root / "array.mcap", load_mapping(root / "array.toml")).episodes
    got = convert_log(root / "same.mcap", load_mapping(root / "topics.toml")).episodes
    assert len(ref) == len(got) == 1
    np.testing.assert_array_equal(got[0].theta, ref[0].theta)
    np.testing.assert_allclose(got[0].u, ref[0].u, atol=1e-9)
    assert np.abs(ref[0].u).max() > 300


def test_the_report_names_each_topics_rate(logs, cli, tmp_path):
    root, _ = logs
    rc, out, err = cli(
        "import", root / "apart.mcap", "--mapping", root / "topics.toml", "--dry-run"
    )
    assert rc == 0, err
    assert "/joint_states 50 Hz, /boom/up 25 Hz, /boom/down 16.67 Hz" in out


def _held_mean(t: np.ndarray, x: np.ndarray, lo: float, hi: float) -> float:
    """Reference: the mean over [lo, hi] of x held from each t until the next (a plain loop)."""
    total = 0.0
    for i in range(t.size):
        start = lo if i == 0 else max(t[i], lo)  # the first value holds backwards too
        end = hi if i == t.size - 1 else min(t[i + 1], hi)
        if end > start:
            total += x[i] * (end - start)
    return total / (hi - lo)


def test_apart_is_the_held_difference(logs):
    """Up and down at other rates and times: each output sample is the mean of the held up
    duty minus the mean of the held down duty over its interval (loop reference)."""
    root, cols = logs
    mapping = load_mapping(root / "topics.toml")
    eps = convert_log(root / "apart.mcap", mapping).episodes
    assert len(eps) == 1
    ep = eps[0]
    n = cols["t_ms"].size
    t_up = cols["t_ms"][np.arange(0, n, 2)] * 1e-3
    t_dn = cols["t_ms"][np.arange(1, n, 3)] * 1e-3 + 3e-3
    t0 = cols["t_ms"][0] * 1e-3  # the bag's first message: t = 0
    dt = 1.0 / mapping.spec().rate_hz
    for i, j in enumerate(arm3_plant.JOINTS):
        x_up = cols[f"{j}_up_pct"][np.arange(0, n, 2)]
        x_dn = cols[f"{j}_down_pct"][np.arange(1, n, 3)]
        for k in range(0, ep.n_step, 7):
            lo, hi = ep.time[k] + t0, ep.time[k] + dt + t0
            pct = _held_mean(t_up, x_up, lo, hi) - _held_mean(t_dn, x_dn, lo, hi)
            assert ep.u[k, i] == pytest.approx(pct * 10.0, abs=1e-6), (j, k)


def test_errors_name_the_topic_and_its_row(logs, tmp_path):
    root, cols = logs
    bad = {k: v.copy() for k, v in cols.items()}
    n = bad["t_ms"].size
    bad["arm_down_pct"][31] = -5.0  # row 10 of /arm/down (every 3rd row from 1)
    write_bag(
        tmp_path / "neg.mcap",
        bad,
        storage="mcap",
        split_valves=(np.arange(0, n, 2), np.arange(1, n, 3)),
    )
    mapping = load_mapping(root / "topics.toml")
    with pytest.raises(
        DataError,
        match=r"column '/arm/down:data', row 10: one-way command channel is negative \(-5\)",
    ):
        convert_log(tmp_path / "neg.mcap", mapping)
    bad["arm_down_pct"][31] = 0.0
    bad["boom_up_pct"][40] = 130.0  # row 20 of /boom/up
    write_bag(
        tmp_path / "over.mcap",
        bad,
        storage="mcap",
        split_valves=(np.arange(0, n, 2), np.arange(1, n, 3)),
    )
    with pytest.raises(
        DataError,
        match=r"column '/boom/up:data', row 20: one-way command channel 130 % is beyond full command \(100\)",
    ):
        convert_log(tmp_path / "over.mcap", mapping)
    # --clip-commands clips it instead and counts the clipped samples
    res = convert_log(
        tmp_path / "over.mcap",
        mapping,
        options=dataclasses.replace(mapping.options, clip_commands=True),
    )
    assert res.episodes and res.entry["clipped"]["boom"] >= 1
    assert res.episodes[0].u[:, 0].max() <= 1000.0


def _boom(command: str, more: str = "") -> str:
    """A mapping of one joint, boom, with the ``command`` table's keys ``command``."""
    return (
        HEAD
        + f"""
[[joints]]
name = "boom"
angle = {{ topic = "/joint_states", field = "position[boom_joint]", unit = "rad" }}
command = {{ {command}, unit = "%" }}
{more}"""
    )


@pytest.mark.parametrize(
    ("command", "message"),
    [
        (
            'up = { topic = "/boom/up" }, down = { topic = "/boom/down", field = "data" }',
            r"up = \{ topic = \"...\", field = \"...\" \} names a channel of a ROS topic by both keys",
        ),
        (
            'up = { topic = "/boom/up", field = "data" }, down = "data"',
            r"down needs a topic too: down = \{ topic = \"...\", field = \"data\" \}",
        ),
        (
            'up = { topic = "/a", field = "data" }, up_topic = "/b", down = { topic = "/c", field = "data" }',
            r"give up's topic in its table or as up_topic, not both",
        ),
        (
            'topic = "/valves", field = "data[0]", up_topic = "/b"',
            r"up_topic and down_topic are for up \+ down commands",
        ),
    ],
)
def test_mapping_errors(command, message):
    with pytest.raises(ConfigError, match=r"joint 'boom': command: " + message):
        parse_mapping(tomllib.loads(_boom(command)), path="m.toml")


def test_an_input_is_one_channel():
    text = _boom(
        'topic = "/valves", field = "data[0]"',
        """[[inputs]]
name = "travel"
up = { topic = "/travel/fwd", field = "data" }
down = { topic = "/travel/back", field = "data" }
unit = "physical"
range = [-1.0, 1.0]
""",
    )
    with pytest.raises(ConfigError, match=r"input 'travel': an input is one channel"):
        parse_mapping(tomllib.loads(text), path="m.toml")


def test_two_topics_and_a_shared_topic_mix():
    """``topic`` serves the direction that names none of its own."""
    text = _boom('topic = "/boom/up", up = "data", down = { topic = "/boom/down", field = "data" }')
    m = parse_mapping(tomllib.loads(text), path="m.toml")
    assert [c.label for c in m.command_channels(m.joints[0])] == [
        "/boom/up:data",
        "/boom/down:data",
    ]
