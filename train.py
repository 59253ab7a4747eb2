"""Train an agent on SoftPVTOL-v0 and compare it with the passivity controller.

    python train.py            # PPO, residual mode, hover task, nominal tier (the default agent)
    python train.py --help     # every option

Thin CLI; the logic lives in ``baselines/`` (``baselines/train_agent.py``, ``baselines/training.py``).
"""

import sys

from softpvtol_gym.baselines.util.extras import require

if __name__ == "__main__":
    require("train.py")  # a plain install lacks the 'baselines' extra: say which one, before any import fails
    from softpvtol_gym.baselines.commands.train import main

    sys.exit(main())
