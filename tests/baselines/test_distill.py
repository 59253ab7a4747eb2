"""Distillation: behaviour cloning and DAgger rounds end to end on a tiny budget, labels from the teacher,
the cached datasets and an exact resume, the student loaded like any run, bad input."""

from __future__ import annotations

import dataclasses
import json
import shutil

import numpy as np
import pytest

from softpvtol_gym.baselines.errors import ConfigError
from softpvtol_gym.baselines.training.distill import (
    DATASET_DIR,
    DISTILL_FILE,
    DistillConfig,
    collect,
    distill,
    teacher_policy,
)
from softpvtol_gym.baselines.training.policy import LearnedPolicy

from ._teachers import LinearTeacher, ZeroStudent

#: the env options of the integral loop's students (teacher_integral, the default)
STUDENT_OPTIONS = {"observe_error_integral": True, "error_integral_limit": 8.0, "error_integral_error_limit": 0.5}
#: hover (1,000 steps an episode): 2 rounds of 2 episodes, a few epochs: seconds
TINY = dict(teacher="integral", task="hover", rounds=2, episodes=2, epochs=3, batch_size=256, eval_episodes=1,
            net_arch=(16, 16))


@pytest.fixture(scope="module")
def distilled(tmp_path_factory):
    out = tmp_path_factory.mktemp("distill") / "student"
    return out, distill(DistillConfig(**TINY), out)


@pytest.mark.xdist_group("distilled")  # one worker computes the module fixture once
def test_a_tiny_distillation_is_a_run_that_loads_and_acts(distilled):
    out, result = distilled
    record = json.loads((out / DISTILL_FILE).read_text())
    assert [r["kind"] for r in record["rounds"]] == ["behaviour cloning", "dagger"]
    assert record["rounds"][0]["samples"] == 2_000  # 2 teacher-flown hover episodes of 1,000 steps
    assert record["rounds"][1]["aggregate"] == 2_000 + record["rounds"][1]["samples"]
    assert all(len(r["losses"]) == TINY["epochs"] and np.isfinite(r["losses"]).all() for r in record["rounds"])
    assert record["rounds"][0]["losses"][-1] < record["rounds"][0]["losses"][0]
    assert set(record["rounds"][0]["evaluation"]["nominal"]) == {"student", "teacher"}
    assert sorted(p.name for p in (out / DATASET_DIR).iterdir()) == ["round_00_nominal.npz", "round_01_nominal.npz"]
    policy, config = LearnedPolicy.load(out)
    # the integral loop's student observes the error integrals as its teacher integrates them
    assert (config.action_mode, config.env_options) == ("actuators", STUDENT_OPTIONS)
    obs = np.zeros((3, 21), np.float32)
    action, _ = policy.predict(obs, episode_start=np.ones(3, bool))
    assert action.shape == (3, 4) and np.all(np.abs(action) <= 1)
    # the saved student is the one distill returned
    np.testing.assert_array_equal(action, result["policy"].predict(obs, episode_start=np.ones(3, bool))[0])


@pytest.mark.xdist_group("distilled")  # one worker computes the module fixture once
def test_the_fit_learns_a_smooth_map_with_the_datas_normalisation(distilled):
    from softpvtol_gym.baselines.training.distill import _fresh_student, fit

    out, _ = distilled
    rng = np.random.default_rng(0)
    obs = (rng.normal(size=(2048, 21)) * np.linspace(0.1, 10, 21) + np.arange(21)).astype(np.float32)
    labels = np.tanh((obs - np.arange(21)) / np.linspace(0.1, 10, 21) @ rng.normal(size=(21, 4)) / 5).astype(np.float32)
    _, vecnorm, model = _fresh_student(DistillConfig(**{**TINY, "net_arch": (64, 64)}), out.parent / "fit", len(obs))
    losses = fit(model, vecnorm, obs, labels, epochs=60, batch_size=128, learning_rate=3e-3, seed=0)
    np.testing.assert_allclose(vecnorm.obs_rms.mean, obs.mean(axis=0), rtol=1e-6)
    np.testing.assert_allclose(vecnorm.obs_rms.var, obs.var(axis=0), rtol=1e-5)
    assert losses[-1] < 0.02 * np.var(labels, axis=0).sum() / 4 and losses[-1] < losses[0]
    policy = LearnedPolicy(model, vecnorm)
    predicted, _ = policy.predict(obs[:64], episode_start=np.ones(64, bool))
    assert np.sqrt(np.mean((predicted - labels[:64]) ** 2)) < 0.2 * labels.std()


