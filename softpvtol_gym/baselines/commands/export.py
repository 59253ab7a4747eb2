"""Interoperability with stable-baselines3's own (pickle-based) files, both ways.

    softpvtol export to-sb3 --policy RUN_OR_CHECKPOINT --out model.zip [--vecnormalize vecnormalize.pkl]
    softpvtol export from-sb3 --trust-pickle PATH [--out DIR]

(From a source checkout, ``python baselines/export.py`` takes the same options.)

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
from pathlib import Path

from softpvtol_gym.baselines.checkpoints.manifest import MANIFEST_FILE
from softpvtol_gym.baselines.checkpoints.sb3_compat import from_sb3, legacy_paths, to_sb3
from softpvtol_gym.baselines.errors import ConfigError
from softpvtol_gym.baselines.util.args import Parser, check_output_file, command_main
from softpvtol_gym.baselines.util.paths import Layout


def _main(argv, layout: Layout, prog: str) -> int:
    ap = Parser(prog=prog, description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
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
    fr.add_argument("--force", action="store_true", help="replace a safe checkpoint already in the output folder")
    args = ap.parse_args(argv)
    if args.command == "to-sb3":
        check_output_file(args.out, args.force, "--out")
        if args.vecnormalize is not None:
            check_output_file(args.vecnormalize, args.force, "--vecnormalize")
        to_sb3(args.policy, args.out, args.vecnormalize)
        print(f"wrote {args.out}" + (f" and {args.vecnormalize}" if args.vecnormalize else ""))
        return 0
    if not args.trust_pickle:
        ap.error(f"from-sb3 unpickles {args.path}, which runs any code in it: pass --trust-pickle if you created it "
                 f"or trust its source (nothing was read)")
    out = args.out if args.out is not None else legacy_paths(args.path)[0].parent
    if (out / MANIFEST_FILE).exists() and not args.force:
        raise ConfigError(f"{out} already holds a safe checkpoint ({MANIFEST_FILE}); pass --out for another folder, or "
                          f"--force to replace it (nothing was read or written)")
    print(f"wrote the safe checkpoint {from_sb3(args.path, args.out)}")
    return 0


main = command_main("export.py", _main,
                    "``softpvtol export``: conversions between the safe checkpoint format and SB3's files.")

