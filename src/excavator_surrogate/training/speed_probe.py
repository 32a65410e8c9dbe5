"""How fast a training config's network trains against the recipe's, timed on this computer:
what turns the reference machine's per-step times (:data:`~.plan.STEP_S`,
:data:`~.plan.VAL_STEP_S`, measured with :data:`~.plan.STEP_NET`) into an estimate for any
other stateful network (:meth:`~.estimate.WorkEstimate.with_speed`).

``exsur train --dry-run`` and ``exsur run --dry-run`` call it for a config the cost model does
not cover, e.g. the demo's 64-unit network trained on its own free runs.  It trains two
throwaway networks, the config's and the reference (:func:`reference_config`: the config with
:data:`~.plan.STEP_NET`'s network in :data:`~.plan.STEP_SHAPE`'s sub-sequences), on copies
of the same synthetic episodes through the training loop's own epoch
(:func:`~.loop.run_epoch`), in alternating bursts of :data:`PROBE_SECONDS`, timing each per
sub-sequence step (a ``feedback = "free"`` config also as in its teacher-forced warm-up's
epochs, which cost about half as much), and free-runs each on the same validation episodes
(:func:`~excavator_surrogate.surrogate.validation.free_run_errors`, the two candidates of an
epoch).  The ratios are medians of :data:`PROBE_ROUNDS` bursts.

Only a ratio leaves this module, never a time: the plan stays a function of the data, and the
estimate stays in the reference machine's seconds.  The ratio itself is this computer's: it
moves with the kernels a CPU runs (a wider network gains more from AVX-512 than a narrow one),
and with other work on the machine.  The probe restores torch's global random state and the
thread count, so a training after it is the one it would have been.
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable, Sequence
from dataclasses import replace

import numpy as np
import torch

from ..data.episode import Episode
from ..devices import resolve_device, torch_threads
from ..errors import ConfigError
from ..spec import MachineSpec
from ..surrogate.synthetic import synthetic_episode, synthetic_spec
from ..surrogate.validation import free_run_errors
from .batches import make_data
from .config import TrainConfig
from .estimate import SpeedRatio, WorkEstimate, teacher_forced_epochs
from .loop import run_epoch
from .loss import default_loss
from .modes import make_mode
from .optim import Optimisation
from .parallel import SingleProcess
from .plan import STEP_NET, STEP_SHAPE, count_sequences
from .resume import start

PROBE_SECONDS = 0.4
"""Wall time of one timed burst of training [s] (the probe runs ``2 * PROBE_ROUNDS`` of
them, plus a warm-up and the validation free runs: about 5 s in all; a free-run feedback's
teacher-forced epochs add as many bursts of half this, about 1 s)."""
PROBE_ROUNDS = 3
"""Bursts per network; the ratio is of their medians."""
PROBE_BATCHES = 4
"""Full batches of sub-sequences in the probe's epoch (of the config's or the reference's
``seq_batch``, whichever is larger): a half-empty batch costs nearly a full one's time."""
PROBE_VAL_STEPS = 1000
"""Samples of each of the two validation episodes both networks free-run every round: long
enough that a free run's per-step cost, not its start, is what is timed."""
PROBE_EPOCH = 10
"""The epoch the bursts train as, or the first past a longer teacher-forced warm-up
(:attr:`ThrowawayNetwork.free_epoch`), so a ``feedback = "free"`` config is timed as it
trains most of its epochs."""


def timed_estimate(
    est: WorkEstimate | None, cfg: TrainConfig, *, n_joint: int = 4
) -> WorkEstimate | None:
    """``est`` with a time: scaled by :func:`measure_speed` where its network differs from
    the reference's, else unchanged (no probe runs for the recipe's network, nor for a
    training on a GPU: the probe and the reference times are a CPU's)."""
    if est is None or est.timed or _on_gpu(cfg):
        return est
    return est.with_speed(measure_speed(cfg, n_joint=n_joint))


def reference_config(cfg: TrainConfig) -> TrainConfig:
    """``cfg`` with the network and the sub-sequences :data:`~.plan.STEP_S` prices
    (:data:`~.plan.STEP_NET`, :data:`~.plan.STEP_SHAPE`), on one core as it was measured."""
    return replace(cfg, **STEP_NET, **STEP_SHAPE, num_threads=1)  # type: ignore[arg-type]


