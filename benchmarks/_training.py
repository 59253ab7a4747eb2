"""Items 4 and 6: PPO with the default train.py configuration (share of wall time in the env), and the
wall-clock time of `python train.py` to beat the passivity controller, with its learning curve
(benchmarks/run.py)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from benchmarks._cold_start import _fresh_process
from benchmarks._common import ROOT, fmt_rate, fmt_time, table, verdict


# --------------------------------------------------------------------------------------- 4. PPO
def bench_ppo(quick: bool) -> dict:
    import torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import VecNormalize

    from softpvtol_gym.baselines.config.hyperparams import algo_kwargs, load_hyperparams, normalize_kwargs
    from softpvtol_gym.envs.sb3 import SoftPVTOLSB3VecEnv

    hp = load_hyperparams("ppo", "residual")
    n_envs = int(hp["n_envs"])
    rollout = n_envs * int(hp["n_steps"])
    total = rollout if quick else 5 * rollout
    torch.set_num_threads(1)
    # as train.py builds it (training.models.make_env): no per-step info dicts
    env = SoftPVTOLSB3VecEnv(num_envs=n_envs, action_mode="residual", task="hover", tier="nominal", step_infos=False)
    env.seed(0)
    inside = {"seconds": 0.0, "calls": 0}
    step_wait = env.step_wait

    def timed_step_wait():
        t0 = time.perf_counter()
        out = step_wait()
        inside["seconds"] += time.perf_counter() - t0
        inside["calls"] += 1
        return out

    env.step_wait = timed_step_wait
    norm = normalize_kwargs(hp)
    venv = VecNormalize(env, **norm) if norm is not None else env
    model = PPO(hp.get("policy", "MlpPolicy"), venv, seed=0, device="cpu", verbose=0, **algo_kwargs(hp))
    t0 = time.perf_counter()
    model.learn(total_timesteps=total)
    wall = time.perf_counter() - t0
    steps = int(model.num_timesteps)
    share = inside["seconds"] / wall
    per_step = inside["seconds"] / max(1, inside["calls"])
    rows = [
        ["training env-steps/s (rollouts + updates)", fmt_rate(steps / wall), "-", "n/a"],
        ["time in env.step (SB3 VecEnv step_wait of the adapter)", f"{100 * share:.1f} % of wall time", "<= 10 %",
         verdict(share <= 0.10)],
        [f"one batched env step ({n_envs} envs, residual mode)", fmt_time(per_step), "-", "n/a"],
    ]
    text = ("PPO, residual mode, hover, nominal tier: softpvtol_gym/baselines/data/hyperparams/ppo.yml "
            f"(n_envs={n_envs}, "
            f"n_steps={hp['n_steps']}, batch_size={hp['batch_size']}, n_epochs={hp['n_epochs']}, VecNormalize), "
            f"torch.set_num_threads(1), {steps} env-steps, no callbacks.\n\n")
    text += table(["measure", "value", "target", "verdict"], rows)
    venv.close()
    fast = bench_fast_ppo(quick)
    text += "\n\n" + fast["text"]
    return {"title": "4. PPO training (default train.py configuration; the fast recipe)", "text": text,
            "env_steps": steps, "wall_seconds": wall, "env_steps_per_second": steps / wall,
            "env_seconds": inside["seconds"], "env_share": share, "env_step_seconds": per_step, "fast": fast,
            "targets": {"env_share": {"value": share, "target": "<= 0.10", "pass": share <= 0.10},
                        "fast_env_steps_per_second": {"value": fast["env_steps_per_second"], "target": ">= 50000",
                                                      "pass": fast["env_steps_per_second"] >= 50_000}}}


#: the fast training recipe (softpvtol_gym/baselines/data/hyperparams/recipes.yml)
FAST_RECIPE = "residual-fast"


def bench_fast_ppo(quick: bool) -> dict:
    """The training loop's env-steps/s (rollouts and updates, as train.py builds them: the SB3 adapter,
    VecNormalize, one torch thread) with the fast recipe on the leaderboard's tracking cell (residual mode,
    track_random, nominal), after one untimed rollout. Its quality against the default configuration is
    measured by benchmarks/ppo_speed.py --compare (training runs of 1M steps: too long for this script)."""
    import torch

    import softpvtol_gym.baselines.training.loop as training
    from softpvtol_gym.baselines.config.recipes import load_recipe, recipe_config_fields, recipe_hyperparams
    from softpvtol_gym.baselines.config.run_config import RunConfig

    recipe = load_recipe(FAST_RECIPE)
    hp = recipe_hyperparams(recipe)
    rollout = int(hp["n_envs"]) * int(hp["n_steps"])
    total = rollout * (1 if quick else 8)
    config = RunConfig(**recipe_config_fields(recipe), task="track_random", tier="nominal", timesteps=total, seed=0,
                       n_envs=int(hp["n_envs"]), hyperparams=hp, overrides=list(recipe["hp"]), checkpoint_freq=total,
                       eval_freq=total, eval_episodes=0)
    with tempfile.TemporaryDirectory(prefix="softpvtol-bench-fast-ppo-") as tmp:
        env, vecnorm, model = training.prepare(config, Path(tmp) / "run")
        model.learn(total_timesteps=rollout)  # the first rollout and update: compiles, if the cache is cold
        t0 = time.perf_counter()
        model.learn(total_timesteps=total, reset_num_timesteps=False)
        wall = time.perf_counter() - t0
        steps = int(model.num_timesteps) - rollout
        (vecnorm or env).close()
    rate = steps / wall
    rows = [["training env-steps/s (rollouts + updates)", fmt_rate(rate), ">= 50 k/s", verdict(rate >= 50_000)]]
    text = (f"The fast recipe `{FAST_RECIPE}` (`train.py --recipe {FAST_RECIPE}`: n_envs={hp['n_envs']}, "
            f"n_steps={hp['n_steps']}, batch_size={hp['batch_size']}, n_epochs={hp['n_epochs']}, learning rate "
            f"{hp['learning_rate']}), residual mode, track_random, nominal tier, torch.set_num_threads("
            f"{torch.get_num_threads()}), {steps} env-steps after one untimed rollout, no evaluations.\n\n")
    text += table(["measure", "value", "target", "verdict"], rows)
    return {"recipe": FAST_RECIPE, "hyperparams": hp, "env_steps": steps, "wall_seconds": wall,
            "env_steps_per_second": rate, "text": text}

# ------------------------------------------------------------------------------- 6. time to beat
TIME_TO_BEAT_GOAL = 30.0      # seconds from the start of `python train.py` to the first evaluation above passivity
TRAIN_TOTAL_GOAL = 180.0      # seconds of the whole default `python train.py` (training + final evaluation)


def time_to_beat(evaluations: list[dict], passivity_return: float, launched: float) -> dict | None:
    """The first periodic evaluation whose held-out mean return is above the passivity controller's, with
    its wall-clock seconds since ``launched`` (the epoch time at which train.py was started); None if none."""
    for e in evaluations:
        if e["mean_return"] > passivity_return:
            return {"step": e["step"], "seconds": e["wall_time"] - launched, "mean_return": e["mean_return"],
                    "mean_rms_position_error": e["mean_rms_position_error"]}
    return None


def plot_learning_curve(result: dict, path: Path) -> None:
    """Held-out mean return and RMS position error vs wall-clock seconds since train.py started, with the
    passivity controller's values on the same episodes as lines."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from softpvtol_gym.baselines.util.atomic import atomic_path

    curve, pas = result["curve"], result["passivity"]
    t = [e["seconds"] for e in curve]
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    for ax, key, label in ((axes[0], "mean_return", "held-out mean return"),
                           (axes[1], "mean_rms_position_error", "held-out mean RMS position error [m]")):
        ax.plot(t, [e[key] for e in curve], "o-", ms=3, label="PPO (periodic evaluation)")
        ax.axhline(pas[key], color="k", ls="--", lw=1, label="passivity controller")
        beat = result["beat"]
        if beat is not None:
            ax.axvline(beat["seconds"], color="tab:green", ls=":", lw=1,
                       label=f"first above passivity: {beat['seconds']:.1f} s")
        ax.axvline(result["total_seconds"], color="tab:gray", ls=":", lw=1,
                   label=f"train.py done: {result['total_seconds']:.0f} s")
        ax.set_xlim(left=0)
        ax.set_xlabel("wall-clock seconds since `python train.py` started")
        ax.set_ylabel(label)
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=7)
    axes[0].set_ylim(bottom=max(min(e["mean_return"] for e in curve) - 20, 0))
    fig.suptitle(f"python train.py ({result['description']}); load average {result['loadavg_start'][0]:.2f} at "
                 f"the start, {os.cpu_count()} cores", fontsize=9)
    fig.tight_layout()
    with atomic_path(Path(path)) as tmp:
        fig.savefig(tmp, format="png", dpi=100, metadata={"Software": None})
    plt.close(fig)


