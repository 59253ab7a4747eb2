"""Issue 13: checkpoints that cannot run code, atomic writes, locks, safe paths, no dead ends."""

from __future__ import annotations

import base64
import json
import os
import pickle
import shutil
import subprocess
import sys
import threading
import zipfile
from pathlib import Path

import numpy as np
import pytest
from conftest import ROOT, TINY, copy_run, rewrite_manifest

from softpvtol_gym.baselines.checkpoints.manifest import LEGACY_FILES, MANIFEST_FILE
from softpvtol_gym.baselines.checkpoints.resume import env_state, restore_env_state
from softpvtol_gym.baselines.checkpoints.store import find_checkpoint, latest_checkpoint
from softpvtol_gym.baselines.commands.evaluate import main as evaluate_main
from softpvtol_gym.baselines.commands.train import main as train_main
from softpvtol_gym.baselines.errors import CheckpointError, ConfigError, LockedError
from softpvtol_gym.baselines.util.atomic import atomic_path, atomic_write_text, clean_stale_temps
from softpvtol_gym.baselines.util.locks import DirectoryLock


# ----------------------------------------------------------------------------------- poisoned files
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


def test_latest_pointer_is_validated(tmp_path, tiny_run):
    run = copy_run(tiny_run, tmp_path / "run")
    (tmp_path / "elsewhere").mkdir()
    for content in ("../../elsewhere", "/etc", "step_1", "step_0000000256/../../x"):
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
                    "passivity: [{name: '../../../../x', allocation: exact}]\ntasks: [hover]\ntrained: []\nseeds: []\n")
    with pytest.raises(SystemExit) as exc:
        run_jobs_main(["--spec", str(spec), "--root", str(tmp_path / "root")])
    assert exc.value.code == 2 and "name" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["spec.yml"]


def test_paths_stay_under_the_root(tmp_path):
    from softpvtol_gym.baselines.leaderboard.jobs import Job
    from softpvtol_gym.baselines.util.paths import check_slug, under

    (tmp_path / "root").mkdir()
    os.symlink(tmp_path, tmp_path / "root" / "link")
    for bad in ("../x", "/etc/x", "a/../../x", "link/x"):
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
    from conftest import RUNS_DIR

    from softpvtol_gym.baselines.leaderboard.jobs import load_jobs

    models = sorted(RUNS_DIR.glob("*/seed_*/model.safetensors"))
    # one per learned job of the spec: v2's 50 and leaderboard v4's four recipe cells x 5 seeds
    assert len(models) == sum(job.learned for job in load_jobs()) == 70
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
