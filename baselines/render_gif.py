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


def _main(argv) -> int:
    args = build_parser().parse_args(argv)
    if 100 % args.fps:
        raise ConfigError(f"--fps must divide 100 (the env's rate), got {args.fps}")
    if args.out.suffix.lower() != ".gif":
        raise ConfigError(f"--out must name a .gif file, got {args.out}")
    import numpy as np
    from PIL import Image

    from softpvtol_gym import PassivityPolicy
    from softpvtol_gym.envs.vector import SoftPVTOLVectorEnv

    if args.policy == "passivity":
        task, mode = args.task or "track_paper", "actuators"
        env = SoftPVTOLVectorEnv(num_envs=1, action_mode=mode, task=task, tier=args.tier, render_mode="rgb_array")
        policy, label = PassivityPolicy.from_env(env), f"passivity ({env.config.resolved_controller_loop})"
    else:
        from baselines.training import LearnedPolicy

        policy, config = LearnedPolicy.load(Path(args.policy))
        task, mode = args.task or config.task, config.action_mode
        env = SoftPVTOLVectorEnv(num_envs=1, action_mode=mode, task=task, tier=args.tier, render_mode="rgb_array")
        label = str(args.policy)
    size = (round(600 * args.scale), round(450 * args.scale))
    every = 100 // args.fps
    obs, _ = env.reset(seed=args.seed)
    frames = []
    for k in range(round(args.seconds * 100)):
        if k % every == 0:
            frames.append(Image.fromarray(np.asarray(env.render())).resize(size, Image.BILINEAR))
        action, _ = policy.predict(obs, deterministic=True)
        obs, _, terminated, truncated, _ = env.step(action)
        if terminated[0] or truncated[0]:
            break
    env.close()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    palette = [f.convert("P", palette=Image.ADAPTIVE, colors=64) for f in frames]
    palette[0].save(args.out, save_all=True, append_images=palette[1:], duration=1000 // args.fps, loop=0,
                    optimize=True)
    print(f"{label}: {task} / {args.tier}, {len(frames)} frames ({k + 1} steps) -> {args.out} "
          f"({args.out.stat().st_size / 1e6:.2f} MB)")
    return 0


def main(argv=None) -> int:
    from baselines._extras import require

    require("render_gif.py")
    return run_main(_main, argv, prog="render_gif.py")


if __name__ == "__main__":
    sys.exit(main())