def test_precision_weights_favour_small_errors_and_average_one():
    from softpvtol_gym.baselines.training.distill import sample_weights

    obs = np.zeros((3, 21), np.float32)
    obs[:, 0] = [0.0, 0.03, 0.0]
    obs[:, 1] = [0.0, 0.04, 1.0]  # |e| = 0, 0.05, 1 m
    w = sample_weights(obs, 0.01)
    assert w.mean() == pytest.approx(1.0) and w[0] / w[1] == pytest.approx(6.0) and w[1] / w[2] == pytest.approx(
        1.01 / 0.06)
    assert sample_weights(obs, None) is None


def test_balanced_actions_weigh_each_channel_by_its_inverse_spread():
    import torch

    from softpvtol_gym.baselines.training.distill import action_channel_weights
    from softpvtol_gym.baselines.training.imitation import action_gap

    rng = np.random.default_rng(0)
    actions = rng.normal(size=(1000, 4)) * np.array([0.1, 0.1, 0.01, 0.01])
    w = action_channel_weights(actions)
    assert w.mean() == pytest.approx(1.0)
    assert w[2] / w[0] == pytest.approx(np.var(actions[:, 0]) / np.var(actions[:, 2]))
    assert np.isfinite(action_channel_weights(np.zeros((5, 4)))).all()  # a channel that never varies

    class Fixed:  # a policy whose mean action is 0: the gap is the labels' weighted mean square
        def get_distribution(self, obs):
            return type("D", (), {"distribution": type("N", (), {"mean": torch.zeros(len(obs), 4)})()})()

    labels = torch.as_tensor(actions, dtype=torch.float32)
    obs = torch.zeros(len(labels), 3)
    plain = float(action_gap(Fixed(), obs, labels))
    balanced = float(action_gap(Fixed(), obs, labels, channel_weights=torch.as_tensor(w, dtype=torch.float32)))
    assert plain == pytest.approx(float((labels ** 2).mean()), rel=1e-5)
    assert balanced == pytest.approx(float((labels ** 2 * torch.as_tensor(w, dtype=torch.float32)).mean()), rel=1e-5)
    # each channel's error counts relative to its spread: the small channels weigh as much as the large ones
    per_channel = (labels ** 2 * torch.as_tensor(w, dtype=torch.float32)).mean(dim=0).numpy()
    assert per_channel.max() / per_channel.min() < 1.2


def test_a_balanced_distillation_records_the_setting_and_fits_another_student(distilled, tmp_path):
    _, plain = distilled
    balanced = distill(DistillConfig(**{**TINY, "balance_actions": True}), tmp_path / "balanced")
    assert balanced["record"]["config"]["balance_actions"] is True
    assert plain["record"]["config"]["balance_actions"] is False
    assert balanced["record"]["rounds"][0]["losses"] != plain["record"]["rounds"][0]["losses"]


def test_dagger_rounds_are_flown_by_the_student_and_labelled_by_the_teacher(tmp_path):
    teacher = LinearTeacher()
    config = DistillConfig(**{**TINY, "teacher": "integral"})
    distill(config, tmp_path / "run", teacher=teacher)
    for name in ("round_00_nominal.npz", "round_01_nominal.npz"):
        with np.load(tmp_path / "run" / DATASET_DIR / name, allow_pickle=False) as data:
            np.testing.assert_allclose(data["actions"], teacher.label(data["observations"]).astype(np.float32),
                                       rtol=0, atol=1e-6)
    # round 1's episodes (seeds after round 0's) flown by the teacher itself would visit other states
    with np.load(tmp_path / "run" / DATASET_DIR / "round_01_nominal.npz", allow_pickle=False) as data:
        flown = data["observations"]
    by_teacher, _ = collect(teacher, "hover", "nominal", TINY["episodes"], config.collection_seed(1, 0))
    n = min(len(flown), len(by_teacher))
    assert np.array_equal(flown[0], by_teacher[0])  # the same seeded start
    assert not np.allclose(flown[:n], by_teacher[:n])


