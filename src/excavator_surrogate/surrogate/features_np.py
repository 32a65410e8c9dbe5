"""The raw (un-normalised) features in NumPy: what the normalisation is fitted on, and what
the plain-loop reference, the NumPy loop and the ONNX stepper encode with.

The layout is :mod:`.features`' (angles, sin/cos of a periodic joint; the commands scaled
by their range; the play features; the delayed commands; the velocity input), computed in
float64 from plain arrays, one function per part.  The torch encoding
(:meth:`~.features.Normalization.encode`) is a separate twin, tested against these.
:class:`~.features.Normalization` standardises them.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..spec import MachineSpec
from .command_state import play_features_np, play_np


def scale_commands_np(u: np.ndarray, spec: MachineSpec) -> np.ndarray:
    """Commands ``u: (..., n_u)`` [command units] scaled to ``(u - u_center) / u_scale``."""
    center = np.array([c.u_center for c in spec.u_specs])
    scale = np.array([c.u_scale for c in spec.u_specs])
    return (np.asarray(u, dtype=np.float64) - center) / scale


def play_states_from_rest(
    u: np.ndarray, spec: MachineSpec, play: Sequence[float]
) -> np.ndarray | None:
    """The play operators' states ``(..., n_step, P, n_joint)`` over the commands ``u: (...,
    n_step, n_u)`` [command units] from rest (:func:`.command_state.play_np`), or None without
    ``play``."""
    if not len(play):
        return None
    return play_np(scale_commands_np(u, spec)[..., : spec.n_joint], play)


def angle_columns_np(theta: np.ndarray, periodic: Sequence[bool]) -> np.ndarray:
    """The angle columns of the features before normalisation, in ``theta``'s dtype:
    ``(..., n_joint)`` [rad] -> ``(..., n_angle)``, sin and cos of a periodic joint, else
    the angle."""
    parts = []
    for j, p in enumerate(periodic):
        th = theta[..., j]
        parts += [np.sin(th), np.cos(th)] if p else [th]
    return np.stack(parts, axis=-1)


def encode_np(
    theta: np.ndarray,
    u: np.ndarray,
    spec: MachineSpec,
    *,
    play: Sequence[float] = (),
    z: np.ndarray | None = None,
    lag: np.ndarray | None = None,
    omega: np.ndarray | None = None,
) -> np.ndarray:
    """Raw (un-normalised) features, NumPy version.

    Args:
        theta: (..., n_joint) angles [rad].
        u: (..., n_u) commands [command units]: the joints', then the exogenous inputs'.
        play: half-widths of the play operators (empty: the paper's features).
        z: (..., P, n_joint) play states after this sample (:func:`play_np`); required with ``play``.
        lag: (..., n_joint) each joint's delayed scaled command ``us_j[k - d_j]``, or None
            (not a feature).
        omega: (..., n_joint) velocity input feature [rad/s] (:func:`.angles.omega_in_np`), or None
            (not a feature).

    Returns:
        (..., n_feature) features: angle part (sin/cos for periodic joints), scaled commands,
        the play features, ``lag``, then ``omega``; ``n_feature = spec.n_feature + P * n_joint``
        (+ ``n_joint`` with ``lag``, + ``n_joint`` with ``omega``).
    """
    theta = np.asarray(theta, dtype=np.float64)
    u = np.asarray(u, dtype=np.float64)
    us = scale_commands_np(u, spec)
    out = [angle_columns_np(theta, [js.periodic for js in spec.joints]), us]
    if len(play):
        if z is None:
            raise ValueError("encode_np: play features need the play states z")
        out.append(play_features_np(z, us[..., : spec.n_joint], play))
    if lag is not None:
        out.append(np.asarray(lag, dtype=np.float64))
    if omega is not None:
        out.append(np.asarray(omega, dtype=np.float64))
    return np.concatenate(out, axis=-1)
