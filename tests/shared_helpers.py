"""Helpers shared by the test folders (``tests/`` is on ``sys.path`` through its conftest)."""

from __future__ import annotations

import torch
from torch import nn


def drive_into_stops(net: nn.Module, drive: float, n_joint: int) -> None:
    """Add ``+/- drive`` (alternating by joint, normalised units) to the output bias of an
    untrained surrogate network so that its free runs reach the joint limits (end-stop tests)."""
    if not drive:
        return
    last = net.linear if hasattr(net, "linear") else net.head[-1]
    with torch.no_grad():
        last.bias += drive * torch.tensor([(-1.0) ** j for j in range(n_joint)])