def test_a_teacher_share_mixes_the_teachers_actions_into_the_students_flight_and_labels_every_step():
    teacher, student = LinearTeacher(), ZeroStudent()
    alone, labels = collect(teacher, "hover", "nominal", 2, 7, student=student)
    mixed, mixed_labels = collect(teacher, "hover", "nominal", 2, 7, student=student, teacher_share=0.5)
    again, _ = collect(teacher, "hover", "nominal", 2, 7, student=student, teacher_share=0.5)
    np.testing.assert_allclose(labels, teacher.label(alone).astype(np.float32), rtol=0, atol=1e-6)
    np.testing.assert_allclose(mixed_labels, teacher.label(mixed).astype(np.float32), rtol=0, atol=1e-6)
    assert np.array_equal(mixed, again)  # the draws are seeded
    # the student crashes within a second; with the teacher acting half the time it flies longer
    assert len(mixed) > len(alone) and not np.array_equal(mixed[:len(alone)], alone)
    # a share that draws the teacher at every step is the teacher's own flight
    by_teacher, _ = collect(teacher, "hover", "nominal", 2, 7)
    nearly_always, _ = collect(teacher, "hover", "nominal", 2, 7, student=student, teacher_share=1 - 1e-12)
    assert np.array_equal(nearly_always, by_teacher)
    assert DistillConfig(**{**TINY, "teacher_share": 0.5}).teacher_share == 0.5
    with pytest.raises(ConfigError, match=r"teacher_share=0.5 acts in the DAgger rounds .* rounds=1 is behaviour "
                                          r"cloning only: it would change nothing"):
        DistillConfig(**{**TINY, "teacher_share": 0.5, "rounds": 1})


def test_a_teacher_with_memory_of_its_inputs_is_told_the_actions_the_student_applied():
    class TellingTeacher(LinearTeacher):
        def __init__(self):
            super().__init__()
            self.applied = []

        def observe_applied(self, action):
            self.applied.append(np.array(action))

    teacher, student = TellingTeacher(), ZeroStudent()
    collect(teacher, "hover", "nominal", 2, 7, student=student, teacher_share=0.5)
    told = np.concatenate(teacher.applied)
    labels_used = (told != 0).any(axis=1)  # the steps where the teacher's own action was drawn
    assert len(teacher.applied) == teacher.calls and 0 < labels_used.mean() < 1
    assert np.array_equal(told[~labels_used], np.zeros_like(told[~labels_used]))
    teacher_alone = TellingTeacher()
    collect(teacher_alone, "hover", "nominal", 2, 7)
    assert teacher_alone.applied == []  # flying its own actions, the teacher needs no telling


def test_privileged_labels_are_the_teachers_actions_on_the_true_state():
    """``privileged``: on a tier without sensor noise the labels are the plain ones; on the noisy tier the student
    flies the same episodes on what it observes, and the labels differ: they are the teacher's actions on the
    noise-free observations of the true state (a reference loop: the env stepped by hand, a fresh teacher)."""
    from softpvtol_gym.envs.vector import SoftPVTOLVectorEnv

    def student():
        return teacher_policy("bounded", "hover", STUDENT_OPTIONS)

    def teacher():
        return teacher_policy("integral", "hover", STUDENT_OPTIONS)

    plain = collect(teacher(), "hover", "nominal", 2, 7, student=student(), env_options=STUDENT_OPTIONS)
    privileged = collect(teacher(), "hover", "nominal", 2, 7, student=student(), env_options=STUDENT_OPTIONS,
                         privileged=True)
    assert all(np.array_equal(a, b) for a, b in zip(plain, privileged))
    obs, labels = collect(teacher(), "hover", "noisy", 2, 7, student=student(), env_options=STUDENT_OPTIONS)
    seen, privileged_labels = collect(teacher(), "hover", "noisy", 2, 7, student=student(),
                                      env_options=STUDENT_OPTIONS, privileged=True)
    assert np.array_equal(seen, obs)  # the student's flight and observations are the same
    assert not np.allclose(privileged_labels, labels, rtol=0, atol=1e-3)

    env = SoftPVTOLVectorEnv(num_envs=2, action_mode="actuators", task="hover", tier="noisy", **STUDENT_OPTIONS)
    flier, labeller = student(), teacher()
    observation, _ = env.reset(seed=7)
    start, expected = np.ones(2, bool), []
    for _ in range(50):
        expected.append(labeller.predict(env.noise_free_observations(), episode_start=start)[0])
        action, _ = flier.predict(observation, episode_start=start)
        start[:] = False
        observation, *_ = env.step(action)
    # the rows come step by step, both episodes at each (both fly longer than 50 steps)
    np.testing.assert_array_equal(privileged_labels[:100], np.concatenate(expected))


