"""Rendering: ``render_mode="rgb_array"`` frames of the plant and of the surrogate's pose,
``human`` without a display, and the one-line error without an OpenGL backend.

Frame tests skip, with the renderer's one-line reason, where no OpenGL backend works.
"""

from __future__ import annotations

import pickle
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import excavator_surrogate.env as E
from excavator_surrogate.env.render import PoseScene, RenderError, gl_backend, side_by_side
from excavator_surrogate.errors import ConfigError
from excavator_surrogate.spec import EXCAVATOR, JointSpec, Linkage, MachineSpec
from excavator_surrogate.surrogate.checkpoint import save_checkpoint
from tests.helpers.surrogates import tiny_surrogate

POSE_A = np.array([0.3, 0.2, 1.5, 1.0])
POSE_B = np.array([-1.2, -0.4, 2.2, 0.0])


def _make(kind: str, ckpt: Path, **kw) -> gym.Env:
    if kind == "mujoco":
        return gym.make(E.MUJOCO_ID, **kw)
    return gym.make(E.SURROGATE_ID, ckpt=str(ckpt), **kw)


@pytest.fixture(scope="module")
def gl() -> None:
    """Skip (with the one-line reason) where no OpenGL backend works."""
    env = gym.make(E.MUJOCO_ID, render_mode="rgb_array", render_size=(16, 12))
    env.reset(seed=0)
    try:
        env.render()
    except RenderError as e:
        pytest.skip(str(e))
    finally:
        env.close()


def _mean_diff(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.abs(a.astype(np.float64) - b.astype(np.float64)).mean())


@pytest.mark.parametrize("kind", ["mujoco", "surrogate"])
def test_metadata_lists_the_render_modes(kind: str, stateful_ckpt: Path) -> None:
    env = _make(kind, stateful_ckpt)
    assert env.metadata["render_modes"] == ["rgb_array", "human"]
    assert env.metadata["render_fps"] == 20.0
    cls = E.ExcavatorMujocoEnv if kind == "mujoco" else E.ExcavatorSurrogateEnv
    args = () if kind == "mujoco" else (str(stateful_ckpt),)
    with pytest.raises(ConfigError, match="render_mode must be one of rgb_array, human"):
        cls(*args, render_mode="rgb")


def test_plant_and_surrogate_frames_side_by_side(gl: None, stateful_ckpt: Path) -> None:
    plant = _make("mujoco", stateful_ckpt, render_mode="rgb_array", render_size=(160, 120))
    sur = _make("surrogate", stateful_ckpt, render_mode="rgb_array", render_size=(160, 120))
    frames = {}
    for name, pose in (("a", POSE_A), ("b", POSE_B)):
        plant.reset(options={"theta0": pose})
        sur.reset(options={"theta0": pose})
        frames[name] = (plant.render(), sur.render())
    for f in (*frames["a"], *frames["b"]):
        assert f.shape == (120, 160, 3) and f.dtype == np.uint8
        assert f.std() > 10.0  # not a constant picture
    # at the same pose both draw the same machine; another pose is another picture
    assert _mean_diff(*frames["a"]) < 1.0 and _mean_diff(*frames["b"]) < 1.0
    assert _mean_diff(frames["a"][0], frames["b"][0]) > 5.0
    assert _mean_diff(frames["a"][1], frames["b"][1]) > 5.0
    # the surrogate's frame follows its state while it moves
    before = sur.render()
    for _ in range(10):
        sur.step(np.array([0.0, 0.0, 0.0, 0.0], np.float32))
    sur.unwrapped.theta = sur.unwrapped.theta + np.array([0.8, 0.0, 0.0, 0.0])
    assert _mean_diff(before, sur.render()) > 1.0
    both = side_by_side(*frames["a"])
    assert both.shape == (120, 2 * 160 + 4, 3) and both.dtype == np.uint8
    pickle.loads(pickle.dumps(sur.unwrapped)).render()  # the renderer is rebuilt
    plant.close()
    sur.close()


def test_record_video(gl: None, stateful_ckpt: Path, tmp_path: Path) -> None:
    pytest.importorskip("moviepy", reason="RecordVideo needs moviepy (pip install moviepy)")
    env = _make("mujoco", stateful_ckpt, render_mode="rgb_array", render_size=(96, 64))
    env = gym.wrappers.RecordVideo(env, str(tmp_path / "v"), episode_trigger=lambda i: True)
    env.reset(seed=0)
    for _ in range(5):
        env.step(np.array([800.0, 500.0, -500.0, 500.0], np.float32))
    env.close()
    videos = list((tmp_path / "v").glob("*.mp4"))
    assert len(videos) == 1 and videos[0].stat().st_size > 0


