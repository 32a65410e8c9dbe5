"""What a sweep checks and shows before its first trial: its storage URL (the default one of
a folder, and the URL with its password hidden for logs and reports), the study a sweep
folder already holds (a folder holds one study: :func:`check_owner`), and a ``[train]`` base
that every trial would fail on (:func:`check_base`)."""

from __future__ import annotations

import json
import re
import tomllib
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING

from ..errors import ConfigError

if TYPE_CHECKING:
    from ..spec import MachineSpec
    from ..training import TrainConfig


def safe_url(url: str) -> str:
    """``url`` with its password replaced by ``***`` (for logs and reports): the one of
    ``user:pw@host`` (also with an empty user) and a ``password`` query parameter.

    SQLAlchemy parses the URL; a URL it cannot parse is masked by pattern.  A URL without
    a password is returned unchanged."""
    try:
        from sqlalchemy.engine import make_url

        parsed = make_url(url)
    except Exception:  # not SQLAlchemy's (or no SQLAlchemy): the same two places by pattern
        shown = re.sub(r"(://[^:/@?#]*):[^@/?#]*@", r"\1:***@", url)
        return re.sub(r"([?&]password=)[^&#]*", r"\1***", shown, flags=re.IGNORECASE)
    secret = [k for k in parsed.query if k.lower() == "password"]
    if parsed.password is None and not secret:
        return url
    shown = parsed.difference_update_query(secret).render_as_string(hide_password=True)
    return shown + ("&" if "?" in shown else "?") + "password=***" if secret else shown


def default_storage(out: str | Path) -> str:
    """SQLite URL of ``out/study.db``."""
    return f"sqlite:///{(Path(out) / 'study.db').resolve()}"


def sweep_owner(out: str | Path) -> tuple[str, str] | None:
    """``(study, storage)`` of the sweep ``out`` holds, from its ``config.toml`` ``[command]``
    (or, from a sweep that wrote none, its ``sweep.json``); the storage with its password
    hidden.  None: no sweep there yet (or a record that cannot be read)."""
    for name, parse in (("config.toml", tomllib.loads), ("sweep.json", json.loads)):
        try:
            rec = parse((Path(out) / name).read_text(encoding="utf-8"))
            rec = rec["command"] if name == "config.toml" else rec
            return str(rec["study"]), str(rec["storage"])
        except (OSError, ValueError, KeyError, TypeError):
            continue
    return None


def check_owner(out: str | Path, *, study_name: str, storage: str, overwrite: bool) -> None:
    """Refuse, unless ``overwrite``, to run study ``study_name`` at ``storage`` in an ``out``
    that holds another study's sweep (another name, or the same name in another database):
    trial numbers restart at 0 in every study, so its trials would land in the other's
    ``trials/trial_NNNN`` folders and replace their checkpoints, and its ``best.pt`` and
    report would replace the other's.  ``out``'s own SQLite database counts as the same
    wherever the folder was moved.

    Raises:
        ConfigError: one line naming the folder, both studies and what to do.
    """
    held = None if overwrite else sweep_owner(out)
    if held is None:
        return
    name, where = held
    shown = safe_url(storage)
    same_db = where == shown or (
        storage == default_storage(out)
        and where.startswith("sqlite:")
        and where.endswith("/study.db")
    )
    if name == study_name and same_db:
        return
    other = f"study '{name}'" + ("" if same_db else f" at {where}")
    this = f"study '{study_name}'" + ("" if same_db else f" at {shown}")
    raise ConfigError(
        f"{out}: --out holds the sweep of {other}; {this} would write its trials into that "
        "study's trial folders and replace its best.pt: give it another --out (one --storage "
        "may hold both studies), or pass --overwrite to write into this one"
    )


def check_base(base: TrainConfig | Mapping[str, TrainConfig], spec: MachineSpec) -> None:
    """Refuse, before any trial, a base that would fail every trial: several trainings per
    trial (``members > 1``, ``exogenous = "choose"`` with the machine's inputs,
    ``prior_choice``: a trial trains one network, pruned epoch by epoch) or a device this
    computer lacks.

    Raises:
        ConfigError: one line naming the settings and the ``--set`` that fixes them.
    """
    from ..devices import resolve_device

    for cfg in base.values() if isinstance(base, Mapping) else (base,):
        fixes = [
            (key, now, fix)
            for key, now, fix, bad in (
                ("members", cfg.members, "1", cfg.members > 1),
                ("exogenous", '"choose"', "use", cfg.exogenous == "choose" and spec.n_input),
                ("prior_choice", "true", "false", cfg.prior_choice),
            )
            if bad
        ]
        if fixes:
            raise ConfigError(
                "[train] "
                + ", ".join(f"{key} = {now}" for key, now, _ in fixes)
                + ": a sweep trial trains one network; give "
                + " ".join(f"--set train.{key}={fix}" for key, _, fix in fixes)
            )
        resolve_device(cfg.device)