def test_the_command_refuses_privileged_labels_without_sensor_noise(tmp_path, capsys, monkeypatch):
    from softpvtol_gym.baselines.cli import run_command

    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as exc:
        run_command("distill", ["--privileged", "--tier", "nominal", "--tier", "wind"])
    err = capsys.readouterr().err.strip().splitlines()
    assert exc.value.code == 2 and len(err) == 1 and "only under sensor noise" in err[0], err
    assert list(tmp_path.iterdir()) == []
    assert DistillConfig(**{**TINY, "tiers": ("nominal", "noisy"), "privileged": True}).privileged


def test_noise_free_observations_are_the_true_states():
    from softpvtol_gym.envs.vector import SoftPVTOLVectorEnv

    for tier in ("nominal", "noisy"):
        env = SoftPVTOLVectorEnv(num_envs=3, action_mode="actuators", task="track_random", tier=tier,
                                 observe_error_integral=True)
        obs, _ = env.reset(seed=5)
        for _ in range(10):
            obs, *_ = env.step(np.zeros((3, 4), np.float32))
        true = env.noise_free_observations()
        q, qd = env.state
        assert np.array_equal(true, obs) == (tier == "nominal"), tier
        np.testing.assert_allclose(true[:, :2], q[:, :2] - env.sim.qr[:, :2], rtol=0, atol=1e-6)  # float32
        np.testing.assert_allclose(true[:, 5:7], q[:, 3:5], rtol=0, atol=1e-6)
        np.testing.assert_allclose(true[:, 7:12], qd, rtol=1e-6, atol=1e-6)
        assert np.array_equal(true[:, 18:], obs[:, 18:])  # the env's error integrals


def test_the_students_integrals_are_integrated_as_their_teacher_integrates_them():
    from softpvtol_gym.baselines.training.teachers import student_env_options
    from softpvtol_gym.control import LOOPS

    assert student_env_options("integral", teacher_integral=True) == STUDENT_OPTIONS
    assert STUDENT_OPTIONS["error_integral_limit"] == LOOPS["integral"]["integral_limits"][0]
    assert STUDENT_OPTIONS["error_integral_error_limit"] == LOOPS["integral"]["integral_error_limits"][0]
    for teacher, matched in (("bounded", True), ("integral", False)):  # no integral action, or not asked for
        assert student_env_options(teacher, teacher_integral=matched) == {"observe_error_integral": True}
    assert DistillConfig(**{**TINY, "teacher_integral": False}).env_options == {"observe_error_integral": True}


def test_a_run_made_before_the_newer_settings_resumes_with_the_values_it_had(tmp_path):
    from softpvtol_gym.baselines.training.distill import _check_same_config

    earlier = DistillConfig(**{**TINY, "teacher_integral": False}).to_dict()
    for later in ("teacher_integral", "wide_fraction", "balance_actions", "teacher_share", "history", "privileged",
                  "teacher_shares", "also_tasks"):
        del earlier[later]
    (tmp_path / "distill_config.json").write_text(json.dumps(earlier))
    _check_same_config(tmp_path, DistillConfig(**{**TINY, "teacher_integral": False}))
    with pytest.raises(ConfigError, match="other settings .teacher_integral."):
        _check_same_config(tmp_path, DistillConfig(**TINY))


def test_wide_episodes_start_far_from_the_reference_and_the_others_as_the_task_does(tmp_path):
    from softpvtol_gym.baselines.training.distill import _collect_round

    teacher = LinearTeacher()
    config = DistillConfig(**{**TINY, "episodes": 4, "wide_fraction": 0.5})
    assert config.wide_episodes() == 2
    obs, labels = _collect_round(teacher, config, "hover", "nominal", 0, None, None)
    task_obs, _ = collect(teacher, "hover", "nominal", 2, 0, env_options=config.env_options)  # the task's starts
    assert np.array_equal(obs[:len(task_obs)], task_obs)
    wide_obs, _ = collect(teacher, "hover", "nominal", 2, 2, env_options={**config.env_options,
                                                                         "start_distribution": "wide"})
    assert np.array_equal(obs[len(task_obs):], wide_obs) and len(obs) == len(labels)
    first_errors = np.hypot(obs[:, 0], obs[:, 1])
    assert first_errors[len(task_obs)] > 5 * first_errors[0]  # metres off, not the task's small offsets


