"""The benchmark script end to end (quick mode), the replays it times, and the tables it generates (README,
docs) checked against the committed measurements.
"""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from softpvtol_gym import PassivityPolicy, SoftPVTOLVectorEnv
from softpvtol_gym.control import PassivityController

ROOT = Path(__file__).resolve().parents[2]


# ------------------------------------------------------------------------- benchmark script
@pytest.mark.slow  # benchmarks/run.py --quick in a subprocess
def test_benchmark_script_runs_end_to_end_quick(tmp_path):
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    proc = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "run.py"), "--quick", "--out", str(tmp_path)],
                          cwd=ROOT, env=env, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    md = (tmp_path / "RESULTS.md").read_text()
    data = json.loads((tmp_path / "results.json").read_text())
    assert set(data["items"]) == {"single", "vector", "controller", "ppo", "cold_start", "time_to_beat"}
    for item in data["items"].values():
        assert item["targets"] and all(isinstance(t["pass"], bool) for t in item["targets"].values())
    for key in ("cores", "python", "numpy", "numba", "gymnasium", "torch", "stable_baselines3", "commit"):
        assert key in data["machine"]
    for title in ("1. Single-env", "2. Vector-env", "3. Passivity controller", "4. PPO", "5. Cold start",
                  "6. Time to beat"):
        assert title in md
    item = data["items"]["time_to_beat"]  # a short train.py run: its curve, passivity's line and the plot
    assert item["curve"][0]["step"] == 0 and item["total_seconds"] > item["curve"][-1]["seconds"] > 0
    assert (tmp_path / "time_to_beat.png").stat().st_size > 10_000
    assert "Pendulum-v1" in md and "CartPoleVectorEnv" in md and "do not edit" in md


@pytest.mark.parametrize("n", [1, 3])
@pytest.mark.parametrize("loop", ["exact", "integral", "extended", "controller"])
def test_benchmark_replays_each_controller_along_its_own_closed_loop(n, loop):
    """Item 3 times copies of a controller replaying the calls of its closed loop: each window's replay gives the
    loop's outputs bit for bit, so the timed calls are the loop's (and where the outputs depend on the memory, a
    replay from the wrong window's copy does not)."""
    if str(ROOT) not in sys.path:
        sys.path.insert(0, str(ROOT))
    from benchmarks._env_speed import _ClosedLoop

    if loop == "controller":
        env = SoftPVTOLVectorEnv(num_envs=n, action_mode="residual", task="hover", tier="nominal")
        policy = PassivityController.from_loop("exact")
    else:
        env = SoftPVTOLVectorEnv(num_envs=n, task="hover", tier="nominal")
        policy = PassivityPolicy.from_env(env, loop=loop)
    closed = _ClosedLoop(env, policy, (0, 6), 3, single=n == 1)
    assert [len(calls) for _, calls, _ in closed.windows] == [3, 3]
    for snapshot, calls, outputs in closed.windows:
        fn = closed.caller(snapshot)
        for call, want in zip(calls, outputs, strict=True):
            got = closed.output(fn(*call))
            assert got.shape == ((4,) if n == 1 else (n, 4)) and got.tobytes() == want.tobytes()
    if loop in ("integral", "extended"):  # (the exact loop's outputs do not depend on its memory's warm start)
        wrong = closed.caller(closed.windows[0][0])  # the start's copy on the second window's calls
        (_, calls, outputs) = closed.windows[1]
        assert any(closed.output(wrong(*c)).tobytes() != w.tobytes() for c, w in zip(calls, outputs))
    assert closed.timer()() > 0.0


