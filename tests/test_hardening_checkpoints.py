"""Issue 22 (items 1 and 3): poisoned checkpoints, resume states and config files are refused with one line
naming the field or file, before any kernel runs; config-derived values are rebuilt from the config."""

from __future__ import annotations

import io
import json
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import TINY, copy_run, rewrite_manifest

from softpvtol_gym.baselines.checkpoints.resume import env_state, restore_env_state
from softpvtol_gym.baselines.errors import CheckpointError, ConfigError
from softpvtol_gym.envs.layout import ISTATE, STATE

DEEP_JSON = "[" * 1000 + "]" * 1000
DEEP_YAML = "a: " + "[" * 1000 + "]" * 1000 + "\n"
ALIAS_BOMB = "".join(f"l{i}: &l{i} [" + ", ".join([f"*l{i - 1}" if i else "lol"] * 9) + "]\n" for i in range(12))


# ------------------------------------------------------------------------------ the env's state
def _stepped_env(mode: str = "residual", n: int = 2):
    from softpvtol_gym.envs.sb3 import SoftPVTOLSB3VecEnv

    env = SoftPVTOLSB3VecEnv(num_envs=n, action_mode=mode, task="hover", tier="noisy")
    env.seed(3)
    env.reset()
    rng = np.random.default_rng(1)
    for _ in range(5):
        env.step(rng.uniform(-1, 1, (n, env.action_space.shape[0])))
    return env


def _fresh(mode: str = "residual", n: int = 2):
    from softpvtol_gym.envs.sb3 import SoftPVTOLSB3VecEnv

    return SoftPVTOLSB3VecEnv(num_envs=n, action_mode=mode, task="hover", tier="noisy")


def _poison_F(arrays, meta, fn):
    arrays["sim.F"] = fn(arrays["sim.F"].copy())


def _set_col(field, value, i=0):
    def fn(F):
        F[0, getattr(STATE.at, field) + i] = value
        return F
    return fn


def _set_int(field, value):
    def poison(arrays, meta):
        arrays["sim.I"] = arrays["sim.I"].copy()
        arrays["sim.I"][0, getattr(ISTATE.at, field)] = value
        arrays[f"sim.{field}"] = arrays["sim.I"][:, getattr(ISTATE.at, field)].copy()
    return poison


POISONS = {
    # config-derived: the constant vector cut (the audit's 63 -> 23), scaled, codes out of their enum,
    # an injected max_steps: compared with the values rebuilt from the config, never written
    "constants_truncated": (lambda a, m: a.__setitem__("sim.C", a["sim.C"][:23].copy()), "sim.C"),
    "constants_scaled": (lambda a, m: a.__setitem__("sim.C", a["sim.C"] * 3.0), "sim.C"),
    "codes_out_of_enum": (lambda a, m: a.__setitem__("sim.K", a["sim.K"] + 99), "sim.K"),
    "max_steps_injected": (lambda a, m: m["sim"]["scalars"].__setitem__("max_steps", 3), "sim.max_steps"),
    "dt_changed": (lambda a, m: m["sim"]["scalars"].__setitem__("dt", 1.0), "sim.dt"),
    "controller_constants_scaled": (
        lambda a, m: a.__setitem__("controller.kernel_constants", a["controller.kernel_constants"] * 2),
        "kernel_constants"),
    # the dynamic state: layout (rows = num_envs, columns = the layout's width), dtype, values
    "state_truncated": (lambda a, m: a.__setitem__("sim.F", a["sim.F"][:, :50].copy()), "sim.F"),
    "state_extra_rows": (lambda a, m: a.__setitem__("sim.F", np.vstack([a["sim.F"]] * 2)), "sim.F"),
    "state_float32": (lambda a, m: a.__setitem__("sim.F", a["sim.F"].astype(np.float32)), "sim.F"),
    "state_nan": (lambda a, m: _poison_F(a, m, _set_col("q", np.nan)), "field q"),
    "state_inf_wind": (lambda a, m: _poison_F(a, m, _set_col("wind", np.inf)), "field wind"),
    "action_out_of_range": (lambda a, m: _poison_F(a, m, _set_col("u", 7.0)), "clipped action u"),
    "negative_time": (lambda a, m: _poison_F(a, m, _set_col("t", -1.0)), "episode time t"),
    "zero_mass": (lambda a, m: _poison_F(a, m, _set_col("P", 0.0)), "plant parameters P"),
    "int_state_resized": (lambda a, m: a.__setitem__("sim.I", a["sim.I"][:, :2].copy()), "sim.I"),
    "reason_out_of_enum": (_set_int("reason", 99), "reason"),
    "negative_steps": (_set_int("steps", -5), "steps"),
    "negative_counter": (_set_int("counter", -1), "counter"),
    "lag_flag_out_of_range": (_set_int("lag_init", 7), "lag_init"),
    "keys_wrong_dtype": (lambda a, m: a.__setitem__("sim.key", a["sim.key"].astype(np.int8)), "sim.key"),
    "keys_truncated": (lambda a, m: a.__setitem__("sim.key", a["sim.key"][:1].copy()), "sim.key"),
    "obs_nan": (lambda a, m: a.__setitem__("sim.obs", np.full_like(a["sim.obs"], np.nan)), "sim.obs"),
    "view_disagrees": (lambda a, m: a.__setitem__("sim.q", a["sim.q"] + 1.0), "sim.q"),
    "controller_memory_resized": (lambda a, m: a.__setitem__("controller._state", a["controller._state"][:, :4].copy()),
                                  "controller._state"),
    "autoreset_flags_resized": (lambda a, m: a.__setitem__("venv._autoreset", np.zeros(7, bool)), "venv._autoreset"),
    "generators_missing": (
        lambda a, m: m["venv"]["generators"].__setitem__("_rngs", m["venv"]["generators"]["_rngs"][:1]), "_rngs"),
    "generator_garbage": (lambda a, m: m["venv"]["generators"]["_rngs"].__setitem__(0, {"bit_generator": "PCG64",
                                                                                       "state": 5}), "_rngs[0]"),
    "unknown_attribute": (lambda a, m: m["sim"]["scalars"].__setitem__("evil", 1), "sim.evil"),
    "listed_not_saved": (lambda a, m: a.pop("sim.obs"), "sim.obs"),
    "lists_not_a_list": (lambda a, m: m["sim"].__setitem__("arrays", 5), "sim.arrays"),
    "needs_reset_not_bool": (lambda a, m: m["venv"]["scalars"].__setitem__("_needs_reset", "no"), "_needs_reset"),
}


