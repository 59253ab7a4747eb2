"""The committed results as archives: slim, reproducible, read back without trust, and equal to what they unpack to."""

from __future__ import annotations

import io
import json
import lzma
import subprocess
import tarfile

import numpy as np
import pytest

from softpvtol_gym.baselines.checkpoints.compact import compact_checkpoint, optimizer_tensors
from softpvtol_gym.baselines.packed_results import ARCHIVE_DIR, archives, differences, pack, unpack
from softpvtol_gym.baselines.util.archive import ArchiveError, archive_members, folder_files, pack_file, pack_files
from softpvtol_gym.baselines.util.shared_lists import FORMAT_KEY, REF_KEY, is_thin
from tests.conftest import RESULTS, ROOT, UP, copy_run
from tests.package.test_no_outside_paths import MACHINE

#: what the tracked results may weigh and count (the trained runs and the per-episode detail are archives, the
#: leaderboard JSON a thin one; the bulk is the float32 weights, about 0.4 MB per 256 x 256 seed, which compress
#: little)
MAX_TRACKED_BYTES, MAX_TRACKED_FILES = 15_000_000, 200


def _tracked_results() -> list[str]:
    out = subprocess.run(["git", "ls-files", "-z", "results"], cwd=ROOT, capture_output=True, check=True).stdout
    return [n for n in out.decode().split("\0") if n]


def test_tracked_results_are_slim():
    names = _tracked_results()
    if not names:
        pytest.skip("not a git checkout")
    size = sum((ROOT / n).stat().st_size for n in names)
    assert len(names) <= MAX_TRACKED_FILES, len(names)
    assert size <= MAX_TRACKED_BYTES, f"{size:,} bytes tracked under results/"
    assert not [n for n in names if n.startswith(("results/leaderboard_runs/", "results/ablation_runs/",
                                                  "results/distill_runs/")) or n == "results/leaderboard.json"]


def test_committed_archives_agree_with_the_results_they_unpack_to():
    assert len(archives(RESULTS)) > 40
    assert differences(RESULTS) == []


def test_committed_archives_name_no_machine_path():
    found = []
    for p in archives(RESULTS):
        data = p.archive.read_bytes()
        members = archive_members(data, p.key) if p.is_folder else {p.target.name: p.target.read_bytes()}
        for name, data in members.items():
            found += [f"{p.key}:{name}: {m}" for m in MACHINE.findall(data.decode("utf-8", "replace"))]
    assert found == []


def test_committed_checkpoints_hold_no_optimizer_state():
    from safetensors import safe_open

    models = sorted(RESULTS.glob("*_runs/**/model.safetensors"))
    assert len(models) > 100
    for model in models:
        meta = json.loads((model.parent / "model.json").read_text())
        with safe_open(str(model), "numpy") as f:
            assert optimizer_tensors(f.keys(), meta) == [], model
        assert all(not o["params_with_state"] for o in meta["optimizers"].values()), model
        with safe_open(str(model), "numpy") as f:  # the critic: kept by the students fine-tuning starts from only
            has_critic = any("value_net" in name for name in f.keys())
        assert has_critic == (model.parent / "distill.json").is_file(), model


def test_pack_is_reproducible_and_reads_back(tmp_path):
    files = {"b/c.json": b'{"x": 1}', "a.txt": b"hello"}
    data = pack_files(files)
    assert pack_files(dict(reversed(list(files.items())))) == data
    assert archive_members(data, "x") == files
    (tmp_path / "b").mkdir()
    for name, content in files.items():
        (tmp_path / name).write_bytes(content)
    assert pack_files(folder_files(tmp_path)) == data


def _tar_xz(add) -> bytes:
    buffer = io.BytesIO()
    with tarfile.open(fileobj=buffer, mode="w") as tar:
        add(tar)
    return lzma.compress(buffer.getvalue())


def _member(tar, name: str, kind=tarfile.REGTYPE, data: bytes = b"x"):
    info = tarfile.TarInfo(name)
    info.type, info.size = kind, (len(data) if kind == tarfile.REGTYPE else 0)
    if kind == tarfile.SYMTYPE:
        info.linkname = "/etc/passwd"
    tar.addfile(info, io.BytesIO(data) if kind == tarfile.REGTYPE else None)


@pytest.mark.parametrize("data, message", [
    (b"not xz at all", "is not an xz file"),
    (lzma.compress(b"plain text, no tar"), "is not a tar archive"),
    (pack_files({"a": b"x" * 1000})[:-40], "truncated"),
    (_tar_xz(lambda t: _member(t, f"{UP}/outside.txt")), "is not a relative path inside the folder"),
    (_tar_xz(lambda t: _member(t, "/etc/cron.d/x")), "is not a relative path inside the folder"),
    (_tar_xz(lambda t: _member(t, "link", tarfile.SYMTYPE)), "is not a regular file"),
])
def test_a_crafted_archive_is_one_error(data, message):
    with pytest.raises(ArchiveError, match=message):
        archive_members(data, "crafted.tar.xz")


