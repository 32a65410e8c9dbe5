"""``exsur info LOG --draft-mapping``: a first mapping guessed from a log's channels
(``ingest/draft.py``), checked by importing with it."""

from __future__ import annotations

import tomllib
from pathlib import Path

import numpy as np
import pytest

from excavator_surrogate.ingest.draft import draft_mapping, words
from excavator_surrogate.ingest.inventory import summarize_log
from excavator_surrogate.ingest.mapping_toml import load_mapping, parse_mapping
from excavator_surrogate.ingest.summary import ChannelSummary, LogSummary
from tests.helpers import arm3_plant


def _csv(path: Path, cols: dict[str, np.ndarray]) -> Path:
    names = list(cols)
    rows = [",".join(names)]
    rows += [",".join(f"{cols[k][i]:.6g}" for k in names) for i in range(len(cols[names[0]]))]
    path.write_text("\n".join(rows) + "\n")
    return path


def _summary(*channels: ChannelSummary, kind: str = "csv") -> LogSummary:
    return LogSummary(Path("log.csv"), kind, "CSV", list(channels))


def _imports(cli, log: Path, draft, tmp_path: Path, *options: str) -> None:
    """The import takes the draft (a dry run of ``log`` with it)."""
    (tmp_path / "m.toml").write_text(draft.text)
    rc, _, err = cli("import", log, "--mapping", tmp_path / "m.toml", "--dry-run", *options)
    assert rc == 0, err


def _ch(name: str, lo: float, hi: float, *, unit: str = "", n: int = 101, **kw) -> ChannelSummary:
    return ChannelSummary(name, unit=unit, n_sample=n, lo=lo, hi=hi, **kw)


@pytest.mark.parametrize(
    ("name", "expected"),
    [
        ("Boom_up_duty", ["boom", "up", "duty"]),
        ("BoomAngleRad", ["boom", "angle", "rad"]),
        ("ARMVelocity", ["arm", "velocity"]),
        ("bktang", ["bkt", "ang"]),
        ("position[1]", ["position", "1"]),
        ("boom1-cmd", ["boom", "cmd"]),
        ("Löffel_Winkel", ["loffel", "winkel"]),
        ("LoeffelstielWinkel", ["loeffelstiel", "winkel"]),
        ("Schwenkwerk_Drehrate", ["schwenkwerk", "drehrate"]),
        ("flèche_angle", ["fleche", "angle"]),
    ],
)
def test_words(name: str, expected: list[str]) -> None:
    assert words(name) == expected


def test_the_example_arms_logs_give_its_mapping(arm3_dir: Path, cli, tmp_path: Path) -> None:
    """The arm's logs (``boom_deg``, ``boom_up_pct`` / ``boom_down_pct``, ``t_ms``) give the
    hand-written mapping's channels and units, and the import takes the draft."""
    out = tmp_path / "draft.toml"
    rc, text, err = cli("info", arm3_dir / "logs" / "run01.csv", "--draft-mapping", out)
    assert rc == 0
    assert "- `--draft-mapping MAP.toml` writes a first mapping guessed from these" in text
    assert f"wrote {out}: boom, arm, bucket; 0 TODO, 0 channel(s) not mapped" in err
    draft, hand = load_mapping(out), load_mapping(arm3_dir / "arm3.toml")
    assert draft.time == hand.time
    for d, h in zip(draft.joints, hand.joints, strict=True):
        assert (d.name, d.angle, d.command) == (h.name, h.angle, h.command)
    rc, _, err = cli("import", arm3_dir / "logs", "--mapping", out, "--dry-run")
    assert rc == 0, err


def test_a_dspace_style_rig_with_measurements_beside_the_duties(tmp_path: Path) -> None:
    """A rig's names (``Boom_ang``, ``Arm_out_duty`` / ``Arm_in_duty``): the duties are the
    commands, not the cylinder pressures (``_Cyl_P``) or valve feedbacks (``_FB``) that also
    name a direction; the time's unit comes from its step."""
    cols = arm3_plant.simulate(duration_s=5.0, seed=1)
    n = cols["t_ms"].size
    rng = np.random.default_rng(0)
    table = {"t": cols["t_ms"] / 1000.0}
    for short, j in (("Boom", "boom"), ("Arm", "arm"), ("Bkt", "bucket")):
        up, down = ("up", "dn") if j == "boom" else ("out", "in")
        table[f"{short}_UpH_Cyl_P"] = rng.uniform(10, 300, n)
        table[f"{short}_{up}_duty"] = cols[f"{j}_up_pct"]
        table[f"{short}_{down}_duty"] = cols[f"{j}_down_pct"]
        table[f"{short}_{down}_FB"] = rng.uniform(0, 20, n)
        table[f"{short}_ang"] = cols[f"{j}_deg"]
    log = _csv(tmp_path / "rig.csv", table)
    draft = draft_mapping(summarize_log(log))
    m = parse_mapping(tomllib.loads(draft.text))
    assert (m.time.column, m.time.unit) == ("t", "s")
    assert [j.name for j in m.joints] == ["boom", "arm", "bucket"]
    arm = m.joints[1]
    assert (arm.angle.column, arm.angle.unit) == ("Arm_ang", "deg")
    assert (arm.command.up, arm.command.down) == ("Arm_out_duty", "Arm_in_duty")
    assert arm.command.unit == "%"
    assert sorted(draft.unused)[0].startswith("Arm_UpH_Cyl_P")
    assert len(draft.unused) == 6 and not draft.todo


