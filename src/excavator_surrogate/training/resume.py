"""Starting a run: a fresh network, or the network and training state of a checkpoint."""

from __future__ import annotations

import math
import shutil
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import torch

from ..config import to_dict
from ..data.episode import Episode
from ..errors import CheckpointError, ConfigError
from ..io_utils import atomic_path
from ..spec import SOURCE_META, MachineSpec
from ..surrogate.checkpoint import check_compatible, read_checkpoint, surrogate_from_dict
from ..surrogate.envelope import fill_envelope
from ..surrogate.features import Normalization
from ..surrogate.model import ModelConfig, Surrogate, SurrogateNet
from ..surrogate.prior import PRIOR_MAP
from ..surrogate.structured import fit_prior, max_map_delay
from .config import TrainConfig
from .ignored import narrowed


def with_source(spec: MachineSpec, episodes: list[Episode]) -> MachineSpec:
    """``spec`` with the episodes' data source recorded in its ``meta`` (:data:`SOURCE_META`)."""
    source = "+".join(sorted({str(e.source) for e in episodes}))
    return replace(spec, meta={**spec.meta, SOURCE_META: source})


@dataclass
class Start:
    """Where a run starts: network, normalisation, and the progress of a resumed run."""

    net: SurrogateNet
    norm: Normalization
    spec: MachineSpec
    """The machine the net runs on: the dataset's, with the envelope completed from the
    training data (:func:`~excavator_surrogate.surrogate.envelope.fill_envelope`), or the
    resumed checkpoint's."""
    model_cfg: ModelConfig
    """The net's architecture: the config's, widened by the delayed-command features of a
    delayed speed prior (:meth:`~excavator_surrogate.surrogate.features.Normalization.with_lags`)."""
    derived: list[str] = field(default_factory=list)
    """One line per joint whose bounds came from the data (for the log)."""
    train_state: dict[str, Any] | None = None
    """``last.pt``'s optimiser/scheduler/bookkeeping state (None: fresh run)."""
    history: list[dict[str, Any]] = field(default_factory=list)
    """``log.csv`` rows of the epochs already trained."""

    def surrogate(self, cfg: TrainConfig, device: torch.device) -> Surrogate:
        """The surrogate a training of ``cfg`` updates in place: this start's network, moved
        to ``device`` in training mode, with its spec, normalisation and architecture."""
        self.net.to(device).train()
        return Surrogate(
            net=self.net,
            spec=self.spec,
            norm=self.norm.to(device),
            model_cfg=self.model_cfg,
            mode=cfg.mode,
            train_config=to_dict(cfg),
            metrics={},
            name=cfg.cell,
            end_stops=cfg.end_stops,
        )

    @property
    def epoch(self) -> int:
        """First epoch to train."""
        return int(self.train_state["epoch"]) + 1 if self.train_state else 0

    @property
    def best_val(self) -> float:
        """Best validation error so far."""
        return float(self.train_state["best_val"]) if self.train_state else float("inf")

    @property
    def bad_epochs(self) -> int:
        """Epochs since the last improvement."""
        return int(self.train_state["bad_epochs"]) if self.train_state else 0

    @property
    def elapsed_s(self) -> float:
        """Wall time already spent [s]."""
        return float(self.train_state.get("elapsed_s", 0.0)) if self.train_state else 0.0


def fit_norm(cfg: TrainConfig, train_eps: list[Episode], spec: MachineSpec) -> Normalization:
    """The normalisation a fresh network of ``cfg`` gets, fitted on ``train_eps`` of ``spec``."""
    return Normalization.fit(
        [e.theta for e in train_eps],
        [e.u for e in train_eps],
        spec,
        play=cfg.play,
        omega_in=cfg.velocity_input,
    )


