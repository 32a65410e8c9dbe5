"""Rendering of the excavator environments: ``render_mode="rgb_array"`` (headless frames through
MuJoCo's offscreen renderer) and ``"human"`` (MuJoCo's passive viewer, needs a display).

Both environments draw the same MJCF model: ``ExcavatorMujoco-v0`` its plant's physics
state, ``ExcavatorSurrogate-v0`` the surrogate's predicted pose (``qpos`` set from θ, then
``mj_forward``), so a user can watch the plant and the surrogate side by side
(:func:`side_by_side`).

Headless machines need an OpenGL backend for MuJoCo (``MUJOCO_GL``): :func:`gl_backend`
keeps the user's ``MUJOCO_GL`` and otherwise chooses EGL on a Linux machine without a
display, even when ``mujoco`` was imported before.  Without a working backend the first
frame raises :class:`RenderError` saying what to install.
"""

from __future__ import annotations

import importlib
import os
import sys
from typing import Any

import mujoco
import numpy as np

from ..errors import ConfigError, ExsurError, error_summary
from ..spec import MachineSpec

RENDER_MODES: tuple[str, ...] = ("rgb_array", "human")
"""The render modes of both single environments."""
RENDER_SIZE: tuple[int, int] = (480, 360)
"""Default frame size ``(width, height)`` [pixels] (at most the MJCF's offscreen buffer, 1280 x 720)."""
INSTALL = (
    "install EGL (apt-get install -y libegl1 libgl1) or OSMesa (apt-get install -y libosmesa6 "
    "and set MUJOCO_GL=osmesa), or set MUJOCO_GL to a backend that works here"
)
"""What to do when no OpenGL backend works (the tail of :class:`RenderError` messages)."""


class RenderError(ExsurError):
    """No OpenGL backend for MuJoCo's offscreen renderer, or no display for the viewer."""


def has_display() -> bool:
    """True when a window can be opened (always on macOS/Windows; ``DISPLAY`` or
    ``WAYLAND_DISPLAY`` set on Linux)."""
    if not sys.platform.startswith("linux"):
        return True
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def gl_backend() -> str:
    """The ``MUJOCO_GL`` backend offscreen frames use.

    ``MUJOCO_GL`` if set; otherwise ``egl`` on Linux without a display (set in the
    environment and, if ``mujoco`` chose its GL context already, switched there too), else
    ``glfw`` (MuJoCo's default).
    """
    chosen = os.environ.get("MUJOCO_GL", "").strip().lower()
    if chosen:
        return chosen
    if not (sys.platform.startswith("linux") and not has_display()):
        return "glfw"
    os.environ["MUJOCO_GL"] = "egl"
    os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
    # ``import mujoco`` picked its GLContext class from MUJOCO_GL at import time: point the
    # renderer at EGL (a failure here surfaces as a RenderError on the first frame)
    for name in ("mujoco.rendering.classic.gl_context", "mujoco.gl_context"):
        mod = sys.modules.get(name)
        if mod is not None:
            try:
                mod.GLContext = importlib.import_module("mujoco.egl").GLContext  # type: ignore[attr-defined]
            except Exception:  # reported when the renderer is created
                pass
    return "egl"


def check_render_mode(render_mode: str | None, *, where: str) -> str | None:
    """Raise :class:`ConfigError` unless ``render_mode`` is None or one of :data:`RENDER_MODES`."""
    if render_mode is not None and render_mode not in RENDER_MODES:
        raise ConfigError(
            f"{where}: render_mode must be one of {', '.join(RENDER_MODES)} or None, got "
            f"{render_mode!r}"
        )
    return render_mode


def check_size(size: Any, *, where: str) -> tuple[int, int]:
    """``(width, height)`` as positive ints, or :class:`ConfigError`."""
    try:
        w, h = (int(v) for v in size)
    except (TypeError, ValueError) as e:
        raise ConfigError(f"{where}: render_size must be (width, height), got {size!r}") from e
    if w < 1 or h < 1:
        raise ConfigError(f"{where}: render_size must be positive, got {size!r}")
    return w, h


class FrameRenderer:
    """Offscreen RGB frames of an ``MjModel`` from a fixed free camera that shows the machine.

    Args:
        model: the MJCF model.
        size: ``(width, height)`` [pixels], at most the model's offscreen buffer.
        where: the environment, for messages.

    Raises:
        RenderError: no OpenGL backend works (one line saying what to install).
        ConfigError: the frame is larger than the model's offscreen buffer.
    """

    def __init__(self, model: mujoco.MjModel, *, size: tuple[int, int], where: str) -> None:
        width, height = size
        buf = (int(model.vis.global_.offwidth), int(model.vis.global_.offheight))
        if width > buf[0] or height > buf[1]:
            raise ConfigError(
                f"{where}: render_size {size} exceeds the MJCF's offscreen buffer {buf} "
                "(<visual><global offwidth offheight>)"
            )
        backend = gl_backend()
        try:
            self._renderer = mujoco.Renderer(model, height=height, width=width)
        except Exception as e:  # every GL failure becomes one line
            raise RenderError(
                f"{where}: render_mode='rgb_array' needs an OpenGL backend, and MUJOCO_GL="
                f"{backend} failed ({error_summary(e)}); {INSTALL}"
            ) from e
        self.camera = mujoco.MjvCamera()
        mujoco.mjv_defaultFreeCamera(model, self.camera)
        self.camera.azimuth, self.camera.elevation = 135.0, -20.0
        self.camera.distance = 1.1 * float(model.stat.extent)

    def frame(self, data: mujoco.MjData) -> np.ndarray:
        """The scene of ``data`` as an ``(height, width, 3)`` uint8 RGB array."""
        self._renderer.update_scene(data, camera=self.camera)
        return self._renderer.render().copy()

    def close(self) -> None:
        """Release the GL context."""
        self._renderer.close()


