"""The leaderboard spec (``softpvtol_gym/baselines/data/leaderboard.yml``): its keys and entries, validated before
any job runs (:func:`load_spec`: unknown keys, wrong types, unknown tasks, tiers, kinds or action modes, episode
counts out of range are errors naming the key). :mod:`softpvtol_gym.baselines.leaderboard.jobs` turns it into jobs.

Analytic entries (the spec's ``analytic`` list, or the older ``passivity`` list whose entries are all of kind
``passivity``) have a ``kind``: ``passivity`` (``allocation``, optional ``loop``) or ``mpc`` (optional
``options``, passed to ``softpvtol_gym.MPCPolicy.from_env``). Every entry is evaluated on the same
``evaluation.episodes`` seeded test episodes (an entry's own ``episodes`` is refused: fewer episodes would give
it CIs that are not comparable).

Distilled entries (the spec's ``distilled`` list; :mod:`~softpvtol_gym.baselines.leaderboard.distilled`) are
students of a teacher controller, one job per seed like the ``trained`` PPO cells; both are *learned* entries
(:data:`LEARNED_POLICIES`).

``evaluation``: ``episodes`` and ``seed`` (the test episodes, seeds ``seed + i``), ``tiers``, and optionally
``selection_episodes`` and ``selection_seed`` (default :data:`SELECTION_SEED`): the held-out episodes on which the
headline chooses each side's strongest entry before it reports that entry on the test episodes (0, the default,
chooses on the test episodes), and ``inference`` (:data:`INFERENCE`, default ``lean``): the forward pass that
learned entries are scored with.
"""

from __future__ import annotations

import math
from pathlib import Path

from softpvtol_gym.baselines.config.hyperparams import (
    MAX_EPISODES,
    MAX_TIMESTEPS,
    TRAIN_SEED_LIMIT,
    apply_overrides,
    load_hyperparams,
    read_yaml,
)
from softpvtol_gym.baselines.config.recipes import load_recipe, recipe_hyperparams
from softpvtol_gym.baselines.config.run_config import RunConfig
from softpvtol_gym.baselines.config.validation import validate_hyperparams
from softpvtol_gym.baselines.errors import ConfigError
from softpvtol_gym.baselines.evaluation import EVAL_SEED_OFFSET
from softpvtol_gym.baselines.leaderboard.distilled import distill_config
from softpvtol_gym.baselines.util.paths import check_slug, data_file
from softpvtol_gym.control import LOOPS
from softpvtol_gym.envs.actions import ACTION_MODES
from softpvtol_gym.envs.tiers import registered_tiers
from softpvtol_gym.tasks import registered_tasks

#: the leaderboard spec shipped with the package (``--spec`` passes another)
SPEC_FILE = data_file("leaderboard.yml")
#: the spec's keys, and those of its entries (anything else is an error, not ignored)
SPEC_KEYS = ("evaluation", "passivity", "analytic", "tasks", "trained", "distilled", "seeds")
REQUIRED_SPEC_KEYS = ("evaluation", "tasks", "trained", "seeds")  # passivity, analytic, distilled: optional ([])
EVALUATION_KEYS = ("episodes", "seed", "tiers", "selection_episodes", "selection_seed", "inference")
REQUIRED_EVALUATION_KEYS = ("episodes", "seed", "tiers")
#: the first seed of the selection episodes by default (the test episodes' default seed is 1,000,000)
SELECTION_SEED = 2_000_000
#: the forward passes a learned entry can be scored with (LearnedPolicy's ``inference``)
INFERENCE = ("lean", "torch")
# loop: optional, default the loop named as the allocation
PASSIVITY_KEYS = ("name", "allocation", "loop")
#: the kinds of analytic entries, and the keys each takes (name and kind required; see validate_spec)
ANALYTIC_KINDS = {"passivity": ("name", "kind", "allocation", "loop"),
                  "mpc": ("name", "kind", "options")}
ANALYTIC_KEYS = ("name", "kind", "allocation", "loop", "options")
# the last three optional; recipe: a training recipe of data/hyperparams/recipes.yml (its action mode must be the
# cell's; hp overrides apply on top of the recipe's)
TRAINED_KEYS = ("action_mode", "task", "tier", "timesteps", "also_evaluated_on", "hp", "recipe", "init_from",
                "imitation")
#: a fine-tuning cell's imitation term (RunConfig.imitation): its keys
IMITATION_KEYS = ("teacher", "weight", "decay_steps", "epochs")
#: the keys of a ``distilled`` entry (the first three required; leaderboard/distilled.py)
DISTILLED_KEYS = ("teacher", "task", "tier", "variant", "options", "also_evaluated_on")
#: the ``policy`` of the learned jobs: PPO cells (``trained``) and students (``distilled``); every other policy is
#: an analytic entry's name
LEARNED_POLICIES = ("ppo", "distilled")
ALLOCATIONS = ("paper", "exact")


