"""The recurrent layers a stateful :class:`~.engine.SurrogateEngine` steps (:class:`RecurrentKernel`).

One of three implementations of the same folded layers (:class:`~.fused.FusedStep`'s weights):

- ``cell``: per-layer ``torch.lstm_cell``/``torch.gru_cell`` ops (small batches);
- ``module``: a folded ``nn.LSTM``/``nn.GRU`` (oneDNN), from :data:`MODULE_MIN_BATCH` envs on;
- ``members``: a merged LSTM seed ensemble's diagonal blocks as one batched matmul
  (:mod:`~excavator_surrogate.surrogate.member_lstm`), from :data:`MEMBERS_MIN_BATCH` envs on,
  skipping the zero blocks of the dense kernels.

The state ``(h, c)`` is (n_layer, n, hidden), or (n_layer, M, n, hidden / M) for ``members``
(:meth:`RecurrentKernel.dense` and :meth:`RecurrentKernel.from_dense` convert).
"""

from __future__ import annotations

from typing import Literal

import torch
from torch import nn

from ..errors import ConfigError
from ..surrogate.member_lstm import MemberLSTM, from_dense, member_count, to_dense
from ..surrogate.model import step_layers
from .fused import FusedStep

Impl = Literal["auto", "cell", "module", "members"]
IMPLS: tuple[str, ...] = ("auto", "cell", "module", "members")

MODULE_MIN_BATCH = 256
"""``impl="auto"`` uses the folded ``nn.LSTM`` module (oneDNN) from this batch size on."""

MEMBERS_MIN_BATCH = 64
"""``impl="auto"`` steps a merged LSTM ensemble member by member from this batch size on
(one core, the demo's two members of width 64: a whole engine step takes 1.04 ms against the
dense cell's 1.42 at 256 envs; a first, slower prototype already broke even at 64)."""


def check_impl(impl: str) -> None:
    """Refuse an ``impl`` that is not one of :data:`IMPLS`, in one line."""
    if impl not in IMPLS:
        raise ConfigError(f"impl must be 'auto', 'cell', 'module' or 'members', got {impl!r}")


