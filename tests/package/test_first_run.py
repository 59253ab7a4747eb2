"""First-run experience: the compile message, display-only pygame, the
``"softpvtol_gym:SoftPVTOL-v0"`` id in worker processes that never imported the package."""

import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest

import softpvtol_gym
from softpvtol_gym import _cache

# a light kernel (the gravity vector): compiles in seconds, so the message test does not pay the step's compile
_LIGHT = ("import numpy as np, softpvtol_gym; "
          "softpvtol_gym.dynamics.gravity_vector(np.zeros(5), softpvtol_gym.SoftPVTOLParams())")


def _run(code: str, cache_dir, timeout=600) -> subprocess.CompletedProcess:
    env = dict(os.environ, SOFTPVTOL_GYM_CACHE_DIR=str(cache_dir))
    return subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=timeout)


def test_first_run_message_once_then_silent(tmp_path):
    first = _run(_LIGHT, tmp_path)
    assert first.returncode == 0, first.stderr
    lines = [ln for ln in first.stderr.splitlines() if ln.startswith("softpvtol_gym: compil")]
    assert lines[0] == _cache.FIRST_RUN_MESSAGE
    assert f"first run only, about {_cache.COLD_COMPILE_SECONDS} s" in lines[0]
    assert sum(ln == _cache.FIRST_RUN_MESSAGE for ln in lines) == 1
    # every compile of a kernel: its start and its end with the seconds it took
    starts = [ln for ln in lines if ln.startswith("softpvtol_gym: compiling ") and ln != _cache.FIRST_RUN_MESSAGE]
    ends = [ln for ln in lines if ln.startswith("softpvtol_gym: compiled ")]
    assert starts and len(starts) == len(ends), lines
    assert _cache.COMPILE_START.format(name="batched.batch_gravity_vector") in starts  # (the import compiles others)
    assert ends[-1].startswith("softpvtol_gym: compiled batched.batch_gravity_vector in ") and ends[-1].endswith(" s")
    second = _run(_LIGHT, tmp_path)  # the kernel is in the cache now
    assert second.returncode == 0, second.stderr
    assert "softpvtol_gym: compil" not in second.stderr


def test_no_message_with_a_warm_cache():
    # the cache holds the kernels of the light call, a reset and a step (compiled here if no other test did)
    softpvtol_gym.dynamics.gravity_vector(np.zeros(5), softpvtol_gym.SoftPVTOLParams())
    env = softpvtol_gym.SoftPVTOLEnv()
    env.reset(seed=0)
    env.step(np.zeros(4, dtype=np.float32))
    out = _run(_LIGHT + "; e = softpvtol_gym.SoftPVTOLEnv(); e.reset(seed=0); e.step(np.zeros(4))",
               softpvtol_gym.NUMBA_CACHE_DIR.parent)
    assert out.returncode == 0, out.stderr
    assert "softpvtol_gym: compil" not in out.stderr


class _Event:
    def __init__(self, module, name):
        def f():
            pass

        f.__module__, f.__name__ = module, name
        self.data = {"dispatcher": type("D", (), {"py_func": staticmethod(f)})()}


def test_a_compile_says_its_start_progress_and_end_once_for_its_callees():
    import time

    said = []
    ann = _cache.CompileAnnouncer(first_run=False, say=said.append, progress_seconds=0.05)
    outer, inner = _Event("softpvtol_gym.envs.step", "step_serial"), _Event("softpvtol_gym.model.rk4", "rk4_lanes")
    other = _Event("numpy.linalg", "solve")  # another package's compile: not ours to announce
    ann.on_start(outer)
    ann.on_start(inner)
    ann.on_start(other)
    time.sleep(0.3)
    ann.on_end(other)
    ann.on_end(inner)
    ann.on_end(outer)
    time.sleep(0.1)  # the progress thread has stopped: nothing after the end line
    assert said[0] == _cache.COMPILE_START.format(name="step.step_serial")
    assert said[-1].startswith("softpvtol_gym: compiled step.step_serial in ")
    progress = said[1:-1]
    assert len(progress) >= 2
    assert all(ln.startswith("softpvtol_gym: ... still compiling step.step_serial (") for ln in progress)
    assert not any("rk4_lanes" in ln or "solve" in ln for ln in said)
    ann.on_start(inner)  # the next outermost compile is announced again
    ann.on_end(inner)
    assert said[-2] == _cache.COMPILE_START.format(name="rk4.rk4_lanes")


def test_the_first_run_message_precedes_the_first_compile_only():
    said = []
    ann = _cache.CompileAnnouncer(first_run=True, say=said.append)
    for _ in range(2):
        ev = _Event("softpvtol_gym.envs.step", "step_serial")
        ann.on_start(ev)
        ann.on_end(ev)
    assert said[0] == _cache.FIRST_RUN_MESSAGE and said.count(_cache.FIRST_RUN_MESSAGE) == 1
    assert len(said) == 5


def test_cache_is_empty_looks_for_numba_index_files(tmp_path):
    assert _cache.cache_is_empty(tmp_path)
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "step.step_serial-1.py311.nbi").write_bytes(b"")
    assert not _cache.cache_is_empty(tmp_path)


