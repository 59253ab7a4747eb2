"""What a run writes besides results.json: RESULTS.md and the table of the measurements in benchmarks/README.md."""

from __future__ import annotations

from pathlib import Path

from benchmarks._common import ROOT, table, verdict
from benchmarks._training import TIME_TO_BEAT_GOAL, TRAIN_TOTAL_GOAL
from softpvtol_gym.baselines.util.atomic import atomic_write_text

# ------------------------------------------------------------------------------- README table
README = ROOT / "benchmarks" / "README.md"  # the page with the generated table of the measurements
README_START = "<!-- benchmarks/run.py: table start (generated from benchmarks/results.json, do not edit) -->"
README_END = "<!-- benchmarks/run.py: table end -->"


#: the ratios of item 3 in the table, in this order
_CONTROLLER_RATIOS = ("ratio_residual_extra", "ratio_policy", "ratio_controller", "ratio_policy_integral",
                      "ratio_policy_extended")


def readme_table(payload: dict) -> str:
    """The README's Performance table from a full run's results.json payload."""
    it = payload["items"]
    tg = {name: {k: t["value"] for k, t in res["targets"].items()} for name, res in it.items()}
    ctl = it["controller"]["results"]
    cold = it["cold_start"]
    ppo = it["ppo"]
    ttb = it["time_to_beat"]
    beat = ttb["beat"]
    rows = [
        ["1. single env step (`gym.make(\"SoftPVTOL-v0\")`, random actions, resets counted) / `Pendulum-v1`: "
         "idle; another process keeping one core busy",
         f"{tg['single']['ratio_vs_pendulum']:.2f}x; {tg['single']['ratio_vs_pendulum_busy']:.2f}x "
         f"(Acrobot-v1: {it['single']['ratio_vs_acrobot']:.2f}x)", "<= 0.6x"],
        ["2. vector env, N = 4096, random actions: idle; another process keeping one core busy",
         f"{tg['vector']['steps_per_second_4096'] / 1e6:.2f} M env-steps/s, "
         f"{tg['vector']['ratio_vs_cartpole_4096']:.2f}x `CartPoleVectorEnv`; "
         f"{tg['vector']['ratio_vs_cartpole_4096_busy']:.2f}x", ">= 5 M/s, >= 0.25x; >= 0.15x"],
        ["2. vector env / `make_vec(..., \"sync\")`, N = 256", f"{tg['vector']['ratio_vs_sync_256']:.0f}x", ">= 50x"],
        ["3. controllers / one env step, single: residual mode's base controller, `PassivityPolicy.predict`, "
         "`PassivityController()`, the integral loop's and the extended loop's `predict`",
         ", ".join(f"{ctl['single'][k]:.2f}x" for k in _CONTROLLER_RATIOS), "report"],
        ["3. the same, batched (N = 4096, per env)",
         ", ".join(f"{ctl['batched'][k]:.2f}x" for k in _CONTROLLER_RATIOS), "report"],
        ["3. a residual-mode env step (the default agent's) / an actuators-mode one, vector env, N = 4096",
         f"{tg['controller']['batched_ratio_residual_step']:.2f}x", "<= 2.5x"],
        ["4. PPO (default `train.py` configuration): share of wall time in `env.step` (training env-steps/s)",
         f"{100 * ppo['env_share']:.1f} % ({ppo['env_steps_per_second'] / 1e3:.1f} k env-steps/s)", "<= 10 %"],
        [f"4. the fast recipe (`train.py --recipe {ppo['fast']['recipe']}`) on the tracking cell (residual, "
         "track_random, nominal): training env-steps/s, rollouts + updates (its quality and wall time against the "
         "default: `benchmarks/ppo_speed.py --compare`, below)",
         f"{ppo['fast']['env_steps_per_second'] / 1e3:.1f} k env-steps/s", ">= 50 k/s"],
        ["5. `import softpvtol_gym` + first reset and step, fresh process",
         f"{tg['cold_start']['import_plus_first_step']:.2f} s", "< 2 s"],
        ["5. the same with a cold numba cache (it compiles), CPU seconds: actuators mode; residual mode; the README's "
         "quickstart (a whole process)",
         f"{tg['cold_start']['cold_actuators_first_step_cpu']:.1f} s; "
         f"{tg['cold_start']['cold_residual_first_step_cpu']:.1f} s; {tg['cold_start']['cold_quickstart_cpu']:.1f} s",
         "<= 20 s; <= 30 s; <= 30 s"],
        ["5. longest silence while compiling (cold first steps; a cold `python train.py`)",
         f"{max(cold['cold_actuators']['longest_silence'], cold['cold_residual']['longest_silence']):.1f} s; "
         f"{cold['cold_train']['longest_silence']:.1f} s", "<= 10 s"],
        ["6. `python train.py`: from its start to the first periodic held-out evaluation above the passivity "
         "controller; the whole run ([learning curve](time_to_beat.png))",
         f"{tg['time_to_beat']['seconds_to_beat']:.1f} s ({beat['step']:,} steps); "
         f"{tg['time_to_beat']['train_total_seconds']:.0f} s (load average {ttb['loadavg_start'][0]:.2f})"
         if beat is not None else f"never; {tg['time_to_beat']['train_total_seconds']:.0f} s",
         f"<= {TIME_TO_BEAT_GOAL:.0f} s; <= {TRAIN_TOTAL_GOAL:.0f} s"],
    ]
    m = payload["machine"]
    head = (f"From `{payload['command']}`, {payload['date']}, {m['cores']} cores, "
            f"load average {m['loadavg_start'][0]:.2f} at the start.")
    return "\n".join([head, "", table(["item", "measured", "target"], rows)])


