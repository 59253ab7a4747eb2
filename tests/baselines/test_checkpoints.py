"""Checkpoints that cannot run code, atomic writes, locks, safe paths, no dead ends; poisoned
checkpoints, resume states and config files are refused with one line naming the field or file, before any
kernel runs; config-derived values are rebuilt from the config.
"""

from __future__ import annotations

import base64
import io
import json
import os
import pickle
import shutil
import subprocess
import sys
import threading
import time
import zipfile
from pathlib import Path

import numpy as np
import pytest

from softpvtol_gym.baselines.checkpoints.manifest import LEGACY_FILES, MANIFEST_FILE
from softpvtol_gym.baselines.checkpoints.resume import env_state, restore_env_state
from softpvtol_gym.baselines.checkpoints.store import find_checkpoint, latest_checkpoint
from softpvtol_gym.baselines.commands.evaluate import main as evaluate_main
from softpvtol_gym.baselines.commands.train import main as train_main
from softpvtol_gym.baselines.errors import CheckpointError, ConfigError, LockedError
from softpvtol_gym.baselines.util.atomic import atomic_path, atomic_write_text, clean_stale_temps
from softpvtol_gym.baselines.util.locks import DirectoryLock
from softpvtol_gym.envs.packed_state import ISTATE, STATE
from tests.conftest import ROOT, TINY, UP, copy_run, rewrite_manifest


class _Payload:
    """Unpickling this creates the marker file: stands for any code a pickle can run."""

    def __init__(self, marker: Path):
        self.marker = marker

    def __reduce__(self):
        return (Path.touch, (self.marker,))


def _pickle_payload(marker: Path) -> bytes:
    return pickle.dumps(_Payload(marker))


def _sb3_zip_payload(marker: Path, real_zip_source: Path) -> bytes:
    """A real SB3 model.zip whose ``data`` carries the payload the way SB3 stores objects (cloudpickle,
    base64): ``PPO.load`` would run it and still load the model."""
    import io

    from stable_baselines3 import PPO

    from softpvtol_gym.baselines.training.policy import LearnedPolicy

    policy, _ = LearnedPolicy.load(real_zip_source)
    buf = io.BytesIO()
    policy.model.save(buf)
    src = zipfile.ZipFile(io.BytesIO(buf.getvalue()))
    data = json.loads(src.read("data"))
    data["payload"] = {":type:": "<class 'object'>", ":serialized:": base64.b64encode(_pickle_payload(marker)).decode()}
    out = io.BytesIO()
    with zipfile.ZipFile(out, "w") as dst:
        for item in src.namelist():
            dst.writestr(item, json.dumps(data) if item == "data" else src.read(item))
    assert PPO  # imported above: the format is SB3's
    return out.getvalue()


def _npz_payload(marker: Path) -> bytes:
    import io

    buf = io.BytesIO()
    arr = np.empty(1, dtype=object)
    arr[0] = _Payload(marker)
    np.savez(buf, sim_F=arr)  # an object array: np.save pickles it
    return buf.getvalue()


def test_the_payloads_do_run_code_when_unpickled(tmp_path, tiny_run):
    """The test below is only meaningful if its payloads are live: unpickling each creates the marker."""
    import io

    from stable_baselines3 import PPO

    marker = tmp_path / "marker"
    pickle.loads(_pickle_payload(marker))
    assert marker.exists()
    marker.unlink()
    PPO.load(io.BytesIO(_sb3_zip_payload(marker, tiny_run)), device="cpu")
    assert marker.exists()
    marker.unlink()
    with np.load(io.BytesIO(_npz_payload(marker)), allow_pickle=True) as z:
        z["sim_F"]
    assert marker.exists()


def _plant_everywhere(run: Path, marker: Path) -> None:
    """The payload under every file name a loader of this or an earlier version knows, in the run folder
    and in every checkpoint folder (next to the real files)."""
    folders = [run, *sorted((run / "checkpoints").glob("step_*"))]
    zip_bytes = _sb3_zip_payload(marker, run)
    for folder in folders:
        for name in LEGACY_FILES:
            (folder / name).write_bytes(zip_bytes if name.endswith(".zip") else _pickle_payload(marker))
        for name in ("policy.pth", "pytorch_variables.pth", "data.pkl"):
            (folder / name).write_bytes(_pickle_payload(marker))


