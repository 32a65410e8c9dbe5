"""The output-folder rule: what exsur may replace or write into, and when.

Every command that writes ``--out`` checks it first with :func:`check_out_dir` (folders) or
:func:`check_out_file` (single files), before it reads or computes anything expensive:

- a folder that does not exist, or is empty, is always fine;
- an existing folder is replaced (``simulate``, ``clean``, ``run``, ``import``, ``control``) or
  written into (``train``, ``evaluate``, ``compare``, ``sweep``) only when exsur wrote it: it
  holds the marker :data:`MARKER` (written before the first file of every output folder) and
  nothing but what exsur wrote (:func:`is_exsur_output`: the files the marker records, for an
  output written whole; else names exsur writes), and it is an output of a kind the command
  may use (:data:`ACCEPTS`); anything else, including a folder of an older exsur without the
  marker, needs an explicit ``--overwrite``;
- an input of the command (a log, the mapping, a dataset) never lies inside the output folder,
  nor the output folder inside an input that is an exsur output, not even with ``--overwrite``;
- the current folder, or one of its parents, is never an output folder;
- a file output (``export``, ``merge``) is never an existing folder nor one of the inputs, has
  the command's suffix, and replaces only a file exsur wrote (checked by content);
- one writer per folder: the CLI holds an OS lock (:func:`~.outlock.lock_out`) on ``.<name>.lock`` next
  to the folder for the whole command; the OS releases it when the process dies.

:func:`~excavator_surrogate.io_utils.atomic_dir` applies the same rule when it replaces a
folder, so the Python API is protected too; ``--overwrite`` reaches it through
:func:`replace_allowed`.
"""

from __future__ import annotations

import contextlib
import contextvars
import fnmatch
import json
import os
import re
from collections.abc import Iterable, Iterator
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from .errors import ConfigError, need_path
from .outlock import checked_under_lock, lock_out, note_checked, note_folders_made
from .version import __version__

MARKER = ".exsur.json"
"""The file that marks a folder as an exsur output, by content (:func:`marker`)."""

MARKER_FORMAT = "exsur-output"
"""The ``format`` field of :data:`MARKER`."""

PNG_SOFTWARE = f"exsur {__version__}"
"""The ``Software`` text of the PNG files exsur writes alone (``exsur plot``)."""

KINDS = ("dataset", "model", "evaluation", "compare", "run", "control", "sweep", "output")
"""What an output folder is (the marker's ``kind``)."""

ACCEPTS = {
    "dataset": ("dataset",),
    "run": ("run",),
    "control": ("control",),
    "model": ("model", "evaluation", "output"),
    "evaluation": ("evaluation", "model", "output"),
    "compare": ("compare", "output"),
    "sweep": ("sweep", "output"),
}
"""The kinds of an existing output that a command writing a ``kind`` output may replace
(dataset, run, control: only their own) or write into (a model and its evaluation share a
folder, no file name of one is the other's) without ``--overwrite``; a kind not listed (the
API's ``output``) takes any."""

NESTED = {"dataset": (), "control": (), "run": ("dataset", "model", "evaluation")}
"""The kinds of exsur output that a replaced kind of output holds inside it (a run: its data,
models and the evaluation against cleaned data); another output found inside one is not
part of it."""

FILES = (
    "manifest.json",
    "metrics.json",
    "best.pt",
    "last.pt",
    "sweep.json",
    "report.md",
    "config.toml",
    "import_report.json",
    "import_report.md",
    "table.md",
    "cbe.png",
    "cbe_*.png",
    "horizon.png",
    "fusion_*.png",
    "compare.png",
    "tracking.png",
    "learning_curve.png",
    "trajectories.npz",
    "log.csv",
    "sweep.md",
    "sweep.png",
    "study.db",
    "study.db-*",
    "*.pt",
    "*.onnx",
)
"""Names exsur writes at any level of its output folders (shell patterns)."""

DIRS = {"episodes": ("*.parquet", "*.png"), "figures": ("*.png",), "tb": ("events.out.tfevents.*",)}
"""Sub-folders with a fixed content pattern (`exsur plot` puts PNGs next to episodes); other
sub-folders must follow the rule themselves."""

