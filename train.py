"""Train an agent on SoftPVTOL-v0 and compare it with the passivity controller.

    python train.py            # PPO, residual mode, hover task, nominal tier (the default agent)
    python train.py --help     # every option

Thin wrapper (as rl-baselines3-zoo's train.py): it runs ``softpvtol train`` with this checkout's paths
(``baselines/_clone.py``); the logic lives in ``softpvtol_gym/baselines/``.
"""

import sys

from baselines._clone import run

if __name__ == "__main__":
    sys.exit(run("train", "train.py"))
