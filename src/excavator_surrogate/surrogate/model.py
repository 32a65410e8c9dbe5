"""Surrogate networks and the :class:`Surrogate` bundle (network + spec + normalisation).

- :class:`SurrogateNet`: ``n_layer`` stacked LSTM (or GRU) of width ``hidden`` -> FC -> ReLU ->
  linear -> one normalised angular velocity per joint (paper III-B: 2 x LSTM(128), W = 30).
  Two ways to run it:

  * windowed: ``net(x)`` with ``x: (n_batch, W, n_feature)`` -> ``(n_batch, n_joint)``, starting
    each window from a zero state (the paper's sliding-window operator);
  * stateful: ``net.step(x_t, (h, c))`` with ``x_t: (n_batch, n_feature)`` -> ``(y, (h, c))``,
    carrying the recurrent state sample by sample (``h``, ``c``: ``(n_layer, n_batch, hidden)``;
    for the GRU ``c`` is an unused zero tensor so every cell has the same interface).

- :class:`ARXNet`: the linear ARX baseline on the same normalised window (windowed only).

Inputs and outputs are *normalised* (see :class:`~.features.Normalization`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import Any, Literal

import numpy as np
import torch
from torch import nn

from ..errors import CheckpointError
from ..spec import MachineSpec
from .angles import envelope
from .features import Normalization
from .prior import SpeedPrior

State = tuple[torch.Tensor, torch.Tensor]
"""Recurrent state ``(h, c)``, each ``(n_layer, n_batch, hidden)``."""

Cell = Literal["lstm", "gru", "arx"]


@dataclass(frozen=True)
class ModelConfig:
    """Architecture of a surrogate network (stored in the checkpoint)."""

    n_feature: int
    """Input width (``spec.n_feature``)."""
    n_joint: int
    """Output width (one angular velocity per joint)."""
    window: int = 30
    """Window length W [samples] (windowed mode; also the warm-up length)."""
    hidden: int = 128
    """Recurrent state width."""
    n_layer: int = 2
    """Stacked recurrent layers."""
    cell: Cell = "lstm"
    """``lstm``, ``gru`` or ``arx`` (linear baseline)."""
    head_hidden: int = 128
    """Width of the FC layer between the recurrent output and the linear output layer."""
    residual: bool = False
    """The head predicts the change of the velocity: ``y = head(h) + x[..., -n_joint:]``, the
    last ``n_joint`` inputs being the velocity feature, normalised like the target
    (:attr:`~.features.Normalization.omega_in`); LSTM/GRU only."""
    prior: bool = False
    """The head corrects a static per-joint valve map of the command (:mod:`.prior`):
    ``omega[k+1] = s(u[k]) + y_std * head``; LSTM/GRU only."""

    def to_dict(self) -> dict[str, Any]:
        """Plain dict."""
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> ModelConfig:
        """Inverse of :meth:`to_dict`; raises :class:`CheckpointError` on bad entries."""
        try:
            cfg = cls(**d)
        except TypeError as e:
            raise CheckpointError(f"model entry is malformed ({e})") from e
        for name in ("n_feature", "n_joint", "window", "hidden", "n_layer", "head_hidden"):
            v = getattr(cfg, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                raise CheckpointError(
                    f"model entry is malformed ({name} = {v!r}: not a positive integer)"
                )
        for name in ("residual", "prior"):
            if not isinstance(getattr(cfg, name), bool):
                raise CheckpointError(
                    f"model entry is malformed ({name} = {getattr(cfg, name)!r}: not true/false)"
                )
        if cfg.cell not in ("lstm", "gru", "arx"):
            raise CheckpointError(f"unknown cell '{cfg.cell}' (this exsur knows lstm, gru, arx)")
        if cfg.residual and (cfg.cell == "arx" or cfg.n_feature <= cfg.n_joint):
            raise CheckpointError("a residual head needs an LSTM/GRU with a velocity feature")
        if cfg.prior and (cfg.cell == "arx" or cfg.residual):
            raise CheckpointError("a speed prior needs an LSTM/GRU without a residual head")
        return cfg


CELL_WEIGHTS = ("weight_ih", "weight_hh", "bias_ih", "bias_hh")
"""Per-layer parameter names of ``nn.LSTM`` / ``nn.GRU`` (suffix ``_l<layer>``)."""
CELL_GATES = {"lstm": 4, "gru": 3}
"""Gates of a cell: its weight matrices stack this many ``hidden``-row blocks."""


def step_layers(
    x: torch.Tensor,
    h: torch.Tensor,
    c: torch.Tensor,
    weights: Sequence[tuple[torch.Tensor, ...]],
    *,
    lstm: bool,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """One sample through stacked LSTM / GRU layers, one fused cell op per layer.

    Args:
        x: (n_batch, n_in) layer-0 input.
        h, c: (n_layer, n_batch, hidden) state (``c`` passes through for a GRU).
        weights: per layer ``(w_ih, w_hh, b_ih, b_hh)``.
        lstm: LSTM cells (else GRU).

    Returns:
        The last layer's output (n_batch, hidden) and the new ``h``, ``c`` (new tensors).
    """
    hs, cs = [], []
    inp = x
    for layer, w in enumerate(weights):
        # gates = W_ih x + b_ih + W_hh h + b_hh, then the LSTM / GRU update of (h, c)
        if lstm:
            h_l, c_l = torch.lstm_cell(inp, (h[layer], c[layer]), *w)
        else:
            h_l, c_l = torch.gru_cell(inp, h[layer], *w), c[layer]
        hs.append(h_l)
        cs.append(c_l)
        inp = h_l
    return inp, torch.stack(hs), torch.stack(cs)


class SurrogateNet(nn.Module):
    """Stacked LSTM/GRU with an FC-ReLU-linear head; outputs normalised omega per joint (with
    ``cfg.residual``: the head's output plus the normalised velocity feature of the same
    sample, i.e. the net predicts how the velocity changes)."""

    stateful_capable = True

    def __init__(self, cfg: ModelConfig) -> None:
        super().__init__()
        if cfg.cell not in ("lstm", "gru"):
            raise ValueError(f"SurrogateNet cell must be lstm or gru, got {cfg.cell}")
        self.cfg = cfg
        rnn = nn.LSTM if cfg.cell == "lstm" else nn.GRU
        self.rnn = rnn(cfg.n_feature, cfg.hidden, num_layers=cfg.n_layer, batch_first=True)
        want = [f"{n}_l{k}" for k in range(cfg.n_layer) for n in CELL_WEIGHTS]
        # step() reads the cells' weights from the module's flat list when it has this layout
        self._flat_layout = list(getattr(self.rnn, "_flat_weights_names", [])) == want
        self.head = nn.Sequential(
            nn.Linear(cfg.hidden, cfg.head_hidden),
            nn.ReLU(),
            nn.Linear(cfg.head_hidden, cfg.n_joint),
        )
        self.prior = SpeedPrior(cfg.n_joint) if cfg.prior else None

    def init_state(self, n_batch: int) -> State:
        """Zero state ``(h, c)``, each ``(n_layer, n_batch, hidden)`` on the net's device/dtype."""
        p = next(self.parameters())
        z = torch.zeros(self.cfg.n_layer, n_batch, self.cfg.hidden, device=p.device, dtype=p.dtype)
        return z, z.clone()

    def forward_seq(
        self, x: torch.Tensor, state: State | None = None
    ) -> tuple[torch.Tensor, State]:
        """Run a sequence.

        Args:
            x: (n_batch, n_step, n_feature) normalised features.
            state: ``(h, c)`` to start from; zeros if None.

        Returns:
            ``y``: (n_batch, n_step, n_joint) normalised omega (output at step k predicts
            omega[k+1]); and the final ``(h, c)``.
        """
        if state is None:
            state = self.init_state(x.shape[0])
        if self.cfg.cell == "lstm":
            out, (h, c) = self.rnn(x, state)
        else:
            out, h = self.rnn(x, state[0])
            c = state[1]
        return self._out(out, x), (h, c)

    def _out(self, out: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        """Head of the recurrent output ``out`` (..., hidden) for the inputs ``x`` (...,
        n_feature) of the same samples: ``head(out)`` (+ the velocity feature if residual, + the
        speed prior's normalised speed if prior)."""
        y = self.head(out)
        if self.cfg.residual:
            # omega[k+1] = omega[k] + change, in the target's normalisation
            y = y + x[..., -self.cfg.n_joint :]
        if self.prior is not None:
            # omega[k+1] = s(u[k]) + y_std head  (the prior carries the -y_mean / y_std)
            y = y + self.prior(x)
        return y

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Windowed forward: ``x: (n_batch, W, n_feature)`` -> ``(n_batch, n_joint)`` from the last step."""
        out, _ = self.rnn(x)
        return self._out(out[:, -1], x[:, -1])

    def step(self, x_t: torch.Tensor, state: State) -> tuple[torch.Tensor, State]:
        """One sample: ``x_t: (n_batch, n_feature)`` -> (``(n_batch, n_joint)``, new ``(h, c)``).

        The same maths as :meth:`forward_seq` on a one-sample sequence, with one fused cell op
        per layer (``torch.lstm_cell`` / ``torch.gru_cell``): a one-step ``nn.LSTM`` call costs
        ~190 us forward + ~290 us backward in oneDNN's sequence kernel on CPU, the cell ~2x less
        (free-run training and validation step one sample at a time).
        """
        n = len(CELL_WEIGHTS)
        if self._flat_layout:
            # nn.LSTM / nn.GRU keep their parameters in this list, 4 per layer in CELL_WEIGHTS'
            # order: one attribute read instead of 4 module lookups a layer (~10 % of a step)
            flat = self.rnn._flat_weights
        else:  # another torch's layout: the same tensors, looked up by name
            layers = range(self.cfg.n_layer)
            flat = [getattr(self.rnn, f"{w}_l{k}") for k in layers for w in CELL_WEIGHTS]
        weights = [tuple(flat[n * k : n * (k + 1)]) for k in range(self.cfg.n_layer)]
        out, h, c = step_layers(x_t, *state, weights, lstm=self.cfg.cell == "lstm")
        return self._out(out, x_t), (h, c)


class ARXNet(nn.Module):
    """Linear ARX baseline: ``y = A vec(x_window) + b`` on the normalised window."""

    stateful_capable = False

    def __init__(self, cfg: ModelConfig) -> None:
        super().__init__()
        self.cfg = cfg
        self.linear = nn.Linear(cfg.window * cfg.n_feature, cfg.n_joint)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """``x: (n_batch, W, n_feature)`` -> ``(n_batch, n_joint)`` normalised omega."""
        return self.linear(x.reshape(x.shape[0], -1))


def build_net(cfg: ModelConfig) -> nn.Module:
    """The network for ``cfg.cell``."""
    return ARXNet(cfg) if cfg.cell == "arx" else SurrogateNet(cfg)


@dataclass
class Surrogate:
    """A trained surrogate: network, machine spec, normalisation and how to run it.

    ``mode`` is how the model was trained and must be rolled out: ``windowed`` (zero state per
    window of ``window`` samples) or ``stateful`` (state carried sample by sample).
    """

    net: nn.Module
    spec: MachineSpec
    norm: Normalization
    model_cfg: ModelConfig
    mode: Literal["windowed", "stateful"] = "windowed"
    train_config: dict[str, Any] | None = None
    metrics: dict[str, Any] | None = None
    name: str = "lstm"
    end_stops: bool = False
    """Keep free runs inside the machine's envelope: clip integrated angles to the spec's joint
    limits (mechanical end stops) and predicted velocities to its speed bounds."""

    def limits_np(self) -> tuple[np.ndarray, ...] | None:
        """``(lo, hi)`` end stops, each (n_joint,) float64 [rad], followed by ``omega_max``
        [rad/s] when the spec bounds any joint's speed; None when ``end_stops`` is off or the
        spec bounds nothing."""
        if not self.end_stops:
            return None
        lo, hi, w = envelope(self.spec)
        if np.isfinite(w).any():
            return lo, hi, w
        if not (np.isfinite(lo).any() or np.isfinite(hi).any()):
            return None
        return lo, hi

    def limits(self) -> tuple[torch.Tensor, ...] | None:
        """:meth:`limits_np` as tensors on the net's device/dtype."""
        lim = self.limits_np()
        if lim is None:
            return None
        t = {"device": self.device, "dtype": self.dtype}
        return tuple(torch.as_tensor(a, **t) for a in lim)

    @property
    def window(self) -> int:
        """Window / warm-up length W [samples]."""
        return self.model_cfg.window

    @property
    def device(self) -> torch.device:
        """Device of the network's parameters."""
        return next(self.net.parameters()).device

    @property
    def dtype(self) -> torch.dtype:
        """Dtype of the network's parameters."""
        return next(self.net.parameters()).dtype

    def to(
        self, device: torch.device | str | None = None, dtype: torch.dtype | None = None
    ) -> Surrogate:
        """Move network and normalisation (in place); returns self."""
        self.net.to(device=device, dtype=dtype)
        self.norm = self.norm.to(self.device, self.dtype)
        return self

    def eval(self) -> Surrogate:
        """Put the network in eval mode; returns self."""
        self.net.eval()
        return self