def test_compact_checkpoint_keeps_the_policy_and_drops_the_moments(tiny_run, tmp_path):
    from softpvtol_gym.baselines.checkpoints.load import load_folder

    run = copy_run(tiny_run, tmp_path / "run")
    before, _, _, _ = load_folder(run)
    assert compact_checkpoint(run) is True
    assert compact_checkpoint(run) is False  # nothing left to drop: nothing written
    after, _, _, _ = load_folder(run)  # the manifest verifies, the strict loader accepts it
    obs = np.random.default_rng(0).normal(size=(5, *before.observation_space.shape)).astype(np.float32)
    assert np.array_equal(before.predict(obs, deterministic=True)[0], after.predict(obs, deterministic=True)[0])
    for a, b in zip(before.policy.state_dict().values(), after.policy.state_dict().values()):
        assert np.array_equal(a.numpy(), b.numpy())
    assert after.policy.optimizer.state_dict()["state"] == {}
    assert before.policy.optimizer.state_dict()["state"] != {}


def test_compact_checkpoint_can_drop_the_critic_and_the_actor_replays_unchanged(tiny_run, tmp_path):
    from safetensors import safe_open

    from softpvtol_gym.baselines.checkpoints.load import load_folder
    from softpvtol_gym.baselines.errors import CheckpointError

    run = copy_run(tiny_run, tmp_path / "run")
    before, _, _, _ = load_folder(run)
    assert compact_checkpoint(run, drop_value_function=True) is True
    assert compact_checkpoint(run, drop_value_function=True) is False
    with safe_open(str(run / "model.safetensors"), "numpy") as f:
        kept = set(f.keys())
    meta = json.loads((run / "model.json").read_text())
    assert meta["tensors_dropped"] and not kept & set(meta["tensors_dropped"])
    assert all("value_net" in name for name in meta["tensors_dropped"])
    after, _, _, _ = load_folder(run)
    again, _, _, _ = load_folder(run)
    obs = np.random.default_rng(0).normal(size=(5, *before.observation_space.shape)).astype(np.float32)
    assert np.array_equal(before.predict(obs, deterministic=True)[0], after.predict(obs, deterministic=True)[0])
    b, a, c = before.policy.state_dict(), after.policy.state_dict(), again.policy.state_dict()
    for name in b:
        critic = f"policy/{name}" in meta["tensors_dropped"]
        assert np.array_equal(b[name].numpy(), a[name].numpy()) != critic, name  # the critic: a fresh one
        assert np.array_equal(a[name].numpy(), c[name].numpy()), name  # the same fresh one on every load

    meta["tensors_dropped"].append("policy/not_a_tensor")
    (run / "model.json").write_text(json.dumps(meta, indent=1))
    from softpvtol_gym.baselines.checkpoints.manifest import read_manifest, write_manifest

    manifest = read_manifest(run)
    write_manifest(run, list(manifest["files"]), manifest["algo"], manifest["num_timesteps"], manifest["kind"])
    with pytest.raises(CheckpointError, match="tensors_dropped names tensors the model does not have"):
        load_folder(run)


def test_pack_then_unpack_gives_the_same_folders(tiny_run, tmp_path):
    results = tmp_path / "results"
    copy_run(tiny_run, results / "leaderboard_runs" / "job_a" / "seed_0")
    (results / "leaderboard_runs" / "job_a" / "seed_0" / "datasets").mkdir()
    (results / "leaderboard_runs" / "job_a" / "seed_0" / "datasets" / "big.npz").write_bytes(b"cache")
    (results / "leaderboard.json").write_text('{"meta": {}}')
    written = pack(results)
    assert sorted(p.key for p in written) == [f"{ARCHIVE_DIR}/leaderboard.json.xz",
                                              f"{ARCHIVE_DIR}/leaderboard_runs/job_a.tar.xz"]
    assert pack(results) == []  # the same folders: the same bytes, nothing written
    assert differences(results) == []  # a distilled run's cached datasets are not packed
    kept = sorted(p.relative_to(results) for p in (results / "leaderboard_runs").rglob("*") if p.is_file())

    # a fresh clone: only the archives
    clone = tmp_path / "clone"
    clone.mkdir()
    (clone / ARCHIVE_DIR).mkdir()
    subprocess.run(["cp", "-r", str(results / ARCHIVE_DIR), str(clone)], check=True)
    done, left = unpack(clone)
    assert len(done) == 2 and left == []
    assert json.loads((clone / "leaderboard.json").read_text()) == {"meta": {}}
    unpacked = sorted(p.relative_to(clone) for p in (clone / "leaderboard_runs").rglob("*") if p.is_file())
    assert unpacked == [k for k in kept if "datasets" not in k.parts]
    assert differences(clone) == []
    assert unpack(clone) == ([], [])  # unchanged archives: nothing unpacked again


