"""Episode frames of a policy and animated GIFs of them (``softpvtol render-gif``, ``softpvtol figures --only gif``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from softpvtol_gym import PassivityPolicy
from softpvtol_gym.baselines.errors import ConfigError
from softpvtol_gym.baselines.training.policy import LearnedPolicy
from softpvtol_gym.baselines.util.atomic import atomic_path
from softpvtol_gym.envs.vector import SoftPVTOLVectorEnv


def make_policy_env(policy_arg: str, task: str | None, tier: str, render_mode: str | None = "rgb_array"):
    """``(policy, env, label)`` for ``--policy`` (``passivity`` or a checkpoint path): a one-env
    :class:`SoftPVTOLVectorEnv` on ``task`` (default: the checkpoint's; ``track_paper`` for passivity) and
    ``tier``, in the policy's action mode; a checkpoint gets the base loop it was trained on."""

    if policy_arg == "passivity":
        env = SoftPVTOLVectorEnv(num_envs=1, action_mode="actuators", task=task or "track_paper", tier=tier,
                                 render_mode=render_mode)
        return PassivityPolicy.from_env(env), env, f"passivity ({env.config.resolved_controller_loop})"

    policy, config = LearnedPolicy.load(Path(policy_arg))
    env = SoftPVTOLVectorEnv(num_envs=1, action_mode=config.action_mode, task=task or config.task, tier=tier,
                             render_mode=render_mode, **config.eval_env_kwargs())
    return policy, env, str(policy_arg)


def render_frames(policy, env, seed: int, seconds: float, fps: int, scale: float) -> tuple[list, int]:
    """Run ``policy`` (deterministic) on ``env`` (one env, ``render_mode="rgb_array"``) from ``seed`` for at
    most ``seconds`` (the episode may end first); ``(frames, steps)``: every ``100 / fps``-th rendered frame
    as a PIL image scaled by ``scale``, and the number of steps run. Closes ``env``."""
    from PIL import Image

    if 100 % fps:
        raise ConfigError(f"fps must divide 100 (the env's rate), got {fps}")
    size = (round(600 * scale), round(450 * scale))
    every = 100 // fps
    obs, _ = env.reset(seed=seed)
    frames, steps = [], 0
    for k in range(round(seconds * 100)):
        if k % every == 0:
            frames.append(Image.fromarray(np.asarray(env.render())).resize(size, Image.BILINEAR))
        action, _ = policy.predict(obs, deterministic=True)
        obs, _, terminated, truncated, _ = env.step(action)
        steps = k + 1
        if terminated[0] or truncated[0]:
            break
    env.close()
    return frames, steps


def save_gif(frames: list, out: Path, fps: int) -> int:
    """Write ``frames`` (PIL images) as a looping GIF at ``fps`` to ``out`` atomically; its size in bytes."""
    from PIL import Image


    if not frames:
        raise ConfigError(f"no frames to write to {out}")
    palette = [f.convert("P", palette=Image.ADAPTIVE, colors=64) for f in frames]
    with atomic_path(Path(out)) as tmp:
        palette[0].save(tmp, format="GIF", save_all=True, append_images=palette[1:], duration=1000 // fps, loop=0,
                        optimize=True)
    return Path(out).stat().st_size