TEMP_RANDOM = "[a-z0-9_]{8}"
"""The random part of :mod:`tempfile`'s names (``mkstemp``, ``mkdtemp``)."""

TEMP = re.compile(rf"\..+\.\d+-{TEMP_RANDOM}\.tmp")
"""The temporary file of exsur's atomic writes, ``.NAME.<pid>-XXXXXXXX.tmp``: inside an output
folder only while a command writes it, or after a killed one (the next write sweeps it)."""

_ALLOWED: contextvars.ContextVar[frozenset[Path]] = contextvars.ContextVar(
    "exsur_replace_allowed", default=frozenset()
)


def _match(name: str, patterns: Iterable[str]) -> bool:
    return any(fnmatch.fnmatchcase(name, p) for p in patterns)


def _is_temp(e: Path) -> bool:
    """``e`` is a temporary file of exsur's (:data:`TEMP`); never a folder or a link."""
    return TEMP.fullmatch(e.name) is not None and e.is_file() and not e.is_symlink()


def marker(kind: str) -> dict[str, Any]:
    """The content of :data:`MARKER` for an output folder of ``kind`` (one of :data:`KINDS`)."""
    if kind not in KINDS:
        raise ValueError(f"output kind {kind!r} is not one of {KINDS}")
    created = datetime.now(UTC).isoformat(timespec="seconds")
    return {"format": MARKER_FORMAT, "kind": kind, "version": __version__, "created": created}


def read_marker(path: str | Path) -> dict[str, Any] | None:
    """The marker of folder ``path`` (None: absent, unreadable or not exsur's)."""
    try:
        d = json.loads((Path(path) / MARKER).read_text())
    except (OSError, ValueError):
        return None
    ok = isinstance(d, dict) and d.get("format") == MARKER_FORMAT and d.get("kind") in KINDS
    return d if ok else None


def foreign_entry(path: Path, *, top: bool = True, within: str = "") -> str | None:
    """The first entry of folder ``path`` that exsur did not write (None: all are exsur's).

    At the top level the folder must hold a valid :data:`MARKER` (an empty folder passes);
    without one the answer is ``MARKER`` itself.  A marker that records what exsur wrote
    (``files``: an output written whole, :func:`~excavator_surrogate.io_utils.atomic_dir`)
    is exact: every entry must be recorded.  A marker without a record (a folder commands
    write into, or an output of exsur before session 114) falls back to the names exsur
    writes (:data:`FILES`, :data:`DIRS`), and an exsur output inside it must be of a kind
    the output around it holds (:data:`NESTED`; ``within``: that kind, in the recursion).
    """
    try:
        entries = sorted(e for e in path.iterdir() if e.name != MARKER)
    except OSError as e:
        return f"{path.name} ({e.strerror})"
    if not entries:
        return None
    mark = read_marker(path)
    if top and mark is None:
        return MARKER
    if mark is not None and isinstance(mark.get("files"), list):
        return _unrecorded(path, set(mark["files"]))
    within = (mark or {}).get("kind", within)
    for e in entries:
        name = e.name
        if _is_temp(e):
            continue
        if e.is_symlink():
            return name
        if e.is_dir():
            if name in DIRS:
                try:
                    bad = next(
                        (
                            c.name
                            for c in e.iterdir()
                            if not _match(c.name, DIRS[name]) and not _is_temp(c)
                        ),
                        None,
                    )
                except OSError as err:  # an unreadable episodes/ is not known to be exsur's
                    return f"{name} ({err.strerror})"
                if bad is not None:
                    return f"{name}/{bad}"
                continue
            inner = read_marker(e)
            if inner is not None and inner["kind"] not in NESTED.get(within, KINDS):
                return name  # another output, not part of this one
            sub = foreign_entry(e, top=False, within=within)
            if sub is not None:
                return f"{name}/{sub}"
            continue
        if not _match(name, FILES):
            return name
    return None