def test_the_leaderboard_json_is_archived_thin_and_rebuilt_from_the_job_folders(tmp_path):
    results = tmp_path / "results"
    episodes = [{"rms_position_error": 0.1 * k + 1e-17, "crashed": k == 2} for k in range(3)]
    (results / "leaderboard_runs" / "job_a" / "seed_0").mkdir(parents=True)
    (results / "leaderboard_runs" / "job_a" / "seed_0" / "eval.json").write_text(
        json.dumps({"eval": {"nominal": episodes}}))
    board = json.dumps({"meta": {}, "cells": [{"entry": "a", "episodes": episodes}] * 50}, indent=1).encode()
    (results / "leaderboard.json").write_bytes(board)
    pack(results)
    archived = lzma.decompress((results / ARCHIVE_DIR / "leaderboard.json.xz").read_bytes())
    assert is_thin(archived) and b"rms_position_error" not in archived  # the episodes: referred to, not copied

    clone = tmp_path / "clone"
    clone.mkdir()
    subprocess.run(["cp", "-r", str(results / ARCHIVE_DIR), str(clone)], check=True)
    unpack(clone)
    assert (clone / "leaderboard.json").read_bytes() == board
    assert differences(clone) == []
    (clone / "leaderboard_runs" / "job_a" / "seed_0" / "eval.json").write_text("{}")  # a job folder edited by hand
    assert any("leaderboard_runs/job_a/seed_0/eval.json is not the file it was made from" in d
               for d in differences(clone))


def test_a_thin_archive_reads_no_file_of_its_own_choosing(tmp_path):
    (tmp_path / ARCHIVE_DIR).mkdir()
    (tmp_path / "secret.json").write_text('{"x": [{"a": 1}]}')
    crafted = {FORMAT_KEY: 1, "sha256": "0" * 64, "sources": {}, "document": {"x": {REF_KEY: ["secret.json", "x"]}}}
    (tmp_path / ARCHIVE_DIR / "leaderboard.json.xz").write_bytes(pack_file(json.dumps(crafted).encode()))
    with pytest.raises(ArchiveError, match="secret.json is missing"):
        unpack(tmp_path)
    assert not (tmp_path / "leaderboard.json").exists()


def test_unpack_keeps_a_folder_no_archive_wrote_unless_forced(tiny_run, tmp_path):
    results = tmp_path / "results"
    copy_run(tiny_run, results / "leaderboard_runs" / "job_a" / "seed_0")
    pack(results)
    (results / ".unpacked.json").unlink()  # the folder is now one that no archive wrote (work of its own)
    (results / "leaderboard_runs" / "job_a" / "mine.txt").write_text("my work")
    done, kept = unpack(results)
    assert done == [] and [p.key for p in kept] == [f"{ARCHIVE_DIR}/leaderboard_runs/job_a.tar.xz"]
    assert (results / "leaderboard_runs" / "job_a" / "mine.txt").is_file()
    done, kept = unpack(results, force=True)
    assert len(done) == 1 and kept == []
    assert not (results / "leaderboard_runs" / "job_a" / "mine.txt").exists()
    assert differences(results) == []


def test_an_archive_that_changed_replaces_its_folder(tiny_run, tmp_path):
    results = tmp_path / "results"
    (results / "distill_runs" / "x").mkdir(parents=True)
    (results / "distill_runs" / "x" / "distill.json").write_text("1")
    pack(results)
    unpack(results)
    archive = results / ARCHIVE_DIR / "distill_runs" / "x.tar.xz"
    archive.write_bytes(pack_files({"distill.json": b"2"}))  # what a git pull brings
    assert differences(results) == [f"{results / 'distill_runs/x/distill.json'} differs from "
                                    f"{ARCHIVE_DIR}/distill_runs/x.tar.xz"]
    done, _ = unpack(results)
    assert [p.key for p in done] == [f"{ARCHIVE_DIR}/distill_runs/x.tar.xz"]
    assert (results / "distill_runs" / "x" / "distill.json").read_text() == "2"


def test_results_command_check_and_bad_input(tmp_path, capsys):
    from softpvtol_gym.baselines.commands.results import main

    (tmp_path / "distill_runs" / "x").mkdir(parents=True)
    (tmp_path / "distill_runs" / "x" / "distill.json").write_text("1")
    assert main(["check", "--results", str(tmp_path)]) == 1
    assert "has no archive" in capsys.readouterr().out
    assert main(["pack", "--results", str(tmp_path)]) == 0
    assert main(["check", "--results", str(tmp_path)]) == 0
    (tmp_path / ARCHIVE_DIR / "distill_runs" / "x.tar.xz").write_bytes(b"garbage, and longer than an xz header")
    (tmp_path / ".unpacked.json").unlink()
    import shutil

    shutil.rmtree(tmp_path / "distill_runs" / "x")
    with pytest.raises(SystemExit) as exc:
        main(["unpack", "--results", str(tmp_path)])
    err = capsys.readouterr().err
    assert exc.value.code == 2 and "x.tar.xz is not an xz file" in err and len(err.strip().splitlines()) == 1
    with pytest.raises(SystemExit) as exc:
        main(["pack", "--force", "--results", str(tmp_path)])
    assert exc.value.code == 2 and "--force is an option of unpack only" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["check", "--results", str(tmp_path / "missing")])
    assert "is not a folder" in capsys.readouterr().err