def test_a_german_rigs_names(tmp_path: Path, cli) -> None:
    """``Ausleger`` / ``Stiel`` / ``Löffel`` with ``Winkel``, ``Heben`` / ``Senken``, ``Aus`` /
    ``Ein``; a cylinder pressure (``Druck``) is no command, an engine speed (``Drehzahl``) is
    offered as an input; the import takes the draft."""
    cols = arm3_plant.simulate(duration_s=5.0, seed=4)
    n = cols["t_ms"].size
    table = {"Zeit": cols["t_ms"] / 1000.0}
    for short, j, (up, down) in (
        ("Ausleger", "boom", ("Heben", "Senken")),
        ("Stiel", "arm", ("Aus", "Ein")),
        ("Löffel", "bucket", ("Auf", "Ab")),
    ):
        table[f"{short}_Winkel"] = cols[f"{j}_deg"]
        table[f"{short}_{up}_Druck"] = np.full(n, 120.0)
        table[f"{short}_{up}"] = cols[f"{j}_up_pct"]
        table[f"{short}_{down}"] = cols[f"{j}_down_pct"]
    table["Motor_Drehzahl"] = np.full(n, 1800.0)
    log = _csv(tmp_path / "pruefstand.csv", table)
    draft = draft_mapping(summarize_log(log))
    m = parse_mapping(tomllib.loads(draft.text))
    assert (m.time.column, m.time.unit) == ("Zeit", "s")
    assert [j.name for j in m.joints] == ["boom", "arm", "bucket"]
    assert [(j.angle.column, j.angle.unit) for j in m.joints] == [
        ("Ausleger_Winkel", "deg"),
        ("Stiel_Winkel", "deg"),
        ("Löffel_Winkel", "deg"),
    ]
    assert [(j.command.up, j.command.down) for j in m.joints] == [
        ("Ausleger_Heben", "Ausleger_Senken"),
        ("Stiel_Aus", "Stiel_Ein"),
        ("Löffel_Auf", "Löffel_Ab"),
    ]
    assert '# column = "Motor_Drehzahl"' in draft.text and not draft.todo
    assert sorted(u.split(" ")[0] for u in draft.unused) == [
        "Ausleger_Heben_Druck",
        "Löffel_Auf_Druck",
        "Stiel_Aus_Druck",
    ]
    _imports(cli, log, draft, tmp_path)


def test_units_velocities_swing_strokes_and_raw_commands() -> None:
    """Radians from the range, a velocity in the angle's unit per second, a periodic swing,
    a stroke in mm from its name, a signed raw command over the span the log shows."""
    draft = draft_mapping(
        _summary(
            _ch("time", 0.0, 10.0),
            _ch("SwingAngle", -3.1, 3.1),
            _ch("SwingVel", -0.5, 0.5),
            _ch("SwingCmd", -4000.0, 4095.0),
            _ch("boom_stroke_mm", 250.0, 2000.0),
            _ch("boom_rate", -100.0, 100.0, unit="mm/s"),
            _ch("boom_valve", -100.0, 100.0),
        )
    )
    text = draft.text
    assert "periodic = true  # guessed" in text
    assert (
        'angle = { column = "SwingAngle", unit = "rad" }  # guessed: the range -3.1 .. 3.1 fits'
        in text
    )
    assert 'velocity = { column = "SwingVel", unit = "rad/s" }  # guessed' in text
    assert 'unit = "raw", raw_range = [-4000.0, 4095.0] }  # guessed: raw' in text
    assert 'position = { column = "boom_stroke_mm", unit = "mm" }' in text
    assert 'velocity = { column = "boom_rate", unit = "mm/s" }\n' in text  # the log's unit
    assert 'command = { column = "boom_valve", unit = "%" }  # guessed: % (it stays' in text
    m = parse_mapping(tomllib.loads(text))
    assert [(j.name, j.periodic) for j in m.joints] == [("swing", True), ("boom", False)]
    assert m.spec().joints[1].kind == "linear"