@pytest.mark.xdist_group("distilled")  # one worker computes the module fixture once
def test_resume_loads_the_cached_datasets_and_gives_the_same_student(distilled, tmp_path):
    out, _ = distilled
    again = tmp_path / "again"
    again.mkdir()
    shutil.copytree(out / DATASET_DIR, again / DATASET_DIR)
    shutil.copy(out / "distill_config.json", again / "distill_config.json")

    class NoTeacher:
        def predict(self, *args, **kwargs):
            raise AssertionError("a cached round was collected again")

    with pytest.raises(ConfigError, match="already holds a distilled run"):
        distill(DistillConfig(**TINY), again, teacher=NoTeacher())
    with pytest.raises(ConfigError, match="other settings.*epochs"):
        distill(DistillConfig(**{**TINY, "epochs": 4}), again, resume=True, teacher=NoTeacher())
    # the evaluations fly the teacher: only they may call it
    distill(DistillConfig(**{**TINY}), again, resume=True, teacher=teacher_policy("integral", "hover"))
    assert (again / "model.safetensors").read_bytes() == (out / "model.safetensors").read_bytes()


@pytest.mark.parametrize("damage", ["truncated", "garbage", "empty", "pickled objects"])
def test_an_unreadable_cached_dataset_is_collected_again_not_a_traceback(damage, tmp_path, capsys):
    from softpvtol_gym.baselines.training.distill import _load_dataset, _save_dataset

    path = tmp_path / "round_00_nominal.npz"
    obs, labels = np.zeros((8, 18), np.float32), np.zeros((8, 4), np.float32)
    _save_dataset(path, obs, labels)
    data = path.read_bytes()
    if damage == "pickled objects":
        np.savez(path, observations=np.array([{"a": 1}], dtype=object), actions=labels)
    else:
        path.write_bytes({"truncated": data[: len(data) // 2], "garbage": b"PK\x03\x04" + b"x" * 100,
                          "empty": b""}[damage])
    assert _load_dataset(path, 18) is None
    assert f"{path} is unreadable" in capsys.readouterr().err


@pytest.mark.parametrize("changes, words", [
    ({"teacher": "pid"}, "teacher must be one of"),
    ({"rounds": 0}, "rounds must be an integer in"),
    ({"tiers": ()}, "tiers must be distinct names"),
    ({"tiers": ("nominal", "nominal")}, "tiers must be distinct names"),
    ({"tiers": ("calm",)}, "tiers must be distinct names"),
    ({"net_arch": (0,)}, "net_arch must be hidden layer sizes"),
    ({"learning_rate": float("nan")}, "learning_rate must be in"),
    ({"seed": 50}, "collection seeds"),
    ({"episodes": True}, "episodes must be an integer"),
    ({"precision_scale": 0.0}, "precision_scale must be None or a length"),
    ({"wide_fraction": 1.5}, "wide_fraction must be a share in"),
    ({"wide_fraction": True}, "wide_fraction must be a share in"),
    ({"teacher_integral": 1}, "teacher_integral must be a bool"),
    ({"balance_actions": "yes"}, "balance_actions must be a bool"),
    ({"teacher_share": 1.0}, "teacher_share must be a probability in"),
    ({"teacher_share": -0.1}, "teacher_share must be a probability in"),
    ({"history": 0}, "history must be an integer in"),
    ({"history": 2.0}, "history must be an integer in"),
    ({"privileged": 1}, "privileged must be a bool"),
    ({"privileged": True}, "privileged labels differ from the plain ones only under sensor noise"),
])
def test_bad_settings_are_refused_with_what_was_given(changes, words):
    with pytest.raises(ConfigError, match=words):
        DistillConfig(**{**TINY, **changes})


def test_the_command_distils_and_evaluate_loads_the_student(tmp_path, capsys):
    from softpvtol_gym.baselines.cli import main

    out = tmp_path / "cli"
    args = ["distill", "--teacher", "integral", "--task", "hover", "--rounds", "1", "--episodes", "1", "--epochs", "1",
            "--net-arch", "8", "--eval-episodes", "0", "--out", str(out), "--no-progress-bar", "--balance-actions"]
    assert main(args) == 0
    assert json.loads((out / DISTILL_FILE).read_text())["config"]["balance_actions"] is True
    assert "softpvtol evaluate --policy" in capsys.readouterr().out
    for argv, words in ((args, "already holds a distilled run"),  # the run exists: nothing overwritten
                        (["distill", "--net-arch", "64,x", "--out", str(tmp_path / "bad")],
                         "--net-arch must be comma-separated")):
        with pytest.raises(SystemExit) as exc:
            main(argv)
        err = capsys.readouterr().err
        assert exc.value.code == 2 and words in err and len(err.strip().splitlines()) == 1, err
    assert main(["evaluate", "--policy", str(out), "--episodes", "1"]) == 0
    assert "actuators / hover / nominal" in capsys.readouterr().out


# ------------------------------------------------------------------------------------- fine-tuning a student
@pytest.mark.xdist_group("distilled")  # one worker computes the module fixture once
def test_a_fine_tuned_run_starts_from_the_students_weights_and_statistics(distilled, tmp_path):
    import torch

    from softpvtol_gym.baselines.training.imitation import FROZEN_COUNT
    from softpvtol_gym.baselines.training.loop import prepare

    out, result = distilled
    student = result["run_config"]
    config = dataclasses.replace(student, tier="wind", timesteps=256, init_from=str(out))
    _, vecnorm, model = prepare(config, tmp_path / "ft")
    theirs = result["policy"].model.policy.state_dict()
    for key, value in model.policy.state_dict().items():
        assert torch.equal(value, theirs[key]), key
    np.testing.assert_array_equal(vecnorm.obs_rms.mean, result["policy"].vecnorm.obs_rms.mean)
    assert vecnorm.obs_rms.count == FROZEN_COUNT
    with pytest.raises(ConfigError, match="does not have this run's shape"):
        prepare(dataclasses.replace(config, hyperparams={**config.hyperparams, "policy_kwargs": "dict(net_arch=[8])"}),
                tmp_path / "other")


def test_the_imitation_weight_decays_linearly_to_zero():
    from softpvtol_gym.baselines.training.imitation import imitation_weight

    spec = {"teacher": "integral", "weight": 2.0, "decay_steps": 1000, "epochs": 1}
    assert [imitation_weight(spec, t) for t in (0, 250, 1000, 5000)] == [2.0, 1.5, 0.0, 0.0]


@pytest.mark.xdist_group("distilled")  # one worker computes the module fixture once
def test_train_init_from_fine_tunes_the_student_with_the_imitation_term(distilled, tmp_path, capsys):
    import yaml

    from softpvtol_gym.baselines.cli import main
    out, result = distilled
    run = tmp_path / "ft"
    tiny = ["--n-envs", "2", "--hp", "n_steps=64", "--hp", "batch_size=64", "--hp", "n_epochs=1",
            "--eval-episodes", "0", "--no-progress-bar"]
    assert main(["train", "--init-from", str(out), "--timesteps", "256", "--bc-teacher", "integral", "--bc-weight",
                 "5", "--bc-decay-steps", "100000", *tiny, "--out", str(run)]) == 0
    saved = yaml.safe_load((run / "config.yaml").read_text())
    assert (saved["action_mode"], saved["task"], saved["init_from"]) == ("actuators", "hover", str(out))
    assert saved["imitation"] == {"teacher": "integral", "weight": 5.0, "decay_steps": 100000, "epochs": 1}
    assert saved["env_options"] == STUDENT_OPTIONS  # the student's interface, kept
    policy, _ = LearnedPolicy.load(run)
    obs = np.zeros((2, 21), np.float32)
    moved = policy.predict(obs, episode_start=np.ones(2, bool))[0]
    assert not np.array_equal(moved, result["policy"].predict(obs, episode_start=np.ones(2, bool))[0])
    capsys.readouterr()
    for argv, words in ((["train", "--bc-teacher", "integral", "--out", str(tmp_path / "x")], "--bc-teacher needs"),
                        (["train", "--init-from", str(out), "--action-mode", "residual", "--out", str(tmp_path / "y")],
                         "differs from the --init-from run's actuators"),
                        (["train", "--init-from", str(tmp_path / "none"), "--out", str(tmp_path / "z")],
                         "--init-from")):
        with pytest.raises(SystemExit) as exc:
            main(argv)
        err = capsys.readouterr().err
        assert exc.value.code == 2 and words in err and len(err.strip().splitlines()) == 1, err


def _fine_tuning_with_imitation(distilled, tmp_path, monkeypatch, timesteps: int, epochs: int):
    """(teacher, vecnorm, model, imitation term) of a tiny fine-tuning of a distilled run (2 envs x 64 steps a
    rollout), its imitation term toward a :class:`LinearTeacher`, whose labels the checks can recompute."""
    from softpvtol_gym.baselines.training import imitation
    from softpvtol_gym.baselines.training.loop import prepare

    out, result = distilled
    teacher = LinearTeacher()
    monkeypatch.setattr(imitation, "teacher_policy", lambda name, task, env_options: teacher)
    spec = {"teacher": "integral", "weight": 1.0, "decay_steps": 100_000, "epochs": epochs}
    config = dataclasses.replace(result["run_config"], n_envs=2, timesteps=timesteps, init_from=str(out),
                                 imitation=spec,
                                 hyperparams={**result["run_config"].hyperparams, "n_steps": 64, "batch_size": 64})
    _, vecnorm, model = prepare(config, tmp_path / "ft")
    return teacher, vecnorm, model, imitation.imitation_callback(config, vecnorm)


@pytest.mark.xdist_group("distilled")  # one worker computes the module fixture once
def test_the_imitation_term_fits_the_teachers_labels_of_the_observations_acted_on(distilled, tmp_path,
                                                                                     monkeypatch):
    teacher, vecnorm, model, term = _fine_tuning_with_imitation(distilled, tmp_path, monkeypatch, 256, epochs=5)
    seen = []
    original = term._imitate

    def check():
        obs, labels = np.concatenate(term.obs), np.concatenate(term.labels)
        assert len(obs) == 64 * 2  # one label per env step of the rollout
        raw = vecnorm.unnormalize_obs(obs.astype(np.float64))
        whole = np.all(np.abs(obs) < vecnorm.clip_obs, axis=1)  # rows the normalisation's clip left as they were
        assert whole.mean() > 0.5
        np.testing.assert_allclose(labels[whole], teacher.label(raw[whole]), atol=1e-4)
        seen.append(len(obs))
        original()

    term._imitate = check
    model.learn(total_timesteps=256, callback=term)
    assert seen == [128, 128]  # after each of the two updates (the last at the end of training)
    assert all(h["gap_after"] < h["gap_before"] for h in term.history) and len(term.history) == 2


def test_the_docs_table_is_generated_from_the_committed_distilled_run():
    from softpvtol_gym.baselines.training.distill import distill_table
    from softpvtol_gym.baselines.util.blocks import read_block
    from tests.conftest import RESULTS, ROOT

    run = RESULTS / "distill_runs" / "integral_track_random"
    record = json.loads((run / DISTILL_FILE).read_text())
    source = f"results/distill_runs/integral_track_random/{DISTILL_FILE}"
    assert read_block("distill.py integral_track_random", source, ROOT / "benchmarks" / "STUDIES.md") == \
        distill_table(record).strip()
    policy, config = LearnedPolicy.load(run)  # the committed student loads (its manifest verifies)
    assert config.env_options == {"observe_error_integral": True} and record["config"]["teacher"] == "integral"


@pytest.mark.parametrize("fields, words", [
    ({"imitation": {"teacher": "integral", "weight": 0.0, "decay_steps": 10, "epochs": 1}}, "imitation must be None"),
    ({"imitation": {"teacher": "integral", "weight": 1.0, "decay_steps": 10}}, "imitation must be None"),
    ({"imitation": {"teacher": "integral", "weight": 1.0, "decay_steps": 10, "epochs": 1}, "action_mode": "residual"},
     "needs action_mode 'actuators'"),
    ({"init_from": ""}, "init_from must be a run directory's path"),
])
def test_bad_fine_tuning_settings_are_refused(fields, words):
    from softpvtol_gym.baselines.config.run_config import RunConfig

    with pytest.raises(ConfigError, match=words):
        RunConfig(**{"action_mode": "actuators", **fields})


# ------------------------------------------------------------------------------------- a student with history
def test_collected_rows_hold_each_episodes_last_observations_with_nan_before_its_start():
    teacher = LinearTeacher()
    flat, _ = collect(teacher, "hover", "nominal", 2, 7, env_options=STUDENT_OPTIONS)
    stacked, labels = collect(LinearTeacher(), "hover", "nominal", 2, 7, env_options=STUDENT_OPTIONS, history=3)
    assert stacked.shape == (len(flat), 63) and labels.shape == (len(flat), 4)
    np.testing.assert_array_equal(stacked[:, -21:], flat)
    # rows are step-major (both episodes' step 0, then both episodes' step 1, ...): a row's older slots are the
    # same episode's earlier observations, NaN before its start
    assert np.isnan(stacked[:2, :42]).all() and np.isnan(stacked[2:4, :21]).all()
    np.testing.assert_array_equal(stacked[2:4, 21:42], flat[:2])
    np.testing.assert_array_equal(stacked[4:6, :21], flat[:2])
    np.testing.assert_array_equal(stacked[4:6, 21:42], flat[2:4])
    assert not np.isnan(stacked[4:]).any()


@pytest.fixture(scope="module")
def distilled_with_history(tmp_path_factory):
    out = tmp_path_factory.mktemp("distill") / "history"
    return out, distill(DistillConfig(**{**TINY, "history": 3}), out)


@pytest.mark.xdist_group("distilled")
def test_a_student_with_history_is_fitted_on_what_its_frame_stack_feeds_it(distilled_with_history):
    """The rows a frame-stacked student's flight is collected into, passed through the fit's input path, give back
    the actions the student applied at those steps: the fit and the policy see the same stacked inputs."""
    import torch

    from softpvtol_gym.baselines.training.distill import stacked_inputs

    out, result = distilled_with_history
    student = result["policy"]
    assert student.model.policy.observation_space.shape == (63,)
    assert json.loads((out / DISTILL_FILE).read_text())["config"]["history"] == 3
    rows, applied = collect(student, "hover", "nominal", 2, 11, env_options=STUDENT_OPTIONS, history=3)
    x = torch.as_tensor(stacked_inputs(student.vecnorm, rows, 3))
    with torch.no_grad():
        mean = student.model.policy.get_distribution(x).distribution.mean.numpy()
    np.testing.assert_allclose(np.clip(mean, -1, 1), applied, atol=1e-5)
    loaded, _ = LearnedPolicy.load(out)  # as softpvtol evaluate loads it: the frame stack from the run's config
    action, _ = loaded.predict(rows[:2, -21:], episode_start=np.ones(2, bool), deterministic=True)
    np.testing.assert_allclose(action, applied[:2], atol=1e-5)


@pytest.mark.xdist_group("distilled")
def test_fine_tuning_a_student_with_history_keeps_its_frame_stack(distilled_with_history, tmp_path):
    import torch

    from softpvtol_gym.baselines.config.hyperparams import apply_overrides, frame_stack
    from softpvtol_gym.baselines.training.imitation import source_overrides
    from softpvtol_gym.baselines.training.loop import prepare

    out, result = distilled_with_history
    student = result["run_config"]
    # a fine-tuning run's own hyperparameters, with what the source run's config carries over
    hp = {k: v for k, v in student.hyperparams.items() if k not in ("frame_stack", "policy_kwargs", "normalize")}
    hp = apply_overrides(hp, source_overrides(LearnedPolicy.load(out)[1]))
    assert frame_stack(hp) == 3
    config = dataclasses.replace(student, tier="wind", timesteps=256, init_from=str(out), hyperparams=hp)
    _, _, model = prepare(config, tmp_path / "ft")
    theirs = result["policy"].model.policy.state_dict()
    assert all(torch.equal(v, theirs[k]) for k, v in model.policy.state_dict().items())


@pytest.mark.xdist_group("distilled")
def test_the_imitation_term_of_a_student_with_history_fits_on_its_frame_stack(distilled_with_history, tmp_path,
                                                                            monkeypatch):
    """The term's inputs are what the policy acts on (the stack of 3 normalised observations), its labels the
    teacher's on the newest raw one."""
    teacher, vecnorm, model, term = _fine_tuning_with_imitation(distilled_with_history, tmp_path, monkeypatch, 128,
                                                                epochs=2)
    original = term._imitate

    def check():
        obs, labels = np.concatenate(term.obs), np.concatenate(term.labels)
        assert obs.shape == (128, 63)
        raw = vecnorm.unnormalize_obs(obs[:, -21:].astype(np.float64))
        whole = np.all(np.abs(obs[:, -21:]) < vecnorm.clip_obs, axis=1)
        np.testing.assert_allclose(labels[whole], teacher.label(raw[whole]), atol=1e-4)
        # each env's stack is the one of its step before shifted by one observation (but after a crash's reset)
        shifted = np.all(obs[2:, :42] == obs[:-2, 21:], axis=1)
        assert shifted.mean() > 0.9, shifted.mean()
        original()

    term._imitate = check
    model.learn(total_timesteps=128, callback=term)
    assert len(term.history) == 1 and term.history[0]["gap_after"] < term.history[0]["gap_before"]