def test_poisoned_run_is_evaluated_and_resumed_without_running_the_payload(tmp_path, tiny_run, capsys):
    run = copy_run(tiny_run, tmp_path / "run")
    marker = tmp_path / "marker"
    _plant_everywhere(run, marker)
    assert not marker.exists()
    out = tmp_path / "e.json"
    assert evaluate_main(["--policy", str(run), "--episodes", "2", "--json", str(out)]) == 0
    assert json.loads(out.read_text())["summary"]["episodes"] == 2
    for ck in sorted((run / "checkpoints").glob("step_*")):
        assert evaluate_main(["--policy", str(ck / "model.safetensors"), "--episodes", "1"]) == 0
    # resume: a longer run continues from the newest checkpoint (the payload sits next to it)
    assert train_main(["--timesteps", "768", *TINY, "--out", str(run), "--resume"]) == 0
    assert json.loads((run / "model.json").read_text())["counters"]["num_timesteps"] == 768
    assert not marker.exists()
    # the pickle-based names themselves are refused, not loaded
    for name in ("model.zip", "vecnormalize.pkl"):
        with pytest.raises(SystemExit) as exc:
            evaluate_main(["--policy", str(run / name)])
        assert exc.value.code == 2 and "pickle" in capsys.readouterr().err
    assert not marker.exists()


@pytest.mark.parametrize("name", ["model.safetensors", "model.json", "vecnormalize.json", "config.yaml",
                                  "checkpoint.json", "resume_state.json", "resume_state.npz"])
@pytest.mark.parametrize("forged_manifest", [False, True], ids=["corrupt", "forged"])
def test_payload_in_place_of_a_real_file_is_a_clear_error(name, forged_manifest, tmp_path, tiny_run, capsys):
    """The payload replaces a real file (with a manifest rewritten to match it, as a forger would): loading
    fails with a one-line error naming the file; the payload never runs."""
    run = copy_run(tiny_run, tmp_path / "run")
    marker = tmp_path / "marker"
    ckpts = sorted((run / "checkpoints").glob("step_*"))
    targets = [run, *ckpts] if not name.startswith("resume_state") else ckpts
    for folder in targets:
        if name == "resume_state.npz":
            payload = _npz_payload(marker)
        elif name == "config.yaml":
            payload = f"!!python/object/apply:pathlib.Path.touch [{str(marker)!r}]\n".encode()
        else:
            payload = _pickle_payload(marker)
        (folder / name).write_bytes(payload)
        if forged_manifest and name != "checkpoint.json":
            rewrite_manifest(folder)
    if not name.startswith("resume_state"):
        with pytest.raises(SystemExit) as exc:
            evaluate_main(["--policy", str(run), "--episodes", "1"])
        err = capsys.readouterr().err
        assert exc.value.code == 2 and len(err.strip().splitlines()) == 1 and "Traceback" not in err, err
    # resume, asking for more steps: every checkpoint is unusable -> a clear error, nothing trained
    with pytest.raises(SystemExit) as exc:
        train_main(["--timesteps", "768", *TINY, "--out", str(run), "--resume"])
    err = capsys.readouterr().err
    assert exc.value.code == 2 and "Traceback" not in err.splitlines()[-1], err
    assert not marker.exists()