def test_a_stroke_in_metres_is_drafted_in_m() -> None:
    """A stroke named ``*_m``, or with no unit word and metre-sized values, is drafted in m
    (it was drafted in mm: 1000x too short through the whole pipeline); a stroke of
    mm-sized values with no unit word stays mm."""
    draft = draft_mapping(
        _summary(
            _ch("time", 0.0, 10.0),
            _ch("boom_stroke_m", 1.06, 1.83),
            _ch("u_boom", -1000.0, 1000.0),
            _ch("arm_stroke", 0.4, 1.6),
            _ch("u_arm", -1000.0, 1000.0),
            _ch("bucket_stroke", 105.0, 1661.0),
            _ch("u_bucket", -1000.0, 1000.0),
        )
    )
    text = draft.text
    assert (
        'position = { column = "boom_stroke_m", unit = "m" }  # guessed: \'m\' in the name' in text
    )
    assert (
        'position = { column = "arm_stroke", unit = "m" }  # guessed: a stroke of 0.4 .. 1.6 '
        "with no unit is metre-sized: check m"
    ) in text
    assert (
        'position = { column = "bucket_stroke", unit = "mm" }  # guessed: a stroke of 105 .. '
        "1661 with no unit: check mm, cm or m"
    ) in text
    m = parse_mapping(tomllib.loads(text))
    assert [j.unit for j in m.spec().joints] == ["m", "m", "mm"]


def test_what_it_cannot_decide_is_a_todo_and_inputs_are_offered_commented() -> None:
    draft = draft_mapping(
        _summary(
            _ch("Timestamp", 0.0, 1e4),  # ms, from the step
            _ch("boom_deg", -10.0, 60.0),
            _ch("boom_deg_alt", -10.0, 60.0),
            _ch("arm_deg", 30.0, 150.0),
            _ch("bucket_deg", -30.0, 140.0),
            _ch("bucket_cmd", -100.0, 100.0),
            _ch("EngineRPM", 800.0, 2200.0, unit="rpm"),
        )
    )
    assert 'unit = "ms"  # guessed: a mean step of 100 per sample' in draft.text
    assert draft.joints == ["bucket"]
    assert any(t.startswith("boom: 2 angle channels") for t in draft.todo)
    assert "arm: no command channel (none): map it" in draft.todo
    assert '# [[inputs]]\n# name = "engine_rpm"' in draft.text
    assert '# physical_unit = "rpm"' in draft.text
    m = parse_mapping(tomllib.loads(draft.text))
    assert not m.inputs and [j.name for j in m.joints] == ["bucket"]
    assert "# TODO: arm: no command channel" in draft.text


def test_a_ros_bags_joint_states_by_name(tmp_path: Path, cli) -> None:
    """A ``JointState``'s positions by joint name; a ``/valves`` array whose channels name no
    joint, twice as many as the joints, goes to them in pairs, in order (flagged), and the
    import takes the draft."""
    pytest.importorskip("rosbags")
    from tests.helpers.ros_bags import write_bag

    cols = arm3_plant.simulate(duration_s=6.0, seed=2, log_rate_hz=50.0)
    write_bag(tmp_path / "bag", cols, storage="mcap")
    draft = draft_mapping(summarize_log(tmp_path / "bag"))
    assert draft.joints == list(arm3_plant.JOINTS) and not draft.todo and not draft.unused
    m = parse_mapping(tomllib.loads(draft.text))
    arm = m.joints[1]
    assert (arm.angle.topic, arm.angle.field, arm.angle.unit) == (
        "/joint_states",
        "position[arm_joint]",
        "rad",
    )
    assert (arm.command.topic, arm.command.up, arm.command.down) == (
        "/valves",
        "data[2]",
        "data[3]",
    )
    assert "by its order among commands that name no joint" in draft.text
    _imports(cli, tmp_path / "bag", draft, tmp_path, "--min-steps", "20")


def test_a_valves_two_directions_on_two_topics(tmp_path: Path, cli) -> None:
    """``/boom/up`` and ``/boom/down`` (a ``Float64`` each) are drafted as ``up = { topic,
    field }`` and ``down = { ... }``, and the import takes the draft."""
    pytest.importorskip("rosbags")
    from tests.helpers.ros_bags import write_bag

    cols = arm3_plant.simulate(duration_s=6.0, seed=2, log_rate_hz=50.0)
    n = cols["t_ms"].size
    write_bag(tmp_path / "bag", cols, storage="mcap", split_valves=(np.arange(n), np.arange(n)))
    draft = draft_mapping(summarize_log(tmp_path / "bag"))
    assert draft.joints == list(arm3_plant.JOINTS) and not draft.todo and not draft.unused
    assert 'up = { topic = "/boom/up", field = "data" }' in draft.text
    m = parse_mapping(tomllib.loads(draft.text))
    assert [c.label for c in m.command_channels(m.joints[2])] == [
        "/bucket/up:data",
        "/bucket/down:data",
    ]
    _imports(cli, tmp_path / "bag", draft, tmp_path, "--min-steps", "20")