@pytest.mark.parametrize("kind", ["mujoco", "surrogate"])
def test_human_without_a_display_is_one_line(
    kind: str, stateful_ckpt: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    env = _make(kind, stateful_ckpt, render_mode="human")
    with pytest.raises(RenderError, match="needs a display") as err:
        env.reset(seed=0)
    assert "rgb_array" in str(err.value) and "\n" not in str(err.value)


def test_no_gl_backend_says_what_to_install(
    stateful_ckpt: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import mujoco

    def broken(*args, **kwargs):
        raise AttributeError("'NoneType' object has no attribute 'glGetError'")

    monkeypatch.setattr(mujoco, "Renderer", broken)
    env = _make("surrogate", stateful_ckpt, render_mode="rgb_array")
    env.reset(seed=0)
    with pytest.raises(RenderError, match="apt-get install -y libegl1") as err:
        env.render()
    assert "MUJOCO_GL=" in str(err.value) and "\n" not in str(err.value)


def test_headless_linux_defaults_to_egl(monkeypatch: pytest.MonkeyPatch) -> None:
    import sys

    for name in ("mujoco.rendering.classic.gl_context", "mujoco.gl_context"):
        if name in sys.modules:  # restored after the test (gl_backend switches it to EGL)
            monkeypatch.setattr(sys.modules[name], "GLContext", sys.modules[name].GLContext)
    monkeypatch.setattr("sys.platform", "linux")
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    monkeypatch.setenv("MUJOCO_GL", "")
    assert gl_backend() == "egl"
    import os

    assert os.environ["MUJOCO_GL"] == "egl"
    monkeypatch.setenv("MUJOCO_GL", "osmesa")  # the user's choice is kept
    assert gl_backend() == "osmesa"


LINKAGES = {  # examples/stroke_make_logs.py's made-up cylinders [m, rad]
    "boom": Linkage(a=1.25, b=3.4, phi=1.15, l0=2.05),
    "arm": Linkage(a=0.9, b=3.2, phi=-0.25, l0=2.25),
    "bucket": Linkage(a=0.75, b=2.6, phi=0.62, l0=1.75),
}


def _stroke_spec(*, linkage: bool = True) -> MachineSpec:
    """The excavator with boom, arm and bucket sensed as strokes in mm."""
    joints = [EXCAVATOR.joints[0]]
    for j in EXCAVATOR.joints[1:]:
        lk = LINKAGES[j.name]
        lo, hi = sorted(float(s) for s in lk.stroke(np.array([j.theta_min, j.theta_max])))
        joints.append(
            JointSpec(
                j.name,
                kind="linear",
                unit="mm",
                theta_min=lo,
                theta_max=hi,
                linkage=lk if linkage else None,
            )
        )
    return MachineSpec(tuple(joints), rate_hz=EXCAVATOR.rate_hz)


def _strokes(pose: np.ndarray) -> np.ndarray:
    """A pose [rad] of the excavator as the stroke machine's values (swing [rad], strokes [m])."""
    out = np.array(pose, dtype=np.float64)
    for k, name in enumerate(("boom", "arm", "bucket"), start=1):
        out[k] = LINKAGES[name].stroke(pose[k])
    return out


def test_a_stroke_is_posed_at_its_linkages_angle() -> None:
    """Strokes [m] were written into qpos as angles [rad]: the boom's 1.9 m as 1.9 rad."""
    scene = PoseScene(_stroke_spec(), where="t")
    data = scene.pose(_strokes(POSE_A))
    np.testing.assert_allclose(data.qpos[scene._qadr], POSE_A, atol=1e-12)
    revolute = PoseScene(EXCAVATOR, where="t")  # an angle goes in as it is
    np.testing.assert_array_equal(revolute.pose(POSE_B).qpos[revolute._qadr], POSE_B)


def test_a_stroke_without_a_linkage_is_refused_when_made(tmp_path: Path) -> None:
    ckpt = save_checkpoint(tmp_path / "s.pt", tiny_surrogate(_stroke_spec(linkage=False)))
    with pytest.raises(ConfigError) as err:
        gym.make(E.SURROGATE_ID, ckpt=str(ckpt), render_mode="rgb_array")
    assert "cannot render joint 'boom': a stroke without a linkage" in str(err.value)
    assert "\n" not in str(err.value)
    env = gym.make(E.SURROGATE_ID, ckpt=str(ckpt))  # without rendering it runs
    env.reset(seed=0)
    env.close()


def test_a_stroke_machine_draws_the_revolute_picture(gl: None, stateful_ckpt: Path) -> None:
    rev = _make("surrogate", stateful_ckpt, render_mode="rgb_array", render_size=(160, 120))
    sur = E.ExcavatorSurrogateEnv(
        tiny_surrogate(_stroke_spec()), render_mode="rgb_array", render_size=(160, 120)
    )
    rev.reset(options={"theta0": POSE_A})
    sur.reset(options={"theta0": _strokes(POSE_A)})
    assert _mean_diff(rev.render(), sur.render()) < 1.0
    rev.close()
    sur.close()