def test_evaluate_with_trust_pickle_loads_an_sb3_zip_with_a_warning(tmp_path, tiny_run, capsys):
    """Interop: export to SB3's format and read it back (only with --trust-pickle)."""
    from softpvtol_gym.baselines.commands.export import main as export_main

    zip_path, pkl = tmp_path / "sb3" / "model.zip", tmp_path / "sb3" / "vecnormalize.pkl"
    assert export_main(["to-sb3", "--policy", str(tiny_run), "--out", str(zip_path), "--vecnormalize", str(pkl)]) == 0
    shutil.copy(tiny_run / "config.yaml", zip_path.parent / "config.yaml")
    with pytest.raises(SystemExit):
        evaluate_main(["--policy", str(zip_path), "--episodes", "1"])
    assert "--trust-pickle" in capsys.readouterr().err
    a, b = tmp_path / "a.json", tmp_path / "b.json"
    assert evaluate_main(["--policy", str(zip_path), "--trust-pickle", "--episodes", "2", "--json", str(a)]) == 0
    assert "runs any code" in capsys.readouterr().err
    assert evaluate_main(["--policy", str(tiny_run), "--episodes", "2", "--json", str(b)]) == 0
    from softpvtol_gym.baselines.evaluation import without_timing

    assert [without_timing(e) for e in json.loads(a.read_text())["episodes"]] == [
        without_timing(e) for e in json.loads(b.read_text())["episodes"]]  # compute_us_per_step: wall time
    # and converted back into the safe format, bit for bit
    with pytest.raises(SystemExit):
        export_main(["from-sb3", str(zip_path)])
    assert export_main(["from-sb3", "--trust-pickle", str(zip_path), "--out", str(tmp_path / "safe")]) == 0
    from safetensors.torch import load_file

    x, y = load_file(tiny_run / "model.safetensors"), load_file(tmp_path / "safe" / "model.safetensors")
    assert sorted(x) == sorted(y) and all((x[k] == y[k]).all() for k in x)
    # a safe checkpoint already there is not replaced without --force
    with pytest.raises(SystemExit):
        export_main(["from-sb3", "--trust-pickle", str(zip_path), "--out", str(tmp_path / "safe")])
    assert "already holds a safe checkpoint" in capsys.readouterr().err
    assert export_main(["from-sb3", "--trust-pickle", "--force", str(zip_path), "--out", str(tmp_path / "safe")]) == 0


# ---------------------------------------------------------------------------------- env state
def _walk(obj, path="", seen=None):
    """(path, value) of every leaf of an object graph below softpvtol_gym objects (their pickled state), lists,
    tuples, dicts."""
    seen = set() if seen is None else seen
    if id(obj) in seen:
        return
    if isinstance(obj, np.ndarray):
        yield path, ("array", obj.dtype.str, obj.shape, obj.tobytes() if obj.dtype.kind != "O" else repr(obj))
    elif isinstance(obj, np.random.Generator):
        yield path, ("rng", json.dumps(obj.bit_generator.state, default=str, sort_keys=True))
    elif isinstance(obj, (bool, int, float, str, type(None), np.generic)):
        yield path, obj
    elif isinstance(obj, (list, tuple)):
        seen.add(id(obj))
        for i, v in enumerate(obj):
            yield from _walk(v, f"{path}[{i}]", seen)
    elif isinstance(obj, dict):
        seen.add(id(obj))
        for k, v in obj.items():
            yield from _walk(v, f"{path}[{k!r}]", seen)
    elif type(obj).__module__.startswith("softpvtol_gym") and hasattr(obj, "__dict__"):
        seen.add(id(obj))
        state = obj.__getstate__()  # what the object is (caches that a copy rebuilds left out, e.g. UniformDraws')
        for k, v in (state if isinstance(state, dict) else vars(obj)).items():
            yield from _walk(v, f"{path}.{k}", seen)


@pytest.mark.parametrize("mode", ["residual", "actuators"])
def test_env_state_round_trips_every_attribute_and_steps_identically(mode):
    from softpvtol_gym.envs.sb3 import SoftPVTOLSB3VecEnv

    rng = np.random.default_rng(0)
    a = SoftPVTOLSB3VecEnv(num_envs=3, action_mode=mode, task="hover", tier="noisy")
    dim = a.action_space.shape[0]
    a.seed(5)
    a.reset()
    for _ in range(40):
        a.step(rng.uniform(-1, 1, (3, dim)))
    meta, arrays = env_state(a.venv)
    json.dumps(meta)  # plain data only
    b = SoftPVTOLSB3VecEnv(num_envs=3, action_mode=mode, task="hover", tier="noisy")
    restore_env_state(b.venv, json.loads(json.dumps(meta)), {k: v.copy() for k, v in arrays.items()}, "test")
    wa, wb = dict(_walk(a.venv)), dict(_walk(b.venv))
    assert wa.keys() == wb.keys()
    assert [k for k in wa if wa[k] != wb[k]] == []
    for _ in range(300):  # across episode ends (noisy tier: resets draw from the sub-env generators)
        act = rng.uniform(-1, 1, (3, dim))
        oa, ra, da, _ = a.step(act)
        ob, rb, db, _ = b.step(act)
        assert oa.tobytes() == ob.tobytes() and ra.tobytes() == rb.tobytes() and (da == db).all()


