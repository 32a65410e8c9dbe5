"""The command state ``z``: play operators, then the command delay line.

Some features depend on the commands' history, not only on the current sample, and every
runtime carries that history as one tensor ``z: (..., Q + L, n_joint)`` of scaled commands
``us = (u - u_center) / u_scale`` (the joints' only):

- rows ``0..Q-1``: the play (backlash) operators of half-widths ``b_1..b_Q``,
  ``z_p[k] = clip(z_p[k-1], us[k] - b_p, us[k] + b_p)``; their features are
  ``(z_p - us) / b_p`` in [-1, 1] (width-major);
- rows ``Q..Q+L-1``: the last ``L`` commands, oldest first; their features are each joint's
  command ``d_j`` samples back, row ``L - 1 - d_j`` (``lag_index``).

:func:`command_step` (:func:`command_rows_step` with rows after the command state, and
:func:`command_rows_seq` over a whole sequence),
:func:`command_features` and :func:`delayed_commands` are the only torch code that knows
this layout; :class:`.features.Normalization`, the fused step and the
ONNX graphs call them.
The NumPy functions are the plain-loop references.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch


def play_np(us: np.ndarray, widths: Sequence[float], z0: np.ndarray | None = None) -> np.ndarray:
    """Play operators over time, plain loop (the reference of :func:`play_step`).

    Args:
        us: (..., n_step, n_joint) scaled commands (:func:`.features_np.scale_commands_np`).
        widths: P half-widths ``b_p`` > 0 [scaled command units].
        z0: (..., P, n_joint) state before the first sample; None: at rest (0).

    Returns:
        ``z``: (..., n_step, P, n_joint) operator outputs after each sample.
    """
    us = np.asarray(us, dtype=np.float64)
    b = np.asarray(widths, dtype=np.float64)[:, None]  # (P, 1)
    lead = us.shape[:-2]
    n_step, n_joint = us.shape[-2:]
    z = np.zeros((*lead, len(b), n_joint)) if z0 is None else np.array(z0, dtype=np.float64)
    out = np.empty((*lead, n_step, len(b), n_joint))
    # the bounds of every sample at once (the same sums as one sample at a time):
    # lo[k] = us[k] - b,  hi[k] = us[k] + b
    x = us[..., None, :]
    lo, hi = x - b, x + b
    for k in range(n_step):
        # z[k] = min(max(z[k-1], lo[k]), hi[k]), written in place
        z = np.minimum(np.maximum(z, lo[..., k, :, :]), hi[..., k, :, :], out=out[..., k, :, :])
    return out


def play_step(z: torch.Tensor, us: torch.Tensor, widths: torch.Tensor) -> torch.Tensor:
    """One sample of the play operators: ``z: (..., P, n_joint)``, scaled commands
    ``us: (..., n_joint)``, half-widths ``widths: (P,)`` -> new ``z``."""
    x = us.unsqueeze(-2)
    b = widths.unsqueeze(-1)
    # z[k] = min(max(z[k-1], us[k] - b), us[k] + b)
    return torch.minimum(torch.maximum(z, x - b), x + b)


def play_features(z: torch.Tensor, us: torch.Tensor, widths: torch.Tensor) -> torch.Tensor:
    """``(z - us) / b`` in [-1, 1], ``z: (..., P, n_joint)``, ``us: (..., n_joint)``, ``widths:
    (P,)`` -> ``(..., P * n_joint)`` (width-major; torch twin of :func:`play_features_np`)."""
    return ((z - us.unsqueeze(-2)) / widths.unsqueeze(-1)).flatten(-2)


def play_features_np(z: np.ndarray, us: np.ndarray, widths: Sequence[float]) -> np.ndarray:
    """``(z - us) / b`` in [-1, 1], ``z: (..., P, n_joint)``, ``us: (..., n_joint)`` ->
    ``(..., P * n_joint)`` (width-major)."""
    b = np.asarray(widths, dtype=np.float64)[:, None]
    f = (z - np.asarray(us, dtype=np.float64)[..., None, :]) / b
    return f.reshape(*f.shape[:-2], -1)


def line_step(line: torch.Tensor, us: torch.Tensor) -> torch.Tensor:
    """One sample of the command delay line: ``line: (..., L, n_joint)`` the scaled commands
    ``us[k-L..k-1]``, ``us: (..., n_joint)`` -> ``us[k-L+1..k]`` (oldest first)."""
    return torch.cat([line[..., 1:, :], us.unsqueeze(-2)], dim=-2)


def line_features(line: torch.Tensor, lag_index: torch.Tensor) -> torch.Tensor:
    """Each joint's delayed command from the delay line: ``line: (..., L, n_joint)`` after
    sample k, ``lag_index: (n_joint,)`` long ``L - 1 - d_j`` -> ``(..., n_joint)`` ``us_j[k - d_j]``."""
    cols = torch.arange(line.shape[-1], device=line.device)
    return line[..., lag_index, cols]


def line_from_rest_np(us: np.ndarray, n_line: int) -> np.ndarray:
    """The delay line after each sample, plain NumPy: ``us: (..., n_step, n_joint)`` scaled
    commands -> ``(..., n_step, n_line, n_joint)``, row ``r`` of sample ``k`` holding
    ``us[k - n_line + 1 + r]`` (0 before the first sample)."""
    us = np.asarray(us, dtype=np.float64)
    n_step = us.shape[-2]
    pad = np.zeros((*us.shape[:-2], n_line - 1, us.shape[-1]))
    full = np.concatenate([pad, us], axis=-2)
    return np.stack([full[..., r : r + n_step, :] for r in range(n_line)], axis=-2)


def command_step(z: torch.Tensor, us: torch.Tensor, widths: torch.Tensor) -> torch.Tensor:
    """The command state after one sample: ``z: (..., Q + L, n_joint)`` before it, scaled
    joint commands ``us: (..., n_joint)``, play half-widths ``widths: (Q,)`` -> the new ``z``
    (the play operators stepped, the delay line shifted)."""
    q = widths.numel()
    if z.shape[-2] == q:
        return play_step(z, us, widths)
    line = line_step(z[..., q:, :], us)
    return torch.cat([play_step(z[..., :q, :], us, widths), line], dim=-2) if q else line


def command_rows_step(
    z: torch.Tensor, us: torch.Tensor, widths: torch.Tensor, n_command: int
) -> torch.Tensor:
    """:func:`command_step` on the first ``n_command`` (Q + L) rows of ``z: (..., Q + L + R,
    n_joint)``; the R rows after them (the network's own angle and velocity,
    :mod:`.own_angles`) pass through unchanged."""
    if z.shape[-2] == n_command:
        return command_step(z, us, widths)
    rest = z[..., n_command:, :]
    return torch.cat([command_step(z[..., :n_command, :], us, widths), rest], dim=-2)


def command_rows_seq(
    z: torch.Tensor, us: torch.Tensor, widths: torch.Tensor, n_command: int
) -> torch.Tensor:
    """:func:`command_rows_step` over every sample of ``us: (n_batch, n_step, n_joint)`` from
    ``z: (n_batch, Q + L + R, n_joint)``; returns the states after each sample, ``(n_batch,
    n_step, Q + L + R, n_joint)``.  Only the play operators need a loop over the samples: the
    delay line after sample k is a window of the commands, and the R rows pass through."""
    n_batch, n_step, n_joint = us.shape
    q = widths.numel()
    parts = []
    if q:
        p, ps = z[:, :q, :], []
        for k in range(n_step):
            p = play_step(p, us[:, k], widths)
            ps.append(p)
        parts.append(torch.stack(ps, dim=1) if ps else z.new_zeros(n_batch, 0, q, n_joint))
    n_line = n_command - q
    if n_line:
        # line[k] = us[k-L+1..k], the L commands up to sample k, oldest first: a window of
        # full = [line before the first sample, us]
        full = torch.cat([z[:, q:n_command, :], us], dim=1)  # (n_batch, L + n_step, n_joint)
        windows = full.unfold(1, n_line, 1)[:, 1:]  # (n_batch, n_step, n_joint, L)
        parts.append(windows.transpose(-1, -2))
    if z.shape[-2] > n_command:
        parts.append(z[:, None, n_command:, :].expand(n_batch, n_step, -1, n_joint))
    if not parts:
        return z.new_zeros(n_batch, n_step, 0, n_joint)
    return torch.cat(parts, dim=-2) if len(parts) > 1 else parts[0].contiguous()


def command_features(
    z: torch.Tensor, us: torch.Tensor, widths: torch.Tensor, lag_index: torch.Tensor
) -> torch.Tensor:
    """The features of the command state ``z: (..., Q + L, n_joint)`` after the sample of
    ``us: (..., n_joint)``: the play features (..., Q * n_joint), then with a delay line
    each joint's delayed command (..., n_joint) (``lag_index``: (n_joint,) long)."""
    q = widths.numel()
    parts = [play_features(z[..., :q, :], us, widths)] if q else []
    if z.shape[-2] > q:
        parts.append(delayed_commands(z, widths, lag_index))
    return torch.cat(parts, dim=-1) if len(parts) > 1 else parts[0]


def delayed_commands(
    z: torch.Tensor, widths: torch.Tensor, lag_index: torch.Tensor
) -> torch.Tensor:
    """Each joint's scaled command ``d_j`` samples back, ``(..., n_joint)``, from the delay
    line of ``z: (..., Q + L, n_joint)`` (``widths``: the Q play half-widths before it)."""
    return line_features(z[..., widths.numel() :, :], lag_index)
