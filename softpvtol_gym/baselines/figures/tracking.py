"""Tracking plots, learning curves and the GIF of a learned policy against the strongest analytic entry
(the pictures); ``softpvtol figures`` (:mod:`softpvtol_gym.baselines.commands.figures`) draws them."""

from __future__ import annotations

import dataclasses
import math
import statistics
import textwrap
from pathlib import Path

import numpy as np

from softpvtol_gym import PassivityPolicy
from softpvtol_gym.baselines.config.run_config import RunConfig
from softpvtol_gym.baselines.errors import ConfigError
from softpvtol_gym.baselines.evaluation import EVAL_SEED_OFFSET, run_episodes
from softpvtol_gym.baselines.leaderboard.spec import analytic_entries, load_spec
from softpvtol_gym.baselines.training.loop import EVALUATIONS_FILE
from softpvtol_gym.baselines.training.policy import LearnedPolicy
from softpvtol_gym.baselines.util.atomic import atomic_path
from softpvtol_gym.baselines.util.paths import relative_to_root
from softpvtol_gym.baselines.util.safe_load import loads_json
from softpvtol_gym.envs.vector import SoftPVTOLVectorEnv

#: the pictures' file names (under the layout's results: ``<results>/tracking/``)
TRACKING_PNG_NAME, CURVES_PNG_NAME, GIF_NAME = "track_paper.png", "learning_curves.png", "best_policy_track_paper.gif"
FIGURES = ("tracking", "curves", "gif")
REFERENCE = "passivity-bounded"  # the strongest analytic entry of the leaderboard (the env's default loop)
TASK, SELECTION_TIER = "track_paper", "nominal"


# ------------------------------------------------------------------------------- the learned policy
@dataclasses.dataclass(frozen=True)
class Selection:
    """The learned entry drawn, and which of its seeds (``checkpoint``: absolute path)."""

    entry: str
    seed: int
    checkpoint: Path
    seeds: int                    # how many seeds the entry has on track_paper nominal
    seed_rms: float               # the chosen seed's mean RMS position error there [m]
    entry_iqm: float              # the entry's IQM RMS position error there [m]

    def caption(self) -> str:
        return (f"{self.entry}, seed {self.seed}: the median of its {self.seeds} seeds' mean RMS position error on "
                f"{TASK} {SELECTION_TIER} ({self.seed_rms:.3f} m; entry IQM {self.entry_iqm:.3f} m), a typical seed")


def _learned(row: dict) -> bool:
    return row.get("policy") == "ppo" or bool(row.get("checkpoint"))


