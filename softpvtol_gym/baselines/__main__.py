"""``python -m softpvtol_gym.baselines``: the ``softpvtol`` console command."""

import sys

from softpvtol_gym.baselines.cli import main

sys.exit(main())