class Viewer:
    """MuJoCo's passive viewer window over ``data`` (``render_mode="human"``).

    Raises:
        RenderError: no display, or the viewer cannot open.
    """

    def __init__(self, model: mujoco.MjModel, data: mujoco.MjData, *, where: str) -> None:
        if not has_display():
            raise RenderError(
                f"{where}: render_mode='human' needs a display (DISPLAY is not set); use "
                "render_mode='rgb_array' for frames without one"
            )
        try:
            import mujoco.viewer

            self._viewer = mujoco.viewer.launch_passive(model, data)
        except Exception as e:  # one line, whatever the GUI stack raises
            raise RenderError(
                f"{where}: MuJoCo's viewer cannot open ({error_summary(e)}); use "
                "render_mode='rgb_array'"
            ) from e

    def show(self) -> None:
        """Draw the current state of the viewer's ``data``."""
        if self._viewer.is_running():
            self._viewer.sync()

    def close(self) -> None:
        """Close the window."""
        self._viewer.close()


class PoseScene:
    """The built-in excavator's MJCF posed at given joint angles (what the surrogate draws).

    A linear joint (a cylinder stroke) is drawn at the joint angle its linkage gives
    (:meth:`~excavator_surrogate.spec.Linkage.angle`); without a linkage its pose is
    unknown, and the machine is refused.

    Args:
        spec: the machine; each joint must exist in the MJCF under its name.
        where: the environment, for messages.

    Raises:
        ConfigError: a joint of ``spec`` is not in the MJCF, or is a stroke without a linkage.
    """

    def __init__(self, spec: MachineSpec, *, where: str) -> None:
        from ..simulate.plant import default_xml

        xml = default_xml()
        self.model = mujoco.MjModel.from_xml_path(str(xml))
        self.data = mujoco.MjData(self.model)
        adr = []
        for joint in spec.joints:
            name = joint.name
            j = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_JOINT, name)
            if j < 0:
                raise ConfigError(
                    f"{where}: cannot render joint '{name}': the built-in excavator MJCF ({xml.name}) "
                    f"has no joint of that name; render a machine with joints of the excavator"
                )
            if joint.linear and joint.linkage is None:
                raise ConfigError(
                    f"{where}: cannot render joint '{name}': a stroke without a linkage (the "
                    "MJCF poses joint angles); give the joint's linkage in the import mapping "
                    "(docs/import.md, Linear joints), or leave render_mode unset"
                )
            adr.append(int(self.model.jnt_qposadr[j]))
        self._qadr = np.array(adr, dtype=int)
        self._linkages = [(k, j.linkage) for k, j in enumerate(spec.joints) if j.linkage]
        """(index, linkage) of each linear joint (all have one), whose stroke is drawn at its
        angle."""

    def pose(self, theta: np.ndarray) -> mujoco.MjData:
        """``data`` with the joints at ``theta`` (n_joint,) [rad; a stroke in m, drawn at its
        linkage's angle] and positions, lights and cameras updated (``mj_forward``)."""
        q = np.array(theta, dtype=np.float64)
        for k, linkage in self._linkages:
            # θ_k = arccos((a² + b² − (l0 + s_k)²) / (2ab)) − phi
            q[k] = linkage.angle(q[k])
        self.data.qpos[self._qadr] = q
        mujoco.mj_forward(self.model, self.data)
        return self.data


def side_by_side(*frames: np.ndarray, gap: int = 4) -> np.ndarray:
    """Frames ``(height, width_i, 3)`` uint8 of equal height joined left to right with a
    ``gap``-pixel white bar, e.g. ``side_by_side(plant.render(), surrogate.render())``."""
    if not frames:
        raise ConfigError("side_by_side: give at least one frame")
    heights = {f.shape[0] for f in frames}
    if len(heights) != 1 or any(f.ndim != 3 or f.shape[2] != 3 for f in frames):
        raise ConfigError(
            f"side_by_side: frames must be (height, width, 3) of one height, got "
            f"{[f.shape for f in frames]}"
        )
    bar = np.full((frames[0].shape[0], gap, 3), 255, dtype=np.uint8)
    parts: list[np.ndarray] = []
    for k, f in enumerate(frames):
        parts += [bar] if k else []
        parts.append(np.asarray(f, dtype=np.uint8))
    return np.concatenate(parts, axis=1)