@pytest.mark.parametrize("case", sorted(POISONS))
def test_poisoned_env_state_is_refused_before_anything_is_written(case):
    """Every poisoned field is refused with one line naming it; the env it was restored into is untouched (so
    no compiled kernel ever sees the checkpoint's values)."""
    meta, arrays = env_state(_stepped_env().venv)
    meta = json.loads(json.dumps(meta))
    arrays = {k: v.copy() for k, v in arrays.items()}
    poison, field = POISONS[case]
    poison(arrays, meta)
    target = _fresh()
    sim = target.venv._sim
    before = {k: getattr(sim, k).copy() for k in ("F", "I", "key", "obs", "C", "K")}
    rngs_before = [g.bit_generator.state for g in target.venv._rngs]
    with pytest.raises(CheckpointError) as exc:
        restore_env_state(target.venv, meta, arrays, "ckpt")
    msg = str(exc.value)
    assert "\n" not in msg and msg.startswith("ckpt: the saved env state does not fit") and field in msg, msg
    assert all(getattr(sim, k).tobytes() == v.tobytes() for k, v in before.items())
    assert [g.bit_generator.state for g in target.venv._rngs] == rngs_before
    assert sim.max_steps == target.venv.config.max_steps


@pytest.mark.parametrize("mode", ["residual", "actuators"])
def test_restored_env_keeps_the_config_derived_values_of_a_fresh_env(mode):
    """A valid restore writes the dynamic state only: the constants, codes and settings stay the very objects
    the config built (the kernels read those), and the env then steps like the saved one."""
    a = _stepped_env(mode)
    meta, arrays = env_state(a.venv)
    b = _fresh(mode)
    sim = b.venv._sim
    C, K, ctrl = sim.C, sim.K, sim.controller
    restore_env_state(b.venv, json.loads(json.dumps(meta)), arrays, "ckpt")
    assert sim.C is C and sim.K is K and sim.controller is ctrl
    fresh = _fresh(mode).venv._sim
    assert sim.C.tobytes() == fresh.C.tobytes() and sim.K.tobytes() == fresh.K.tobytes()
    assert (sim.max_steps, sim.dt, sim.n) == (fresh.max_steps, fresh.dt, fresh.n)
    assert np.shares_memory(sim.q, sim.F)  # views stay views
    act = np.random.default_rng(2).uniform(-1, 1, (2, a.action_space.shape[0]))
    oa, ra, _, _ = a.step(act)
    ob, rb, _, _ = b.step(act)
    assert oa.tobytes() == ob.tobytes() and ra.tobytes() == rb.tobytes()


