"""The committed MPC episodes are what the current code gives, bit for bit, where numpy's OpenBLAS runs the
kernels they were computed with. The MPC's disturbance estimate and its QP's matrices go through numpy's BLAS,
whose kernels OpenBLAS picks by CPU (``OPENBLAS_CORETYPE`` overrides the pick): the committed results were computed
with its SkylakeX kernels, so on a CPU with AVX-512 (which runs them) a process with the variable set to SkylakeX
reproduces them; other kernels change the last bits, which the noisy tiers amplify (docs/baselines.md, "The
leaderboard"). A change of the MPC must re-evaluate its cells: python baselines/run_jobs.py --reevaluate --only mpc_."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from tests.baselines.test_leaderboard import check_replay

pytest.importorskip("casadi")

ROOT = Path(__file__).resolve().parents[2]
#: the MPC's cells replayed: where its episodes are most sensitive to round-off (noisy observations; hover: short)
#: and a tier whose model error the disturbance estimate sees
MPC_REPLAYS = [("hover", "noisy"), ("track_random", "mismatch")]
REPLAY = """
import json, sys
from tests.baselines.test_leaderboard import analytic_replay
got, want = analytic_replay("mpc", sys.argv[1], sys.argv[2])
print(json.dumps({"got": got, "want": want[:len(got)]}))
"""


def _has_avx512() -> bool:
    try:
        return "avx512f" in Path("/proc/cpuinfo").read_text()
    except OSError:
        return False


@pytest.mark.slow  # four MPC episodes in a process of its own: ~15 s
@pytest.mark.skipif(not _has_avx512(), reason="OpenBLAS's SkylakeX kernels need a CPU with AVX-512")
@pytest.mark.parametrize("task, tier", MPC_REPLAYS, ids=["-".join(r) for r in MPC_REPLAYS])
def test_committed_mpc_cells_reproduce_with_the_blas_kernels_they_were_computed_with(task, tier):
    env = {**os.environ, "OPENBLAS_CORETYPE": "SkylakeX", "NUMBA_NUM_THREADS": "1"}
    done = subprocess.run([sys.executable, "-c", REPLAY, task, tier], env=env, capture_output=True, text=True,
                          timeout=600, cwd=ROOT)
    assert done.returncode == 0, done.stderr[-2000:]
    result = json.loads(done.stdout.strip().splitlines()[-1])
    check_replay(result["got"], result["want"])