def test_the_cli_never_replaces_a_file_it_did_not_write(
    arm3_dir: Path, cli, tmp_path: Path
) -> None:
    log = arm3_dir / "logs" / "run01.csv"
    mine = tmp_path / "mine.toml"
    mine.write_text("# my own mapping\n")
    rc, _, err = cli("info", log, "--draft-mapping", mine)
    assert rc != 0 and "--draft-mapping exists (a mapping, perhaps edited" in err
    assert mine.read_text() == "# my own mapping\n"
    rc, _, _ = cli("info", log, "--draft-mapping", mine, "--overwrite")
    assert rc == 0 and mine.read_text().startswith("# exsur import mapping drafted from run01.csv")
    # exsur's own draft is not replaced either (it said 'exsur did not write it')
    rc, _, err = cli("info", log, "--draft-mapping", mine)
    assert rc != 0 and "--draft-mapping exists (a mapping, perhaps edited" in err
    rc, _, err = cli("info", log, "--draft-mapping", tmp_path / "x.json")
    assert rc != 0 and "--draft-mapping must end in .toml" in err
    rc, _, err = cli("info", arm3_dir / "arm3.toml", "--draft-mapping", tmp_path / "y.toml")
    assert rc != 0 and not (tmp_path / "y.toml").exists()
    assert "--draft-mapping drafts a mapping for a raw log" in err
    rc, _, err = cli("info", arm3_dir / "logs", "--draft-mapping", tmp_path / "y.toml")
    assert rc != 0 and not (tmp_path / "y.toml").exists()
    assert f"a folder of 4 raw log(s); draft from one of them, e.g. exsur info {log}" in err


def test_an_mdf_logs_own_units_win_over_the_range(tmp_path: Path) -> None:
    """An MDF channel's unit (``°``, ``°/s``) decides, even where the range would fit radians;
    a command in mA that leaves ±100 is ``raw`` over the span the log shows."""
    asammdf = pytest.importorskip("asammdf")
    t = np.arange(0.0, 5.0, 0.01)
    angle = 2.0 + np.sin(t)  # 1..3: small enough for radians, but the log says degrees
    signals = [
        asammdf.Signal(angle, t, name="BoomPos", unit="°"),
        asammdf.Signal(np.gradient(angle, t), t, name="BoomRate", unit="°/s"),
        asammdf.Signal(300.0 + 250.0 * np.sin(t), t, name="BoomValve", unit="mA"),
    ]
    mdf = asammdf.MDF(version="4.10")
    mdf.append(signals)
    mdf.save(tmp_path / "run.mf4", overwrite=True)
    mdf.close()
    draft = draft_mapping(summarize_log(tmp_path / "run.mf4"))
    assert 'angle = { column = "BoomPos", unit = "deg" }\n' in draft.text
    assert 'velocity = { column = "BoomRate", unit = "deg/s" }\n' in draft.text
    assert 'command = { column = "BoomValve", unit = "raw", raw_range = [50.0' in draft.text
    m = parse_mapping(tomllib.loads(draft.text))
    assert m.joints[0].command.raw_range[1] == pytest.approx(550.0, abs=0.1)


def test_a_wheel_loaders_lift_and_tilt_are_its_boom_and_bucket() -> None:
    draft = draft_mapping(
        _summary(
            _ch("Time", 0.0, 42.0, n=841),
            _ch("LiftAngle", -40.0, 45.0),
            _ch("TiltAngle", -50.0, 60.0),
            _ch("LiftJoystick", -100.0, 100.0),
            _ch("Tilt_dump", 0.0, 100.0),
            _ch("Tilt_crowd", 0.0, 100.0),
            _ch("EngineSpeed", 700.0, 2100.0, unit="rpm"),
        )
    )
    m = parse_mapping(tomllib.loads(draft.text))
    assert [j.name for j in m.joints] == ["boom", "bucket"]
    assert m.joints[0].command.column == "LiftJoystick"
    assert (m.joints[1].command.up, m.joints[1].command.down) == ("Tilt_dump", "Tilt_crowd")
    assert (m.time.column, m.time.unit) == ("Time", "s")
    assert "rate_hz = 20.0  # the log runs at 20 Hz" in draft.text
    assert '# name = "engine_speed"' in draft.text