def test_env_state_of_another_layout_is_refused():
    from softpvtol_gym.envs.sb3 import SoftPVTOLSB3VecEnv

    a = SoftPVTOLSB3VecEnv(num_envs=2, action_mode="residual")
    meta, arrays = env_state(a.venv)
    b = SoftPVTOLSB3VecEnv(num_envs=3, action_mode="residual")
    with pytest.raises(CheckpointError, match="does not fit"):
        restore_env_state(b.venv, meta, arrays, "test")
    del meta["sim"]["arrays"][0]
    with pytest.raises(CheckpointError, match="lacks"):
        restore_env_state(SoftPVTOLSB3VecEnv(num_envs=2, action_mode="residual").venv, meta, arrays, "test")


def test_env_state_of_another_configuration_names_the_first_differing_entry():
    from softpvtol_gym.envs.sb3 import SoftPVTOLSB3VecEnv

    a = SoftPVTOLSB3VecEnv(num_envs=2, action_mode="residual")
    meta, arrays = env_state(a.venv)
    arrays = {k: v.copy() for k, v in arrays.items()}
    arrays["controller._no_residual"].flat[-1] += 1.0  # same dtype and shape, another value
    message = (r"controller\._no_residual is float64\(1, 5\) with np\.float64\(1\.0\) at \(0, 4\), this run's config "
               r"gives np\.float64\(0\.0\) there")
    with pytest.raises(CheckpointError, match=message):
        restore_env_state(SoftPVTOLSB3VecEnv(num_envs=2, action_mode="residual").venv, meta, arrays, "test")


# --------------------------------------------------------------------------- no dead ends
def test_corrupt_newest_checkpoint_falls_back_to_the_previous_one(tmp_path, tiny_run, capsys):
    run = copy_run(tiny_run, tmp_path / "run")
    newest = run / "checkpoints" / (run / "checkpoints" / "latest").read_text()
    data = bytearray((newest / "model.safetensors").read_bytes())
    data[-5] ^= 0xFF  # one flipped bit in a weight: only the checksum notices
    (newest / "model.safetensors").write_bytes(bytes(data))
    assert latest_checkpoint(run).name == "step_0000000256"
    assert train_main(["--timesteps", "768", *TINY, "--out", str(run), "--resume"]) == 0
    err = capsys.readouterr().err
    assert "corrupt" in err and "previous checkpoint" in err and "step_0000000256" in err


def test_out_of_range_rng_integer_in_the_newest_resume_state_falls_back_to_the_previous_checkpoint(tmp_path, tiny_run,
                                                                                                    capsys):
    run = copy_run(tiny_run, tmp_path / "run")
    newest = run / "checkpoints" / (run / "checkpoints" / "latest").read_text()
    state = json.loads((newest / "resume_state.json").read_text())
    state["numpy_rng"]["pos"] = 2**70
    (newest / "resume_state.json").write_text(json.dumps(state))
    rewrite_manifest(newest)
    assert train_main(["--timesteps", "768", *TINY, "--out", str(run), "--resume"]) == 0
    err = capsys.readouterr().err
    assert "invalid RNG state" in err and "previous checkpoint" in err and "step_0000000256" in err, err


