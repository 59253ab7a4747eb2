"""Render an episode of a policy to an animated GIF (the README's picture of the best policy).

    softpvtol render-gif --policy passivity --task track_paper --out docs/track_paper.gif
    softpvtol render-gif --policy results/leaderboard_runs/<run> --task track_paper --out x.gif

(From a source checkout, ``python baselines/render_gif.py`` takes the same options.)

``--policy``: ``passivity`` (PassivityPolicy with the env's default loop) or a checkpoint (run
directory, checkpoint directory or model.safetensors; the safe format only, nothing is unpickled).
The episode runs at the env's 100 Hz from seed ``--seed``; every ``100 / --fps``-th frame of the
renderer (600 x 450) is kept, scaled by ``--scale``. ``--out`` is checked writable before anything renders.
Exit codes: 0 done, 2 bad input, 74 an unwritable output, 130 / 143 interrupted (nothing written).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from softpvtol_gym.baselines.errors import ConfigError
from softpvtol_gym.baselines.figures.gif import make_policy_env, render_frames, save_gif
from softpvtol_gym.baselines.util.args import Parser, check_output_file, command_main, float_arg, int_arg
from softpvtol_gym.baselines.util.paths import Layout
from softpvtol_gym.envs.tiers import registered_tiers
from softpvtol_gym.tasks import registered_tasks


def build_parser(prog: str = "render_gif.py") -> argparse.ArgumentParser:
    ap = Parser(prog=prog, description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--policy", required=True, help="'passivity' or a checkpoint path")
    ap.add_argument("--task", choices=registered_tasks(), default=None,
                    help="default: the checkpoint's; 'track_paper' for passivity")
    ap.add_argument("--tier", choices=registered_tiers(), default="nominal")
    ap.add_argument("--seed", type=int_arg(0, 2**62), default=1_000_000)
    ap.add_argument("--seconds", type=float_arg(0.1, 600.0), default=20.0, help="episode length to render [s]")
    ap.add_argument("--fps", type=int_arg(1, 100), default=20, help="GIF frames per second (divides 100)")
    ap.add_argument("--scale", type=float_arg(0.1, 1.0), default=0.5, help="frame size x 600 x 450")
    ap.add_argument("--out", type=Path, required=True, help="the GIF to write")
    return ap



def _main(argv, layout: Layout, prog: str) -> int:
    args = build_parser(prog).parse_args(argv)
    if 100 % args.fps:
        raise ConfigError(f"--fps must divide 100 (the env's rate), got {args.fps}")
    if args.out.suffix.lower() != ".gif":
        raise ConfigError(f"--out must name a .gif file, got {args.out}")
    check_output_file(args.out, force=True, option="--out")  # before rendering anything
    policy, env, label = make_policy_env(args.policy, args.task, args.tier)
    task = env.config.task
    frames, steps = render_frames(policy, env, args.seed, args.seconds, args.fps, args.scale)
    size = save_gif(frames, args.out, args.fps)
    print(f"{label}: {task} / {args.tier}, {len(frames)} frames ({steps} steps) -> {args.out} "
          f"({size / 1e6:.2f} MB)")
    return 0


main = command_main("render_gif.py", _main,
                    "``softpvtol render-gif``: one episode of a policy as an animated GIF (--out).")