# ----------------------------------------------------------------------- end to end: train --resume
def _poison_resume_states(run: Path, edit) -> None:
    """Apply ``edit(state_json, arrays)`` to the resume state of every checkpoint of ``run`` (manifests
    rewritten to match, as a forger would)."""
    for ck in sorted((run / "checkpoints").glob("step_*")):
        state = json.loads((ck / "resume_state.json").read_text())
        with np.load(ck / "resume_state.npz") as z:
            arrays = {k: z[k] for k in z.files}
        edit(state, arrays)
        (ck / "resume_state.json").write_text(json.dumps(state))
        buf = io.BytesIO()
        np.savez(buf, **arrays)
        (ck / "resume_state.npz").write_bytes(buf.getvalue())
        rewrite_manifest(ck)


RESUME_POISONS = {
    "constants_truncated": (lambda s, a: a.__setitem__("env/sim.C", a["env/sim.C"][:23].copy()), "sim.C"),
    "max_steps_injected": (lambda s, a: s["env"]["sim"]["scalars"].__setitem__("max_steps", 3), "sim.max_steps"),
    "state_resized": (lambda s, a: a.__setitem__("env/sim.F", a["env/sim.F"][:, :40].copy()), "sim.F"),
    "vecnormalize_returns_resized": (lambda s, a: a.__setitem__("vecnormalize_returns", np.zeros(9)),
                                     "vecnormalize_returns"),
    "vecnormalize_returns_nan": (lambda s, a: a.__setitem__("vecnormalize_returns", np.full(4, np.nan)),
                                 "vecnormalize_returns"),
    "vecnormalize_old_obs_resized": (lambda s, a: a.__setitem__("vecnormalize_old_obs", np.zeros((4, 3), np.float32)),
                                     "vecnormalize_old_obs"),
    "numpy_rng_key_truncated": (lambda s, a: a.__setitem__("numpy_rng_key", a["numpy_rng_key"][:5].copy()),
                                "numpy_rng_key"),
}


@pytest.mark.parametrize("case", sorted(RESUME_POISONS))
def test_poisoned_resume_state_ends_train_resume_with_one_line(case, tmp_path, tiny_run, capsys):
    from softpvtol_gym.baselines.commands.train import main as train_main

    run = copy_run(tiny_run, tmp_path / "run")
    edit, field = RESUME_POISONS[case]
    _poison_resume_states(run, edit)
    weights = (run / "model.safetensors").read_bytes()
    with pytest.raises(SystemExit) as exc:
        train_main(["--timesteps", "768", *TINY, "--out", str(run), "--resume"])
    err = capsys.readouterr().err
    assert exc.value.code == 2
    last = err.strip().splitlines()[-1]
    assert "no checkpoint" in last and field in last, err
    assert (run / "model.safetensors").read_bytes() == weights  # nothing trained, nothing replaced


# ---------------------------------------------------------------------------------- checkpoint files
def _edit_model_json(run: Path, fn) -> None:
    meta = json.loads((run / "model.json").read_text())
    fn(meta)
    (run / "model.json").write_text(json.dumps(meta))
    rewrite_manifest(run)


def _edit_tensor(run: Path, name_start: str, fn) -> str:
    from safetensors.torch import load_file, save_file

    tensors = load_file(run / "model.safetensors")
    name = next(k for k in sorted(tensors) if k.startswith(name_start))
    tensors[name] = fn(tensors[name].clone())
    save_file(tensors, run / "model.safetensors", metadata={"format": "softpvtol-gym checkpoint", "version": "1"})
    rewrite_manifest(run)
    return name


def _edit_vecnorm(run: Path, key: str, literal: str) -> None:
    """The first entry of obs_rms.<key> of vecnormalize.json replaced by a JSON literal (NaN, 1e400 = inf)."""
    data = json.loads((run / "vecnormalize.json").read_text())
    data["obs_rms"][key][0] = "PLACEHOLDER"
    (run / "vecnormalize.json").write_text(json.dumps(data).replace('"PLACEHOLDER"', literal))
    rewrite_manifest(run)


def _nan(t):
    t.view(-1)[0] = float("nan")
    return t


def _huge(t):
    t.view(-1)[0] = 1e30
    return t


