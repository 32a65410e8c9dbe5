"""Self-describing checkpoints (nanoGPT style), loadable with ``torch.load(weights_only=True)``.

A checkpoint is one ``.pt`` file holding only tensors and plain Python types::

    {
      "format": "exsur-surrogate", "format_version": 1, "exsur_version": "0.1.0",
      "name": "lstm",                       # model label (lstm, gru, arx ...)
      "mode": "windowed" | "stateful",      # how to roll the model out
      "end_stops": bool,                    # clip free-run angles to the spec's joint limits
      "model": {...ModelConfig...},         # architecture
      "spec": {...MachineSpec.to_dict()...},
      "norm": {"x_mean", "x_std", "y_mean", "y_std"},   # float32 tensors
      "state_dict": {...},                  # network weights
      "train_config": {...TrainConfig...},  # plain dict (None values dropped)
      "metrics": {...},                     # e.g. best validation error, epoch
      "history": [{epoch, time_s, lr, train_loss, val_error, ...}, ...],
      "train_state": {epoch, optimizer, scheduler, best_val, bad_epochs, elapsed_s} | None,
    }

It is written atomically; a missing, corrupt or incompatible file raises
:class:`~excavator_surrogate.errors.CheckpointError` with a one-line message.  Corrupt
includes a single changed byte: the CRC-32 of every entry of the zip file is checked before
``torch.load``, which does not check them.
"""

from __future__ import annotations

import contextlib
import errno
import os
import sys
import zipfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import torch

from ..devices import one_thread_in_forked_children, resolve_device
from ..errors import CheckpointError, ConfigError
from ..io_utils import atomic_path
from ..spec import MachineSpec
from ..version import __version__
from .features import Normalization
from .model import ModelConfig, Surrogate, build_net
from .sizes import check_fits, n_param

FORMAT = "exsur-surrogate"
FORMAT_VERSION = 1
_FIX = "re-train or copy the file again"

_NOT_CHECKPOINTS = {
    ".onnx": "an ONNX export (exsur info describes it; env.OnnxStepper runs it)",
    ".parquet": "a Parquet file (a dataset's episode or a log)",
    ".csv": "a CSV file (a log)",
    ".toml": "a TOML file (a preset or a mapping)",
    ".json": "a JSON file",
}
"""Files exsur writes or reads that a user may give where a checkpoint is expected."""