class RecurrentKernel:
    """The folded recurrent layers of ``fused``, stepped by the implementation ``impl`` picks.

    Args:
        fused: the surrogate's folded single step (its ``w_ih``, ``w_hh``, ``b_ih``, ``b_hh``
            per layer and its head).
        n_envs: the batch the engine steps (``impl="auto"`` chooses by it).
        impl: ``"cell"``, ``"module"``, ``"members"`` or ``"auto"`` (members from
            :data:`MEMBERS_MIN_BATCH` envs on when ``fused`` is a merged LSTM ensemble of
            equal members, else module from :data:`MODULE_MIN_BATCH` envs on, else cell).
        name: the surrogate's name, for the error when ``impl="members"`` cannot apply.
    """

    def __init__(self, fused: FusedStep, *, n_envs: int, impl: Impl, name: str) -> None:
        check_impl(impl)
        self.fused = f = fused
        self.n_layer, self.hidden = f.n_layer, f.hidden
        # plain tensors: indexing ParameterLists costs more than the cell ops at n_envs = 1
        self.layers = [
            (f.w_ih[k].data, f.w_hh[k].data, f.b_ih[k].data, f.b_hh[k].data)
            for k in range(f.n_layer)
        ]
        self.head = (f.w1.data, f.b1.data, f.w2.data, f.b2.data)
        """The head's ``(w1, b1, w2, b2)``: ``omega = w2 relu(w1 out + b1) + b2``."""
        self.is_lstm = f.cell == "lstm"
        self.members = self._member_kernel(impl, n_envs=n_envs, name=name)
        self.impl: str
        if self.members is not None:
            self.impl = "members"
        elif impl == "auto":
            self.impl = "module" if n_envs >= MODULE_MIN_BATCH else "cell"
        else:
            self.impl = impl
        self.module = self._folded_module() if self.impl == "module" else None

    def _member_kernel(self, impl: Impl, *, n_envs: int, name: str) -> MemberLSTM | None:
        """The per-member kernel when ``impl`` asks for it (or ``auto`` picks it), else None."""
        if impl not in ("auto", "members") or (impl == "auto" and n_envs < MEMBERS_MIN_BATCH):
            return None
        # the finest equal blocks: a merge of merges steps as its smallest members
        count = member_count(self.layers) if self.is_lstm else None
        kernel = None if count is None else MemberLSTM.from_layers(self.layers, count)
        if impl == "members" and kernel is None:
            raise ConfigError(
                f"impl='members' needs a merged LSTM seed ensemble of equal members; "
                f"'{name}' is not one (use impl='auto')"
            )
        return kernel

    def _folded_module(self) -> nn.Module:
        f = self.fused
        cls = nn.LSTM if f.cell == "lstm" else nn.GRU
        device = f.w_ih[0].device
        mod = cls(f.n_raw, f.hidden, num_layers=f.n_layer, batch_first=True).to(device)
        with torch.no_grad():
            for layer in range(f.n_layer):
                getattr(mod, f"weight_ih_l{layer}").copy_(f.w_ih[layer])
                getattr(mod, f"weight_hh_l{layer}").copy_(f.w_hh[layer])
                getattr(mod, f"bias_ih_l{layer}").copy_(f.b_ih[layer])
                getattr(mod, f"bias_hh_l{layer}").copy_(f.b_hh[layer])
        mod.requires_grad_(False)
        return mod.eval()

    def state_shape(self, n: int) -> tuple[int, ...]:
        """Shape of ``h``/``c`` for ``n`` envs in this kernel's layout."""
        if self.members is not None:
            m = self.members
            return (self.n_layer, m.n_member, n, m.width)
        return (self.n_layer, n, self.hidden)

    def dense(
        self, h: torch.Tensor, c: torch.Tensor, row: int | None = None
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """``(h, c)`` as (n_layer, n, hidden) whatever the layout (``row``: only that env,
        (n_layer, 1, hidden)); copies."""
        sl = slice(None) if row is None else slice(row, row + 1)
        if self.members is not None:
            return to_dense(h[:, :, sl]), to_dense(c[:, :, sl])
        return h[:, sl].clone(), c[:, sl].clone()

    def from_dense(self, h: torch.Tensor, c: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The inverse of :meth:`dense`: (n_layer, n, hidden) into this kernel's layout."""
        if self.members is not None:
            n_member = self.members.n_member
            return from_dense(h, n_member), from_dense(c, n_member)
        return h, c

    def cells(
        self, x: torch.Tensor, h: torch.Tensor, c: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """One sample through the layers with cell ops (the member kernel's, if any); x (m,
        n_raw); returns (out, h, c) new tensors."""
        if self.members is not None:
            return self.members.step(x, h, c)
        return step_layers(x, h, c, self.layers, lstm=self.is_lstm)

    def seq(
        self, x: torch.Tensor, h: torch.Tensor, c: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """A sequence x (m, n_step, n_raw) from state (h, c); returns (last output, h, c)."""
        if self.module is not None:
            if self.is_lstm:
                out, (h, c) = self.module(x, (h.contiguous(), c.contiguous()))
            else:
                out, h = self.module(x, h.contiguous())
            return out[:, -1], h, c
        out = x.new_zeros(x.shape[0], self.hidden)
        for k in range(x.shape[1]):
            out, h, c = self.cells(x[:, k], h, c)
        return out, h, c

    def step(
        self, x: torch.Tensor, h: torch.Tensor, c: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """One sample x (m, n_raw) through the layers and the head's hidden layer, as the
        engine's step runs it; returns (the head's activations (m, head), h, c)."""
        if self.module is not None:
            out, h, c = self.seq(x.unsqueeze(1), h, c)
        else:
            out, h, c = self.cells(x, h, c)
        w1, b1, _, _ = self.head
        return torch.relu(torch.addmm(b1, out, w1.t())), h, c