FILE_POISONS = {
    "model_json_deeply_nested": (lambda r: ((r / "model.json").write_text(DEEP_JSON), rewrite_manifest(r)),
                                 "model.json is nested too deeply"),
    "model_json_counters_not_a_mapping": (lambda r: _edit_model_json(r, lambda m: m.__setitem__("counters", 5)),
                                          "counters"),
    "model_json_counter_negative": (lambda r: _edit_model_json(
        r, lambda m: m["counters"].__setitem__("_n_updates", -3)), "counters._n_updates"),
    "model_json_optimizers_garbage": (lambda r: _edit_model_json(r, lambda m: m.__setitem__("optimizers", [1])),
                                      "optimizers"),
    "model_json_episode_buffer_garbage": (lambda r: _edit_model_json(r, lambda m: m.__setitem__("ep_info_buffer", 5)),
                                          "ep_info_buffer"),
    "config_yaml_deeply_nested": (lambda r: ((r / "config.yaml").write_text(DEEP_YAML), rewrite_manifest(r)),
                                  "config.yaml is not valid YAML"),
    "config_yaml_alias_bomb": (lambda r: ((r / "config.yaml").write_text(ALIAS_BOMB), rewrite_manifest(r)),
                               "once its aliases are expanded"),
    "manifest_deeply_nested": (lambda r: (r / "checkpoint.json").write_text(DEEP_JSON), "checkpoint.json"),
    "weight_nan": (lambda r: _edit_tensor(r, "policy/", _nan), "tensor policy/"),
    "weight_huge": (lambda r: _edit_tensor(r, "policy/", _huge), "tensor policy/"),
    "optimizer_state_nan": (lambda r: _edit_tensor(r, "policy.optimizer/state/", _nan), "tensor policy.optimizer/"),
    "vecnormalize_nan": (lambda r: _edit_vecnorm(r, "mean", "NaN"), "vecnormalize.json is not valid JSON (NaN"),
    "vecnormalize_huge": (lambda r: _edit_vecnorm(r, "var", "1e400"), "obs_rms holds non-finite"),
    "vecnormalize_clip_negative": (lambda r: ((r / "vecnormalize.json").write_text(
        json.dumps({**json.loads((r / "vecnormalize.json").read_text()), "clip_obs": -1.0})), rewrite_manifest(r)),
        "clip_obs"),
}


@pytest.mark.parametrize("case", sorted(FILE_POISONS))
def test_poisoned_checkpoint_file_is_refused_by_evaluate_and_to_sb3(case, tmp_path, tiny_run, capsys):
    """evaluate and export to-sb3 end with one line naming the file or tensor; to-sb3 writes nothing."""
    from softpvtol_gym.baselines.commands.evaluate import main as evaluate_main
    from softpvtol_gym.baselines.commands.export import main as export_main

    run = copy_run(tiny_run, tmp_path / "run")
    poison, expected = FILE_POISONS[case]
    poison(run)
    t0 = time.monotonic()
    out = tmp_path / "sb3" / "model.zip"
    for main, args in ((evaluate_main, ["--policy", str(run), "--episodes", "1"]),
                       (export_main, ["to-sb3", "--policy", str(run), "--out", str(out), "--vecnormalize",
                                      str(tmp_path / "sb3" / "vn.pkl")])):
        with pytest.raises(SystemExit) as exc:
            main(args)
        err = capsys.readouterr().err
        assert exc.value.code == 2, err
        lines = [line for line in err.strip().splitlines() if not line.startswith("warning")]
        assert len(lines) == 1 and expected in lines[0], err
    assert not out.exists()
    assert time.monotonic() - t0 < 60  # the alias bomb is refused, not expanded