def bench_time_to_beat(quick: bool, out: Path | None = None) -> dict:
    """`python train.py` (the default agent) in a fresh process, warm numba cache: the wall-clock seconds from
    its start until its periodic held-out evaluation first beats the passivity controller (mean return on
    the same 10 held-out hover episodes), and of the whole run. --quick: a short run (not the default)."""
    from softpvtol_gym.baselines.config.hyperparams import load_hyperparams

    _fresh_process()  # the numba cache warm, as for item 5
    hp = load_hyperparams("ppo", "residual")
    args = ["--no-progress-bar"]
    if quick:
        args += ["--timesteps", str(2 * int(hp["n_envs"]) * int(hp["n_steps"]))]
    with tempfile.TemporaryDirectory(prefix="softpvtol-bench-train-") as tmp:
        run_dir = Path(tmp) / "run"
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join([str(ROOT), *filter(None, [env.get("PYTHONPATH")])])
        load_start = list(os.getloadavg())
        launched = time.time()
        proc = subprocess.run([sys.executable, str(ROOT / "train.py"), *args, "--out", str(run_dir)], cwd=tmp,
                              env=env, capture_output=True, text=True)
        total = time.time() - launched
        load_end = list(os.getloadavg())
        if proc.returncode != 0:
            raise RuntimeError(f"train.py failed ({proc.returncode}): {proc.stderr[-2000:]}")
        evaluations = json.loads((run_dir / "evaluations.json").read_text())
        report = json.loads((run_dir / "result.json").read_text())
    pas = report["passivity"]["summary"]
    learned = report["ppo"]["summary"]
    beat = time_to_beat(evaluations, pas["mean_return"], launched)
    cfg = report["config"]
    description = (f"PPO, residual mode, hover, nominal; {cfg['timesteps']:,} steps, {cfg['n_envs']} envs x "
                   f"{cfg['hyperparams']['n_steps']} steps, batch {cfg['hyperparams']['batch_size']}, "
                   f"{cfg['hyperparams']['n_epochs']} epochs")
    curve = [{"step": e["step"], "seconds": e["wall_time"] - launched, "mean_return": e["mean_return"],
              "mean_rms_position_error": e["mean_rms_position_error"]} for e in evaluations]
    result = {
        "title": "6. Time to beat the passivity controller (`python train.py`, fresh process)",
        "command": "python train.py" + (" " + " ".join(args) if args else ""),
        "description": description, "beat": beat, "total_seconds": total, "train_seconds": report["train_seconds"],
        "curve": curve, "passivity": {k: pas[k] for k in ("mean_return", "mean_rms_position_error")},
        "final": {k: learned[k] for k in ("mean_return", "mean_rms_position_error", "crash_rate")},
        "loadavg_start": load_start, "loadavg_end": load_end,
        # what train.py printed (the README shows it: a test checks that the README's block matches)
        "stdout": proc.stdout.replace(str(run_dir), "<run dir>"),
    }
    beat_ok = beat is not None and beat["seconds"] <= TIME_TO_BEAT_GOAL
    rows = [
        ["first periodic evaluation above passivity (mean return, 10 held-out episodes)",
         "never" if beat is None else f"{beat['seconds']:.1f} s ({beat['step']:,} steps; {beat['mean_return']:.1f} vs "
         f"{pas['mean_return']:.1f}, RMS position error {beat['mean_rms_position_error']:.3f} m vs "
         f"{pas['mean_rms_position_error']:.3f} m)", f"<= {TIME_TO_BEAT_GOAL:.0f} s", verdict(beat_ok)],
        ["whole run (training + final evaluation)", f"{total:.1f} s (training {report['train_seconds']:.1f} s)",
         f"<= {TRAIN_TOTAL_GOAL:.0f} s", verdict(total <= TRAIN_TOTAL_GOAL)],
        ["final evaluation: PPO vs passivity (return, RMS position error)",
         f"{learned['mean_return']:.1f} / {learned['mean_rms_position_error']:.3f} m vs {pas['mean_return']:.1f} / "
         f"{pas['mean_rms_position_error']:.3f} m", "-", "n/a"],
        ["load average (1 min) at the start / end", f"{load_start[0]:.2f} / {load_end[0]:.2f}", "-", "n/a"],
    ]
    text = (f"`{result['command']}` ({description}) in a fresh process, warm numba cache; seconds from its "
            f"start (wall clock). The periodic evaluation (every `--eval-freq` steps, 10 held-out episodes) is "
            f"part of the timed run.\n\n")
    text += table(["measure", "value", "target", "verdict"], rows)
    if out is not None:
        plot_learning_curve(result, out / "time_to_beat.png")
        text += "\n\n![learning curve](time_to_beat.png)"
    result["text"] = text
    result["targets"] = {
        "seconds_to_beat": {"value": float("nan") if beat is None else beat["seconds"],
                            "target": f"<= {TIME_TO_BEAT_GOAL:.0f}", "pass": beat_ok},
        "train_total_seconds": {"value": total, "target": f"<= {TRAIN_TOTAL_GOAL:.0f}",
                                "pass": total <= TRAIN_TOTAL_GOAL},
    }
    return result