def measure_speed(cfg: TrainConfig, *, n_joint: int = 4) -> SpeedRatio:
    """Time ``cfg``'s network against the reference (:func:`reference_config`) on this computer.

    Args:
        cfg: a stateful training config (its network, sub-sequences, feedback, threads).
        n_joint: joints of the machine (the synthetic episodes' and the networks').

    Returns:
        ``cfg``'s time over the reference network's, for an epoch's training steps, for
        those of its teacher-forced warm-up (:func:`~.estimate.teacher_forced_epochs`; ``None``
        without one) and for an epoch's validation free run.
    """
    ref_cfg = reference_config(cfg)
    spec = synthetic_spec(n_joint, periodic_first=True)
    # batches as full as in a real epoch: PROBE_BATCHES of the larger seq_batch, from copies
    # of two episodes (what the data says does not change the time a step takes)
    both = (cfg, ref_cfg)
    steps = max(600, *(4 * c.seq_len for c in both))
    eps = [synthetic_episode(spec, n_step=steps, seed=k) for k in range(2)]
    per_ep = max(
        1,
        min(count_sequences(np.array([steps]), seq_len=c.seq_len, burn_in=c.burn_in) for c in both),
    )
    want = PROBE_BATCHES * max(c.seq_batch for c in both)
    train_eps = eps * max(1, -(-want // (2 * per_ep)))
    val_eps = [synthetic_episode(spec, n_step=PROBE_VAL_STEPS, seed=10 + k) for k in range(2)]
    bursts: list[Callable[[ThrowawayNetwork], float]] = [lambda p: p.train_burst(PROBE_SECONDS)]
    if teacher_forced_epochs(cfg) > 0:  # its teacher-forced epochs train at another speed
        bursts.append(lambda p: p.train_burst(PROBE_SECONDS / 2, epoch=0))  # few epochs: short
    t0 = time.perf_counter()
    train, val = side_by_side(
        (cfg, ref_cfg), spec, train_eps, val_eps, rounds=PROBE_ROUNDS, train=bursts
    )
    return SpeedRatio(
        train=train[0],
        val=val,
        teacher=train[1] if len(train) > 1 else None,
        seconds=time.perf_counter() - t0,
    )


def side_by_side(
    cfgs: tuple[TrainConfig, TrainConfig],
    spec: MachineSpec,
    train_eps: list[Episode],
    val_eps: list[Episode],
    *,
    rounds: int,
    train: Sequence[Callable[[ThrowawayNetwork], float]],
    warmup_s: float | None = None,
) -> tuple[list[float], float]:
    """A throwaway network of each of ``cfgs`` timed in alternation, ``rounds`` times each,
    after a warm-up: ``(training, validation)``, the first's median time over the second's,
    one training ratio for each of ``train``.

    Args:
        train: timed pieces of training of a network, each returning its time per
            sub-sequence step [s] (:meth:`ThrowawayNetwork.train_burst` or
            :meth:`ThrowawayNetwork.train_epoch`, e.g. at two epochs); every round runs each
            on both networks.
        warmup_s: the untimed burst each network trains first [s] (None: half of
            :data:`PROBE_SECONDS`).
    """
    with torch.random.fork_rng(devices=[]):  # NumPy draws only from explicit generators
        torch.manual_seed(0)
        probes = [ThrowawayNetwork(c, spec, train_eps, val_eps) for c in cfgs]
        for p in probes:  # warm-up: first calls allocate and pick kernels
            p.train_burst(PROBE_SECONDS / 2 if warmup_s is None else warmup_s)
            p.validate()
        train_s = [[[] for _ in train] for _ in probes]  # [network][piece][round]
        val_s: list[list[float]] = [[], []]
        for _ in range(rounds):  # alternating: a drift in speed hits both alike
            for k, p in enumerate(probes):
                for j, piece in enumerate(train):
                    train_s[k][j].append(piece(p))
                val_s[k].append(p.validate())
    ratios = [
        statistics.median(train_s[0][j]) / statistics.median(train_s[1][j])
        for j in range(len(train))
    ]
    return ratios, statistics.median(val_s[0]) / statistics.median(val_s[1])


def _on_gpu(cfg: TrainConfig) -> bool:
    """Whether ``cfg`` trains on another device than the CPU (a device this computer lacks
    counts as one: the training will say so)."""
    try:
        return resolve_device(cfg.device).type != "cpu"
    except ConfigError:
        return True


class ThrowawayNetwork:
    """A fresh network of ``cfg`` with its optimiser and its training loop's epoch, on
    ``train_eps`` and ``val_eps``: timed, never kept (``bench/estimate.py`` times whole
    epochs with it)."""

    def __init__(
        self,
        cfg: TrainConfig,
        spec: MachineSpec,
        train_eps: list[Episode],
        val_eps: list[Episode],
    ) -> None:
        cpu = torch.device("cpu")
        st = start(cfg, cfg.model_config(cfg.n_feature(spec), spec.n_joint), spec, train_eps, None)
        self.cfg, self.val_eps = cfg, val_eps
        self.free_epoch = max(PROBE_EPOCH, teacher_forced_epochs(cfg))
        """The epoch the bursts train as by default: :data:`PROBE_EPOCH`, past the warm-up."""
        self.sur = st.surrogate(cfg, cpu)  # as the training loop builds it
        self.net = self.sur.net
        par = SingleProcess(device=cpu)
        self.optim = Optimisation.build(cfg, self.sur)
        self.mode = make_mode(cfg, make_data(train_eps, st.norm, cpu), self.sur)
        self.epoch: Callable[..., tuple[float, int]] = lambda past, epoch: run_epoch(
            self.mode,
            self.net,
            par,
            self.optim.opt,
            epoch=epoch,
            rng=np.random.default_rng(epoch),
            loss_fn=default_loss(lambda_bias=cfg.lambda_bias),
            grad_clip=cfg.grad_clip,
            lr_at=lambda: None,
            past=past,
            show=lambda it, **kw: it,
        )

    def train_burst(self, seconds: float, *, epoch: int | None = None) -> float:
        """Train for about ``seconds`` (whole batches) as epoch ``epoch`` trains (0: a free-run
        feedback's teacher-forced warm-up; None: :attr:`free_epoch`); the time per sub-sequence
        step [s]."""
        at = self.free_epoch if epoch is None else epoch
        with torch_threads(self.cfg.num_threads or 1):
            self.net.train()
            t0 = time.perf_counter()
            deadline, total = t0 + seconds, 0
            while time.perf_counter() < deadline:
                _, n = self.epoch(lambda: time.perf_counter() > deadline, at)
                total += n
            return self._per_step(time.perf_counter() - t0, total)

    def train_epoch(self, *, epoch: int | None = None) -> float:
        """Train one whole epoch as epoch ``epoch`` trains (None: :attr:`free_epoch`); the time
        per sub-sequence step [s]."""
        at = self.free_epoch if epoch is None else epoch
        with torch_threads(self.cfg.num_threads or 1):
            self.net.train()
            t0 = time.perf_counter()
            _, n = self.epoch(lambda: False, at)
            return self._per_step(time.perf_counter() - t0, n)

    def _per_step(self, seconds: float, n_loss: int) -> float:
        """``seconds`` over the sub-sequence steps, burn-in included, of ``n_loss`` loss
        samples (``seq_len - burn_in + 1`` of each sub-sequence): the unit the cost model's
        :data:`~.plan.STEP_S` prices, whatever the share of the burn-in::

            seconds / (n_loss / (seq_len - burn_in + 1) * seq_len)
        """
        cfg = self.cfg
        steps = n_loss / (cfg.seq_len - cfg.burn_in + 1) * cfg.seq_len
        return seconds / max(steps, 1.0)

    def validate(self) -> float:
        """One epoch's validation free run of two candidates on ``val_eps`` [s]."""
        with torch_threads(self.cfg.num_threads or 1), torch.no_grad():
            t0 = time.perf_counter()
            free_run_errors([self.sur, self.sur], self.val_eps)
            seconds = time.perf_counter() - t0
        self.net.train()
        return seconds
