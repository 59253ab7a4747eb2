"""Rendering: rgb_array frames, the pygame "human" window (headless), RecordVideo, bad render modes."""

import os

# headless pygame for every test in this module (read when the display is initialised)
os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
os.environ.setdefault("SDL_AUDIODRIVER", "dummy")
os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")

import subprocess
import time
import warnings

import gymnasium as gym
import numpy as np
import pytest

import softpvtol_gym  # noqa: F401
from softpvtol_gym import SoftPVTOLEnv
from softpvtol_gym.envs.rendering import HEIGHT, WIDTH

pygame = pytest.importorskip("pygame")


@pytest.fixture(autouse=True)
def _headless(monkeypatch):
    monkeypatch.setenv("SDL_VIDEODRIVER", "dummy")
    monkeypatch.setenv("SDL_AUDIODRIVER", "dummy")
    monkeypatch.setenv("PYGAME_HIDE_SUPPORT_PROMPT", "1")
    yield
    pygame.display.quit()


# ------------------------------------------------------------------------------------ rgb_array
def test_rgb_frame_changes_when_arms_bend():
    env = SoftPVTOLEnv(render_mode="rgb_array")
    env.reset(seed=0, options={"q0": [0, 2, 0, 0, 0], "qdot0": [0] * 5})
    f0 = env.render()
    env.reset(seed=0, options={"q0": [0, 2, 0, 1.5, -1.5], "qdot0": [0] * 5})
    f1 = env.render()
    assert f0.shape == (HEIGHT, WIDTH, 3) == (450, 600, 3) and f0.dtype == np.uint8
    assert f1.shape == f0.shape and f1.dtype == np.uint8
    assert (f0 != f1).any(axis=2).sum() > 50
    env.close()


def test_rgb_frame_is_a_fresh_array_and_needs_no_display():
    env = gym.make("SoftPVTOL-v0", render_mode="rgb_array")
    env.reset(seed=0)
    f0 = env.render()
    f0[:] = 0
    f1 = env.render()
    assert f1.any()  # a copy, not a view of the renderer's surface
    assert not pygame.display.get_init()  # off-screen drawing opens no window
    env.close()
    env.close()


def test_gymnasium_check_env_render_check_passes():
    from gymnasium.utils.env_checker import check_env

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_env(gym.make("SoftPVTOL-v0", render_mode="rgb_array").unwrapped)  # .spec: checks "human" too


def test_rgb_array_list_through_gym_make():
    env = gym.make("SoftPVTOL-v0", render_mode="rgb_array_list")
    env.reset(seed=0)
    for _ in range(3):
        env.step(np.zeros(env.action_space.shape, np.float32))
    frames = env.render()
    assert len(frames) == 4 and all(f.shape == (HEIGHT, WIDTH, 3) for f in frames)
    env.close()


# ------------------------------------------------------------------------------------ RecordVideo
def test_record_video_writes_an_mp4(tmp_path):
    imageio_ffmpeg = pytest.importorskip("imageio_ffmpeg")  # comes with moviepy (the `test` extra)
    pytest.importorskip("moviepy")
    n_steps = 30
    folder = tmp_path / "videos"  # RecordVideo warns when its folder already exists
    env = gym.wrappers.RecordVideo(gym.make("SoftPVTOL-v0", render_mode="rgb_array"), str(folder),
                                   episode_trigger=lambda e: True)
    env.reset(seed=0)
    env.action_space.seed(0)
    for _ in range(n_steps):
        env.step(env.action_space.sample())
    env.close()  # writes the episode's video
    videos = list(folder.glob("*.mp4"))
    assert [v.name for v in videos] == ["rl-video-episode-0.mp4"]
    assert videos[0].stat().st_size > 0
    # decode with the ffmpeg binary that imageio-ffmpeg ships (its read_frames leaks pipes)
    out = subprocess.run([imageio_ffmpeg.get_ffmpeg_exe(), "-v", "error", "-i", str(videos[0]),
                          "-f", "rawvideo", "-pix_fmt", "rgb24", "-"], capture_output=True, check=True).stdout
    assert len(out) % (HEIGHT * WIDTH * 3) == 0
    frames = np.frombuffer(out, np.uint8).reshape(-1, HEIGHT, WIDTH, 3)
    assert len(frames) == n_steps + 1  # the reset frame and one per step
    # the first frame is the reset frame, up to the codec's loss
    ref = gym.make("SoftPVTOL-v0", render_mode="rgb_array")
    ref.reset(seed=0)
    assert np.abs(frames[0].astype(float) - ref.render()).mean() < 0.6  # ~0.2 here; another seed: ~1.3
    ref.close()
    n, secs = imageio_ffmpeg.count_frames_and_secs(str(videos[0]))
    assert n == n_steps + 1
    assert secs == pytest.approx((n_steps + 1) / env.metadata["render_fps"], abs=0.02)