def select_learned(data: dict, source: str = "leaderboard JSON", base: Path = Path(".")) -> Selection:
    """The learned entry with the lowest IQM RMS position error on track_paper nominal in leaderboard
    ``data`` (``aggregates`` rows: task, tier, entry, policy, rms_position_error_iqm; ``cells``: entry, task,
    tier, seed, checkpoint, episodes), and its median seed. Cells of entries trained on another task count
    like any other (a ``train_task`` field, where rows carry one, must match between row and cells). A relative
    checkpoint path in a cell is taken relative to ``base`` (where the jobs ran)."""
    if not isinstance(data, dict) or not isinstance(data.get("aggregates"), list) \
            or not isinstance(data.get("cells"), list):
        raise ConfigError(f"{source} is not a leaderboard JSON (expected an object with 'aggregates' and 'cells' "
                          f"lists); re-create it with python baselines/leaderboard.py")
    try:
        rows = [r for r in data["aggregates"] if r["task"] == TASK and r["tier"] == SELECTION_TIER and _learned(r)]
        if not rows:
            raise ConfigError(f"{source} has no learned entry evaluated on {TASK} {SELECTION_TIER}; pass --checkpoint")
        best = min(rows, key=lambda r: (float(r["rms_position_error_iqm"]), r["entry"]))
        cells = [c for c in data["cells"]
                 if c["entry"] == best["entry"] and c["task"] == TASK and c["tier"] == SELECTION_TIER
                 and c.get("train_task") == best.get("train_task", c.get("train_task"))]
        seeds = [int(c["seed"]) for c in cells]
        if not cells or len(set(seeds)) != len(seeds) or any(not c.get("checkpoint") for c in cells):
            raise ConfigError(f"{source}: the cells of entry {best['entry']!r} on {TASK} {SELECTION_TIER} are not one "
                              f"checkpoint per seed (seeds {sorted(seeds)}); pass --checkpoint")
        ranked = sorted(((statistics.fmean(float(e["rms_position_error"]) for e in c["episodes"]), int(c["seed"]), c)
                         for c in cells), key=lambda t: (t[0], t[1]))
    except (KeyError, TypeError, ValueError, statistics.StatisticsError) as exc:
        raise ConfigError(f"{source} is not a usable leaderboard JSON ({type(exc).__name__}: {exc}); re-create it "
                          f"with python baselines/leaderboard.py") from None
    rms, seed, cell = ranked[(len(ranked) - 1) // 2]
    path = Path(cell["checkpoint"])
    return Selection(entry=best["entry"], seed=seed, checkpoint=path if path.is_absolute() else Path(base) / path,
                     seeds=len(ranked), seed_rms=rms, entry_iqm=float(best["rms_position_error_iqm"]))


def read_leaderboard(path: Path) -> dict:
    if not Path(path).is_file():
        raise ConfigError(f"no leaderboard JSON at {path}; create it with python baselines/leaderboard.py or pass "
                          f"--checkpoint")
    try:
        return loads_json(Path(path).read_text(encoding="utf-8"), str(path))
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise ConfigError(f"leaderboard JSON {path} is not valid JSON ({exc})") from None


def load_learned(checkpoint: Path, caption: str | None = None):
    """``(policy, run_config, label, caption)`` of a checkpoint (safe format only; nothing is unpickled)."""

    if not Path(checkpoint).exists():
        raise ConfigError(f"checkpoint {checkpoint} does not exist")
    policy, config = LearnedPolicy.load(Path(checkpoint))
    label = f"{config.algo.upper()}-{config.action_mode} (trained on {config.task} {config.tier})"
    if caption is None:
        caption = f"seed {config.seed}, given by --checkpoint {_shown(Path(checkpoint))}"
    return policy, config, label, caption


def _shown(path: Path) -> str:
    """``path`` relative to the current directory where it lies in it (shorter titles)."""
    return relative_to_root(path, Path.cwd())


def reference_env_kwargs(spec_path: Path) -> dict:
    """Env arguments of passivity-bounded as the leaderboard's jobs pass them (allocation, loop)."""

    for p in analytic_entries(load_spec(spec_path)):
        if p["name"] == REFERENCE and p["kind"] == "passivity":
            return {"allocation": p["allocation"], "controller_loop": p.get("loop", p["allocation"])}
    raise ConfigError(f"leaderboard spec {spec_path} has no passivity entry named {REFERENCE!r}")


# ------------------------------------------------------------------------------------- episodes
def run_trajectory(policy, action_mode: str, task: str, tier: str, seed: int, seconds: float | None,
                   env_kwargs: dict) -> dict:
    """One deterministic episode on a one-env vector env: time, position, reference, how it ended."""


    env = SoftPVTOLVectorEnv(num_envs=1, action_mode=action_mode, task=task, tier=tier, **env_kwargs)
    obs, _ = env.reset(seed=seed)
    t, pos, ref = [0.0], [env.sim.q[0, :2].copy()], [env.sim.qr[0, :2].copy()]
    limit = math.inf if seconds is None else round(seconds * 100)
    crashed, reason, steps = False, "", 0
    start = np.ones(1, bool)
    while steps < limit:
        action, _ = policy.predict(obs, episode_start=start, deterministic=True)
        start[:] = False
        obs, _, terminated, truncated, info = env.step(action)
        steps += 1
        t.append(float(info["time"][0]))
        pos.append(env.sim.q[0, :2].copy())
        ref.append(env.sim.qr[0, :2].copy())
        if terminated[0]:
            crashed, reason = True, str(info["termination_reason"][0])
        if terminated[0] or truncated[0]:
            break
    env.close()
    pos, ref = np.array(pos), np.array(ref)
    err = np.linalg.norm(pos - ref, axis=1)
    return {"t": np.array(t), "pos": pos, "ref": ref, "err": err, "crashed": crashed, "reason": reason,
            "rms": float(np.sqrt(np.mean(err[1:] ** 2))) if steps else float("nan")}


def tracking_figure(tiers, seed: int, seconds: float | None, learned, passivity_kwargs: dict, out: Path) -> dict:
    """Write the tracking plot; the RMS position error and crash of each drawn episode (for the log)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt


    policy, config, label, caption = learned
    analytic = PassivityPolicy.from_env(SoftPVTOLVectorEnv(num_envs=1, action_mode="actuators", task=TASK,
                                                           **passivity_kwargs))
    runs = {}
    for tier in tiers:
        runs[tier] = {
            REFERENCE: run_trajectory(analytic, "actuators", TASK, tier, seed, seconds, passivity_kwargs),
            label: run_trajectory(policy, config.action_mode, TASK, tier, seed, seconds, config.eval_env_kwargs()),
        }
    colors = {REFERENCE: "tab:blue", label: "tab:orange"}
    rows = (("x [m]", lambda r: r["pos"][:, 0], lambda r: r["ref"][:, 0]),
            ("z [m]", lambda r: r["pos"][:, 1], lambda r: r["ref"][:, 1]),
            ("|e| position error [m]", lambda r: r["err"], None))
    fig, axes = plt.subplots(len(rows), len(tiers), figsize=(3.4 * len(tiers) + 1.2, 8.0), squeeze=False,
                             sharex="col", sharey="row")
    for j, tier in enumerate(tiers):
        for i, (ylabel, value, reference) in enumerate(rows):
            ax = axes[i][j]
            first = runs[tier][REFERENCE]
            if reference is not None:
                ax.plot(first["t"], reference(first), color="black", lw=1.0, ls="--", label="reference")
            for name, run in runs[tier].items():
                ax.plot(run["t"], value(run), color=colors[name], lw=1.2, label=name)
                if run["crashed"]:
                    ax.plot(run["t"][-1], value(run)[-1], marker="X", ms=11, color="red", mec="black", zorder=5,
                            ls="none", label="crash (episode ends early)")
                    ax.axvline(run["t"][-1], color="red", lw=0.8, ls=":")
            if i == 0:
                ax.set_title(tier)
            if j == 0:
                ax.set_ylabel(ylabel)
            if i == len(rows) - 1:
                ax.set_xlabel("t [s]")
                ax.set_yscale("log")
                lines = [(f"RMS {run['rms']:.2f} m" + (f", crash at {run['t'][-1]:.1f} s ({run['reason']})"
                                                       if run["crashed"] else ""), colors[name])
                         for name, run in runs[tier].items()]
                for k, (text, color) in enumerate(lines):
                    ax.text(0.97, 0.95 - 0.09 * k, text, transform=ax.transAxes, ha="right", va="top", fontsize=7.5,
                            color=color, bbox=dict(facecolor="white", edgecolor="none", alpha=0.7, pad=1))
            ax.grid(True, alpha=0.3)
    handles = {}
    for ax in axes.flat:
        for h, name in zip(*ax.get_legend_handles_labels()):
            handles.setdefault(name, h)
    fig.legend(handles.values(), handles.keys(), loc="lower center", ncol=len(handles), fontsize=9)
    width = max(60, 28 * len(tiers))  # characters per title line
    fig.suptitle("\n".join(textwrap.wrap(f"{TASK}, evaluation episode seed {seed}: {REFERENCE} (actuators mode) vs "
                                         f"{label}. Learned policy: {caption}", width)), fontsize=9)
    fig.tight_layout(rect=(0, 0.04, 1, 1))
    with atomic_path(out) as tmp:
        fig.savefig(tmp, format="png", dpi=100, metadata={"Software": None})
    plt.close(fig)
    return {tier: {name: episode_summary(run) for name, run in r.items()} for tier, r in runs.items()}


#: the summary's thresholds: when the position error is first below CLOSE, its largest value after SETTLED
CLOSE, SETTLED = 0.2, 10.0  # [m], [s]


def episode_summary(run: dict) -> dict:
    """RMS position error, crash, length, the first time |e| < CLOSE (None: never) and max |e| from SETTLED on."""

    below = np.flatnonzero(run["err"] < CLOSE)
    late = run["err"][run["t"] >= SETTLED]
    return {"rms": run["rms"], "crashed": run["crashed"], "seconds": float(run["t"][-1]),
            "first_close": float(run["t"][below[0]]) if below.size else None,
            "max_settled": float(late.max()) if late.size else None}


def _summary_text(v: dict) -> str:
    close = "never" if v["first_close"] is None else f"at {v['first_close']:.2f} s"
    settled = "" if v["max_settled"] is None else f", max |e| from {SETTLED:g} s on {v['max_settled']:.3f} m"
    return (f"RMS {v['rms']:.3f} m over {v['seconds']:.1f} s{' (crash)' if v['crashed'] else ''}, |e| < {CLOSE:g} m "
            f"first {close}{settled}")


# ------------------------------------------------------------------------------- learning curves
def read_curves(runs_dir: Path) -> list[dict]:
    """Every learned run under ``runs_dir`` with an evaluations.json: its config and curve."""

    out = []
    for path in sorted(Path(runs_dir).glob(f"ppo[_-]*/seed_*/{EVALUATIONS_FILE}")):  # ppo-<recipe>_...: recipe cells
        config = RunConfig.load(path.parent / "config.yaml")
        try:
            history = loads_json(path.read_text(encoding="utf-8"), str(path))
            points = [(int(h["step"]), h.get("train_seconds"), float(h["mean_rms_position_error"])) for h in history]
        except (OSError, UnicodeDecodeError, ValueError, KeyError, TypeError) as exc:
            raise ConfigError(f"{path} is not an evaluations.json of a training run ({exc})") from None
        if points:
            out.append({"cell": path.parent.parent.name, "config": config, "points": points,
                        "timed": all(s is not None for _, s, _ in points)})
    if not out:
        raise ConfigError(f"no learned run with an evaluations.json under {runs_dir} (expected "
                          f"ppo_*/seed_*/evaluations.json)")
    return out


def _cell_name(cell: str, cfg) -> str:
    """A learned cell's legend name: its recipe (job folder ``ppo-<recipe>_<task>_<tier>``) or its action mode."""
    suffix = f"_{cfg.task}_{cfg.tier}"
    if cell.startswith("ppo-") and cell.endswith(suffix):
        return f"PPO {cell[len('ppo-'):-len(suffix)]}"
    return f"PPO-{cfg.action_mode}"


def heldout_reference(task: str, tier: str, configs: list, passivity_kwargs: dict) -> float:
    """passivity-bounded's mean RMS position error on each run's held-out episodes, median over the runs."""

    policy = PassivityPolicy.from_env(SoftPVTOLVectorEnv(num_envs=1, action_mode="actuators", task=task,
                                                         **passivity_kwargs))
    span = max(c.seed + c.eval_episodes for c in configs)  # run i's episodes: seeds 1000000 + seed + [0, eval_episodes)
    episodes = run_episodes(policy, "actuators", task, tier, span, EVAL_SEED_OFFSET, env_kwargs=passivity_kwargs)
    per_run = [statistics.fmean(e["rms_position_error"] for e in episodes[c.seed:c.seed + c.eval_episodes])
               for c in configs]
    return statistics.median(per_run)


def leaderboard_reference(data: dict, task: str, tier: str) -> float | None:
    for r in data.get("aggregates", []) if isinstance(data, dict) else []:
        if r.get("entry") == REFERENCE and r.get("task") == task and r.get("tier") == tier:
            return float(r["rms_position_error_iqm"])
    return None


def curves_figure(curves: list[dict], reference: str, passivity_kwargs: dict, leaderboard: dict | None,
                  out: Path) -> dict:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt


    tasks = sorted({c["config"].task for c in curves})
    fig, axes = plt.subplots(1, len(tasks), figsize=(5.6 * len(tasks), 5.0), squeeze=False)
    cells = sorted({c["cell"] for c in curves})
    colors = {cell: plt.get_cmap("tab10")(i % 10) for i, cell in enumerate(cells)}
    levels = {}
    for ax, task in zip(axes[0], tasks):
        mine = [c for c in curves if c["config"].task == task]
        timed = all(c["timed"] for c in mine)
        x_of = (lambda p: p[1]) if timed else (lambda p: p[0])
        for cell in sorted({c["cell"] for c in mine}):
            runs = [c for c in mine if c["cell"] == cell]
            cfg = runs[0]["config"]
            for run in runs:
                ax.plot([x_of(p) for p in run["points"]], [p[2] for p in run["points"]], color=colors[cell], lw=0.6,
                        alpha=0.45)
            n = min(len(r["points"]) for r in runs)
            med_x = [float(np.median([x_of(r["points"][k]) for r in runs])) for k in range(n)]
            med_y = [float(np.median([r["points"][k][2] for r in runs])) for k in range(n)]
            ax.plot(med_x, med_y, color=colors[cell], lw=2.2, marker="o", ms=3,
                    label=f"{_cell_name(cell, cfg)}, {cfg.tier} (median of {len(runs)} seeds)")
        for style, tier in zip(("--", "-.", ":"), sorted({c["config"].tier for c in mine})):
            configs = [c["config"] for c in mine if c["config"].tier == tier]
            if reference == "heldout":
                level = heldout_reference(task, tier, configs, passivity_kwargs)
                text = f"{REFERENCE}, {tier}: same held-out episodes (median of seeds)"
            else:
                level = leaderboard_reference(leaderboard, task, tier)
                text = f"{REFERENCE}, {tier}: leaderboard IQM (20 evaluation episodes)"
            if level is not None:
                levels[f"{task}/{tier}"] = level
                ax.axhline(level, color="0.3", ls=style, lw=1.3, label=text)
        ax.set_yscale("log")
        note = "" if timed else "\n(runs saved before train_seconds was recorded: x = steps)"
        ax.set_title(f"trained on {task}{note}", fontsize=10)
        ax.set_xlabel("training wall-clock time [s] (incl. periodic evaluations)" if timed else "environment steps")
        ax.set_ylabel("held-out mean RMS position error [m]")
        ax.grid(True, alpha=0.3, which="both")
        ax.legend(fontsize=7)
    fig.suptitle("Periodic held-out evaluations during training (thin: seeds, thick: median)", fontsize=10)
    fig.tight_layout()
    with atomic_path(out) as tmp:
        fig.savefig(tmp, format="png", dpi=100, metadata={"Software": None})
    plt.close(fig)
    return levels