def test_deep_nesting_and_aliases_in_every_yaml_and_json_loader(tmp_path):
    """Hyperparameter files, search spaces, leaderboard specs, run configs, overrides, dict(...) strings,
    eval.json and the leaderboard JSON: one ConfigError naming the file, no RecursionError."""
    from softpvtol_gym.baselines.commands.tune import load_space
    from softpvtol_gym.baselines.config.hyperparams import apply_overrides, load_hyperparams, parse_dict_call, read_yaml
    from softpvtol_gym.baselines.config.run_config import RunConfig
    from softpvtol_gym.baselines.leaderboard.jobs import load_jobs, read_eval
    from softpvtol_gym.baselines.leaderboard.stats import read_data

    deep, bomb = tmp_path / "deep.yml", tmp_path / "bomb.yml"
    deep.write_text(DEEP_YAML)
    bomb.write_text(ALIAS_BOMB)
    (tmp_path / "ppo.yml").write_text(DEEP_YAML)
    for call, name in ((lambda: read_yaml(deep, "x"), "deep.yml"), (lambda: read_yaml(bomb, "x"), "bomb.yml"),
                       (lambda: load_hyperparams("ppo", "residual", tmp_path), "ppo.yml"),
                       (lambda: load_space(deep, "ppo", {}), "deep.yml"),
                       (lambda: load_space(bomb, "ppo", {}), "bomb.yml"),
                       (lambda: load_jobs(deep), "deep.yml"),
                       (lambda: RunConfig.load(bomb), "bomb.yml"),
                       (lambda: apply_overrides({}, ["gamma=" + "[" * 1000]), "gamma"),
                       (lambda: parse_dict_call("dict(a=" + "[" * 1000 + "]" * 1000 + ")"), "policy_kwargs")):
        with pytest.raises(ConfigError) as exc:
            call()
        assert name in str(exc.value) and "\n" not in str(exc.value)
    deep_json = tmp_path / "eval.json"
    deep_json.write_text(DEEP_JSON)
    for call in (lambda: read_eval(deep_json), lambda: read_data(deep_json)):
        with pytest.raises(ConfigError, match="eval.json"):
            call()


def test_bounded_loaders_directly():
    from softpvtol_gym.baselines.util.safe_load import UnsafeInputError, loads_json, loads_yaml

    assert loads_yaml("a: [1, {b: c}]\n", "s") == {"a": [1, {"b": "c"}]}
    assert loads_json('{"a": [1, 2.5]}', "s", allow_nan=False) == {"a": [1, 2.5]}
    for call, what in ((lambda: loads_json(DEEP_JSON, "f.json"), "nested too deeply"),
                       (lambda: loads_json('{"a": NaN}', "f.json", allow_nan=False), "NaN"),
                       (lambda: loads_json("{}" + " " * 100, "f.json", max_bytes=10), "bytes"),
                       (lambda: loads_yaml(DEEP_YAML, "f.yml"), "nested more than"),
                       (lambda: loads_yaml(ALIAS_BOMB, "f.yml"), "once its aliases are expanded"),
                       (lambda: loads_yaml("a: !!python/object:os.system x\n", "f.yml"), "f.yml")):
        with pytest.raises(UnsafeInputError, match=what) as exc:
            call()
        assert str(exc.value).startswith("f.") and "\n" not in str(exc.value)


# ------------------------------------------------------------------------------ network sizes, tune
@pytest.mark.parametrize("net_arch", ["[4000000000]", "[-1]", "[0]", "[64] * 9", "[64.5]", "dict(pi=[64], xx=[64])",
                                      "dict(pi=[0], vf=[64])", "'big'"])
def test_network_sizes_are_validated(net_arch):
    from softpvtol_gym.baselines.config.validation import validate_hyperparams

    pk = f"dict(net_arch={net_arch})" if "*" not in net_arch else f"dict(net_arch=[{', '.join(['64'] * 9)}])"
    with pytest.raises(ConfigError, match=r"policy_kwargs must be a dict whose net_arch is a list of at most 8 layer "
                                          r"sizes, each an integer in \[1, 4096\]"):
        validate_hyperparams("ppo", {"policy_kwargs": pk})
    validate_hyperparams("ppo", {"policy_kwargs": "dict(net_arch=dict(pi=[64, 64], vf=[64, 64]))"})
    validate_hyperparams("sac", {"policy_kwargs": {"net_arch": [256, 256]}})


def test_train_refuses_a_zero_width_network_before_training(tmp_path, capsys):
    from softpvtol_gym.baselines.commands.train import main as train_main

    with pytest.raises(SystemExit) as exc:
        train_main(["--timesteps", "256", *TINY, "--hp", "policy_kwargs=dict(net_arch=[0])",
                    "--out", str(tmp_path / "r")])
    assert exc.value.code == 2 and "net_arch" in capsys.readouterr().err
    assert not (tmp_path / "r" / "model.safetensors").exists()


@pytest.mark.parametrize("key,spec", [("n_steps", "{uniform: [64, 512]}"), ("batch_size", "{loguniform: [64, 256]}"),
                                      ("n_epochs", "{uniform: [3.0, 10.0]}")])
