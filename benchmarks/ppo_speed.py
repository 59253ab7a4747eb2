"""PPO configurations compared by time to beat the passivity controller.

    python benchmarks/ppo_speed.py --mode residual --timesteps 3000000 \
        --config "default16=n_envs=16;n_steps=256;batch_size=256;n_epochs=10" \
        --config "n256=n_envs=256;n_steps=64;batch_size=4096;n_epochs=5" --out benchmarks/ppo_speed_residual.json

Each configuration is the YAML entry of the mode (``softpvtol_gym/baselines/data/hyperparams/ppo.yml``) with the given
overrides, trained by the same code as ``train.py`` (:func:`softpvtol_gym.baselines.training.loop.train`: the
native vector env through the SB3 adapter, VecNormalize, ``torch.set_num_threads(1)``, the periodic held-out evaluation
of 10 episodes every ``--eval-freq`` steps). Per configuration it records

* the learning curve: per periodic evaluation the env steps, the seconds since training started, the
  held-out mean return and RMS position error;
* the passivity controller on the same held-out episodes (the line to beat);
* ``steps_to_beat`` / ``seconds_to_beat``: the first evaluation whose mean return is above passivity's
  (``null`` if none within ``--timesteps``);
* the throughput of the whole training loop (env steps / wall seconds, evaluations included and
  excluded) and the share of the wall time spent in the env's ``step`` (the adapter's ``step_wait``).

Wall-clock figures depend on the machine's load: the JSON records ``os.getloadavg()`` before and after
each configuration. Time to beat = steps to beat x wall time per step, the selection criterion. Each run
is a fresh interpreter (as ``python train.py``). ``--table`` prints the Markdown table of a results file
(benchmarks/STUDIES.md, "The PPO defaults").
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from softpvtol_gym.baselines.util.atomic import atomic_write_text  # noqa: E402


def parse_config(text: str, mode: str) -> tuple[str, list[str]]:
    """``"name=k1=v1;k2=v2"`` -> ``("name", ["k1=v1", "k2=v2"])``; ``"name="`` -> no overrides;
    ``"name=recipe:NAME"`` -> the ``hp`` overrides of a training recipe (recipes.yml) of action mode ``mode``
    that sets nothing else."""
    name, sep, rest = text.partition("=")
    if not sep or not name:
        raise SystemExit(f"--config must look like name=key=value;key=value (name= for the YAML entry), got {text!r}")
    if rest.startswith("recipe:"):
        from softpvtol_gym.baselines.config.recipes import load_recipe

        recipe = load_recipe(rest[len("recipe:"):])
        others = [k for k in ("controller_loop", "start_error_curriculum", "env_options", "train_env_options")
                  if recipe[k]]
        if recipe["algo"] != "ppo" or others:
            raise SystemExit(f"--config {text!r}: this script trains PPO entries with hp overrides only; the recipe "
                             f"is {recipe['algo']} and sets {others}")
        if recipe["action_mode"] != mode:
            raise SystemExit(f"--config {text!r}: the recipe is for the {recipe['action_mode']} mode, this run's "
                             f"--mode is {mode}; pass --mode {recipe['action_mode']}")
        return name, list(recipe["hp"])
    return name, [item for item in rest.split(";") if item]


def run_one(name: str, overrides: list[str], mode: str, timesteps: int, eval_freq: int, seed: int,
            task: str = "hover", tier: str = "nominal") -> dict:
    import softpvtol_gym.baselines.training.loop as training
    from softpvtol_gym import PassivityPolicy
    from softpvtol_gym.baselines.config.hyperparams import apply_overrides, load_hyperparams
    from softpvtol_gym.baselines.config.run_config import RunConfig
    from softpvtol_gym.baselines.evaluation import EVAL_SEED_OFFSET, evaluate
    from softpvtol_gym.envs.vector import SoftPVTOLVectorEnv

    hp = apply_overrides(load_hyperparams("ppo", mode), overrides)
    config = RunConfig(algo="ppo", action_mode=mode, task=task, tier=tier, timesteps=timesteps, seed=seed,
                       n_envs=int(hp["n_envs"]), hyperparams=hp, overrides=overrides, checkpoint_freq=timesteps,
                       eval_freq=eval_freq, eval_episodes=10)
    probe = SoftPVTOLVectorEnv(num_envs=1, **config.env_kwargs())
    passivity = evaluate(PassivityPolicy.from_env(probe), mode, task, tier, 10, EVAL_SEED_OFFSET + seed)
    load_before = os.getloadavg()
    with tempfile.TemporaryDirectory(prefix="issue-fast-ppo-speed-") as tmp:
        run_dir = Path(tmp) / "run"
        env, vecnorm, model = training.prepare(config, run_dir)
        inside = {"env": 0.0, "eval": 0.0}
        step_wait = env.step_wait

        def timed_step_wait():
            t0 = time.perf_counter()
            out = step_wait()
            inside["env"] += time.perf_counter() - t0
            return out

        env.step_wait = timed_step_wait
        run_episodes = training.run_episodes

        def timed_run_episodes(*args, **kwargs):
            t0 = time.perf_counter()
            out = run_episodes(*args, **kwargs)
            inside["eval"] += time.perf_counter() - t0
            return out

        training.run_episodes = timed_run_episodes
        try:
            result = training.train(config, run_dir, prepared=(env, vecnorm, model))
        finally:
            training.run_episodes = run_episodes
        history = json.loads((run_dir / training.EVALUATIONS_FILE).read_text())
    wall = result["seconds"]
    steps = result["num_timesteps"]
    line = passivity["summary"]["mean_return"]
    curve = [{"step": e["step"], "seconds": e["train_seconds"], "mean_return": e["mean_return"],
              "mean_rms_position_error": e["mean_rms_position_error"], "crash_rate": e["crash_rate"]}
             for e in history]
    first = next((e for e in curve if e["mean_return"] > line), None)
    return {
        "name": name, "overrides": overrides, "action_mode": mode, "task": task, "tier": tier, "seed": seed,
        "timesteps": steps,
        "hyperparams": hp, "wall_seconds": wall, "eval_seconds": inside["eval"], "env_seconds": inside["env"],
        "steps_per_second": steps / wall, "steps_per_second_without_evaluations": steps / (wall - inside["eval"]),
        "env_share": inside["env"] / wall,
        "passivity": {k: passivity["summary"][k] for k in ("mean_return", "mean_rms_position_error", "crash_rate")},
        "steps_to_beat": None if first is None else first["step"],
        "seconds_to_beat": None if first is None else first["seconds"],
        "best_return": max(e["mean_return"] for e in curve) if curve else None,
        "final": curve[-1] if curve else None,
        "curve": curve, "loadavg_before": list(load_before), "loadavg_after": list(os.getloadavg()),
    }


def markdown_table(results: list[dict]) -> str:
    """One row per run of a results file (the table of benchmarks/STUDIES.md, "The PPO defaults")."""
    lines = ["| mode | configuration | seed | steps to beat passivity | seconds to beat (load) | return at the end | "
             "env-steps/s (evaluations excluded) | env share |", "|---|---|---|---|---|---|---|---|"]
    for r in results:
        hp = r["hyperparams"]
        config = (f"{r['name']}: {hp['n_envs']} x {hp['n_steps']}, batch {hp['batch_size']}, {hp['n_epochs']} epochs, "
                  f"lr {hp['learning_rate']}, target_kl {hp.get('target_kl')}")
        beat = "never" if r["steps_to_beat"] is None else f"{r['steps_to_beat']:,}"
        secs = "-" if r["seconds_to_beat"] is None else f"{r['seconds_to_beat']:.0f} s"
        load = r["loadavg_before"][0]
        where = (r.get("task", "hover"), r.get("tier", "nominal"))
        mode = r["action_mode"] + ("" if where == ("hover", "nominal") else f", {where[0]} / {where[1]}")
        lines.append(f"| {mode} | {config} | {r['seed']} | {beat} | {secs} ({load:.1f}) | "
                     f"{r['final']['mean_return']:.1f} vs {r['passivity']['mean_return']:.1f} at {r['timesteps']:,} | "
                     f"{r['steps_per_second'] / 1e3:.1f} k ({r['steps_per_second_without_evaluations'] / 1e3:.1f} k) | "
                     f"{100 * r['env_share']:.1f} % |")
    return "\n".join(lines)


def compare(results: list[dict], baseline: str, candidate: str) -> dict:
    """The ``candidate`` configuration against ``baseline`` on the seeds both ran (same task,
    tier and mode). Quality is the mean over those seeds of the final held-out evaluation (10 episodes per
    seed): RMS position error and return. The candidate passes when its mean final RMS error is at most the
    baseline's, its mean return at least the baseline's, its mean training wall time (evaluations included) at
    most a third of the baseline's, and its env-steps/s at least 50 k: those of the training loop, rollouts and
    updates (the periodic held-out evaluations, which train.py runs every --eval-freq steps, excluded; the rate
    with them is reported beside it)."""
    runs = {name: {r["seed"]: r for r in results if r["name"] == name} for name in (baseline, candidate)}
    for name, by_seed in runs.items():
        if not by_seed:
            raise SystemExit(f"no run named {name!r} in the results (names: {sorted({r['name'] for r in results})})")
    seeds = sorted(set(runs[baseline]) & set(runs[candidate]))
    if not seeds:
        raise SystemExit(f"{baseline!r} and {candidate!r} share no seed")
    out = {"seeds": seeds}
    for name in (baseline, candidate):
        rs = [runs[name][s] for s in seeds]
        cells = {(r["action_mode"], r.get("task", "hover"), r.get("tier", "nominal")) for r in rs}
        if len(cells) != 1:
            raise SystemExit(f"the runs of {name!r} are of different cells: {sorted(cells)}")
        out[name] = {
            "cell": cells.pop(), "hyperparams": rs[0]["hyperparams"],
            "timesteps": [r["timesteps"] for r in rs],
            "final_rms": [r["final"]["mean_rms_position_error"] for r in rs],
            "final_return": [r["final"]["mean_return"] for r in rs],
            "crash_rate": [r["final"]["crash_rate"] for r in rs],
            "wall_seconds": [r["wall_seconds"] for r in rs],
            "steps_per_second": [r["steps_per_second"] for r in rs],
            "steps_per_second_without_evaluations": [r["steps_per_second_without_evaluations"] for r in rs],
            "loadavg_before": [r["loadavg_before"][0] for r in rs],
        }
    b, c = out[baseline], out[candidate]
    if b["cell"] != c["cell"]:
        raise SystemExit(f"{baseline!r} ran {b['cell']}, {candidate!r} ran {c['cell']}: not the same cell")
    mean = statistics.fmean
    out["checks"] = {
        "final RMS error at most the baseline's": mean(c["final_rms"]) <= mean(b["final_rms"]),
        "final return at least the baseline's": mean(c["final_return"]) >= mean(b["final_return"]),
        "wall time at most a third of the baseline's": mean(c["wall_seconds"]) <= mean(b["wall_seconds"]) / 3,
        "at least 50 k env-steps/s, rollouts and updates": mean(c["steps_per_second_without_evaluations"]) >= 50_000,
    }
    out["passed"] = all(out["checks"].values())
    return out


def compare_table(results: list[dict], baseline: str, candidate: str) -> str:
    """The Markdown table of :func:`compare` (benchmarks/README.md, the fast recipe), its checks below it."""
    cmp = compare(results, baseline, candidate)
    mean = statistics.fmean

    def spread(xs, fmt):
        return f"{fmt.format(mean(xs))} ({fmt.format(min(xs))}-{fmt.format(max(xs))})"

    lines = [f"seeds {', '.join(map(str, cmp['seeds']))}; mean over the seeds (lowest-highest)", "",
             "| configuration | steps | final RMS position error [m] | final return | crash rate | wall seconds | "
             "env-steps/s: rollouts and updates; with the evaluations | load |", "|---|---|---|---|---|---|---|---|"]
    for name in (baseline, candidate):
        r, hp = cmp[name], cmp[name]["hyperparams"]
        config = (f"{name}: {hp['n_envs']} x {hp['n_steps']}, batch {hp['batch_size']}, {hp['n_epochs']} epochs, "
                  f"lr {hp['learning_rate']}")
        lines.append(f"| {config} | {spread(r['timesteps'], '{:,.0f}')} | {spread(r['final_rms'], '{:.3f}')} | "
                     f"{spread(r['final_return'], '{:.1f}')} | {mean(r['crash_rate']):.2f} | "
                     f"{spread(r['wall_seconds'], '{:.1f}')} | "
                     f"{spread([v / 1e3 for v in r['steps_per_second_without_evaluations']], '{:.1f} k')}; "
                     f"{spread([v / 1e3 for v in r['steps_per_second']], '{:.1f} k')} | "
                     f"{max(r['loadavg_before']):.2f} |")
    lines.append("")
    lines += [f"- {'pass' if ok else 'FAIL'}: {what}" for what, ok in cmp["checks"].items()]
    return "\n".join(lines)


def plot_compare(results: list[dict], names: list[str], path: Path) -> None:
    """Held-out RMS position error and return against training wall seconds, one line per run of ``names``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from softpvtol_gym.baselines.util.atomic import atomic_path

    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    for n, name in enumerate(names):
        runs = [r for r in results if r["name"] == name]
        for k, r in enumerate(runs):
            t = [e["seconds"] for e in r["curve"]]
            for ax, key in ((axes[0], "mean_rms_position_error"), (axes[1], "mean_return")):
                ax.plot(t, [e[key] for e in r["curve"]], color=f"C{n}", marker=".", alpha=0.8,
                        label=name if k == 0 else None)
    passivity = next(r["passivity"] for r in results if r["name"] in names)
    for ax, key, label in ((axes[0], "mean_rms_position_error", "held-out mean RMS position error [m]"),
                           (axes[1], "mean_return", "held-out mean return")):
        ax.axhline(passivity[key], color="k", ls="--", lw=1, label="passivity (seed 0's episodes)")
        ax.set_xlabel("training wall time [s]")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    axes[0].set_yscale("log")
    axes[0].legend()
    fig.suptitle("PPO configurations: learning curve against wall time (python benchmarks/ppo_speed.py --plot)")
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=90)
    plt.close(fig)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--mode", default="residual", choices=("residual", "virtual", "actuators"))
    ap.add_argument("--task", default="hover", help="the training and evaluation task (default: hover)")
    ap.add_argument("--tier", default="nominal", help="the training and evaluation tier (default: nominal)")
    ap.add_argument("--config", action="append", help="name=key=value;key=value (repeatable)")
    ap.add_argument("--table", action="store_true", help="print the Markdown table of --out and exit")
    ap.add_argument("--compare", nargs=2, metavar=("BASELINE", "CANDIDATE"),
                    help="print the comparison of two configurations of --out and exit")
    ap.add_argument("--plot", type=Path, help="with --compare: also draw their learning curves against wall time "
                                              "to this PNG")
    ap.add_argument("--timesteps", type=int, default=2_000_000)
    ap.add_argument("--eval-freq", type=int, default=50_000)
    ap.add_argument("--seed", type=int, action="append", help="training seed (repeatable; default 0)")
    ap.add_argument("--out", type=Path, required=True, help="JSON file (results are appended per configuration)")
    args = ap.parse_args(argv)
    results = json.loads(args.out.read_text()) if args.out.is_file() else []
    if args.table:
        print(markdown_table(results))
        return 0
    if args.compare:
        print(compare_table(results, *args.compare))
        if args.plot:
            plot_compare(results, list(args.compare), args.plot)
        return 0
    if not args.config:
        ap.error("--config is required (or --table)")
    for text in args.config:
        name, overrides = parse_config(text, args.mode)
        for seed in args.seed or [0]:
            # each run in a fresh interpreter, as `python train.py` runs: runs in one process are not
            # independent (a second run with the same seed differs from a fresh process's)
            with multiprocessing.get_context("spawn").Pool(1) as pool:
                r = pool.apply(run_one, (name, overrides, args.mode, args.timesteps, args.eval_freq, seed, args.task,
                                         args.tier))
            r["command"] = "python benchmarks/ppo_speed.py " + " ".join(sys.argv[1:] if argv is None else argv)
            results.append(r)
            atomic_write_text(args.out, json.dumps(results, indent=1) + "\n")
            beat = ("never" if r["steps_to_beat"] is None
                    else f"{r['steps_to_beat']:,} steps, {r['seconds_to_beat']:.1f} s")
            print(f"{args.mode} {args.task}/{args.tier} {name} seed {seed}: "
                  f"{r['steps_per_second'] / 1e3:.1f} k steps/s "
                  f"({r['steps_per_second_without_evaluations'] / 1e3:.1f} k without evaluations), env share "
                  f"{100 * r['env_share']:.1f} %, beats passivity ({r['passivity']['mean_return']:.1f}) after {beat}; "
                  f"best {r['best_return']:.1f}, final {r['final']['mean_return']:.1f} / "
                  f"{r['final']['mean_rms_position_error']:.3f} m; load {r['loadavg_before'][0]:.2f}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