def is_int(v) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def _mapping(value, keys: tuple, where: str, required: tuple | None = None) -> dict:
    if not isinstance(value, dict):
        raise ConfigError(f"{where} must be a mapping with the keys {list(keys)}, got {value!r}")
    unknown = [k for k in value if k not in keys]
    if unknown:
        raise ConfigError(f"{where} has unknown keys {unknown}; valid ones are {list(keys)}")
    lost = [k for k in (keys if required is None else required) if k not in value]
    if lost:
        raise ConfigError(f"{where} lacks the keys {lost}")
    return value


def _list(value, where: str, allow_empty: bool = True) -> list:
    if not isinstance(value, list) or (not allow_empty and not value):
        raise ConfigError(f"{where} must be a{'' if allow_empty else ' non-empty'} list, got {value!r}")
    return value


def _choice(value, valid, where: str):
    if not isinstance(value, str) or value not in valid:
        raise ConfigError(f"{where} must be one of {list(valid)}, got {value!r}")
    return value


def validate_spec(spec, source: str = "leaderboard spec") -> dict:
    """``spec`` if it is a valid leaderboard spec, else ConfigError naming the key and what is expected."""

    if spec is None:
        raise ConfigError(f"{source} is empty; expected a mapping with the keys {list(SPEC_KEYS)}")
    _mapping(spec, SPEC_KEYS, source, required=REQUIRED_SPEC_KEYS)
    ev = _mapping(spec["evaluation"], EVALUATION_KEYS, f"{source}: evaluation", required=REQUIRED_EVALUATION_KEYS)
    _evaluation_episodes(ev, source)
    tiers = _list(ev["tiers"], f"{source}: evaluation.tiers", allow_empty=False)
    for t in tiers:
        _choice(t, registered_tiers(), f"{source}: each of evaluation.tiers")
    if len(set(tiers)) != len(tiers):
        raise ConfigError(f"{source}: evaluation.tiers lists a tier twice: {tiers}")
    tasks = _list(spec["tasks"], f"{source}: tasks", allow_empty=False)
    for t in tasks:
        _choice(t, registered_tasks(), f"{source}: each of tasks")
    if len(set(tasks)) != len(tasks):
        raise ConfigError(f"{source}: tasks lists a task twice: {tasks}")
    names = set()
    for section in ("passivity", "analytic"):
        for i, p in enumerate(_list(spec.get(section, []), f"{source}: {section}")):
            _analytic_entry(p, section, f"{source}: {section}[{i}]", names)
    cells = set()
    for i, c in enumerate(_list(spec["trained"], f"{source}: trained")):
        _mapping(c, TRAINED_KEYS, f"{source}: trained[{i}]", required=TRAINED_KEYS[:4])
        _choice(c["action_mode"], ACTION_MODES, f"{source}: trained[{i}].action_mode")
        _choice(c["task"], registered_tasks(), f"{source}: trained[{i}].task")
        _choice(c["tier"], registered_tiers(), f"{source}: trained[{i}].tier")
        if not is_int(c["timesteps"]) or not 1 <= c["timesteps"] <= MAX_TIMESTEPS:
            raise ConfigError(f"{source}: trained[{i}].timesteps must be an integer in [1, {MAX_TIMESTEPS:,}], "
                              f"got {c['timesteps']!r}")
        _also_evaluated_on(c, tasks, source, f"trained[{i}]")
        hp = _list(c.get("hp", []), f"{source}: trained[{i}].hp")
        if not all(isinstance(h, str) for h in hp):
            raise ConfigError(f"{source}: trained[{i}].hp must be a list of 'key=value' strings, got {hp!r}")
        recipe = None
        if c.get("recipe") is not None:
            try:
                recipe = load_recipe(c["recipe"])
            except ConfigError as exc:
                raise ConfigError(f"{source}: trained[{i}].recipe: {exc}") from None
            if recipe["action_mode"] != c["action_mode"]:
                raise ConfigError(f"{source}: trained[{i}].action_mode is {c['action_mode']!r}, its recipe "
                                  f"{c['recipe']!r} trains the {recipe['action_mode']!r} mode; make them agree")
        if hp or recipe is not None:
            try:  # validated as train.py --hp would be, before anything runs
                algo = "ppo" if recipe is None else recipe["algo"]
                base = load_hyperparams("ppo", c["action_mode"]) if recipe is None else recipe_hyperparams(recipe)
                validate_hyperparams(algo, apply_overrides(base, hp))
            except ConfigError as exc:
                raise ConfigError(f"{source}: trained[{i}].hp: {exc}") from None
        _fine_tuning(c, spec, f"{source}: trained[{i}]")
        key = (c["action_mode"], c["task"], c["tier"], c.get("recipe"))
        if key in cells:
            raise ConfigError(f"{source}: trained[{i}] repeats the cell {key}")
        cells.add(key)
    for i, d in enumerate(_list(spec.get("distilled", []), f"{source}: distilled")):
        key = _distilled_entry(d, source, f"distilled[{i}]", tasks)
        if key in cells:
            raise ConfigError(f"{source}: distilled[{i}] repeats the cell {key}; give one a variant")
        cells.add(key)
    seeds = _list(spec["seeds"], f"{source}: seeds", allow_empty=not (spec["trained"] or spec.get("distilled")))
    for s in seeds:
        if not is_int(s) or not 0 <= s < TRAIN_SEED_LIMIT:
            raise ConfigError(f"{source}: seeds must be integers in [0, {TRAIN_SEED_LIMIT:,}), got {s!r}")
    if len(set(seeds)) != len(seeds):
        raise ConfigError(f"{source}: seeds lists a seed twice: {seeds}")
    return spec