def checkpoint_dict(
    sur: Surrogate,
    *,
    history: list[dict[str, Any]] | None = None,
    train_state: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """The plain-data checkpoint of ``sur`` (tensors moved to CPU)."""
    return {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "exsur_version": __version__,
        "name": sur.name,
        "mode": sur.mode,
        "end_stops": bool(sur.end_stops),
        "model": sur.model_cfg.to_dict(),
        "spec": sur.spec.to_dict(),
        "norm": sur.norm.state_dict(),
        "state_dict": {k: v.detach().cpu() for k, v in sur.net.state_dict().items()},
        "train_config": dict(sur.train_config or {}),
        "metrics": dict(sur.metrics or {}),
        "history": list(history or []),
        "train_state": train_state,
    }


def save_checkpoint(
    path: str | Path,
    sur: Surrogate,
    *,
    history: list[dict[str, Any]] | None = None,
    train_state: dict[str, Any] | None = None,
) -> Path:
    """Write ``sur`` (and optional training state for resuming) to ``path`` atomically."""
    return write_checkpoint_dict(
        path, checkpoint_dict(sur, history=history, train_state=train_state)
    )


def write_checkpoint_dict(path: str | Path, ckpt: dict[str, Any]) -> Path:
    """Write a checkpoint dict to ``path`` atomically, and byte-for-byte reproducibly.

    ``torch.save`` to a *file name* records that name inside the zip archive, and the atomic
    write's temporary name holds a pid and a random suffix; saved through an open file the
    archive's folder is always ``archive``, so the same dict gives the same bytes.  Its plain
    data is written as :func:`canonical` makes it, so equal content gives equal bytes too.
    """
    path = Path(path)
    with _write_errors(path), atomic_path(path) as tmp, open(tmp, "wb") as f:
        torch.save(canonical(ckpt), f)
    return path


def canonical(obj: Any) -> Any:
    """``obj`` with every string interned and every dict, list and tuple a new one: the pickle
    then depends on the content only.  Pickle writes an object it has seen as a reference to
    the first, so a string shared by two entries (a config's default) and the same string
    read twice from TOML or a checkpoint gave other bytes for the same content.  Everything
    else (tensors, numbers) is the same object."""
    if type(obj) is str:
        return sys.intern(obj)
    if type(obj) is dict:
        return {canonical(k): canonical(v) for k, v in obj.items()}
    if type(obj) in (list, tuple):
        return type(obj)(canonical(v) for v in obj)
    return obj


@contextlib.contextmanager
def _write_errors(path: Path) -> Iterator[None]:
    """A failed checkpoint write (full disk, quota, unwritable folder) as one line naming
    ``path``; ``torch.save`` reports a full disk as a RuntimeError (``unexpected pos``)."""
    try:
        yield
    except OSError as e:
        raise CheckpointError(f"{path}: cannot write the checkpoint ({_why(e, path)})") from e
    except RuntimeError as e:
        text = str(e)
        if not any(s in text for s in ("unexpected pos", "write failed", "PytorchStreamWriter")):
            raise
        raise CheckpointError(
            f"{path}: cannot write the checkpoint (the write failed: disk full?); free disk space "
            "or write elsewhere"
        ) from e


def _why(e: OSError, path: Path) -> str:
    if e.errno in (errno.ENOSPC, errno.EDQUOT):
        return f"{e.strerror}; free disk space or write elsewhere"
    if e.errno in (errno.EEXIST, errno.ENOTDIR):  # the folder to create is a file
        file = next((p for p in path.parents if p.exists() and not p.is_dir()), None)
        if file is not None:
            return f"{file} is a file, not a folder; write the checkpoint elsewhere"
    return f"{e.strerror or e}; check the folder and its permissions"


def read_checkpoint(path: str | Path) -> dict[str, Any]:
    """Load the raw checkpoint dict with ``weights_only=True`` and check its format.

    Raises:
        CheckpointError: missing file, unreadable/corrupt file, or another format/version.
    """
    if not isinstance(path, str | os.PathLike):
        raise ConfigError(f"a checkpoint path is needed (a .pt file), got {type(path).__name__}")
    path = Path(path)
    if path.is_dir():
        raise CheckpointError(
            f"{path}: is a folder, not a checkpoint file; give the file in it, e.g. "
            f"{checkpoint_in(path)}"
        )
    if not path.is_file():
        raise CheckpointError(
            f"{path}: checkpoint not found (train one with 'exsur train DATASET --out DIR')"
        )
    if path.suffix.lower() in _NOT_CHECKPOINTS:
        raise CheckpointError(
            f"{path}: {_NOT_CHECKPOINTS[path.suffix.lower()]}, not a checkpoint; give the .pt "
            "file 'exsur train' wrote (best.pt)"
        )
    bad = _crc_failure(path)
    if bad is not None:
        raise CheckpointError(
            f"{path}: corrupt checkpoint (entry {bad} fails its CRC check: the file changed "
            "after it was written); re-train or copy the file again"
        )
    try:
        ckpt = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as e:  # zip/pickle/unpickler errors come in many types
        first = _first_line(e, 120)
        raise CheckpointError(
            f"{path}: not a readable exsur checkpoint ({type(e).__name__}{': ' + first if first else ''}); "
            "re-train or copy the file again"
        ) from e
    if not isinstance(ckpt, dict) or ckpt.get("format") != FORMAT:
        raise CheckpointError(f"{path}: not an exsur surrogate checkpoint (no format '{FORMAT}')")
    version = ckpt.get("format_version")
    if version != FORMAT_VERSION:
        raise CheckpointError(
            f"{path}: checkpoint format_version {version!r} is not supported (this exsur reads "
            f"{FORMAT_VERSION}); re-train with this version"
        )
    missing = [k for k in ("model", "spec", "norm", "state_dict", "mode") if k not in ckpt]
    if missing:
        raise CheckpointError(f"{path}: checkpoint lacks entries {missing}; re-train")
    return ckpt


def checkpoint_in(folder: Path) -> Path:
    """The checkpoint a user most likely meant by ``folder``: its ``best.pt`` (an ``exsur
    train`` folder), else ``model/best.pt`` (an ``exsur run`` folder), else the first
    ``*/best.pt`` one level down; ``folder/best.pt`` when there is none."""
    for cand in (folder / "best.pt", folder / "model" / "best.pt"):
        if cand.is_file():
            return cand
    try:
        below = sorted(folder.glob("*/best.pt"))
    except OSError:
        below = []
    return below[0] if below else folder / "best.pt"


def surrogate_from_dict(ckpt: dict[str, Any], *, where: str = "checkpoint") -> Surrogate:
    """Build a :class:`Surrogate` from a checkpoint dict (see :func:`read_checkpoint`)."""
    try:
        spec = MachineSpec.from_dict(ckpt["spec"])
    except ConfigError as e:
        raise CheckpointError(f"{where}: malformed joint spec ({e}); {_FIX}") from e
    try:
        mcfg = ModelConfig.from_dict(ckpt["model"])
        norm = Normalization.from_state_dict(ckpt["norm"], spec)
    except CheckpointError as e:
        raise CheckpointError(f"{where}: {e}; {_FIX}") from e
    if mcfg.n_feature != norm.n_feature or mcfg.n_joint != spec.n_joint:
        raise CheckpointError(
            f"{where}: model sizes ({mcfg.n_feature} features, {mcfg.n_joint} joints) do not match its "
            f"spec and features ({norm.n_feature}, {spec.n_joint}); {_FIX}"
        )
    mode = ckpt["mode"]
    if mode not in ("windowed", "stateful"):
        raise CheckpointError(f"{where}: unknown mode {mode!r} (windowed or stateful); {_FIX}")
    n = n_param(mcfg)  # before allocating: a crafted or corrupt size must not exhaust memory
    check_fits(
        4 * n,
        what=f"{where}: the stored network (hidden = {mcfg.hidden}, {n:.3g} parameters x 4 B)",
        fix="this is not a checkpoint exsur wrote for this machine; re-train or copy it again",
        error=CheckpointError,
    )
    net = build_net(mcfg)
    try:
        net.load_state_dict(ckpt["state_dict"])
    except (RuntimeError, TypeError, AttributeError) as e:
        msg = _first_line(e, 160)
        raise CheckpointError(
            f"{where}: weights do not fit the stored architecture ({msg}); the file was "
            "altered or is damaged: re-train or copy it again"
        ) from e
    _check_finite(net, norm, where)
    net.eval()
    return Surrogate(
        net=net,
        spec=spec,
        norm=norm,
        model_cfg=mcfg,
        mode=mode,
        train_config=dict(ckpt.get("train_config") or {}),
        metrics=dict(ckpt.get("metrics") or {}),
        name=str(ckpt.get("name", mcfg.cell)),
        end_stops=bool(ckpt.get("end_stops", False)),
    )


def _check_finite(net: torch.nn.Module, norm: Normalization, where: str) -> None:
    """Refuse NaN/inf weights and a normalisation no training writes (non-finite, std <= 0):
    such a network predicts NaN, which would be scored and exported as if it were a model."""
    stored = [(k, getattr(norm, k)) for k in ("x_mean", "x_std", "y_mean", "y_std", "play")]
    for kind, items in (("weights", net.state_dict().items()), ("normalisation", stored)):
        for name, t in items:
            if t.is_floating_point() and not bool(torch.isfinite(t).all()):
                raise CheckpointError(
                    f"{where}: non-finite {kind} ({name}): its training diverged or the file "
                    "was altered; re-train it (lower train.lr) or use another checkpoint"
                )
    for name in ("x_std", "y_std"):
        if not bool((getattr(norm, name) > 0).all()):
            raise CheckpointError(
                f"{where}: normalisation {name!r} is not positive (no training writes that); "
                "re-train or copy the file again"
            )


def check_compatible(
    model: MachineSpec, data: MachineSpec, *, ckpt: str | Path, data_name: str | Path
) -> None:
    """Refuse a checkpoint trained for another machine: other joints, rate or command ranges.

    Args:
        model: the checkpoint's spec.
        data: the spec of the data, environment or dataset it is used with.
        ckpt: the checkpoint (for the message).
        data_name: what it is used with (for the message), e.g. the dataset folder.

    Raises:
        CheckpointError: one line naming both and the first difference.
    """
    diff = model.mismatch(data)
    if diff is None:
        return
    raise CheckpointError(
        f"{ckpt}: the checkpoint does not fit {data_name} ({diff}, checkpoint vs data); use a "
        "checkpoint trained on this machine at this rate, or data of the checkpoint's machine"
    )


def _crc_failure(path: Path) -> str | None:
    """The first entry of checkpoint ``path`` (a zip file, as :func:`torch.save` writes it)
    whose bytes do not match the CRC-32 stored with them, or None.  ``torch.load`` does not
    check them, so a changed weight byte (bit rot, a bad copy) would load as another model.
    One sequential read of the file, in 1 MiB chunks.  A file that is no zip at all is left
    to ``torch.load`` to refuse."""
    try:
        with zipfile.ZipFile(path) as z:
            return z.testzip()
    except (zipfile.BadZipFile, OSError, EOFError):
        return None


def _first_line(e: BaseException, n: int) -> str:
    """First line of ``str(e)``, shortened to at most ``n`` characters at a word boundary."""
    text = str(e).strip().splitlines()[0] if str(e).strip() else ""
    if len(text) <= n:
        return text
    cut = text[:n].rsplit(" ", 1)[0].rstrip(",;:")
    return cut + " ..."


def load_checkpoint(path: str | Path, *, device: str | torch.device = "cpu") -> Surrogate:
    """Load a surrogate from a checkpoint file (``weights_only=True``), in eval mode on ``device``
    (``cpu``, ``cuda``, ``cuda:N``, ``auto``: a GPU if one is usable, else the CPU; see
    :func:`~excavator_surrogate.devices.resolve_device`).

    Raises:
        CheckpointError: one line naming the file and what to do.
        ConfigError: ``device`` is unknown or not available on this computer (one line).
    """
    one_thread_in_forked_children()  # a forked env worker must not hang on torch's threads
    dev = resolve_device(device)  # before the file is read: one line, not torch's error
    ckpt = read_checkpoint(path)
    sur = surrogate_from_dict(ckpt, where=str(path))
    return sur.to(dev)
