"""The plain install (``pip install softpvtol-gym``) without its extras: torch, stable-baselines3, pygame and casadi
made unimportable in a subprocess, the env, the vector env and the analytic policy still work, and what
needs an extra says which one.

The subprocess runs ``_PRELUDE`` first: a meta-path finder at the front of ``sys.meta_path`` that raises
ImportError for the blocked top-level names (as a machine without them would), then ``_CHECKS``.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
BLOCKED = ("torch", "stable_baselines3", "pygame", "casadi")

_PRELUDE = f"""
import sys
from importlib.abc import MetaPathFinder

BLOCKED = {BLOCKED!r}
ATTEMPTS = []


class Blocker(MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in BLOCKED:
            ATTEMPTS.append(name)
            raise ImportError(f"No module named {{name!r}} (blocked by tests/package/test_extras.py)", name=name)
        return None


for name in list(sys.modules):
    assert name.split(".")[0] not in BLOCKED, name
sys.meta_path.insert(0, Blocker())
"""

_CHECKS = """
import json
import gymnasium as gym
import numpy as np

import softpvtol_gym
from softpvtol_gym import PassivityPolicy, SoftPVTOLVectorEnv
from softpvtol_gym.envs import ACTION_MODES, ENV_ID, MODE_ENV_IDS

out = {"steps": {}, "errors": {}}
for mode in ACTION_MODES:
    for env_id, kwargs in ((ENV_ID, {"action_mode": mode}), (MODE_ENV_IDS[mode], {})):
        env = gym.make(env_id, task="hover", **kwargs)
        obs, _ = env.reset(seed=0)
        for _ in range(3):
            obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
        out["steps"][f"{env_id}/{mode}"] = bool(np.isfinite(obs).all() and np.isfinite(reward))
        env.close()

venv = SoftPVTOLVectorEnv(num_envs=3, task="hover")
obs, _ = venv.reset(seed=0)
obs, reward, *_ = venv.step(venv.action_space.sample())
out["vector"] = list(obs.shape) + [bool(np.isfinite(reward).all())]
venv.close()
venv = gym.make_vec(ENV_ID, num_envs=2, vectorization_mode="vector_entry_point", task="hover")
out["make_vec"] = type(venv.unwrapped).__name__
venv.close()

env = gym.make(ENV_ID, task="hover", action_mode="actuators")
obs, _ = env.reset(seed=0)
policy = PassivityPolicy.from_env(env)
action, _ = policy.predict(obs, deterministic=True)
obs, reward, terminated, truncated, _ = env.step(action)
out["policy"] = [list(np.shape(action)), bool(env.action_space.contains(action)), bool(np.isfinite(reward))]
env.close()

for render_mode in ("rgb_array", "human"):
    env = gym.make(ENV_ID, task="hover", render_mode=render_mode)
    try:
        env.reset(seed=0)
        env.render()
        out["errors"][render_mode] = None
    except ImportError as e:
        out["errors"][render_mode] = str(e)
    env.close()
try:
    import softpvtol_gym.envs.sb3  # noqa: F401
    out["errors"]["sb3"] = None
except ImportError as e:
    out["errors"]["sb3"] = str(e)

# the MPC's names import without casadi; building one says which extra installs it
from softpvtol_gym import MPCPolicy
from softpvtol_gym.policies import MPCPolicy as MPCPolicy2
out["mpc_same"] = MPCPolicy is MPCPolicy2
try:
    MPCPolicy.from_env(SoftPVTOLVectorEnv(num_envs=1, task="hover"))
    out["errors"]["mpc"] = None
except ImportError as e:
    out["errors"]["mpc"] = str(e)

out["attempted"] = sorted(set(ATTEMPTS))
out["loaded"] = sorted(n for n in sys.modules if n.split(".")[0] in BLOCKED)
print("RESULT " + json.dumps(out))
"""


def _run_without_extras() -> dict:
    env = {**os.environ, "PYTHONPATH": str(ROOT), "SDL_VIDEODRIVER": "dummy", "PYGAME_HIDE_SUPPORT_PROMPT": "1"}
    proc = subprocess.run([sys.executable, "-c", _PRELUDE + _CHECKS], cwd=ROOT, env=env, capture_output=True,
                          text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-4000:]
    line = next(ln for ln in proc.stdout.splitlines() if ln.startswith("RESULT "))
    return json.loads(line[len("RESULT "):])


def test_plain_install_runs_without_torch_sb3_pygame():
    from softpvtol_gym.envs import ACTION_MODES
    from softpvtol_gym.envs.observation import OBS_DIM

    out = _run_without_extras()
    # every action mode, under SoftPVTOL-v0 and its per-mode id, reset and stepped with finite results
    assert len(out["steps"]) == 2 * len(ACTION_MODES) and all(out["steps"].values()), out["steps"]
    assert out["vector"] == [3, OBS_DIM, True], out["vector"]
    assert out["make_vec"] == "SoftPVTOLVectorEnv"
    assert out["policy"][1:] == [True, True], out["policy"]
    # rendering and the SB3 adapter name the extra that installs what they miss, in one line
    for render_mode in ("rgb_array", "human"):
        msg = out["errors"][render_mode]
        assert msg is not None and "\n" not in msg, msg
        assert "pygame" in msg and 'pip install "softpvtol-gym[render]"' in msg, msg
    msg = out["errors"]["sb3"]
    assert msg is not None and "\n" not in msg, msg
    assert "stable-baselines3" in msg and 'pip install "softpvtol-gym[train]"' in msg, msg
    assert out["mpc_same"]
    msg = out["errors"]["mpc"]
    assert msg is not None and "\n" not in msg, msg
    assert "CasADi" in msg and 'pip install "softpvtol-gym[mpc]"' in msg, msg
    # nothing got hold of a blocked module another way, and the blocker was what refused them
    assert out["loaded"] == [], out["loaded"]
    assert {"pygame", "stable_baselines3", "casadi"} <= set(out["attempted"]), out["attempted"]
