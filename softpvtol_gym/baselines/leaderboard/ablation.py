"""The ablation of the learned controller: what each training ingredient does, per time window.

An ablation spec (``baselines/ablation.yml`` in a checkout; the leaderboard spec's format) lists one trained cell
per recipe (softpvtol_gym/baselines/data/hyperparams/recipes.yml), each adding one ingredient to the one before.
:func:`build` scores every recipe's runs as the leaderboard does (IQM and 95 % stratified-bootstrap CI per
window and crash rate, :func:`softpvtol_gym.baselines.leaderboard.stats.aggregate`) and, as its first row, a
reference cell of the leaderboard itself (by default v2's PPO-residual cell trained on the same task and tier:
the bounded base loop and no aids), restricted to the ablation's seeds. :func:`render_markdown` gives the table
of docs/baselines.md, "Ablation"; nothing is dropped, whichever way a row goes.
"""

from __future__ import annotations

from pathlib import Path

from softpvtol_gym.baselines.config.recipes import load_recipes
from softpvtol_gym.baselines.errors import ConfigError
from softpvtol_gym.baselines.leaderboard.render import num
from softpvtol_gym.baselines.leaderboard.spec import load_spec
from softpvtol_gym.baselines.leaderboard.stats import aggregate, collect

#: the windows of the table: (column name, per-episode metric)
ABLATION_WINDOWS = (("first quarter", "rms_position_error_transient"), ("last half", "rms_position_error_steady"))
#: the tiers of the table (every tier is in the JSON)
TABLE_TIERS = ("nominal", "wind", "hard", "model_gap")
REFERENCE_LABEL = "v2: PPO-residual, bounded base loop, no aids"


def _steps(n: int) -> str:
    return f"{n / 1e6:g}M steps" if n >= 1_000_000 else f"{n:,} steps"


def _rows_of(cells: list[dict], label: str) -> list[dict]:
    for c in cells:
        c["entry"] = label
    return aggregate(cells)


def build(ablation_spec: Path, ablation_root: Path, leaderboard_spec: Path, leaderboard_root: Path,
          reference: tuple[str, str, str] | None = ("residual", "track_random", "hard")) -> dict:
    """Per recipe of the ablation spec (in its order; ``reference``, a leaderboard cell (action mode, task, tier)
    without recipe, first): its aggregate rows per (task, tier). ConfigError if a run is missing."""
    spec = load_spec(ablation_spec)
    seeds = sorted(spec["seeds"])
    recipes = load_recipes()
    cells, missing = collect(ablation_root, ablation_spec)
    if missing:
        raise ConfigError(f"the ablation lacks results: {missing[:5]}{' ...' if len(missing) > 5 else ''}; run "
                          f"python baselines/run_jobs.py --spec {ablation_spec} --root {ablation_root}")
    out = []
    ref_cells = collect(leaderboard_root, leaderboard_spec)[0] if reference is not None else []
    if reference is not None:
        mode, task, tier = reference
        ref = [c for c in ref_cells if c["policy"] == "ppo" and not c.get("recipe") and c["action_mode"] == mode
               and c["train_task"] == task and c["train_tier"] == tier and c["seed"] in seeds]
        if not ref:
            raise ConfigError(f"the leaderboard under {leaderboard_root} holds no PPO-{mode} cell trained on {task} "
                              f"({tier}) with the seeds {seeds}")
        out.append({"label": REFERENCE_LABEL, "recipe": None, "description": "leaderboard v2's cell",
                    "timesteps": ref[0]["timesteps"], "seeds": sorted({c["seed"] for c in ref}),
                    "rows": _rows_of(ref, REFERENCE_LABEL)})
    for cell in spec["trained"]:
        name = cell.get("recipe")
        mine = [c for c in cells if c.get("recipe") == name and c["train_task"] == cell["task"]
                and c["train_tier"] == cell["tier"] and c["action_mode"] == cell["action_mode"]]
        label = f"{name or 'PPO-' + cell['action_mode']}, {_steps(cell['timesteps'])}"
        out.append({"label": label, "recipe": name, "timesteps": cell["timesteps"],
                    "description": recipes[name]["description"] if name else "the action mode's PPO entry",
                    "seeds": sorted({c["seed"] for c in mine}), "rows": _rows_of(mine, label)})
    if reference is not None:  # the leaderboard's own recipe cells of the same mode, task and tier: their budget
        for cell in load_spec(leaderboard_spec)["trained"]:
            name = cell.get("recipe")
            if name is None or (cell["action_mode"], cell["task"], cell["tier"]) != reference or any(
                    (c.get("recipe"), c["timesteps"]) == (name, cell["timesteps"]) for c in spec["trained"]):
                continue  # not of the reference's mode, task and tier, or the same runs as a row above
            mine = [c for c in ref_cells if c.get("recipe") == name and c["train_task"] == cell["task"]
                    and c["train_tier"] == cell["tier"] and c["seed"] in seeds]
            if not mine:
                raise ConfigError(f"the leaderboard under {leaderboard_root} lacks the runs of its {name} cell (seeds "
                                  f"{seeds})")
            label = f"{name}, {_steps(cell['timesteps'])} (leaderboard)"
            out.append({"label": label, "recipe": name, "timesteps": cell["timesteps"],
                        "description": recipes[name]["description"], "seeds": sorted({c["seed"] for c in mine}),
                        "rows": _rows_of(mine, label)})
    return {"spec": str(ablation_spec), "tasks": spec["tasks"], "tiers": spec["evaluation"]["tiers"],
            "episodes": spec["evaluation"]["episodes"], "recipes": out}


def _cell(row: dict | None, metric: str) -> str:
    if row is None or f"{metric}_iqm" not in row:
        return "—"
    ci = row[f"{metric}_ci"]
    return f"{num(row[f'{metric}_iqm'])} [{num(ci[0])}, {num(ci[1])}]"


def render_markdown(data: dict) -> str:
    """One table per evaluation task: a row per recipe, per tier of :data:`TABLE_TIERS` the IQM [95 % CI] of the
    first-quarter and last-half RMS position error [m], and the crash rate over those tiers."""
    lines = []
    tiers = [t for t in TABLE_TIERS if t in data["tiers"]]
    for task in data["tasks"]:
        lines += [f"**Evaluated on {task}** (IQM [95 % CI] of the RMS position error [m], {data['episodes']} "
                  f"episodes per run; crash: mean crash rate over the tiers shown)", ""]
        head = ["ingredients (recipe)", "seeds"] + [f"{tier}: {w}" for tier in tiers for w, _ in ABLATION_WINDOWS]
        head.append("crash")
        lines += ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
        for rec in data["recipes"]:
            rows = {r["tier"]: r for r in rec["rows"] if r["task"] == task}
            cols = [f"{rec['label']}", ",".join(map(str, rec["seeds"]))]
            cols += [_cell(rows.get(tier), metric) for tier in tiers for _, metric in ABLATION_WINDOWS]
            crash = [rows[t]["crash_rate"] for t in tiers if t in rows]
            cols.append(f"{sum(crash) / len(crash):.2f}" if crash else "—")
            lines.append("| " + " | ".join(cols) + " |")
        lines.append("")
    return "\n".join(lines)