def test_saving_the_same_model_twice_gives_byte_identical_files(tmp_path, tiny_run):
    """safetensors writes its metadata in a hash map's order, which varies between saves (one in two differed):
    the saved file sorts it, so that identical runs have identical file hashes."""
    from softpvtol_gym.baselines.checkpoints.load import load_folder
    from softpvtol_gym.baselines.checkpoints.model_state import save_model

    model = load_folder(tiny_run)[0]
    saved = set()
    for i in range(16):
        (tmp_path / str(i)).mkdir()
        save_model(model, tmp_path / str(i))
        saved.add((tmp_path / str(i) / "model.safetensors").read_bytes())
    assert len(saved) == 1
    data = saved.pop()
    header = data[8:8 + int.from_bytes(data[:8], "little")]
    assert header.startswith(b'{"__metadata__":{"format":"softpvtol-gym checkpoint","version":"1"}')


def test_latest_pointer_is_validated(tmp_path, tiny_run):
    run = copy_run(tiny_run, tmp_path / "run")
    (tmp_path / "elsewhere").mkdir()
    for content in (f"{UP}/{UP}/elsewhere", "/etc", "step_1", "step_0000000256/../../x"):
        (run / "checkpoints" / "latest").write_text(content)
        assert latest_checkpoint(run).name == "step_0000000512"  # the pointer ignored, the newest step used


def test_norm_obs_run_without_its_normalisation_is_an_error(tmp_path, tiny_run):
    run = copy_run(tiny_run, tmp_path / "run")
    (run / "vecnormalize.json").unlink()
    rewrite_manifest(run)
    with pytest.raises(CheckpointError, match="normalisation"):
        from softpvtol_gym.baselines.training.policy import LearnedPolicy

        LearnedPolicy.load(run)


def test_resume_on_a_finished_run_says_so_and_exits_0(tmp_path, tiny_run, capsys):
    run = copy_run(tiny_run, tmp_path / "run")
    before = {p: p.stat().st_mtime_ns for p in run.rglob("*") if p.is_file()}
    assert train_main(["--out", str(run), "--resume"]) == 0  # options left out: the run's own
    assert "finished run (512 steps" in capsys.readouterr().out
    assert {p: p.stat().st_mtime_ns for p in run.rglob("*") if p.is_file() and ".softpvtol.lock" not in p.name} \
        == {p: t for p, t in before.items() if ".softpvtol.lock" not in p.name}


@pytest.mark.parametrize("resume", [False, True])
def test_run_killed_before_its_first_checkpoint_restarts_with_the_same_command(tmp_path, resume, capsys):
    out = tmp_path / "run"
    out.mkdir()
    (out / "config.yaml").write_text("algo: ppo\n")  # what a run killed early (or an old bad --hp) leaves
    (out / ".model.safetensors.999999.0123abcd.tmp").write_bytes(b"half")  # a killed writer's temp file
    (out / "checkpoints").mkdir()
    (out / "checkpoints" / ".tmp_step_0000000256_999999").mkdir()  # an earlier version's temp checkpoint
    assert train_main(["--timesteps", "256", *TINY, "--out", str(out), *(["--resume"] if resume else [])]) == 0
    assert (out / MANIFEST_FILE).is_file()
    assert not list(out.glob(".*.tmp")) and not list((out / "checkpoints").glob(".tmp*"))


def test_bad_hp_does_not_block_the_corrected_command(tmp_path, capsys):
    out = tmp_path / "run"
    with pytest.raises(SystemExit) as exc:
        train_main(["--timesteps", "256", *TINY, "--hp", "learning_rate=-1", "--out", str(out)])
    assert exc.value.code == 2 and not out.exists()
    assert train_main(["--timesteps", "256", *TINY, "--out", str(out)]) == 0


def test_progress_bar_ends_at_its_total(tmp_path, capsys):
    from softpvtol_gym.baselines.config.hyperparams import load_hyperparams
    from softpvtol_gym.baselines.config.run_config import RunConfig
    from softpvtol_gym.baselines.training.loop import _ProgressBar, prepare

    hp = {**load_hyperparams("ppo", "residual"), "n_steps": 64, "batch_size": 64, "n_envs": 4}
    config = RunConfig(timesteps=300, n_envs=4, hyperparams=hp)
    _, _, model = prepare(config, tmp_path / "x")
    total = _ProgressBar.planned_steps(model, 300)
    assert total == 512  # whole rollouts of 4 x 64
    bar = _ProgressBar.callback(total)
    model.learn(300, callback=bar)
    assert model.num_timesteps == 512 and bar.n == bar.total == 512


