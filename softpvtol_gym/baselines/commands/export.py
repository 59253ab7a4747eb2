"""Interoperability with stable-baselines3's own (pickle-based) files, both ways.

    python baselines/export.py to-sb3 --policy RUN_OR_CHECKPOINT --out model.zip [--vecnormalize vecnormalize.pkl]
    python baselines/export.py from-sb3 --trust-pickle PATH [--out DIR]

``to-sb3`` writes an SB3 ``model.zip`` (``PPO.load`` / ``SAC.load`` read it) and, for a run with
normalisation, the ``VecNormalize.save`` pickle, for users of SB3's tools. It reads the checkpoint in
the safe format (nothing is unpickled).

``from-sb3`` converts an SB3 ``model.zip`` (with the ``vecnormalize.pkl`` and the ``config.yaml`` of
its run next to it or one folder up) into the safe format: ``model.safetensors``, ``model.json``,
``vecnormalize.json``, ``config.yaml`` and the manifest ``checkpoint.json`` (into ``--out``, default the
zip's folder). Reading the zip and the pickle *unpickles* them, which runs any code they contain:
``--trust-pickle`` is required, and should only be given for files you created or whose source you
trust. Pickle-based training checkpoints (``resume_state.pkl``) are not converted: a run continues from
its converted final model only by training a new run.

Exit codes: 0 done, 2 bad input (one line; nothing written).
"""

from __future__ import annotations

import argparse
import io
import sys
from pathlib import Path

from baselines.cli import Parser, run_main
from baselines.errors import CheckpointError, ConfigError

PICKLE_WARNING = ("unpickling {files}: this runs any code they contain; only do this for files you created or whose "
                  "source you trust (--trust-pickle)")


def _legacy_paths(path: Path) -> tuple[Path, Path | None, Path]:
    """(model.zip, vecnormalize.pkl or None, config.yaml) of a pickle-based run folder or zip."""
    from baselines.checkpoints import CONFIG_FILE

    path = Path(path)
    if path.is_dir():
        zip_path = path / "model.zip"
    elif path.is_file() and path.suffix == ".zip":
        zip_path = path
    elif path.is_file() and path.name == "vecnormalize.pkl":
        zip_path = path.parent / "model.zip"
    else:
        raise CheckpointError(f"{path} is neither an SB3 model.zip nor a folder holding one")
    if not zip_path.is_file():
        raise CheckpointError(f"no SB3 model.zip at {zip_path}")
    folder = zip_path.parent
    pkl = folder / "vecnormalize.pkl"
    for cfg in (folder / CONFIG_FILE, folder.parent / CONFIG_FILE):
        if cfg.is_file():
            return zip_path, (pkl if pkl.is_file() else None), cfg
    raise CheckpointError(f"no config.yaml next to {zip_path} or one folder up: the run's settings are needed")


def _read_pickled(path: Path):
    """(model, VecNormalize or None, RunConfig) of pickle-based files, as saved, with a warning."""
    from baselines.checkpoints import warn
    from baselines.config import RunConfig, normalize_kwargs
    from baselines.models import algo_class, make_env

    zip_path, pkl, cfg = _legacy_paths(path)
    config = RunConfig.load(cfg)
    if normalize_kwargs(config.hyperparams) is not None and pkl is None:
        raise CheckpointError(f"{cfg} asks for normalisation but there is no vecnormalize.pkl next to {zip_path}")
    if pkl is not None and normalize_kwargs(config.hyperparams) is None:
        raise CheckpointError(f"{pkl} is present but {cfg} has no normalisation")
    warn(PICKLE_WARNING.format(files=", ".join(str(p) for p in (zip_path, pkl) if p is not None)))
    model = algo_class(config.algo).load(zip_path, device="cpu")
    vecnorm = None
    if pkl is not None:
        from stable_baselines3.common.vec_env import VecNormalize

        vecnorm = VecNormalize.load(str(pkl), make_env(config, 1))
    return model, vecnorm, config, zip_path, cfg


