"""Train an agent on SoftPVTOL-v0 and compare it with the passivity controller.

    python train.py [--action-mode residual] [--task hover] [--tier nominal] [--timesteps N] [--seed S] [--out DIR]

Thin CLI; the logic lives in ``baselines/``.
"""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from baselines.train_minimal import main  # noqa: E402

if __name__ == "__main__":
    sys.exit(main())