# ------------------------------------------------------------------------------- atomic writes
def test_atomic_write_replaces_whole_files_and_cleans_up(tmp_path):
    target = tmp_path / "r.json"
    atomic_write_text(target, "old")
    with pytest.raises(RuntimeError), atomic_path(target) as tmp:
        tmp.write_text("half")
        raise RuntimeError("killed")
    assert target.read_text() == "old" and sorted(p.name for p in tmp_path.iterdir()) == ["r.json"]
    dead = tmp_path / ".r.json.999999.0123abcd.tmp"  # left by a killed process (pid 999999 is not running)
    dead.write_text("x")
    live = tmp_path / f".r.json.{os.getpid()}.0123abcd.tmp"
    live.write_text("x")
    atomic_write_text(target, "new")
    assert target.read_text() == "new" and not dead.exists() and live.exists()
    assert clean_stale_temps(tmp_path, everything=True) == []  # our own temp files are never removed
    live.unlink()


def test_every_result_writer_uses_the_atomic_helper():
    """No result is written with a plain write_text / open(..., 'w') / savefig to its final path."""
    import re

    files = [*sorted((ROOT / "softpvtol_gym" / "baselines").rglob("*.py")), *sorted((ROOT / "baselines").glob("*.py")),
             *sorted((ROOT / "benchmarks").glob("*.py")), ROOT / "train.py"]
    pattern = re.compile(r"\.write_text\(|\.write_bytes\(|open\([^)]*['\"]w|savefig\((?!tmp)|json\.dump\(")
    offenders = [f"{f.name}:{i}" for f in files for i, line in enumerate(f.read_text().splitlines(), 1)
                 if pattern.search(line) and "atomic" not in f.name and "tmp" not in line]
    assert offenders == []


# -------------------------------------------------------------------------------------- locks
def test_a_second_user_of_a_locked_run_gets_exit_2_naming_the_holder(tmp_path, lock_holder, capsys):
    out = tmp_path / "run"
    proc = lock_holder(out)
    with pytest.raises(LockedError, match=f"pid {proc.pid} on host"):
        DirectoryLock(out, "run directory").acquire()
    with pytest.raises(SystemExit) as exc:
        train_main(["--timesteps", "256", *TINY, "--out", str(out)])
    err = capsys.readouterr().err
    assert exc.value.code == 2 and f"is in use by pid {proc.pid}" in err and len(err.strip().splitlines()) == 1
    assert sorted(p.name for p in out.iterdir()) == [".softpvtol.lock", ".softpvtol.lock.json"]


def test_lock_is_reentrant_in_one_thread_and_exclusive_across_threads(tmp_path):
    with DirectoryLock(tmp_path, "d"), DirectoryLock(tmp_path, "d"):
        errors = []

        def other():
            try:
                DirectoryLock(tmp_path, "d").acquire()
            except LockedError as exc:
                errors.append(exc)

        t = threading.Thread(target=other)
        t.start()
        t.join()
        assert len(errors) == 1
    with DirectoryLock(tmp_path, "d"):  # released
        pass


# --------------------------------------------------------------------------------------- paths
def test_escaping_job_name_is_refused_before_anything_is_written(tmp_path, capsys):
    from softpvtol_gym.baselines.commands.run_jobs import main as run_jobs_main

    spec = tmp_path / "spec.yml"
    spec.write_text("evaluation: {episodes: 1, seed: 1000000, tiers: [nominal]}\n"
                    f"passivity: [{{name: '{UP}/{UP}/{UP}/{UP}/x', allocation: exact}}]\n"
                    "tasks: [hover]\ntrained: []\nseeds: []\n")
    with pytest.raises(SystemExit) as exc:
        run_jobs_main(["--spec", str(spec), "--root", str(tmp_path / "root")])
    assert exc.value.code == 2 and "name" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["spec.yml"]