def load_pickled(path: Path):
    """``(LearnedPolicy, RunConfig)`` from pickle-based files (an SB3 zip and VecNormalize pickle), with a
    warning. Only reached with an explicit trust_pickle / --trust-pickle."""
    from baselines.config import frame_stack
    from baselines.training import LearnedPolicy

    model, vecnorm, config, _, _ = _read_pickled(path)
    if vecnorm is not None:
        vecnorm.training = False
        vecnorm.norm_reward = False
    return LearnedPolicy(model, vecnorm, frame_stack=frame_stack(config.hyperparams)), config


def from_sb3(path: Path, out: Path | None = None) -> Path:
    """Convert pickle-based files to the safe format (see the module docstring); returns the folder."""
    from baselines.checkpoints import CONFIG_FILE, write_model_files

    model, vecnorm, config, zip_path, cfg = _read_pickled(path)
    out = zip_path.parent if out is None else Path(out)
    out.mkdir(parents=True, exist_ok=True)
    if cfg != out / CONFIG_FILE:  # the config next to the model (a checkpoint folder holds its own)
        config.save(out / CONFIG_FILE)
    write_model_files(out, model, vecnorm, config, "run")
    return out


def to_sb3(policy_path: Path, out: Path, vecnormalize: Path | None = None) -> None:
    """Write an SB3 zip (and the VecNormalize pickle) of a safe checkpoint."""
    from baselines.atomic import atomic_path, atomic_write_bytes
    from baselines.checkpoints import find_checkpoint, load_folder

    model, vecnorm, _, _ = load_folder(find_checkpoint(policy_path))
    if vecnorm is not None and vecnormalize is None:
        raise ConfigError(f"{policy_path} has observation normalisation: pass --vecnormalize PATH for its statistics "
                          f"(SB3 needs them to use the model)")
    buf = io.BytesIO()
    model.save(buf)
    atomic_write_bytes(out, buf.getvalue())
    if vecnorm is not None:
        with atomic_path(vecnormalize) as tmp:
            vecnorm.save(str(tmp))


def _main(argv=None) -> int:
    ap = Parser(prog="export.py", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="command", required=True, parser_class=Parser)
    to = sub.add_parser("to-sb3", help="write an SB3 model.zip (+ VecNormalize pickle) of a checkpoint")
    to.add_argument("--policy", type=Path, required=True, help="run directory, checkpoint directory or its file")
    to.add_argument("--out", type=Path, required=True, help="the SB3 zip to write")
    to.add_argument("--vecnormalize", type=Path, default=None, help="where to write the VecNormalize pickle")
    to.add_argument("--force", action="store_true", help="overwrite existing files")
    fr = sub.add_parser("from-sb3", help="convert an SB3 model.zip (+ vecnormalize.pkl) you trust to the safe format")
    fr.add_argument("path", type=Path, help="an SB3 model.zip, or the folder holding it")
    fr.add_argument("--out", type=Path, default=None, help="output folder (default: the zip's folder)")
    fr.add_argument("--trust-pickle", action="store_true", help="required: reading the files runs code they contain")
    args = ap.parse_args(argv)
    if args.command == "to-sb3":
        from baselines.evaluate import check_output_file

        check_output_file(args.out, args.force, "--out")
        if args.vecnormalize is not None:
            check_output_file(args.vecnormalize, args.force, "--vecnormalize")
        to_sb3(args.policy, args.out, args.vecnormalize)
        print(f"wrote {args.out}" + (f" and {args.vecnormalize}" if args.vecnormalize else ""))
        return 0
    if not args.trust_pickle:
        ap.error(f"from-sb3 unpickles {args.path}, which runs any code in it: pass --trust-pickle if you created it "
                 f"or trust its source (nothing was read)")
    print(f"wrote the safe checkpoint {from_sb3(args.path, args.out)}")
    return 0


def main(argv=None) -> int:
    from baselines._extras import require

    require("export.py")
    return run_main(_main, argv, prog="export.py")


if __name__ == "__main__":
    sys.exit(main())
