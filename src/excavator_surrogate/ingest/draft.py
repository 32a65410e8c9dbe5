"""A first mapping for a raw log, from what it holds (``exsur info LOG --draft-mapping MAP.toml``).

Writing the mapping is the first thing a user with their own machine does, and the channel
names of most loggers already say most of it: ``Boom_ang``, ``boom_up_pct``,
``ArmVelocity``, ``bkt_in_duty``, a ``JointState``'s ``position[boom_joint]``.  From a
:class:`~.summary.LogSummary` (:func:`~.inventory.summarize_log`) this guesses

- the **joint** of each channel from its name's words (swing/slew, boom, arm/stick/dipper,
  bucket/bkt; a ROS ``JointState``'s joint names), and its **role** (angle or stroke,
  velocity, command) from cue words (``ang``, ``pos``, ``vel``, ``cmd``, ``duty``, ``valve``
  ...) and the log's unit;
- the **units**: the log's own unit label where it gives one (:func:`~.checks.log_unit_name`),
  else a unit word in the name (``deg``, ``rad``, ``mm``), else the range (an angle beyond
  ±2π is in degrees); a command in % where the name or unit says so or it stays within
  ±100, else ``raw`` over the span the log shows;
- a joint's **two one-way command channels** (``up``/``down``) from direction words (up/dn,
  out/in, extend/retract, raise/lower, open/close, left/right ...), with a topic each where
  a ROS machine publishes the two directions on two topics;
- the **time column** of a table (``t``, ``time``, ``timestamp`` ...) and its unit from the
  name (``t_ms``) or the time step.

Every guess is written beside its line as a ``# guessed: ...`` comment, what it could not
decide as a ``# TODO`` line, and the channels it did not use are listed at the end, so the
user checks a short file instead of writing one.  A joint is written only with an angle and
a command (the mapping's required pair); one that has only one of them is listed in the
TODO lines.  Exogenous-looking channels (engine speed, throttle, pressure, gear) are offered
as a commented ``[[inputs]]`` table, not mapped: whether one helps is for the data to show
(``train.exogenous``).
"""

from __future__ import annotations

import math
import re
import unicodedata
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

from ..config import toml_value
from .checks import log_unit_name
from .mapping import TIME_UNIT_S
from .options import CsvOptions
from .summary import ChannelSummary, LogSummary