# ------------------------------------------------------------------------------------ human
def test_human_mode_opens_a_window_and_closes_idempotently():
    env = gym.make("SoftPVTOL-v0", render_mode="human")
    obs, info = env.reset(seed=0)
    assert obs.shape == env.observation_space.shape
    surf = pygame.display.get_surface()
    assert surf is not None and surf.get_size() == (WIDTH, HEIGHT)
    assert pygame.display.get_caption()[0] == "SoftPVTOL-v0"
    assert env.render() is None
    out = env.step(np.zeros(env.action_space.shape, np.float32))
    assert len(out) == 5 and np.isfinite(out[0]).all()
    assert env.render() is None
    # the window shows the last frame: not blank
    pix = pygame.surfarray.array3d(pygame.display.get_surface())
    assert (pix != 255).any()
    env.close()
    assert not pygame.display.get_init() and pygame.display.get_surface() is None
    env.close()  # idempotent
    assert env.unwrapped._renderer is None
    # a reset after close opens the window again
    env.reset(seed=1)
    assert pygame.display.get_surface().get_size() == (WIDTH, HEIGHT)
    env.close()


def test_human_mode_ticks_at_render_fps():
    env = SoftPVTOLEnv(render_mode="human")
    fps = env.metadata["render_fps"]
    assert fps == round(1.0 / env.dt) == 100
    env.reset(seed=0)
    assert env._renderer.fps == fps and env._renderer.clock is not None
    n = 20
    t0 = time.perf_counter()
    for _ in range(n):
        env.step(np.zeros(env.action_space.shape, np.float32))
    elapsed = time.perf_counter() - t0
    assert elapsed >= 0.75 * n / fps  # the clock holds the window to at most render_fps
    env.close()


def test_closing_an_rgb_env_keeps_a_human_window_open():
    human = SoftPVTOLEnv(render_mode="human")
    human.reset(seed=0)
    rgb = SoftPVTOLEnv(render_mode="rgb_array")
    rgb.reset(seed=0)
    rgb.render()
    rgb.close()
    assert pygame.display.get_surface() is not None
    human.step(np.zeros(human.action_space.shape, np.float32))
    human.close()
    assert pygame.display.get_surface() is None


def test_render_without_mode_warns_and_returns_none():
    env = SoftPVTOLEnv()
    env.reset(seed=0)
    with pytest.warns(UserWarning, match="without specifying any render mode"):
        assert env.render() is None
    env.close()


# ------------------------------------------------------------------------------------ bad modes
@pytest.mark.parametrize("mode", ["ascii", "RGB_ARRAY", "", 1, "rgb"])
def test_bad_render_mode_lists_valid_ones(mode):
    with pytest.raises(ValueError, match=r"render_mode must be one of \[None, 'rgb_array', 'human'\]"):
        SoftPVTOLEnv(render_mode=mode)


def test_bad_render_mode_through_gym_make():
    with pytest.raises(ValueError, match="render_mode must be one of"), pytest.warns(UserWarning):
        gym.make("SoftPVTOL-v0", render_mode="ascii")


@pytest.mark.parametrize("mode", ["human", "ascii"])
def test_vector_env_bad_render_mode_lists_valid_ones(mode):
    with pytest.raises(ValueError, match=r"render_mode must be one of \[None, 'rgb_array'\]"):
        gym.make_vec("SoftPVTOL-v0", num_envs=2, vectorization_mode="vector_entry_point", render_mode=mode)