def test_readme_performance_table_is_the_generated_one():
    """The table of the measurements (benchmarks/README.md, where benchmarks/run.py writes it) = benchmarks/run.py's
    table from the committed results.json."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("softpvtol_benchmarks_run", ROOT / "benchmarks" / "run.py")
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    payload = json.loads((ROOT / "benchmarks" / "results.json").read_text())
    assert bench.README == ROOT / "benchmarks" / "README.md"
    text = bench.README.read_text()
    block = text[text.index(bench.README_START) + len(bench.README_START):text.index(bench.README_END)]
    assert block.strip() == bench.readme_table(payload).strip()
    assert not payload["quick"]


def _train_block(text: str) -> list[str]:
    """The lines of the README's block that shows what `python train.py` prints."""
    start = text.index("```\nPPO vs passivity")
    return text[start + 4:text.index("```", start + 4)].strip().splitlines()


def test_readme_train_py_output_and_time_to_beat_are_the_committed_measurement():
    """The README's `python train.py` output is what the committed benchmark's train.py run printed (the run
    directory aside), its time to beat passivity is the first evaluation above passivity on the committed
    learning curve, and the committed learning-curve PNG exists."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("softpvtol_benchmarks_run", ROOT / "benchmarks" / "run.py")
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    item = json.loads((ROOT / "benchmarks" / "results.json").read_text())["items"]["time_to_beat"]
    printed = [line for line in item["stdout"].strip().splitlines() if line.strip()]
    block = _train_block((ROOT / "README.md").read_text())
    assert block[0].split("; run in ")[0] == printed[-4].split("; run in ")[0]
    assert block[1:] == printed[-3:]
    assert item["command"] == "python train.py --no-progress-bar"  # the default agent, nothing changed
    curve = [{"step": e["step"], "wall_time": e["seconds"], "mean_return": e["mean_return"],
              "mean_rms_position_error": e["mean_rms_position_error"]} for e in item["curve"]]
    beat = bench.time_to_beat(curve, item["passivity"]["mean_return"], 0.0)
    assert beat == item["beat"] and beat is not None
    assert all(e["mean_return"] <= item["passivity"]["mean_return"] for e in curve if e["step"] < beat["step"])
    png = (ROOT / "benchmarks" / "time_to_beat.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 10_000


def test_docs_ppo_speed_table_is_the_generated_one():
    """benchmarks/STUDIES.md's PPO-defaults table = benchmarks/ppo_speed.py --table of the committed JSON, and
    every run's steps to beat is the first evaluation above passivity on its committed learning curve."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("softpvtol_ppo_speed", ROOT / "benchmarks" / "ppo_speed.py")
    speed = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(speed)
    results = json.loads((ROOT / "benchmarks" / "ppo_speed.json").read_text())
    text = (ROOT / "benchmarks" / "STUDIES.md").read_text()
    start = "<!-- benchmarks/ppo_speed.py --table: start (generated from benchmarks/ppo_speed.json, do not edit) -->"
    block = text[text.index(start) + len(start):text.index("<!-- benchmarks/ppo_speed.py --table: end -->")]
    assert block.strip() == speed.markdown_table(results).strip()
    for r in results:
        above = [e for e in r["curve"] if e["mean_return"] > r["passivity"]["mean_return"]]
        assert r["steps_to_beat"] == (above[0]["step"] if above else None)
        assert r["command"].startswith("python benchmarks/ppo_speed.py ")


def _ppo_speed_module():
    import importlib.util

    spec = importlib.util.spec_from_file_location("softpvtol_ppo_speed", ROOT / "benchmarks" / "ppo_speed.py")
    speed = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(speed)
    return speed


