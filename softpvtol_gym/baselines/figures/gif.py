"""Render an episode of a policy to an animated GIF (the README's picture of the best policy).

    python baselines/render_gif.py --policy passivity --task track_paper --out docs/track_paper.gif
    python baselines/render_gif.py --policy baselines/results/leaderboard_runs/<run> --task track_paper --out x.gif

``--policy``: ``passivity`` (PassivityPolicy with the env's default loop) or a checkpoint (run
directory, checkpoint directory or model.safetensors; the safe format only, nothing is unpickled).
The episode runs at the env's 100 Hz from seed ``--seed``; every ``100 / --fps``-th frame of the
renderer (600 x 450) is kept, scaled by ``--scale``. Exit codes: 0 done, 2 bad input.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from baselines.cli import Parser, float_arg, int_arg, run_main
from baselines.errors import ConfigError
from softpvtol_gym.envs.core import TASKS, TIERS


def build_parser() -> argparse.ArgumentParser:
    ap = Parser(prog="render_gif.py", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--policy", required=True, help="'passivity' or a checkpoint path")
    ap.add_argument("--task", choices=TASKS, default=None,
                    help="default: the checkpoint's; 'track_paper' for passivity")
    ap.add_argument("--tier", choices=TIERS, default="nominal")
    ap.add_argument("--seed", type=int_arg(0, 2**62), default=1_000_000)
    ap.add_argument("--seconds", type=float_arg(0.1, 600.0), default=20.0, help="episode length to render [s]")
    ap.add_argument("--fps", type=int_arg(1, 100), default=20, help="GIF frames per second (divides 100)")
    ap.add_argument("--scale", type=float_arg(0.1, 1.0), default=0.5, help="frame size x 600 x 450")
    ap.add_argument("--out", type=Path, required=True, help="the GIF to write")
    return ap


def make_policy_env(policy_arg: str, task: str | None, tier: str, render_mode: str | None = "rgb_array"):
    """``(policy, env, label)`` for ``--policy`` (``passivity`` or a checkpoint path): a one-env
    :class:`SoftPVTOLVectorEnv` on ``task`` (default: the checkpoint's; ``track_paper`` for passivity) and
    ``tier``, in the policy's action mode; a checkpoint gets the base loop it was trained on."""
    from softpvtol_gym import PassivityPolicy
    from softpvtol_gym.envs.vector import SoftPVTOLVectorEnv

    if policy_arg == "passivity":
        env = SoftPVTOLVectorEnv(num_envs=1, action_mode="actuators", task=task or "track_paper", tier=tier,
                                 render_mode=render_mode)
        return PassivityPolicy.from_env(env), env, f"passivity ({env.config.resolved_controller_loop})"
    from baselines.training import LearnedPolicy

    policy, config = LearnedPolicy.load(Path(policy_arg))
    env = SoftPVTOLVectorEnv(num_envs=1, action_mode=config.action_mode, task=task or config.task, tier=tier,
                             render_mode=render_mode, **config.eval_env_kwargs())
    return policy, env, str(policy_arg)


def render_frames(policy, env, seed: int, seconds: float, fps: int, scale: float) -> tuple[list, int]:
    """Run ``policy`` (deterministic) on ``env`` (one env, ``render_mode="rgb_array"``) from ``seed`` for at
    most ``seconds`` (the episode may end first); ``(frames, steps)``: every ``100 / fps``-th rendered frame
    as a PIL image scaled by ``scale``, and the number of steps run. Closes ``env``."""
    import numpy as np
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

    from baselines.atomic import atomic_path

    if not frames:
        raise ConfigError(f"no frames to write to {out}")
    palette = [f.convert("P", palette=Image.ADAPTIVE, colors=64) for f in frames]
    with atomic_path(Path(out)) as tmp:
        palette[0].save(tmp, format="GIF", save_all=True, append_images=palette[1:], duration=1000 // fps, loop=0,
                        optimize=True)
    return Path(out).stat().st_size


def _main(argv) -> int:
    args = build_parser().parse_args(argv)
    if 100 % args.fps:
        raise ConfigError(f"--fps must divide 100 (the env's rate), got {args.fps}")
    if args.out.suffix.lower() != ".gif":
        raise ConfigError(f"--out must name a .gif file, got {args.out}")
    policy, env, label = make_policy_env(args.policy, args.task, args.tier)
    task = env.config.task
    frames, steps = render_frames(policy, env, args.seed, args.seconds, args.fps, args.scale)
    size = save_gif(frames, args.out, args.fps)
    print(f"{label}: {task} / {args.tier}, {len(frames)} frames ({steps} steps) -> {args.out} "
          f"({size / 1e6:.2f} MB)")
    return 0


def main(argv=None) -> int:
    from baselines._extras import require

    require("render_gif.py")
    return run_main(_main, argv, prog="render_gif.py")


if __name__ == "__main__":
    sys.exit(main())