JOINT_WORDS: dict[str, tuple[str, ...]] = {
    "swing": (
        *("swing", "slew", "turret", "house"),
        *("schwenk", "schwenkwerk", "drehwerk", "oberwagen", "tourelle", "giro", "senkai"),
    ),
    "boom": ("boom", "lift", "ausleger", "fleche", "pluma"),
    "arm": (
        *("arm", "stick", "dipper"),
        *("stiel", "loeffelstiel", "loffelstiel", "balancier", "brazo"),
    ),
    "bucket": (
        *("bucket", "bkt", "bck", "tilt"),
        *("loeffel", "loffel", "schaufel", "godet", "cuchara", "cucharon"),
    ),
}
"""The excavator's joints, in the mapping's order, and the words that name each in a channel
(a wheel loader's lift arm and tilt are its boom and bucket), in English, German
(``Ausleger``, ``Stiel``, ``Löffel``, ``Drehwerk``), French (``flèche``, ``balancier``,
``godet``, ``tourelle``) and Spanish (``pluma``, ``brazo``, ``cucharón``, ``giro``)."""
_ALL_JOINT_WORDS = frozenset(w for ws in JOINT_WORDS.values() for w in ws)
VELOCITY_WORDS = ("vel", "velocity", "omega", "speed", "dot", "dps", "degps", "radps", "dq")
VELOCITY_WORDS += ("geschw", "geschwindigkeit", "winkelgeschwindigkeit", "drehrate")
VELOCITY_WORDS += ("vitesse", "velocidad")
"""Words of a velocity channel (``boom_vel``, ``ArmOmega``, ``bucket_dps``,
``Stiel_Geschw``)."""
COMMAND_WORDS = (
    "cmd",
    "command",
    "duty",
    "valve",
    "pilot",
    "lever",
    "joy",
    "joystick",
    "pwm",
    "spool",
    "current",
    "u",
    "pct",
    "percent",
    "setpoint",
    "demand",
)
COMMAND_WORDS += ("ventil", "sollwert", "soll", "ansteuerung", "strom", "hebel", "steuer")
COMMAND_WORDS += ("commande", "consigne", "vanne", "comando", "mando", "valvula")
"""Words of a command channel (``boom_cmd``, ``Arm_out_duty``, ``bkt_valve``,
``Ausleger_Ventil``)."""
ANGLE_WORDS = ("ang", "angle", "pos", "position", "theta", "deg", "rad", "q", "enc", "encoder")
ANGLE_WORDS += ("winkel", "angulo", "posicion")
"""Words of an angle channel (``Boom_ang``, ``arm_deg``, ``bucket_pos``, ``Stiel_Winkel``)."""
STROKE_WORDS = ("stroke", "len", "length", "extension")
"""Words of a stroke channel (``boom_stroke_mm``), a linear joint's position."""
STROKE_M_BELOW = 10.0
"""A stroke channel with no unit whose values stay within ± this is drafted in m (cylinder
strokes run 0.1 to 3 m: 100 to 3000 in mm, 10 to 300 in cm); beyond it, in mm."""
MEASURE_WORDS = ("p", "pressure", "press", "fb", "feedback", "meas", "measured", "actual")
MEASURE_WORDS += ("temp", "temperature", "flow", "force", "load", "torque", "bar", "psi")
MEASURE_WORDS += ("druck", "ist", "istwert", "temperatur", "kraft", "pression", "presion")
"""Words of a measurement that is not a command, though it may name a direction
(``Boom_UpH_Cyl_P``, a cylinder pressure; ``Arm_in_FB``, a valve's feedback;
``Ausleger_Heben_Druck``)."""
UP_WORDS = ("up", "out", "extend", "ext", "raise", "open", "left", "cw", "plus", "fwd", "dump")
UP_WORDS += ("heben", "auf", "aus", "ausfahren", "links", "monter", "montee", "sortie")
UP_WORDS += ("gauche", "subir", "arriba", "izquierda")
"""Direction words of the one-way channel that is the command's ``up`` (positive) part."""
DOWN_WORDS = ("dn", "down", "in", "retract", "ret", "lower", "close", "right", "ccw", "minus")
DOWN_WORDS += ("crowd", "curl", "senken", "ab", "ein", "einfahren", "rechts", "descendre")
DOWN_WORDS += ("descente", "rentree", "droite", "bajar", "abajo", "derecha")
"""Direction words of the ``down`` (negative) part."""
INPUT_WORDS = ("rpm", "engine", "eng", "throttle", "pressure", "pump", "gear", "load", "bar")
INPUT_WORDS += ("drehzahl", "motor", "gas", "pumpe", "gang", "moteur")
"""Words of a channel that may be an exogenous input (engine speed, throttle, pump pressure)."""
TIME_WORDS = ("t", "time", "timestamp", "stamp", "ts", "zeit", "sec", "seconds", "tiempo")
"""Words of a table's time column."""
TIME_UNITS = {"s": "s", "sec": "s", "ms": "ms", "msec": "ms", "us": "us", "usec": "us"}
TIME_UNITS |= {"ns": "ns", "nsec": "ns"}


def words(name: str) -> list[str]:
    """The lower-case words of a channel name: ``"BoomAngle_deg"`` -> boom, angle, deg;
    ``"bktang"`` -> bkt, ang (a joint word glued to the rest is split off); accents and
    umlauts lose their marks (``"Löffel_Winkel"`` -> loffel, winkel)."""
    s = unicodedata.normalize("NFKD", name.replace("ß", "ss"))
    s = "".join(ch for ch in s if not unicodedata.combining(ch))
    s = re.sub(r"([a-z0-9])([A-Z])", r"\1 \2", s)
    s = re.sub(r"([A-Z]+)([A-Z][a-z])", r"\1 \2", s)
    out: list[str] = []
    for w in re.split(r"[^A-Za-z0-9]+", s.lower()):
        w = w.strip("0123456789") or w
        if not w:
            continue
        if w in _ALL_JOINT_WORDS:  # Loeffelstiel is the arm, not the bucket and a stick
            out.append(w)
            continue
        glued = next(
            (j for js in JOINT_WORDS.values() for j in js if w.startswith(j) and w != j), None
        )
        out.extend([glued, w[len(glued) :]] if glued and len(glued) >= 3 else [w])
    return out