def update_readme(payload: dict, path: Path = README) -> bool:
    """Replace the README's generated table; False if its markers are missing."""
    text = path.read_text()
    if README_START not in text or README_END not in text:
        return False
    a = text.index(README_START) + len(README_START)
    b = text.index(README_END)
    atomic_write_text(path, text[:a] + "\n" + readme_table(payload) + "\n" + text[b:])
    return True



def results_markdown(command: str, date: str, facts: dict, results: dict) -> str:
    """RESULTS.md: the run's command, machine and versions, the summary of every target, each item's text."""
    summary = [[f"{name}: {key}", f"{t['value']:.3g}", t["target"], verdict(t["pass"])]
               for name, res in results.items() for key, t in res["targets"].items()]
    md = [
        "# Benchmark results",
        "",
        "Generated by `benchmarks/run.py`; do not edit by hand, rerun the command.",
        "",
        f"- command: `{command}`",
        f"- date: {date}",
        f"- machine: {facts['cores']} cores, {facts['platform']} (the commit and CPU model are in results.json); "
        f"load average (1, 5, 15 min) {', '.join(f'{x:.2f}' for x in facts['loadavg_start'])} at the start, "
        f"{', '.join(f'{x:.2f}' for x in facts['loadavg_end'])} at the end",
        f"- versions: python {facts['python']}, numpy {facts['numpy']}, numba {facts['numba']}, "
        f"gymnasium {facts['gymnasium']}, torch {facts['torch']}, stable-baselines3 {facts['stable_baselines3']}, "
        f"softpvtol-gym {facts['softpvtol_gym']}",
        f"- threads for large batches: {facts['numba_num_threads']} (NUMBA_NUM_THREADS)",
        "",
        "Ratios are medians over interleaved repetitions measured in the same process (absolute times on a "
        "shared machine are noisy).",
        "",
        "## Summary",
        "",
        table(["item: measure", "value", "target", "verdict"], summary),
        "",
    ]
    for res in results.values():
        md += [f"## {res['title']}", "", res["text"], ""]
    return "\n".join(md)