def test_paths_stay_under_the_root(tmp_path):
    from softpvtol_gym.baselines.leaderboard.jobs import Job
    from softpvtol_gym.baselines.util.paths import check_slug, under

    (tmp_path / "root").mkdir()
    os.symlink(tmp_path, tmp_path / "root" / "link")
    for bad in (f"{UP}/x", "/etc/x", "a/../../x", "link/x"):
        with pytest.raises(ConfigError):
            under(tmp_path / "root", bad)
    assert under(tmp_path / "root", "a/b") == tmp_path / "root" / "a" / "b"
    for bad in ("..", ".x", "A", "a/b", "a b", "", "a..b", None, 3):
        with pytest.raises(ConfigError):
            check_slug(bad, "name")
    job = Job(policy="passivity-exact", action_mode="actuators", task="hover", train_tier=None, seed=0,
              eval_tiers=("nominal",), eval_episodes=1, eval_seed=1_000_000)
    assert job.folder(tmp_path / "root") == tmp_path / "root" / "passivity-exact_hover"


# --------------------------------------------------------------------------- what is committed
def test_no_pickle_is_committed():
    """`git ls-files '*.pkl'` is empty and no committed archive holds a pickle (CI unpickles nothing)."""
    try:
        files = subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True, check=True).stdout.split()
    except (OSError, subprocess.CalledProcessError):
        pytest.skip("not a git checkout")
    assert [f for f in files if f.endswith((".pkl", ".pickle", ".pth", ".pt"))] == []
    for f in files:
        if f.endswith((".zip", ".npz")) and (ROOT / f).is_file():
            with zipfile.ZipFile(ROOT / f) as z:
                for name in z.namelist():
                    head = z.read(name)[:2]
                    assert name != "data" and not name.endswith((".pkl", ".pth")) and head != b"\x80\x04", (f, name)


def test_committed_checkpoints_are_in_the_safe_format():
    from softpvtol_gym.baselines.leaderboard.jobs import load_jobs
    from tests.conftest import RUNS_DIR

    models = sorted(RUNS_DIR.glob("*/seed_*/model.safetensors"))
    # one per learned job of the spec, 5 seeds each
    assert len(models) == sum(job.learned for job in load_jobs()) == 135
    ablation = sorted((RUNS_DIR.parent / "ablation_runs").glob("*/seed_*/model.safetensors"))
    assert len(ablation) == 18  # baselines/ablation.yml: 6 recipes x 3 seeds
    for m in models + ablation:
        assert find_checkpoint(m) == m.parent and not list(m.parent.glob("*.pkl")) and not list(m.parent.glob("*.zip"))


def test_hyperparameter_validation_covers_the_installed_sb3():
    from softpvtol_gym.baselines.config.validation import _check_sb3_signature

    _check_sb3_signature("ppo")
    _check_sb3_signature("sac")


def test_missing_baselines_extra_is_named(tmp_path):
    code = ("import sys; sys.modules['yaml'] = None; sys.argv = ['train.py']; import runpy; "
            f"runpy.run_path({str(ROOT / 'train.py')!r}, run_name='__main__')")
    r = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=300,
                       env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert r.returncode == 2 and "pip install 'softpvtol-gym[baselines]'" in r.stderr and "pyyaml" in r.stderr
    assert "Traceback" not in r.stderr and len(r.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "runs").exists()