@dataclass
class _Channel:
    """One numeric channel, what its name says and how a mapping names it."""

    summary: ChannelSummary
    ref: dict[str, str]
    """How a mapping names it: ``{"column": ...}`` or ``{"topic": ..., "field": ...}``."""
    words: list[str]
    unit: str | None
    """The log's unit label as a mapping's unit name (:func:`~.checks.log_unit_name`), or None."""
    joint: str | None = None
    role: str | None = None
    """``angle``, ``stroke``, ``velocity``, ``command``, ``input``, ``time`` or None."""
    used: bool = False
    by_order: bool = False
    """Given to its joint by its place among commands that name no joint."""


@dataclass
class Draft:
    """A drafted mapping: its TOML text and what it found."""

    text: str
    """The mapping file, with a ``# guessed`` comment beside each guess."""
    joints: list[str]
    """The joints it maps, in order."""
    todo: list[str] = field(default_factory=list)
    """What it could not decide (also ``# TODO`` lines in ``text``)."""
    unused: list[str] = field(default_factory=list)
    """Channels it left out."""


def _has(ws: Sequence[str], cues: Sequence[str]) -> bool:
    """Whether a word (or its singular: ``valves``) is one of ``cues``."""
    return any(w in cues or (len(w) > 3 and w[-1] == "s" and w[:-1] in cues) for w in ws)


def _sig(x: float) -> float:
    """A value the log shows, to 6 significant digits (for the draft's text)."""
    return float(f"{x:.6g}")


def _channels(summary: LogSummary) -> list[_Channel]:
    """The log's numeric channels with their mapping names and words."""
    ros = summary.kind in ("rosbag2", "mcap", "rosbag1")
    out = []
    for c in summary.channels:
        if not c.name or (c.lo is None and "text" not in c.note and "timestamp" not in c.note):
            continue
        if ros and c.name.startswith("layout."):  # a MultiArray's layout, not a signal
            continue
        if ros:
            topic = c.group.split(" (", 1)[0]
            by_name = c.note[2:] if c.note.startswith("= ") else ""  # position[boom_joint]
            ref = {"topic": topic, "field": by_name or c.name}
            ws = words(by_name or c.name) + words(topic)
        else:
            ref = {"column": c.name}
            ws = words(c.name) + words(c.unit)
        out.append(_Channel(c, ref, ws, log_unit_name(c.unit)))
    return out


def _classify(ch: _Channel, *, table: bool) -> None:
    """Set the joint and the role of a channel from its words and unit."""
    ws, c = ch.words, ch.summary
    joints = [j for j, cues in JOINT_WORDS.items() if _has(ws, cues)]
    ch.joint = joints[0] if len(joints) == 1 else None
    unit = ch.unit
    if c.note.startswith("time base"):  # a dSPACE export's x axis: the time by default
        ch.role, ch.used = "time", True
    elif table and ch.joint is None and _has(ws, TIME_WORDS):
        ch.role = "time"
    elif ch.joint is None and _has(ws, INPUT_WORDS):  # EngineSpeed: not a joint's velocity
        ch.role = "input"
    elif _has(ws, VELOCITY_WORDS) or (unit or "").endswith("/s"):
        ch.role = "velocity"
    elif not _has(ws, MEASURE_WORDS) and (
        _has(ws, COMMAND_WORDS)
        or (ch.joint and _has(ws, UP_WORDS + DOWN_WORDS) and not _has(ws, ANGLE_WORDS))
    ):
        ch.role = "command"
    elif _has(ws, STROKE_WORDS) or unit in ("m", "cm", "mm"):
        ch.role = "stroke"
    elif _has(ws, ANGLE_WORDS) or unit in ("deg", "rad"):
        ch.role = "angle"


