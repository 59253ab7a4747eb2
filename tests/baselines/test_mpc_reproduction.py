"""The committed MPC episodes are reproduced bit for bit where numpy's OpenBLAS runs the kernels they were
computed with. The MPC's disturbance estimate and its QP's matrices go through numpy's BLAS, whose kernels OpenBLAS
picks by CPU (``OPENBLAS_CORETYPE`` overrides the pick): the committed results were computed with its SkylakeX
kernels, so on a CPU with AVX-512 (which runs them) the variable set to SkylakeX reproduces them; other kernels
change the last bits (docs/baselines.md, "The leaderboard")."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from tests.conftest import RUNS_DIR

pytest.importorskip("casadi")

COMMITTED = RUNS_DIR / "mpc_track_random" / "eval.json"
EPISODE = """
import json, sys
from softpvtol_gym import MPCPolicy, SoftPVTOLVectorEnv
from softpvtol_gym.baselines.evaluation import EVAL_SEED_OFFSET, run_episodes
policy = MPCPolicy.from_env(SoftPVTOLVectorEnv(num_envs=1, action_mode="actuators", task="track_random"))
episode = run_episodes(policy, "actuators", "track_random", "mismatch", 1, EVAL_SEED_OFFSET)[0]
print(json.dumps(episode["rms_position_error"]))
"""


def _has_avx512() -> bool:
    try:
        return "avx512f" in Path("/proc/cpuinfo").read_text()
    except OSError:
        return False


@pytest.mark.skipif(not _has_avx512(), reason="OpenBLAS's SkylakeX kernels need a CPU with AVX-512")
def test_the_committed_mpc_episode_is_reproduced_with_the_blas_kernels_it_was_computed_with():
    want = json.loads(COMMITTED.read_text())["eval"]["mismatch"][0]["rms_position_error"]
    env = {**os.environ, "OPENBLAS_CORETYPE": "SkylakeX", "NUMBA_NUM_THREADS": "1"}
    done = subprocess.run([sys.executable, "-c", EPISODE], env=env, capture_output=True, text=True, timeout=600,
                          cwd=Path(__file__).resolve().parents[2])
    assert done.returncode == 0, done.stderr[-2000:]
    got = json.loads(done.stdout.strip().splitlines()[-1])
    assert got == want, f"the MPC's first mismatch test episode: {got!r}, committed {want!r}"