def _unrecorded(folder: Path, record: set[str], rel: str = "") -> str | None:
    """The first entry below ``folder`` (at ``rel`` in the output whose marker holds
    ``record``) that the record does not list; an output inside with a record of its own
    (a run's dataset) answers for its entries."""
    try:
        entries = sorted(folder.iterdir())
    except OSError as e:
        return f"{rel.rstrip('/') or folder.name} ({e.strerror})"
    for e in entries:
        name = rel + e.name
        if name == MARKER or _is_temp(e):
            continue
        if name not in record or e.is_symlink():
            return name
        if e.is_dir():
            own = isinstance((read_marker(e) or {}).get("files"), list)
            sub = foreign_entry(e, top=False) if own else _unrecorded(e, record, name + "/")
            if sub is not None:
                return f"{name}/{sub}" if own else sub
    return None


def refusal(path: Path, flag: str) -> str:
    """The one-line error for a folder exsur may not replace (``foreign_entry`` is not None)."""
    bad = foreign_entry(path)
    hint = "choose a new or empty folder, or pass --overwrite to replace it"
    if bad == MARKER:
        names = sorted(e.name for e in path.iterdir() if e.name != MARKER)
        first = next((n for n in names if not _is_temp(path / n)), names[0] if names else "")
        return (
            f"{path}: {flag} holds '{first}', which exsur did not write (no exsur marker "
            f"{MARKER}; an older exsur's output has none either); {hint}"
        )
    inner = read_marker(path / bad) if bad else None
    if inner is not None:
        return f"{path}: {flag} holds '{bad}', another exsur output (a {inner['kind']}); {hint}"
    return f"{path}: {flag} holds '{bad}', which exsur did not write; {hint}"


def is_exsur_output(path: str | Path) -> bool:
    """True if ``path`` is an empty folder or an output folder that exsur wrote."""
    p = Path(path)
    return p.is_dir() and not p.is_symlink() and foreign_entry(p) is None


def other_kind(path: Path, kind: str | None) -> str | None:
    """The kind of exsur output ``path`` is, if a ``kind`` output may not replace or write
    into it (:data:`ACCEPTS`); None: it may (or ``path`` is no marked output)."""
    found = (read_marker(path) or {}).get("kind")
    ok = found is None or kind is None or found in ACCEPTS.get(kind, KINDS)
    return None if ok else found


def kind_refusal(path: Path, found: str, kind: str, flag: str) -> str:
    """The one-line error for an exsur output of another kind (:func:`other_kind`)."""
    return (
        f"{path}: {flag} is an exsur {found} output ({MARKER}), and this command writes a "
        f"{kind} output; give another {flag}, or pass --overwrite"
    )


@contextlib.contextmanager
def replace_allowed(path: str | Path) -> Iterator[None]:
    """Within the block, :func:`~excavator_surrogate.io_utils.atomic_dir` may replace ``path``
    even if exsur did not write it (the user passed ``--overwrite``)."""
    token = _ALLOWED.set(_ALLOWED.get() | {Path(path).resolve()})
    try:
        yield
    finally:
        _ALLOWED.reset(token)


def may_replace(path: Path, kind: str | None = None) -> bool:
    """True if ``path`` is absent, empty, exsur's own output that a ``kind`` output may replace,
    or allowed by :func:`replace_allowed`."""
    if not path.exists() or path.resolve() in _ALLOWED.get():
        return True
    return is_exsur_output(path) and other_kind(path, kind) is None


def check_not_cwd(path: Path, flag: str = "--out") -> None:
    """Refuse the current folder or one of its parents (``.``, ``..``, ``/``) as an output."""
    rp, cwd = path.resolve(), Path.cwd().resolve()
    if rp == cwd or rp in cwd.parents:
        raise ConfigError(
            f"{path}: {flag} is the current folder or one of its parents; give a new folder name"
        )


def _writable(path: Path, flag: str) -> None:
    """The nearest existing folder of ``path`` accepts new entries."""
    p = path
    while not p.exists() and not p.is_symlink() and p.parent != p:
        p = p.parent
    if p.is_symlink() and not p.exists():  # os.replace and mkdir fail on it, late
        where = flag if p == path else str(p)
        raise ConfigError(
            f"{path}: {where} is a symbolic link to a missing folder; give another {flag}"
        )
    if p.exists() and not p.is_dir():
        raise ConfigError(f"{path}: {p} is a file, not a folder; give another {flag}")
    if not os.access(p, os.W_OK | os.X_OK):
        raise ConfigError(
            f"{path}: {p} is not writable; give another {flag} or fix its permissions"
        )