def distilled_folder(d: dict) -> str:
    """The folder of a ``distilled`` entry's jobs under the root (``<folder>/seed_<s>`` each)."""
    student = d["teacher"] + (f"-{d['variant']}" if d.get("variant") else "")
    return f"distilled-{student}_{d['task']}_{d['tier']}"


def _fine_tuning(c: dict, spec: dict, where: str) -> None:
    """Check a trained cell's ``init_from`` (the folder of a distilled cell of the spec, whose student of the same
    seed the cell's PPO starts from) and ``imitation`` (the term toward a teacher; only with ``init_from``)."""
    if c.get("init_from") is None:
        if c.get("imitation") is not None:
            raise ConfigError(f"{where}.imitation needs init_from (the imitation term fine-tunes a student)")
        return
    folders = [distilled_folder(d) for d in spec.get("distilled", [])
               if isinstance(d, dict) and all(isinstance(d.get(k), str) for k in DISTILLED_KEYS[:3])]
    _choice(c["init_from"], folders, f"{where}.init_from (the folder of a distilled cell of the spec)")
    if c["action_mode"] != "actuators":
        raise ConfigError(f"{where}: a student acts on the actuators; a cell that fine-tunes it has action_mode "
                          f"actuators, got {c['action_mode']!r}")
    imitation = c.get("imitation")
    if imitation is not None:
        _mapping(imitation, IMITATION_KEYS, f"{where}.imitation")
        try:
            RunConfig(algo="ppo", action_mode="actuators", task=c["task"], tier=c["tier"], timesteps=c["timesteps"],
                      seed=0, n_envs=1, hyperparams={}, imitation=dict(imitation))
        except ConfigError as exc:
            raise ConfigError(f"{where}.imitation: {exc}") from None


def is_learned(policy: str) -> bool:
    """Whether a job's or row's ``policy`` is a learned one (:data:`LEARNED_POLICIES`)."""
    return policy in LEARNED_POLICIES


def _also_evaluated_on(cell: dict, tasks: list, source: str, name: str) -> None:
    """Check a learned cell's ``also_evaluated_on`` (``name``: the cell, e.g. ``trained[2]``): tasks of the spec's
    ``tasks``, other than the cell's own, each once."""
    also = _list(cell.get("also_evaluated_on", []), f"{source}: {name}.also_evaluated_on")
    for t in also:
        _choice(t, tasks, f"{source}: each of {name}.also_evaluated_on (a task of the spec's tasks)")
    if cell["task"] in also or len(set(also)) != len(also):
        raise ConfigError(f"{source}: {name}.also_evaluated_on must list other tasks than the cell's own "
                          f"({cell['task']!r}), each once; got {also}")


def _distilled_entry(d, source: str, name: str, tasks: list) -> tuple:
    """Check one ``distilled`` entry (``name``: e.g. ``distilled[0]``; ConfigError naming the key); returns the
    cell's key."""
    where = f"{source}: {name}"
    _mapping(d, DISTILLED_KEYS, where, required=DISTILLED_KEYS[:3])
    _choice(d["task"], tasks, f"{where}.task (a task of the spec's tasks)")
    _choice(d["tier"], registered_tiers(), f"{where}.tier")
    if d.get("variant") is not None:
        check_slug(d["variant"], f"{where}.variant")
    _also_evaluated_on(d, tasks, source, name)
    options = d.get("options", {})
    if not isinstance(options, dict):
        raise ConfigError(f"{where}.options must be a mapping of distillation settings, got {options!r}")
    try:
        distill_config(d["teacher"], d["task"], d["tier"], 0, options)
    except (ConfigError, TypeError) as exc:
        raise ConfigError(f"{where}: {exc}") from None
    return ("distilled", d["teacher"], d["task"], d["tier"], d.get("variant"))