def test_fast_recipe_comparison_is_the_committed_runs_and_the_docs_table():
    """benchmarks/ppo_speed_fast.json holds the default entry and the residual-fast recipe as
    shipped, five seeds each on the tracking cell; benchmarks/README.md's table is --compare's output for it."""
    from softpvtol_gym.baselines.config.recipes import load_recipe

    speed = _ppo_speed_module()
    results = json.loads((ROOT / "benchmarks" / "ppo_speed_fast.json").read_text())
    assert {(r["name"], r["seed"]) for r in results} == {(n, s) for n in ("default", "fast") for s in range(5)}
    for r in results:
        assert (r["action_mode"], r["task"], r["tier"]) == ("residual", "track_random", "nominal")
        assert r["overrides"] == ([] if r["name"] == "default" else load_recipe("residual-fast")["hp"])
        assert r["command"].startswith("python benchmarks/ppo_speed.py ")
        assert r["final"] == r["curve"][-1] and r["timesteps"] >= 1_000_000
    cmp = speed.compare(results, "default", "fast")
    assert cmp["seeds"] == [0, 1, 2, 3, 4] and set(cmp["checks"]) and cmp["passed"] is all(cmp["checks"].values())
    text = (ROOT / "benchmarks" / "README.md").read_text()
    start = ("<!-- benchmarks/ppo_speed.py --compare: start (generated from benchmarks/ppo_speed_fast.json, do not "
             "edit) -->")
    block = text[text.index(start) + len(start):text.index("<!-- benchmarks/ppo_speed.py --compare: end -->")]
    assert block.strip() == speed.compare_table(results, "default", "fast").strip()
    png = (ROOT / "benchmarks" / "ppo_speed_fast.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 10_000


def test_ppo_speed_compare_checks_each_criterion():
    speed = _ppo_speed_module()

    def run(name, seed, rms, ret, wall, rate, rate_no_eval, task="track_random"):
        final = {"step": 1000, "seconds": wall, "mean_return": ret, "mean_rms_position_error": rms, "crash_rate": 0.0}
        return {"name": name, "seed": seed, "action_mode": "residual", "task": task, "tier": "nominal",
                "hyperparams": {}, "timesteps": 1000, "final": final, "wall_seconds": wall, "steps_per_second": rate,
                "steps_per_second_without_evaluations": rate_no_eval, "loadavg_before": [1.0, 1.0, 1.0]}

    base = [run("a", s, 0.07, 1900.0, 60.0, 15e3, 16e3) for s in (0, 1)]
    good = [run("b", s, 0.06, 1910.0, 19.0, 52e3, 55e3) for s in (0, 1)]
    assert speed.compare(base + good, "a", "b")["passed"]
    for bad, failed in (({"rms": 0.08}, "final RMS error at most the baseline's"),
                        ({"ret": 1800.0}, "final return at least the baseline's"),
                        ({"wall": 21.0}, "wall time at most a third of the baseline's"),
                        ({"rate_no_eval": 49e3}, "at least 50 k env-steps/s, rollouts and updates")):
        kw = {"rms": 0.06, "ret": 1910.0, "wall": 19.0, "rate": 52e3, "rate_no_eval": 55e3, **bad}
        cmp = speed.compare(base + [run("b", s, **kw) for s in (0, 1)], "a", "b")
        assert not cmp["passed"] and [k for k, ok in cmp["checks"].items() if not ok] == [failed]
    with pytest.raises(SystemExit, match="no run named 'c'"):
        speed.compare(base, "a", "c")
    with pytest.raises(SystemExit, match="not the same cell"):
        speed.compare(base + [run("b", 0, 0.06, 1910.0, 19.0, 52e3, 55e3, task="hover")], "a", "b")


def test_ppo_speed_config_of_a_recipe_is_its_hp_and_must_match_the_mode():
    from softpvtol_gym.baselines.config.recipes import load_recipe

    speed = _ppo_speed_module()
    assert speed.parse_config("fast=recipe:residual-fast", "residual") == ("fast", load_recipe("residual-fast")["hp"])
    with pytest.raises(SystemExit, match="the recipe is for the residual mode, this run's --mode is actuators"):
        speed.parse_config("fast=recipe:residual-fast", "actuators")
    with pytest.raises(SystemExit, match="hp overrides only"):
        speed.parse_config("x=recipe:residual-precise", "residual")
    assert speed.parse_config("a=n_epochs=3;batch_size=64", "residual") == ("a", ["n_epochs=3", "batch_size=64"])