def start(
    cfg: TrainConfig,
    mcfg: ModelConfig,
    spec: MachineSpec,
    train_eps: list[Episode],
    resume: str | Path | None,
    *,
    data_name: str | Path = "the training data",
) -> Start:
    """A fresh net (weights from the current torch seed, normalisation fitted on ``train_eps``)
    or the state of checkpoint ``resume``.  With ``[train] exogenous = "ignore"`` the training
    runs without the inputs (:mod:`.ignored`), so a checkpoint that has them (its input
    weights zero) resumes without them.

    Raises:
        CheckpointError: ``resume`` is of another machine than ``spec`` (joints, rate,
            command ranges, inputs: the line names ``data_name``, as ``exsur train`` does), or
            has another architecture.
    """
    if resume is None:
        derived: list[str] = []
        if cfg.end_stops:
            spec, bounds = fill_envelope(
                spec, train_eps, limit_margin=cfg.limit_margin, speed_margin=cfg.speed_margin
            )
            for name, b in bounds.items():
                got = [
                    k for k in ("theta_min", "theta_max", "omega_max") if b[f"{k}_source"] == "data"
                ]
                if got:
                    derived.append(
                        f"{name}: {', '.join(f'{k} {b[k]:.4g}' for k in got)} from the training data"
                    )
        spec = with_source(spec, train_eps)
        norm = fit_norm(cfg, train_eps, spec)
        if mcfg.prior:
            # the structured baseline's map, delay included
            fit = fit_prior(train_eps, spec, max_delay=max_map_delay(cfg.window, spec))
            cols = fit["cols"]
            if any(fit["delay"]):
                # omega[k+1] = s(u[k - d]) + net: the delayed commands become features
                norm = norm.with_lags(fit["delay"])
                cols = [norm.lag_start + j for j in range(spec.n_joint)]
                mcfg = replace(mcfg, n_feature=norm.n_feature)
            net = SurrogateNet(mcfg)
            assert net.prior is not None
            net.prior.load_fit(
                **{k: fit[k] for k in PRIOR_MAP if k != "cols"}, cols=cols, norm=norm
            )
            derived += [
                f"{js.name}: speed prior dead zone [{a_n:.4g}, {a_p:.4g}], gains {k_p:.3g} / "
                f"{k_n:.3g} rad/s per command unit, delay {d / spec.rate_hz:.3g} s "
                f"(one-step RMSE {e:.3g} rad/s)"
                for js, a_n, a_p, k_p, k_n, d, e in zip(
                    spec.joints,
                    fit["a_neg"],
                    fit["a_pos"],
                    fit["k_pos"],
                    fit["k_neg"],
                    fit["delay"],
                    fit["rmse"],
                )
            ]
        else:
            net = SurrogateNet(mcfg)
        return Start(net=net, norm=norm, spec=spec, model_cfg=mcfg, derived=derived)
    ck = read_checkpoint(resume)
    old = surrogate_from_dict(ck, where=str(resume))
    if old.spec.n_input and not spec.n_input and cfg.exogenous == "ignore":
        old = narrowed(old, where=str(resume))  # stored with the inputs it was trained without
    if old.norm.own is not None:  # training runs the network alone, not beside a map
        raise CheckpointError(
            f"{resume}: joints {', '.join((old.metrics or {}).get('map_joints') or [])} follow "
            "the static map in parallel with this network (chosen after training); resume "
            "from the run's last.pt, or a member's best.pt, instead"
        )
    # another machine first: its architecture differs too, and the advice would be wrong
    check_compatible(old.spec, spec, ckpt=resume, data_name=data_name)
    # a delayed speed prior widened the first layer by its delayed-command features
    if replace(old.model_cfg, n_feature=old.model_cfg.n_feature - old.norm.n_lag) != mcfg:
        raise CheckpointError(
            f"{resume}: architecture {old.model_cfg.to_dict()} differs from the config's {mcfg.to_dict()}; "
            "resume with the same window/hidden/layers/cell"
        )
    check_same_run(cfg, ck.get("train_config") or {}, resume)
    return Start(
        net=old.net,
        norm=old.norm,
        spec=old.spec,
        model_cfg=old.model_cfg,
        train_state=ck.get("train_state") or None,
        history=list(ck.get("history") or []),
    )


RESUME_MAY_CHANGE = (
    "max_train_seconds",
    "epochs",
    "num_threads",
    "member_workers",
    "tensorboard",
    "device",
)
"""``[train]`` fields a resume may change: the wall-time cap, the planned epochs, the thread
and CPU counts, the TensorBoard logs and the device (a run moved to another computer goes on
as that computer trains).  Any other change (a seed, a learning rate) would continue another
run than the one the checkpoint is part of."""


def check_same_run(cfg: TrainConfig, stored: dict[str, Any], resume: str | Path) -> None:
    """Refuse to resume checkpoint ``resume`` (its ``train_config``: ``stored``) with a
    config that differs in a field outside :data:`RESUME_MAY_CHANGE` (fields only one of the
    two records are not compared: the other mode's knobs, where ``mode`` differs anyway, and
    those of another version).

    Raises:
        ConfigError: one line naming each differing field and its value in ``resume``.
    """
    new = to_dict(cfg)  # a knob of one mode only, or of another version: not compared
    diff = [k for k in stored if k in new and k not in RESUME_MAY_CHANGE and stored[k] != new[k]]
    if diff:
        was = ", ".join(f"{k} = {stored[k]!r} (here {new[k]!r})" for k in diff)
        raise ConfigError(
            f"--resume {resume}: it was trained with {was}; resume with its settings (only "
            f"{', '.join(RESUME_MAY_CHANGE)} may change), or train a new run without --resume"
        )


def carry_best(resume: str | Path, best_path: Path, best_val: float) -> bool:
    """Start a run resumed into another folder from the resumed run's ``best.pt``.

    ``resume`` is the resumed ``last.pt``; its run's best weights are not in it but in the
    ``best.pt`` beside it.  That file is copied to ``best_path`` (atomically) when it is that
    run's best: its recorded ``best_val_error`` equals ``best_val``, the resumed state's.  A
    resumed run whose epochs never beat it then keeps it, where it would otherwise keep its
    last epoch.  Returns False (nothing copied) when ``best_path`` is that file itself, or
    there is no such file: the caller restarts the selection among its own epochs.
    """
    src = Path(resume).parent / "best.pt"
    if not src.is_file() or src.resolve() == Path(best_path).resolve():
        return False
    try:
        recorded = (read_checkpoint(src).get("metrics") or {}).get("best_val_error")
    except CheckpointError:
        return False
    if recorded is None or not math.isclose(float(recorded), best_val, rel_tol=1e-12):
        return False
    with atomic_path(best_path) as tmp:
        shutil.copyfile(src, tmp)
    return True