@pytest.mark.slow  # one 4,096-step PPO training (a single rollout of the leaderboard's hyperparameters)
def test_learned_job_trains_commits_a_safe_model_and_reevaluates_identically(tmp_path):
    from concurrent.futures import ThreadPoolExecutor

    from softpvtol_gym.baselines.leaderboard.jobs import EVAL_FILE, load_jobs, reevaluate_job, run_jobs

    spec = tmp_path / "spec.yml"
    spec.write_text("evaluation: {episodes: 2, seed: 1000000, tiers: [nominal]}\npassivity: []\ntasks: [hover]\n"
                    "trained: [{action_mode: actuators, task: hover, tier: nominal, timesteps: 64}]\nseeds: [0]\n")
    (job,) = load_jobs(spec)
    root = tmp_path / "runs"
    # a training folder left by a job killed before its first checkpoint does not block it
    (root / (job.name + ".run")).mkdir(parents=True)
    (root / (job.name + ".run") / "config.yaml").write_text("algo: ppo\n")
    with ThreadPoolExecutor(max_workers=1) as ex:
        assert run_jobs([job], ex, root) == [job.name]
    out = job.folder(root)
    assert sorted(p.name for p in out.iterdir()) == ["checkpoint.json", "config.yaml", "eval.json", "evaluations.json",
                                                      "model.json", "model.safetensors", "vecnormalize.json"]
    assert not (root / (job.name + ".run")).exists() and find_checkpoint(out) == out
    from softpvtol_gym.baselines.evaluation import without_timing

    record = json.loads((out / EVAL_FILE).read_text())
    assert record["checkpoint"].endswith("seed_0/model.safetensors") and record["train_seconds"] > 0
    reevaluate_job(job, root)
    again = json.loads((out / EVAL_FILE).read_text())
    assert {k: v for k, v in again.items() if k != "eval"} == {k: v for k, v in record.items() if k != "eval"}
    assert {t: [without_timing(e) for e in eps] for t, eps in again["eval"].items()} == {
        t: [without_timing(e) for e in eps] for t, eps in record["eval"].items()}  # all but the wall time


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
    "generator_state_negative": (lambda a, m: m["venv"]["generators"]["_rngs"][0]["state"].__setitem__("state", -1),
                                 "_rngs[0]"),
    "generator_state_too_large": (
        lambda a, m: m["venv"]["generators"]["_rngs"][1]["state"].__setitem__("state", 2**200), "_rngs[1]"),
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
    "numpy_rng_pos_too_large": (lambda s, a: s["numpy_rng"].__setitem__("pos", 2**70), "invalid RNG state"),
    "python_rng_word_too_large": (lambda s, a: s["python_rng"][1].__setitem__(0, 2**200), "invalid RNG state"),
    "env_generator_state_negative": (
        lambda s, a: s["env"]["venv"]["generators"]["_rngs"][0]["state"].__setitem__("state", -1), "_rngs[0]"),
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
    "last_obs_wrong_shape": (lambda r: _edit_tensor(r, "attributes/_last_obs", lambda t: t[:, :5].contiguous()),
                             "attributes/_last_obs is float32(4, 5), this run needs float(4, 18)"),
    "episode_starts_wrong_shape": (lambda r: _edit_tensor(r, "attributes/_last_episode_starts",
                                                          lambda t: t.repeat(2)),
                                   "attributes/_last_episode_starts is bool(8,), this run needs bool(4,)"),
    "episode_starts_floats": (lambda r: _edit_tensor(r, "attributes/_last_episode_starts", lambda t: t.float()),
                              "attributes/_last_episode_starts is float32(4,)"),
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
                       (lambda: loads_yaml("a: !!python/object:os.system x\n", "f.yml"), "f.yml"),
                       (lambda: loads_yaml(b"task: caf\xe9\n", "f.yml"), "is not UTF-8 text"),
                       (lambda: loads_json(b'{"task": "caf\xe9"}', "f.json"), "is not valid JSON")):
        with pytest.raises(UnsafeInputError, match=what) as exc:
            call()
        assert str(exc.value).startswith("f.") and "\n" not in str(exc.value)


def test_a_config_that_is_not_utf8_is_one_error_even_with_a_matching_manifest(tmp_path):
    from softpvtol_gym.baselines.training.policy import LearnedPolicy

    run = copy_run(ROOT / "results/leaderboard_runs/distilled-integral-small_track_random_nominal/seed_0",
                   tmp_path / "run")
    config = run / "config.yaml"
    config.write_bytes(config.read_bytes().replace(b"actuators", b"actuat\xe9rs", 1))
    rewrite_manifest(run)
    with pytest.raises(CheckpointError, match=r"config\.yaml is not UTF-8 text \('utf-8' codec can't decode"):
        LearnedPolicy.load(run)


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