def _inputs_inside(out: Path, inputs: Iterable[str | Path], flag: str) -> None:
    ro = out.resolve()
    for s in inputs:
        rs = Path(s).resolve()
        if rs == ro or ro in rs.parents:
            raise ConfigError(
                f"{s}: this input lies inside {flag} {out}, which exsur writes; "
                "move it out or write elsewhere"
            )
        if rs in ro.parents and read_marker(rs) is not None:
            raise ConfigError(
                f"{out}: {flag} lies inside {s}, an exsur output this command reads; "
                f"give a {flag} outside it"
            )


def check_out_dir(
    out: str | Path,
    *,
    overwrite: bool = False,
    inputs: Iterable[str | Path] = (),
    flag: str = "--out",
    lock: bool = False,
    kind: str | None = None,
) -> Path:
    """Check an output folder against the output-folder rule (see the module docstring).

    Args:
        out: the folder a command will replace or write into.
        overwrite: the user passed ``--overwrite``: a folder exsur did not write may be used.
        inputs: files and folders the command reads; none may lie inside ``out``, nor ``out``
            inside one that is an exsur output (a dataset).
        flag: option name used in messages.
        lock: also take the folder's writer lock (:func:`~.outlock.lock_out`) before the checks.
        kind: the kind of output the command writes (:data:`KINDS`): an exsur output of a
            kind it may not replace or write into (:data:`ACCEPTS`) needs ``overwrite``.

    Returns:
        ``out`` as a Path.

    Raises:
        ConfigError: one line naming the folder, what is wrong and what to do.
    """
    out = Path(out)
    check_not_cwd(out, flag)
    if out.exists() and not out.is_dir():
        raise ConfigError(f"{out}: {flag} exists and is a file; give a folder")
    _inputs_inside(out, inputs, flag)
    _writable(out, flag)
    if lock:
        lock_out(out, flag)
    _check_existing(out, overwrite=overwrite, flag=flag, kind=kind)
    if lock:
        note_checked(out)
    return out  # _writable checked that an existing ``out`` accepts new entries


def check_api_out_dir(
    out: str | Path,
    *,
    overwrite: bool,
    kind: str,
) -> Path:
    """:func:`check_out_dir` for a library entry point (:func:`~.training.api.train`,
    :func:`~.evaluate.cbe.evaluate_checkpoint`) that writes into folder ``out``: the same rule,
    before the first file, with ``overwrite`` the entry point's keyword.  Its inputs are not
    checked against ``out`` here: ``exsur run`` evaluates into the folder that holds the run's
    dataset, which a user's command may not.  Skipped when this
    process already checked ``out`` as it took the folder's writer lock and still holds it
    (the CLI checks before it loads anything, then calls the entry point).

    Raises:
        ConfigError: one line naming the folder, what is wrong and what to do.
    """
    out = need_path(out, "out")
    if checked_under_lock(out):
        return out
    return check_out_dir(out, overwrite=overwrite, flag="output folder", kind=kind)


def _check_existing(out: Path, *, overwrite: bool, flag: str, kind: str | None) -> None:
    """The rule for an existing ``out``: a real folder, exsur's own output of a kind this
    command may use, unless ``overwrite``."""
    if out.is_dir():
        if out.is_symlink() and not overwrite:
            raise ConfigError(
                f"{out}: {flag} is a symbolic link; give a real folder, or pass --overwrite"
            )
        if not overwrite and (found := other_kind(out, kind)) is not None:
            raise ConfigError(kind_refusal(out, found, str(kind), flag))
        if not overwrite and foreign_entry(out) is not None:
            raise ConfigError(refusal(out, flag))