def test_tune_space_with_a_float_distribution_for_an_integer_is_refused(key, spec, tmp_path):
    from softpvtol_gym.baselines.commands.tune import load_space

    path = tmp_path / "space.yml"
    path.write_text(f"ppo:\n  {key}: {spec}\n")
    with pytest.raises(ConfigError, match=f"ppo.{key}: {key} takes integers but .* samples floats; use "
                                          r"\{randint"):
        load_space(path, "ppo", {"n_envs": 4})
    path.write_text(f"ppo:\n  {key}: {{randint: [64, 128]}}\n  gae_lambda: {{uniform: [0.9, 0.99]}}\n")
    assert set(load_space(path, "ppo", {"n_envs": 4})) == {key, "gae_lambda"}


# ------------------------------------------------------------------------------------ replay buffer
def test_poisoned_replay_buffer_is_refused_before_it_is_written():
    from gymnasium import spaces
    from stable_baselines3.common.buffers import ReplayBuffer

    from softpvtol_gym.baselines.checkpoints.resume import restore_replay_buffer

    def buffer():
        return ReplayBuffer(16, spaces.Box(-1, 1, (3,), np.float32), spaces.Box(-1, 1, (2,), np.float32), n_envs=2)

    src = buffer()
    for _ in range(5):
        src.add(np.ones((2, 3)), np.ones((2, 3)), np.zeros((2, 2)), np.ones(2), np.zeros(2), [{}, {}])
    info = {"pos": 5, "full": False, "filled": 5, "buffer_size": src.buffer_size, "n_envs": 2}
    good = {k: getattr(src, k)[:5].copy() for k in ("observations", "next_observations", "actions", "rewards",
                                                    "dones", "timeouts")}
    dst = buffer()
    restore_replay_buffer(dst, info, good, "ck")
    assert dst.pos == 5 and (dst.observations[:5] == 1).all()
    cases = [
        ({**info, "filled": 99}, good, "inconsistent"),
        ({**info, "pos": -1, "filled": -1}, good, "inconsistent"),
        ({**info, "pos": "5"}, good, "pos must be an integer"),
        (info, {**good, "rewards": np.full((5, 2), np.nan, np.float32)}, "rewards holds non-finite"),
        (info, {**good, "observations": good["observations"][:, :, :2].copy()}, "observations is"),
        (info, {**good, "actions": good["actions"].astype(np.float64)}, "actions is"),
        (info, {k: v for k, v in good.items() if k != "dones"}, "dones is missing"),
    ]
    for bad_info, bad_arrays, what in cases:
        dst = buffer()
        with pytest.raises(CheckpointError, match=what) as exc:
            restore_replay_buffer(dst, bad_info, bad_arrays, "ck")
        assert "replay_buffer.npz" in str(exc.value) and dst.pos == 0 and (dst.observations == 0).all()


# ------------------------------------------------------------------------------------ export from-sb3
def test_from_sb3_refuses_an_existing_target_and_nan_weights(tmp_path, tiny_run, capsys):
    """from-sb3 never replaces a safe checkpoint without --force, and never converts NaN weights."""
    import torch
    from stable_baselines3 import PPO

    from softpvtol_gym.baselines.commands.export import main as export_main

    sb3 = tmp_path / "sb3"
    assert export_main(["to-sb3", "--policy", str(tiny_run), "--out", str(sb3 / "model.zip"), "--vecnormalize",
                        str(sb3 / "vecnormalize.pkl")]) == 0
    (sb3 / "config.yaml").write_bytes((tiny_run / "config.yaml").read_bytes())
    target = copy_run(tiny_run, tmp_path / "safe")
    before = (target / "model.safetensors").read_bytes()
    with pytest.raises(SystemExit) as exc:
        export_main(["from-sb3", "--trust-pickle", str(sb3), "--out", str(target)])
    assert exc.value.code == 2 and "already holds a safe checkpoint" in capsys.readouterr().err
    assert (target / "model.safetensors").read_bytes() == before
    model = PPO.load(sb3 / "model.zip", device="cpu")
    with torch.no_grad():
        next(model.policy.parameters()).view(-1)[0] = float("nan")
    model.save(sb3 / "model.zip")
    with pytest.raises(SystemExit) as exc:
        export_main(["from-sb3", "--trust-pickle", "--force", str(sb3), "--out", str(target)])
    err = capsys.readouterr().err.strip().splitlines()
    assert exc.value.code == 2 and "tensor policy/" in err[-1] and "non-finite" in err[-1], err
    assert (target / "model.safetensors").read_bytes() == before
