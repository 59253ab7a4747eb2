"""The pictures: tracking plots, learning curves against wall-clock time, a GIF of the best policy.

    softpvtol figures                      # all three, the learned policy from the leaderboard
    softpvtol figures --checkpoint results/leaderboard_runs/<cell>/seed_<k>
    softpvtol figures --only curves        # one of them (repeat --only for more)

Outputs go under ``./results/`` (``results/tracking/``); in a source checkout ``python
baselines/tracking_figures.py`` writes the committed pictures (``results/tracking/``, the GIF in
``docs/``). With ``--checkpoint`` the default tracking plot and GIF are ``checkpoint_track_paper.png`` and
``checkpoint_best_policy_track_paper.gif`` in the tracking folder: a policy given by hand never overwrites
the leaderboard policy's pictures (pass ``--tracking-out`` / ``--gif-out`` to choose).

``tracking`` (``tracking/track_paper.png``): one column per tier of the leaderboard spec,
rows x(t), z(t) and the position error |e|(t), for one evaluation episode (``--seed``, default 1000000,
the leaderboard's first evaluation episode) of ``passivity-bounded`` (``PassivityPolicy.from_env`` in the
actuators mode, with the spec's allocation and loop, as the leaderboard's jobs run it) and of the learned
policy, on the same seeded env. An episode that ends early (a crash) is marked with an X and its reason.

``gif`` (``best_policy_track_paper.gif``): the learned policy on ``track_paper`` nominal from the same
seed, rendered with :mod:`softpvtol_gym.baselines.figures.gif`'s functions.

The learned policy: ``--checkpoint PATH`` (a run or checkpoint folder, any training task), else the
learned entry of the leaderboard JSON with the lowest IQM RMS position error on ``track_paper`` nominal
(whatever task it was trained on), and of its seeds the one whose own mean RMS position error there is
the median of the entry's seeds (the lower middle one for an even count): a typical seed, not the best.

``curves`` (``tracking/learning_curves.png``): for every learned cell under ``--runs``
(``ppo_*/seed_*/evaluations.json``, recipe cells ``ppo-<recipe>_*/seed_*``), the periodic held-out
evaluation's mean RMS position error against
the run's training wall-clock time, per seed thin lines and their median thick, one panel per training
task. Runs saved before ``train_seconds`` was recorded are drawn against environment steps (the panel says
so). Reference: ``--curve-reference heldout`` (default) evaluates passivity-bounded on the same held-out
episodes (each seed's ``eval_episodes`` episodes from seed 1000000 + seed, on the training tier) and draws
the median over seeds; ``leaderboard`` draws the leaderboard's passivity-bounded IQM of the task's
training tiers instead (labelled as such).

Outputs are overwritten; their folders are checked before any work. Exit codes: 0 done, 2 bad input.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from softpvtol_gym.baselines.errors import ConfigError
from softpvtol_gym.baselines.evaluation import EVAL_SEED_OFFSET
from softpvtol_gym.baselines.figures.gif import render_frames, save_gif
from softpvtol_gym.baselines.figures.tracking import (
    CURVES_PNG_NAME,
    FIGURES,
    GIF_NAME,
    REFERENCE,
    TASK,
    TRACKING_PNG_NAME,
    _summary_text,
    curves_figure,
    load_learned,
    read_curves,
    read_leaderboard,
    reference_env_kwargs,
    select_learned,
    tracking_figure,
)
from softpvtol_gym.baselines.leaderboard.jobs import SPEC_FILE, load_spec
from softpvtol_gym.baselines.util.args import (
    Parser,
    check_output_file,
    command_main,
    float_arg,
    int_arg,
    refuse_overwrite,
)
from softpvtol_gym.baselines.util.paths import Layout
from softpvtol_gym.envs.tiers import registered_tiers
from softpvtol_gym.envs.vector import SoftPVTOLVectorEnv

#: the file-name prefix of the pictures of a policy given by --checkpoint
CHECKPOINT_PREFIX = "checkpoint_"
#: the options that change what the pictures show (another value never overwrites the default pictures)
CONTENT_OPTIONS = ("leaderboard", "spec", "runs", "tiers", "seed", "seconds", "curve_reference", "gif_seconds",
                   "gif_fps", "gif_scale")


def _check_output(path: Path, option: str, suffix: str) -> None:
    if path.is_dir():
        raise ConfigError(f"{option} {path} is a directory; expected a file name")
    if path.suffix.lower() != suffix:
        raise ConfigError(f"{option} must name a {suffix} file, got {path}")
    check_output_file(path, force=True, option=option)  # before anything renders: a writable directory


def build_parser(layout: Layout | None = None, prog: str = "tracking_figures.py") -> Parser:
    """The options; the default outputs under ``layout`` (with ``--checkpoint``: other names, never the
    leaderboard policy's pictures)."""
    layout = layout or Layout()
    ap = Parser(prog=prog, description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--only", action="append", choices=FIGURES, default=None,
                    help="write only this picture (repeatable; default: all three)")
    ap.add_argument("--checkpoint", type=Path, default=None,
                    help="the learned policy (run or checkpoint folder); default: chosen from --leaderboard")
    ap.add_argument("--leaderboard", type=Path, default=layout.results / "leaderboard.json",
                    help="default: %(default)s")
    ap.add_argument("--spec", type=Path, default=SPEC_FILE, help="the leaderboard spec (tiers, passivity-bounded)")
    ap.add_argument("--runs", type=Path, default=layout.runs,
                    help="learned runs for the learning curves (default: %(default)s)")
    ap.add_argument("--tiers", nargs="+", choices=registered_tiers(), default=None,
                    help="default: the spec's evaluation tiers")
    ap.add_argument("--seed", type=int_arg(0, 2**62), default=EVAL_SEED_OFFSET, help="the evaluation episode's seed")
    ap.add_argument("--seconds", type=float_arg(0.01, 600.0), default=None,
                    help="cut the tracking episodes after this long [s] (default: the whole episode)")
    ap.add_argument("--curve-reference", choices=("heldout", "leaderboard"), default="heldout")
    ap.add_argument("--gif-seconds", type=float_arg(0.1, 600.0), default=None,
                    help="cut the GIF's episode after this long [s] (default: the whole episode)")
    ap.add_argument("--gif-fps", type=int_arg(1, 100), default=10, help="divides 100")
    ap.add_argument("--gif-scale", type=float_arg(0.1, 1.0), default=0.6, help="frame size x 600 x 450")
    tracking = layout.results / "tracking"
    gif = layout.doc(GIF_NAME) or tracking / GIF_NAME
    ap.add_argument("--tracking-out", type=Path, default=None,
                    help=f"default: {tracking / TRACKING_PNG_NAME}; with --checkpoint {tracking / CHECKPOINT_PREFIX}"
                         f"{TRACKING_PNG_NAME}")
    ap.add_argument("--curves-out", type=Path, default=tracking / CURVES_PNG_NAME, help="default: %(default)s")
    ap.add_argument("--gif-out", type=Path, default=None,
                    help=f"default: {gif}; with --checkpoint {tracking / CHECKPOINT_PREFIX}{GIF_NAME}")
    ap.add_argument("--force", action="store_true",
                    help="let a run with other settings than the defaults overwrite the default pictures")
    ap.set_defaults(_tracking=tracking, _gif=gif)
    return ap


def _default_outputs(args) -> None:
    """The tracking plot's and the GIF's default paths: the leaderboard policy's pictures, or with
    ``--checkpoint`` other names (a policy given by hand never overwrites the leaderboard's pictures)."""
    prefix = "" if args.checkpoint is None else CHECKPOINT_PREFIX
    if args.tracking_out is None:
        args.tracking_out = args._tracking / (prefix + TRACKING_PNG_NAME)
    if args.gif_out is None:
        args.gif_out = args._gif if args.checkpoint is None else args._tracking / (prefix + GIF_NAME)


def _main(argv, layout: Layout, prog: str) -> int:
    args = build_parser(layout, prog).parse_args(argv)
    _default_outputs(args)
    only = tuple(dict.fromkeys(args.only or FIGURES))
    written = {"tracking": (args.tracking_out, args._tracking / TRACKING_PNG_NAME, "--tracking-out"),
               "curves": (args.curves_out, args._tracking / CURVES_PNG_NAME, "--curves-out"),
               "gif": (args.gif_out, args._gif, "--gif-out")}
    refuse_overwrite(build_parser(layout, prog), args, CONTENT_OPTIONS, [written[name] for name in only])
    outputs = {"tracking": (args.tracking_out, "--tracking-out", ".png"),
               "curves": (args.curves_out, "--curves-out", ".png"), "gif": (args.gif_out, "--gif-out", ".gif")}
    for name in only:
        _check_output(*outputs[name])
    if "gif" in only and 100 % args.gif_fps:
        raise ConfigError(f"--gif-fps must divide 100 (the env's rate), got {args.gif_fps}")
    if args.checkpoint is not None and not args.checkpoint.exists():
        raise ConfigError(f"--checkpoint {args.checkpoint} does not exist")
    if "curves" in only and not args.runs.is_dir():
        raise ConfigError(f"--runs {args.runs} is not a directory")

    spec = load_spec(args.spec)
    tiers = args.tiers or spec["evaluation"]["tiers"]
    passivity_kwargs = reference_env_kwargs(args.spec)
    need_leaderboard = (args.checkpoint is None and {"tracking", "gif"} & set(only)) or (
        "curves" in only and args.curve_reference == "leaderboard")
    leaderboard = read_leaderboard(args.leaderboard) if need_leaderboard else None
    learned = None
    if {"tracking", "gif"} & set(only):
        if args.checkpoint is not None:
            learned = load_learned(args.checkpoint)
        else:
            chosen = select_learned(leaderboard, f"leaderboard JSON {args.leaderboard}", layout.root)
            learned = load_learned(chosen.checkpoint, chosen.caption())
    curves = read_curves(args.runs) if "curves" in only else None
    if learned is not None:
        print(f"learned policy: {learned[3]}")
    if "tracking" in only:
        result = tracking_figure(tiers, args.seed, args.seconds, learned, passivity_kwargs, args.tracking_out)
        for tier, r in result.items():
            for name, v in r.items():
                print(f"  {TASK} {tier}, {name}: {_summary_text(v)}")
        print(f"wrote {args.tracking_out}")
    if "curves" in only:
        levels = curves_figure(curves, args.curve_reference, passivity_kwargs, leaderboard, args.curves_out)
        print(f"wrote {args.curves_out} ({len(curves)} runs; {REFERENCE} levels: "
              + ", ".join(f"{k} {v:.3f} m" for k, v in levels.items()) + ")")
    if "gif" in only:
        policy, config, label, _ = learned
        env = SoftPVTOLVectorEnv(num_envs=1, action_mode=config.action_mode, task=TASK, tier="nominal",
                                 render_mode="rgb_array", **config.eval_env_kwargs())
        seconds = args.gif_seconds or env.config.episode_seconds
        frames, steps = render_frames(policy, env, args.seed, seconds, args.gif_fps, args.gif_scale)
        size = save_gif(frames, args.gif_out, args.gif_fps)
        print(f"wrote {args.gif_out}: {label} on {TASK} nominal, seed {args.seed}, {len(frames)} frames "
              f"({steps} steps), {size / 1e6:.2f} MB")
    return 0


main = command_main("tracking_figures.py", _main,
                    "``softpvtol figures``: the pictures under ``layout`` (default: the current directory's "
                    "``results/``).")