def check_out_file(
    out: str | Path,
    *,
    inputs: Iterable[str | Path] = (),
    flag: str = "--out",
    example: str,
    overwrite: bool = False,
) -> Path:
    """Check a single output file: not a folder, not an input, in a writable folder, with the
    suffix of ``example``; an existing file is replaced only if exsur wrote it
    (:func:`is_exsur_file`) or with ``overwrite``.

    ``example`` is a file name shown in messages (``model.onnx``).
    """
    out = Path(out)
    if out.is_dir() or out.name in ("", ".", ".."):
        raise ConfigError(f"{out}: {flag} is a folder; give a file name such as {example}")
    suffix = Path(example).suffix
    if out.suffix.lower() != suffix:
        raise ConfigError(
            f"{out}: {flag} must end in {suffix} (this command writes a {suffix} file); "
            f"give a file name such as {example}"
        )
    ro = out.resolve()
    for s in inputs:
        if Path(s).resolve() == ro:
            raise ConfigError(f"{s}: {flag} is one of the inputs; write to another file")
    _writable(out.parent if out.exists() else out, flag)
    note_folders_made(out)  # the folders its write will make: gone again if the command fails
    _probe(out, flag)
    if out.exists() or out.is_symlink():
        if not overwrite and not is_exsur_file(out):
            raise ConfigError(
                f"{out}: {flag} exists and exsur did not write it; give a new file name, or "
                "pass --overwrite to replace it"
            )
        if not os.access(out, os.W_OK):
            raise ConfigError(f"{out}: {flag} is not writable; give another file")
    return out


def _probe(out: Path, flag: str) -> None:
    """Create and remove a temporary file in the nearest existing folder of ``out`` (making
    none): a folder that only pretends to be writable (``/proc``, a read-only mount seen by
    root) fails here in one line."""
    import tempfile

    folder = out.parent
    while not folder.exists() and folder.parent != folder:
        folder = folder.parent
    try:
        prefix = f".{out.name}.{os.getpid()}-"  # a killed probe's is swept (io_utils.sweep_stale)
        fd, name = tempfile.mkstemp(prefix=prefix, suffix=".tmp", dir=folder)
        os.close(fd)
        os.unlink(name)
    except OSError as e:
        raise ConfigError(
            f"{out}: cannot write {flag} there ({e.strerror or e}); give another {flag}"
        ) from e


def is_exsur_file(path: str | Path) -> bool:
    """True if ``path`` is a regular file that exsur wrote, checked by content: a ``.pt``
    checkpoint (``format`` ``exsur-*``), an ``.onnx`` model with exsur's metadata or a
    ``.png`` whose ``Software`` text is exsur's (:data:`PNG_SOFTWARE`)."""
    p = Path(path)
    if p.is_symlink() or not p.is_file():
        return False
    suffix = p.suffix.lower()  # as check_out_file accepts it: MODEL.ONNX is a model
    try:
        if suffix == ".pt":
            import torch

            obj = torch.load(p, map_location="cpu", weights_only=True)
            return isinstance(obj, dict) and str(obj.get("format", "")).startswith("exsur-")
        if suffix == ".onnx":
            import onnx

            model = onnx.load(str(p), load_external_data=False)
            return any(m.key == "exsur_spec" for m in model.metadata_props)
        if suffix == ".png":
            from PIL import Image

            with Image.open(p) as im:
                return str(im.info.get("Software", "")).startswith("exsur ")
    except Exception:  # not a checkpoint / model at all: not exsur's
        return False
    return False


@contextlib.contextmanager
def out_dir(
    out: str | Path,
    *,
    overwrite: bool = False,
    inputs: Iterable[str | Path] = (),
    flag: str = "--out",
    kind: str | None = None,
) -> Iterator[Path]:
    """:func:`check_out_dir` with the writer lock, then a block in which ``overwrite`` lets exsur
    replace ``out`` (the lock is released by :func:`~.outlock.release_locks`)."""
    p = check_out_dir(out, overwrite=overwrite, inputs=inputs, flag=flag, lock=True, kind=kind)
    if overwrite:
        with replace_allowed(p):
            yield p
    else:
        yield p


def preset_files(preset: str | Path | None) -> list[Path]:
    """``[preset]`` if it names a file (an input that must not lie inside ``--out``), else ``[]``."""
    if preset is None:
        return []
    p = Path(str(preset))
    return [p] if p.suffix == ".toml" or p.is_file() else []