def _position_unit(ch: _Channel) -> tuple[str, str]:
    """``(unit, why)`` of an angle or stroke channel; ``why`` is empty where the log says."""
    c, unit = ch.summary, ch.unit
    if unit in ("deg", "rad", "m", "cm", "mm"):
        return unit, ""
    for w in ("deg", "rad", "mm", "cm"):
        if w in ch.words:
            return w, f"'{w}' in the name"
    lo, hi = c.lo or 0.0, c.hi or 0.0
    if ch.role == "stroke":
        if "m" in ch.words:  # boom_stroke_m: a lone 'm' names a unit only beside a stroke
            return "m", "'m' in the name"
        if max(abs(lo), abs(hi)) < STROKE_M_BELOW:
            return "m", f"a stroke of {lo:.4g} .. {hi:.4g} with no unit is metre-sized: check m"
        return "mm", f"a stroke of {lo:.4g} .. {hi:.4g} with no unit: check mm, cm or m"
    if max(abs(lo), abs(hi)) > 2 * math.pi + 0.2:
        return "deg", f"the range {lo:.4g} .. {hi:.4g} is too wide for radians"
    return "rad", f"the range {lo:.4g} .. {hi:.4g} fits radians"


def _assign_by_order(chs: list[_Channel]) -> None:
    """Commands that name no joint (a ROS ``/valves`` array's ``data[0]`` ...), as many as the
    joints that have an angle and no command, or twice as many (up/down pairs), go to those
    joints in order: the first one or two to the first such joint, and so on."""
    loose = [c for c in chs if c.role == "command" and c.joint is None]
    if not loose or len({c.ref.get("topic") for c in loose}) != 1:
        return
    waiting = []
    for name in JOINT_WORDS:
        mine = [c for c in chs if c.joint == name]
        pos = [c for c in mine if c.role in ("angle", "stroke")]
        if len(pos) == 1 and not any(c.role == "command" for c in mine):
            waiting.append(name)
    if not waiting or len(loose) not in (len(waiting), 2 * len(waiting)):
        return
    per = len(loose) // len(waiting)
    for k, c in enumerate(loose):
        c.joint, c.by_order = waiting[k // per], True


def _command(chs: list[_Channel]) -> tuple[dict[str, Any], list[str]] | None:
    """The ``command`` table of a joint from its command channels, and its guesses."""
    guesses: list[str] = []
    if any(c.by_order for c in chs):
        guesses.append("given to this joint by its order among commands that name no joint")
    if len(chs) == 1:
        table: dict[str, Any] = dict(chs[0].ref)
        parts = chs[0:1]
    elif len(chs) == 2:
        up = [c for c in chs if _has(c.words, UP_WORDS)]
        down = [c for c in chs if _has(c.words, DOWN_WORDS)]
        if len(up) == 1 and len(down) == 1 and up[0] is not down[0]:
            parts = [up[0], down[0]]
            guesses.append("up/down from the direction words")
        else:
            parts = list(chs)
            guesses.append("up/down: no direction words, check which one raises the joint")
        if "column" in parts[0].ref:
            table = {"up": parts[0].ref["column"], "down": parts[1].ref["column"]}
        elif parts[1].ref["topic"] == parts[0].ref["topic"]:
            table = {"topic": parts[0].ref["topic"]}
            table |= {"up": parts[0].ref["field"], "down": parts[1].ref["field"]}
        else:  # each direction on a topic of its own
            table = {"up": dict(parts[0].ref), "down": dict(parts[1].ref)}
    else:
        return None
    lo = min(c.summary.lo or 0.0 for c in parts)
    hi = max(c.summary.hi or 0.0 for c in parts)
    units = {c.unit or c.summary.unit.strip() for c in parts}
    pct = _has([w for c in parts for w in c.words], ("pct", "percent", "duty")) or units == {"%"}
    if pct or (-100.5 <= lo and hi <= 100.5):
        table["unit"] = "%"
        if hi - lo < 1e-9 and not pct:
            guesses.append(f"% (this log holds it at {lo:.4g}: check the unit)")
        elif not pct:
            guesses.append(f"% (it stays within ±100: {lo:.4g} .. {hi:.4g})")
    else:
        span = max(abs(lo), abs(hi)) if len(parts) == 2 else None
        raw = [-span, span] if span is not None else [lo, hi]
        table |= {"unit": "raw", "raw_range": [_sig(x) for x in raw]}
        guesses.append(f"raw, full scale {raw[0]:.4g} .. {raw[1]:.4g} as seen in this log")
    return table, guesses


def draft_mapping(summary: LogSummary, *, csv: CsvOptions | None = None) -> Draft:
    """A mapping for the log ``summary`` describes, with its guesses marked (module doc).

    Args:
        summary: what the log holds (:func:`~.inventory.summarize_log`).
        csv: the ``[csv]`` options it was read with (written into the draft).

    Returns:
        The draft: TOML text, the joints it maps, its TODOs and the channels left out.
    """
    table = summary.kind in ("csv", "parquet")
    chs = _channels(summary)
    for ch in chs:
        _classify(ch, table=table)
    lines = [
        f"# exsur import mapping drafted from {summary.path.name} ({summary.label}).",
        "# Check every line marked 'guessed', then: exsur import LOGS --mapping THIS.toml "
        "--dry-run",
        "# (docs/import.md describes every key).",
        "",
        "[machine]",
        'name = "machine"  # your machine\'s name (stored with the data)',
    ]
    rates = [c.rate_hz for c in summary.channels if c.rate_hz]
    log_rate = max(rates) if rates else _table_rate(chs) if table else None
    rate = 20.0 if log_rate is None or log_rate >= 20.0 else float(f"{log_rate:.3g}")
    why = f"  # the log runs at {log_rate:.4g} Hz" if log_rate else ""
    lines.append(f"rate_hz = {toml_value(rate)}{why}")
    todo: list[str] = []
    if table:
        lines += ["", "[time]", *_time_lines(chs, todo)]
    if csv is not None and csv != CsvOptions():
        lines += ["", "[csv]"]
        for k, v in vars(csv).items():
            if v != getattr(CsvOptions(), k):
                lines.append(f"{k} = {toml_value(v)}")
    _assign_by_order(chs)
    joints = []
    for name in JOINT_WORDS:
        mine = [c for c in chs if c.joint == name]
        block = _joint_lines(name, mine, todo)
        if block:
            joints.append(name)
            lines += ["", *block]
    loose = [c for c in chs if c.role == "command" and c.joint is None]
    if loose and len(joints) < len(JOINT_WORDS):
        names = ", ".join(_label(c) for c in loose)
        todo.append(f"command channels of no named joint: {names}")
    inputs = [c for c in chs if c.role == "input" and not c.used]
    if inputs:
        lines += [
            "",
            "# Exogenous inputs: uncomment the ones the machine responds to (docs/import.md).",
        ]
        for c in inputs:
            c.used = True
            own = words(c.ref.get("field", c.ref.get("column", "")))
            name = re.sub(r"[^a-z0-9_]+", "_", "_".join(own)).strip("_") or "input"
            unit = c.summary.unit.strip() or "physical"
            lines += [
                "# [[inputs]]",
                f"# name = {toml_value(name)}",
                *(f"# {k} = {toml_value(v)}" for k, v in c.ref.items()),
                '# unit = "physical"',
                f"# physical_unit = {toml_value(unit)}",
            ]
            if c.summary.lo is not None and c.summary.hi is not None:
                lines.append(f"# range = {toml_value([_sig(c.summary.lo), _sig(c.summary.hi)])}")
    unused = [_label(c) for c in chs if not c.used]
    if todo:
        lines += ["", *(f"# TODO: {t}" for t in todo)]
    if unused:
        lines += ["", "# Channels not mapped:", *(f"#   {u}" for u in unused)]
    return Draft("\n".join(lines) + "\n", joints, todo, unused)


def _label(c: _Channel) -> str:
    s = c.summary
    name = f"{c.ref['topic']} {c.ref['field']}" if "topic" in c.ref else c.ref["column"]
    unit = f" [{s.unit}]" if s.unit else ""
    rng = f" {s.lo:.4g} .. {s.hi:.4g}" if s.lo is not None and s.hi is not None else ""
    return f"{name}{unit}{rng}"


def _mean_step(s: ChannelSummary) -> float:
    """A numeric time column's mean step, in its own unit."""
    return ((s.hi or 0.0) - (s.lo or 0.0)) / max(s.n_sample - 1, 1)


def _table_rate(chs: list[_Channel]) -> float | None:
    """A table's sample rate [Hz] from its time column's span (None: no numeric one)."""
    t = next((c for c in chs if c.role == "time" and c.summary.lo is not None), None)
    if t is None or t.summary.hi is None or t.summary.n_sample < 2 or t.summary.hi <= t.summary.lo:
        return None
    return 1.0 / (_mean_step(t.summary) * TIME_UNIT_S[_time_unit(t)[0]])


def _time_unit(t: _Channel) -> tuple[str, str]:
    """``(unit, why)`` of a time column; ``why`` is empty where its name says."""
    unit_word = next((TIME_UNITS[w] for w in t.words if w in TIME_UNITS), None)
    if t.summary.lo is None:  # text or a timestamp type
        return "datetime", "text or timestamps"
    if unit_word is not None:
        return unit_word, ""
    step = _mean_step(t.summary)
    unit = "s" if step <= 1.0 else "ms" if step <= 1e3 else "us" if step <= 1e6 else "ns"
    return unit, f"a mean step of {step:.4g} per sample"


def _time_lines(chs: list[_Channel], todo: list[str]) -> list[str]:
    """The ``[time]`` table of a CSV or Parquet log."""
    times = [c for c in chs if c.role == "time"]
    if not times:
        todo.append("no time column found: set [time] column and unit")
        return ['# column = "?"', '# unit = "s"']
    t = times[0]
    t.used = True
    unit, why = _time_unit(t)
    mark = f"  # guessed: {why}" if why else ""
    return [f"column = {toml_value(t.ref['column'])}", f"unit = {toml_value(unit)}{mark}"]


def _joint_lines(name: str, chs: list[_Channel], todo: list[str]) -> list[str]:
    """The ``[[joints]]`` table of one joint, or [] (with a TODO) when it lacks a channel."""
    pos = [c for c in chs if c.role in ("angle", "stroke")]
    vel = [c for c in chs if c.role == "velocity"]
    cmd = [c for c in chs if c.role == "command"]
    named = [c for c in cmd if _has(c.words, COMMAND_WORDS)]
    if len(cmd) > 2 and 1 <= len(named) <= 2:  # direction words alone are the weaker cue
        cmd = named
    if not pos and not cmd:
        return []
    if len(pos) != 1:
        todo.append(
            f"{name}: {'no' if not pos else len(pos)} angle channels "
            + ("found" if not pos else f"({', '.join(_label(c) for c in pos)}): keep one")
        )
        return []
    command = _command(cmd) if cmd else None
    if command is None:
        what = "no command channel" if not cmd else f"{len(cmd)} command channels"
        todo.append(f"{name}: {what} ({', '.join(_label(c) for c in cmd) or 'none'}): map it")
        return []
    p = pos[0]
    unit, why = _position_unit(p)
    linear = unit in ("m", "cm", "mm")
    out = ["[[joints]]", f"name = {toml_value(name)}"]
    if name == "swing" and not linear:
        out.append("periodic = true  # guessed: the swing turns without end stops; else false")
    key = "position" if linear else "angle"
    out.append(
        f"{key} = {toml_value(p.ref | {'unit': unit})}" + (f"  # guessed: {why}" if why else "")
    )
    p.used = True
    if len(vel) == 1:
        v = vel[0]
        mark = "" if v.unit == f"{unit}/s" else f"  # guessed: the {key}'s unit per second"
        out.append(f"velocity = {toml_value(v.ref | {'unit': f'{unit}/s'})}{mark}")
        v.used = True
    elif len(vel) > 1:
        todo.append(
            f"{name}: {len(vel)} velocity channels ({', '.join(_label(c) for c in vel)}): keep one"
        )
    table, guesses = command
    mark = f"  # guessed: {'; '.join(guesses)}" if guesses else ""
    out.append(f"command = {toml_value(table)}{mark}")
    for c in cmd:
        c.used = True
    return out