def _evaluation_episodes(ev: dict, source: str) -> None:
    """Check the episode counts, seeds and inference of the spec's ``evaluation`` (ConfigError naming the key): the
    test and selection episodes never share a seed, and neither shares one with training."""
    for key, low in (("episodes", 1), ("selection_episodes", 0)):
        v = ev.get(key, 0)
        if not is_int(v) or not low <= v <= MAX_EPISODES:
            raise ConfigError(f"{source}: evaluation.{key} must be an integer in [{low}, {MAX_EPISODES:,}], "
                              f"got {v!r}")
    for key in ("seed", "selection_seed"):
        v = ev.get(key, SELECTION_SEED)
        if not is_int(v) or v < EVAL_SEED_OFFSET:
            raise ConfigError(f"{source}: evaluation.{key} must be an integer >= {EVAL_SEED_OFFSET:,} (evaluation "
                              f"seeds never overlap training seeds), got {v!r}")
    test = (ev["seed"], ev["seed"] + ev["episodes"])
    selection = (selection_seed(ev), selection_seed(ev) + ev.get("selection_episodes", 0))
    if selection[1] > selection[0] and selection[0] < test[1] and test[0] < selection[1]:
        raise ConfigError(f"{source}: the selection episodes (seeds {selection[0]:,} to {selection[1] - 1:,}) overlap "
                          f"the test episodes (seeds {test[0]:,} to {test[1] - 1:,}); move evaluation.selection_seed")
    _choice(ev.get("inference", "lean"), INFERENCE, f"{source}: evaluation.inference")


def selection_seed(evaluation: dict) -> int:
    """The first seed of the selection episodes of a spec's ``evaluation``."""
    return int(evaluation.get("selection_seed", SELECTION_SEED))


def _analytic_entry(p, section: str, where: str, names: set) -> None:
    """Check one entry of the spec's ``passivity`` (kind passivity only) or ``analytic`` list (ConfigError)."""
    if isinstance(p, dict) and "episodes" in p:
        raise ConfigError(f"{where}.episodes: every entry is evaluated on the same evaluation.episodes seeded "
                          f"episodes (comparable CIs); remove the entry's episodes (got {p['episodes']!r})")
    if section == "passivity":
        _mapping(p, PASSIVITY_KEYS, where, required=("name", "allocation"))
        kind = "passivity"
    else:
        _mapping(p, ANALYTIC_KEYS, where, required=("name", "kind"))
        kind = _choice(p["kind"], ANALYTIC_KINDS, f"{where}.kind")
        wrong = [k for k in p if k not in ANALYTIC_KINDS[kind]]
        if wrong:
            raise ConfigError(f"{where} (kind {kind}) has keys {wrong} that only other kinds take; a {kind} entry "
                              f"takes {list(ANALYTIC_KINDS[kind])}")
    check_slug(p["name"], f"{where}.name")
    if is_learned(p["name"]) or p["name"] in names:
        raise ConfigError(f"{where}.name {p['name']!r} is taken (names must be unique, not one of "
                          f"{list(LEARNED_POLICIES)})")
    names.add(p["name"])
    if kind == "passivity":
        if "allocation" not in p:
            raise ConfigError(f"{where} (kind passivity) lacks the keys ['allocation']")
        _choice(p["allocation"], ALLOCATIONS, f"{where}.allocation")
        if "loop" in p:
            _choice(p["loop"], [k for k in LOOPS if LOOPS[k]["allocation"] == p["allocation"]],
                    f"{where}.loop (a loop with the {p['allocation']} allocation)")
    options = p.get("options", {})
    if not isinstance(options, dict) or not all(isinstance(k, str) and k.isidentifier() for k in options):
        raise ConfigError(f"{where}.options must be a mapping of option names to values (passed to "
                          f"MPCPolicy.from_env), got {options!r}")
    for k, v in options.items():
        if not _option_value(v):
            raise ConfigError(f"{where}.options.{k} must be a number, a string, a boolean or a list of numbers, "
                              f"got {v!r}")


def _option_value(v) -> bool:
    if isinstance(v, (bool, str)) or (isinstance(v, (int, float)) and math.isfinite(v)):
        return True
    return isinstance(v, list) and all(isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)
                                       for x in v)


def analytic_entries(spec: dict) -> list[dict]:
    """The analytic entries of a validated spec (``passivity`` then ``analytic``), each with its ``kind``."""
    return [{"kind": "passivity", **p} for p in spec.get("passivity", [])] + list(spec.get("analytic", []))


def load_spec(spec_path: Path = SPEC_FILE) -> dict:
    """The validated leaderboard spec at ``spec_path`` (ConfigError naming the problem otherwise)."""

    return validate_spec(read_yaml(spec_path, "leaderboard spec"), f"leaderboard spec {spec_path}")