# ------------------------------------------------------------------------------------ pygame
def test_human_mode_initialises_only_the_display(monkeypatch):
    pygame = pytest.importorskip("pygame")
    monkeypatch.setenv("SDL_VIDEODRIVER", "dummy")
    monkeypatch.delenv("SDL_AUDIODRIVER", raising=False)  # audio, if started, would find no device here

    def no_full_init(*args, **kwargs):
        raise AssertionError("pygame.init() starts audio (ALSA errors on headless machines); init the display only")

    monkeypatch.setattr(pygame, "init", no_full_init)
    env = softpvtol_gym.SoftPVTOLEnv(render_mode="human")
    env.reset(seed=0)
    env.step(np.zeros(4))
    assert pygame.display.get_init()
    assert not pygame.mixer.get_init()
    env.close()
    assert not pygame.display.get_init()


def test_human_mode_headless_prints_no_audio_errors(tmp_path):
    code = textwrap.dedent("""
        import numpy as np, softpvtol_gym, pygame
        env = softpvtol_gym.SoftPVTOLEnv(render_mode="human")
        env.reset(seed=0)
        env.step(np.zeros(4))
        assert pygame.display.get_init() and not pygame.mixer.get_init()
        env.close()
    """)
    env = {k: v for k, v in os.environ.items() if k != "SDL_AUDIODRIVER"}
    env.update(SDL_VIDEODRIVER="dummy", PYGAME_HIDE_SUPPORT_PROMPT="1")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr
    assert "ALSA" not in out.stderr


# --------------------------------------------------------------------- workers and the env id
_ASYNC = textwrap.dedent("""
    import sys
    import gymnasium as gym
    import numpy as np

    def main(context):
        # no `import softpvtol_gym` here: the id's module part makes gymnasium import it
        envs = gym.make_vec("softpvtol_gym:SoftPVTOL-v0", num_envs=2, vectorization_mode="async",
                            vector_kwargs={} if context is None else {"context": context})
        obs, _ = envs.reset(seed=0)
        obs2, reward, *_ = envs.step(np.zeros((2, 4)))
        assert obs.shape == (2, 18) and np.isfinite(obs2).all() and reward.shape == (2,)
        envs.close()
        print("ok")

    if __name__ == "__main__":
        main(None if sys.argv[1] == "default" else sys.argv[1])
""")


@pytest.mark.parametrize("context", ["default", "spawn"])
def test_async_make_vec_with_the_module_id_in_a_fresh_process(tmp_path, context):
    script = tmp_path / "run_async.py"
    script.write_text(_ASYNC)
    out = subprocess.run([sys.executable, str(script), context], capture_output=True, text=True, timeout=900,
                         cwd=tmp_path)
    assert out.returncode == 0, out.stderr[-3000:]
    assert out.stdout.strip().endswith("ok")


_SUBPROC = textwrap.dedent("""
    import numpy as np
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import SubprocVecEnv

    def main():
        # created inside a function, workers started by spawn: only the module id reaches them
        venv = make_vec_env("softpvtol_gym:SoftPVTOL-v0", n_envs=2, vec_env_cls=SubprocVecEnv,
                            vec_env_kwargs={"start_method": "spawn"})
        venv.reset()
        obs, *_ = venv.step(np.zeros((2, 4)))
        assert obs.shape == (2, 18)
        venv.close()
        print("ok")

    if __name__ == "__main__":
        main()
""")


@pytest.mark.slow
def test_sb3_subproc_vec_env_with_the_module_id(tmp_path):
    script = tmp_path / "run_subproc.py"
    script.write_text(_SUBPROC)
    out = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=900, cwd=tmp_path)
    assert out.returncode == 0, out.stderr[-3000:]
    assert out.stdout.strip().endswith("ok")


_COMPILED_NAMES = """
import numpy as np, softpvtol_gym, sys
from numba.core import event
names = set()
class Names(event.Listener):
    def on_start(self, ev):
        names.add(ev.data["dispatcher"].py_func.__name__)
    def on_end(self, ev):
        pass
event.register("numba:compile", Names())
env = softpvtol_gym.SoftPVTOLEnv(action_mode=sys.argv[1], tier=sys.argv[2])
env.reset(seed=0)
env.step(env.action_space.sample())
print(" ".join(sorted(names)))
"""


@pytest.mark.slow  # two cold first steps in a fresh cache: ~25 s
@pytest.mark.parametrize("mode, tier, absent, present", [
    ("actuators", "nominal", {"_virtual_allocation", "rk4_lanes_consistent", "consistent_energies"},
     {"rk4_lanes_partial"}),
    ("virtual", "model_gap", set(), {"_virtual_allocation", "rk4_lanes_consistent", "consistent_energies"}),
])
def test_a_first_step_compiles_only_what_its_env_uses(tmp_path, mode, tier, absent, present):
    """The step and reset kernels take ``virtual`` and ``consistent`` as None unless the env needs them
    (envs.step.kernel_flags): numba prunes those branches, so a first actuators step compiles neither the
    virtual mode's allocation nor the consistent plant, and a virtual-mode model_gap env compiles both."""
    out = subprocess.run([sys.executable, "-c", _COMPILED_NAMES, mode, tier], capture_output=True, text=True,
                         timeout=600, env=dict(os.environ, SOFTPVTOL_GYM_CACHE_DIR=str(tmp_path)))
    assert out.returncode == 0, out.stderr
    names = set(out.stdout.split())
    assert "step_serial_small" in names and not absent & names and present <= names, sorted(names)
