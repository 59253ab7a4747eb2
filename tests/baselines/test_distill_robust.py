"""Distillation for robust students: the mixture of tasks and tiers, the teacher's share per DAgger round, the
privileged teacher told the actuators' true lagged state, a student with a long memory whose lean forward pass
matches torch, and a student that is a residual on the integral loop."""

from __future__ import annotations

import json
import math
import shutil

import numpy as np
import pytest

from softpvtol_gym.baselines.errors import ConfigError
from softpvtol_gym.baselines.training.distill import DATASET_DIR, DISTILL_FILE, DistillConfig, collect, distill
from softpvtol_gym.baselines.training.policy import LearnedPolicy
from softpvtol_gym.envs.vector import SoftPVTOLVectorEnv

from ._teachers import LinearTeacher, ZeroStudent

STUDENT_OPTIONS = {"observe_error_integral": True, "error_integral_limit": 8.0, "error_integral_error_limit": 0.5}
#: two tasks, two tiers, one episode each, two rounds: the mixture's datasets in seconds
MIXTURE = dict(teacher="integral", task="hover", also_tasks=("track_random",), tiers=("nominal", "wind"), rounds=2,
               episodes=1, epochs=2, batch_size=256, eval_episodes=1, net_arch=(16, 16))


@pytest.fixture(scope="module")
def mixture(tmp_path_factory):
    out = tmp_path_factory.mktemp("mixture") / "student"
    return out, distill(DistillConfig(**MIXTURE), out, teacher=LinearTeacher())


@pytest.mark.xdist_group("mixture")
def test_every_round_collects_each_task_and_tier_from_its_own_seeds(mixture):
    out, result = mixture
    config = DistillConfig(**MIXTURE)
    assert config.tasks == ("hover", "track_random") and config.collections == 8
    seeds = [config.collection_seed(k, j, i) for k in range(2) for i in range(2) for j in range(2)]
    assert seeds == list(range(8))  # one episode each, none shared
    teacher = LinearTeacher()
    for k in range(2):
        for i, task in enumerate(config.tasks):
            for j, tier in enumerate(config.tiers):
                name = f"round_{k:02d}_{tier}.npz" if i == 0 else f"round_{k:02d}_{task}_{tier}.npz"
                with np.load(out / DATASET_DIR / name, allow_pickle=False) as data:
                    obs, labels = data["observations"], data["actions"]
                np.testing.assert_allclose(labels, teacher.label(obs).astype(np.float32), rtol=0, atol=1e-6)
                # the dataset's first row is the start of that task's and tier's seeded episode
                start, _ = collect(teacher, task, tier, 1, config.collection_seed(k, j, i),
                                   env_options=config.env_options)
                assert np.array_equal(obs[0], start[0]), name
    for r in result["record"]["rounds"]:
        assert list(r["evaluation"]) == ["nominal", "wind", "track_random nominal", "track_random wind"]
    rows = {k: sum(len(np.load(f, allow_pickle=False)["actions"]) for f in (out / DATASET_DIR).glob(f"round_0{k}_*"))
            for k in range(2)}
    first, second = result["record"]["rounds"]
    assert first["samples"] == first["aggregate"] == rows[0] and second["samples"] == rows[1]
    assert second["aggregate"] == rows[0] + rows[1]
    # a single-task run keeps its datasets' names and seeds (runs made before the mixture resume)
    single = DistillConfig(**{**MIXTURE, "also_tasks": ()})
    assert [single.collection_seed(k, j) for k in range(2) for j in range(2)] == [0, 1, 2, 3]


@pytest.mark.xdist_group("mixture")
def test_a_mixture_run_resumes_from_its_datasets_and_gives_the_same_student(mixture, tmp_path, monkeypatch):
    import softpvtol_gym.baselines.training.distill as distill_module

    out, _ = mixture
    again = tmp_path / "again"
    again.mkdir()
    shutil.copytree(out / DATASET_DIR, again / DATASET_DIR)
    shutil.copy(out / "distill_config.json", again / "distill_config.json")
    with pytest.raises(ConfigError, match=r"other settings \(also_tasks\)"):
        distill(DistillConfig(**{**MIXTURE, "also_tasks": ()}), again, resume=True, teacher=LinearTeacher())

    def no_collection(*args, **kwargs):
        raise AssertionError("a cached dataset was collected again")

    monkeypatch.setattr(distill_module, "_collect_round", no_collection)
    distill(DistillConfig(**MIXTURE), again, resume=True, teacher=LinearTeacher())
    assert (again / "model.safetensors").read_bytes() == (out / "model.safetensors").read_bytes()
    loaded, config = LearnedPolicy.load(out)
    assert config.task == "hover" and loaded.model.policy.observation_space.shape == (21,)


def test_each_dagger_round_gets_its_share_of_the_schedule(tmp_path):
    config = DistillConfig(**{**MIXTURE, "rounds": 4, "teacher_shares": (1.0, 0.5, 0.0)})
    assert [config.round_teacher_share(k) for k in range(4)] == [1.0, 1.0, 0.5, 0.0]
    powers = DistillConfig(**{**MIXTURE, "rounds": 3, "teacher_share": 0.5})
    assert [powers.round_teacher_share(k) for k in range(3)] == [1.0, 0.5, 0.25]
    # a share of 1 is the teacher's own flight, a share of 0 the student's alone
    run = DistillConfig(**{**MIXTURE, "also_tasks": (), "tiers": ("nominal",), "rounds": 3,
                           "teacher_shares": (1.0, 0.0)})
    distill(run, tmp_path / "run", teacher=LinearTeacher())
    flown = {}
    for k in (1, 2):
        with np.load(tmp_path / "run" / DATASET_DIR / f"round_{k:02d}_nominal.npz", allow_pickle=False) as data:
            flown[k] = data["observations"]
    by_teacher, _ = collect(LinearTeacher(), "hover", "nominal", 1, run.collection_seed(1, 0),
                            env_options=run.env_options)
    assert np.array_equal(flown[1], by_teacher)
    by_teacher, _ = collect(LinearTeacher(), "hover", "nominal", 1, run.collection_seed(2, 0),
                            env_options=run.env_options)
    assert not np.array_equal(flown[2][:len(by_teacher)], by_teacher[:len(flown[2])])


@pytest.mark.parametrize("changes, words", [
    ({"also_tasks": ("hover",)}, "also_tasks must be distinct names .* other than task 'hover'"),
    ({"also_tasks": ("track_random", "track_random")}, "also_tasks must be distinct names"),
    ({"also_tasks": ("orbit",)}, "also_tasks must be distinct names"),
    ({"also_tasks": "track_random"}, "also_tasks must be a list, got 'track_random'"),
    ({"teacher_shares": (0.5, 0.2)}, r"one share in \[0, 1\] per DAgger round \(1 with rounds=2\)"),
    ({"rounds": 3, "teacher_shares": (0.5,)}, r"\(2 with rounds=3\), got \[0.5\]"),
    ({"teacher_shares": (1.5,)}, r"got \[1.5\]"),
    ({"teacher_shares": (math.nan,)}, r"got \[nan\]"),
    ({"teacher_shares": (True,)}, r"got \[True\]"),
    ({"teacher_shares": (0.5,), "teacher_share": 0.5}, "both set the teacher's share"),
    ({"residual_on": "pid"}, "residual_on must be None or a loop the residual mode takes as its base"),
    ({"residual_on": "extended"}, r"residual_on .* got 'extended'"),
    ({"residual_on": "ideal"}, r"residual_on .* got 'ideal'"),
    ({"residual_base": "saturated"}, "'saturated' only with residual_on .* got residual_base='saturated' with "
                                     "residual_on=None"),
    ({"residual_on": "integral", "residual_base": "clipped"}, r"residual_base must be one of \['unsaturated', "),
    ({"residual_scale": 0.5}, r"residual_scale=0.5 sets a residual student's authority, but residual_on is None"),
    ({"residual_on": "integral", "residual_scale": 0.0}, r"residual_scale must be a number in \(0, 100\]"),
    ({"residual_on": "integral", "residual_scale": math.nan}, r"residual_scale must be a number .* got nan"),
    ({"attitude_fraction": 1.5}, r"attitude_fraction must be a share in \[0, 1\], got 1.5"),
    ({"attitude_fraction": True}, r"attitude_fraction must be a share in \[0, 1\], got True"),
    ({"episodes": 4, "wide_fraction": 0.5, "attitude_fraction": 0.75}, r"start 2 \+ 3 of the 4 episodes per round"),
])
def test_bad_mixture_settings_are_refused_with_what_was_given(changes, words):
    with pytest.raises(ConfigError, match=words):
        DistillConfig(**{**MIXTURE, **changes})


def test_the_command_takes_the_mixture_and_the_schedule_and_refuses_bad_ones_in_one_line(tmp_path, capsys,
                                                                                          monkeypatch):
    from softpvtol_gym.baselines.cli import run_command

    monkeypatch.chdir(tmp_path)
    for argv, words in ((["--teacher-shares", "0.5,x"], "--teacher-shares must be comma-separated shares"),
                        (["--rounds", "3", "--teacher-shares", "0.5"], "one share in [0, 1] per DAgger round"),
                        (["--also-task", "track_random"], "also_tasks must be distinct names"),
                        (["--residual-on", "pid"], "residual_on must be None or a loop"),
                        (["--residual-base", "saturated"], "'saturated' only with residual_on"),
                        (["--residual-scale", "0.25"], "residual_scale=0.25 sets a residual student's authority"),
                        (["--wide-fraction", "0.5", "--attitude-fraction", "0.75"], "more than there are")):
        with pytest.raises(SystemExit) as exc:
            run_command("distill", argv)
        err = capsys.readouterr().err.strip().splitlines()
        assert exc.value.code == 2 and len(err) == 1 and words in err[0], (argv, err)
    assert list(tmp_path.iterdir()) == []
    out = tmp_path / "run"
    code = run_command("distill", ["--task", "hover", "--also-task", "track_random", "--rounds", "2", "--episodes",
                                   "1", "--epochs", "1", "--eval-episodes", "0", "--net-arch", "8",
                                   "--teacher-shares", "0", "--out", str(out), "--no-progress-bar"])
    assert code == 0
    saved = json.loads((out / "distill_config.json").read_text())
    assert saved["also_tasks"] == ["track_random"] and saved["teacher_shares"] == [0.0]
    assert sorted(p.name for p in (out / DATASET_DIR).iterdir()) == [
        "round_00_nominal.npz", "round_00_track_random_nominal.npz", "round_01_nominal.npz",
        "round_01_track_random_nominal.npz"]


def test_a_round_flies_the_task_starts_then_the_wide_then_the_turned_ones_from_consecutive_seeds():
    from softpvtol_gym.baselines.training.distill import _collect_round

    config = DistillConfig(**{**MIXTURE, "episodes": 4, "wide_fraction": 0.25, "attitude_fraction": 0.25})
    assert (config.wide_episodes(), config.attitude_episodes()) == (1, 1)
    teacher = LinearTeacher()
    obs, labels = _collect_round(teacher, config, "hover", "nominal", 40, None, None)
    parts = [collect(teacher, "hover", "nominal", count, first, env_options={**config.env_options,
                                                                            "start_distribution": start})
             for count, first, start in ((2, 40, "task"), (1, 42, "wide"), (1, 43, "attitude"))]
    np.testing.assert_array_equal(obs, np.concatenate([p[0] for p in parts]))
    np.testing.assert_array_equal(labels, np.concatenate([p[1] for p in parts]))
    # the turned episode starts turned: its first observation differs from the task's start of that seed
    turned_start = parts[2][0][0]
    task_start = collect(teacher, "hover", "nominal", 1, 43, env_options=config.env_options)[0][0]
    assert not np.array_equal(turned_start, task_start)


# ------------------------------------------------------------------------- the actuators' true lagged state
def test_applied_actions_are_the_plants_inputs_after_the_lag():
    lag = SoftPVTOLVectorEnv(num_envs=2, action_mode="actuators", task="hover", tier="noisy")
    plain = SoftPVTOLVectorEnv(num_envs=2, action_mode="actuators", task="hover", tier="nominal")
    first, second = np.full((2, 4), 0.3, np.float32), np.full((2, 4), -0.2, np.float32)
    for env in (lag, plain):
        env.reset(seed=3)
        assert np.isnan(env.applied_actions()).all()  # nothing applied since the reset
        env.step(first)
        np.testing.assert_allclose(env.applied_actions(), first, rtol=0, atol=1e-12)  # the lag starts there
        env.step(second)
    a = 1.0 - math.exp(-lag.config.dt / lag.config.tier_values["actuator_time_constant"])
    was, now = float(first[0, 0]), float(second[0, 0])  # the float32 actions
    np.testing.assert_allclose(lag.applied_actions(), was + a * (now - was), rtol=0, atol=1e-12)
    np.testing.assert_allclose(plain.applied_actions(), second, rtol=0, atol=1e-12)
    plain.step(np.full((2, 4), 3.0, np.float32))  # clipped to the box, as the plant gets it
    np.testing.assert_allclose(plain.applied_actions(), 1.0, rtol=0, atol=1e-12)
    virtual = SoftPVTOLVectorEnv(num_envs=1, action_mode="virtual", task="hover")
    virtual.reset(seed=0)
    virtual.step(np.zeros((1, 5), np.float32))
    assert np.isfinite(virtual.applied_actions()).all()  # the allocation's actuators
    ideal = SoftPVTOLVectorEnv(num_envs=1, action_mode="virtual", allocation="ideal", task="hover")
    with pytest.raises(ValueError, match="applied_actions.*allocation='ideal'.* generalized force tau"):
        ideal.applied_actions()


class TellingTeacher(LinearTeacher):
    """A teacher with memory of its inputs: it records what it is told was applied."""

    def __init__(self):
        super().__init__()
        self.told = []

    def observe_applied(self, action):
        self.told.append(np.array(action))


class SwitchingStudent(ZeroStudent):
    """A student that commands 0.3 on every actuator at its first step and -0.2 ever after."""

    def __init__(self):
        self.calls = 0

    def predict(self, obs, state=None, episode_start=None, deterministic=True):
        self.calls += 1
        return np.full((len(obs), 4), 0.3 if self.calls == 1 else -0.2, np.float32), None


def commands(step: int) -> np.ndarray:
    """SwitchingStudent's commands of two episodes at step ``step`` (0 first)."""
    return np.full((2, 4), 0.3 if step == 0 else -0.2, np.float32)


def test_a_privileged_teacher_with_memory_is_told_the_lagged_inputs_the_plant_received():
    """On a tier with actuator lag (noisy) the privileged teacher is told, after each step, the plant's inputs after
    the lag (a reference: the env stepped by hand); the plain one is told the student's commands; without lag the
    privileged one is told the commands too."""
    teacher = TellingTeacher()
    collect(teacher, "hover", "noisy", 2, 7, student=SwitchingStudent(), env_options=STUDENT_OPTIONS,
            privileged=True)
    env = SoftPVTOLVectorEnv(num_envs=2, action_mode="actuators", task="hover", tier="noisy", **STUDENT_OPTIONS)
    env.reset(seed=7)
    expected = []
    for k in range(30):
        env.step(commands(k))
        expected.append(env.applied_actions())
    np.testing.assert_array_equal(np.stack(teacher.told[:30]), np.stack(expected))
    assert not np.allclose(expected[5], commands(5), atol=1e-3)  # the lag still lags the switch
    plain = TellingTeacher()
    collect(plain, "hover", "noisy", 2, 7, student=SwitchingStudent(), env_options=STUDENT_OPTIONS)
    assert all(np.array_equal(t, commands(k)) for k, t in enumerate(plain.told))
    unlagged = TellingTeacher()
    collect(unlagged, "hover", "nominal", 2, 7, student=SwitchingStudent(), env_options=STUDENT_OPTIONS,
            privileged=True)
    assert unlagged.told and all(np.array_equal(t, commands(k)) for k, t in enumerate(unlagged.told))


def test_the_privileged_mpc_flies_round_zero_on_the_lagged_inputs():
    """The MPC teacher flying its own episode on the noisy tier, privileged: after each step its input memory is
    told the plant's lagged input, which the env stepped by hand with the MPC's actions reproduces, and which is
    not the action it commanded."""
    pytest.importorskip("casadi")
    from softpvtol_gym.baselines.training.teachers import teacher_policy

    mpc = teacher_policy("mpc", "hover", STUDENT_OPTIONS)
    told = []
    observe = mpc.observe_applied
    mpc.observe_applied = lambda action: (told.append(np.array(action)), observe(action))
    obs, labels = collect(mpc, "hover", "noisy", 1, 5, env_options=STUDENT_OPTIONS, privileged=True)
    assert len(told) == len(obs) == len(labels) > 100
    env = SoftPVTOLVectorEnv(num_envs=1, action_mode="actuators", task="hover", tier="noisy", **STUDENT_OPTIONS)
    env.reset(seed=5)
    for k in range(100):
        env.step(labels[k:k + 1])
        np.testing.assert_array_equal(told[k], env.applied_actions())
    assert not np.allclose(np.concatenate(told[:100]), labels[:100], atol=1e-4)


# ------------------------------------------------------------------------- a student with a long memory
@pytest.mark.parametrize("history", [20])
def test_a_long_memory_students_lean_forward_matches_torch(history, tmp_path):
    """A student of 0.2 s of observations (20 frames): its lean forward pass gives torch's actions to 1e-5 along a
    flight (the stack built from the episode's observations step by step), and its checkpoint loads back with the
    same frame stack."""
    config = DistillConfig(**{**MIXTURE, "also_tasks": (), "tiers": ("noisy",), "rounds": 1, "history": history,
                              "eval_episodes": 0})
    out = tmp_path / "memory"
    student = distill(config, out, teacher=LinearTeacher())["policy"]
    assert student.model.policy.observation_space.shape == (21 * history,)
    lean, _ = LearnedPolicy.load(out)
    torch_policy, _ = LearnedPolicy.load(out, inference="torch")
    env = SoftPVTOLVectorEnv(num_envs=3, action_mode="actuators", task="hover", tier="noisy",
                             **config.env_options)
    obs, _ = env.reset(seed=21)
    start = np.ones(3, bool)
    gaps = []
    for _ in range(60):
        a_lean, _ = lean.predict(obs, episode_start=start, deterministic=True)
        a_torch, _ = torch_policy.predict(obs, episode_start=start, deterministic=True)
        gaps.append(np.abs(a_lean - a_torch).max())
        start[:] = False
        obs, *_ = env.step(a_lean)
    assert max(gaps) <= 1e-5 and len(gaps) == 60
    assert json.loads((out / DISTILL_FILE).read_text())["config"]["history"] == history


# ------------------------------------------------------------------------- a residual on the integral loop
RESIDUAL = dict(residual_on="integral", residual_space="actuators")


def test_the_loop_beside_the_env_gives_the_envs_base_command():
    """With a zero correction the residual mode's plant gets its base loop's command, and the loop computed beside
    the env on the observations (what the labels subtract) gives it to the float32 rounding of the observation."""
    from softpvtol_gym.baselines.training.teachers import RESIDUAL_STUDENT_SCALE, teacher_policy

    loop = teacher_policy("integral", "track_random", STUDENT_OPTIONS)
    with pytest.raises(ValueError, match="unclipped_actions.* call predict first"):
        loop.unclipped_actions()
    env = SoftPVTOLVectorEnv(num_envs=3, action_mode="residual", task="track_random", controller_loop="integral",
                             residual_space="actuators", residual_scale=RESIDUAL_STUDENT_SCALE, **STUDENT_OPTIONS)
    obs, _ = env.reset(seed=4)
    start, gaps = np.ones(3, bool), []
    for _ in range(300):
        base, _ = loop.predict(obs, episode_start=start)
        start[:] = False
        obs, *_ = env.step(np.zeros((3, 4), np.float32))
        gaps.append(np.abs(env.applied_actions() - np.clip(loop.unclipped_actions(), -1, 1)).max())
    assert max(gaps) < 1e-3 and np.isfinite(gaps).all()


@pytest.mark.parametrize("residual_base, scale", [("unsaturated", 2.0), ("saturated", 2.0), ("saturated", 0.25)])
def test_residual_labels_are_the_corrections_from_the_loop_to_the_teacher(residual_base, scale):
    """The teacher flying through the residual mode: each label is clip((teacher - base) / scale, -1, 1), base the
    loop's command (clipped to the actuator box on the saturated base), against a reference stepped by hand;
    applied, the correction gives the plant the teacher's own command, always on the saturated base at full
    authority (scale 2) and where the teacher is within the bounded residual's reach (scale 0.25)."""
    from softpvtol_gym.baselines.training.teachers import teacher_policy

    obs, labels = collect(LinearTeacher(), "hover", "nominal", 2, 7, env_options=STUDENT_OPTIONS,
                          residual_on="integral", residual_base=residual_base, residual_scale=scale)
    teacher, loop = LinearTeacher(), teacher_policy("integral", "hover", STUDENT_OPTIONS)
    env = SoftPVTOLVectorEnv(num_envs=2, action_mode="residual", task="hover", controller_loop="integral",
                             residual_space="actuators", residual_scale=scale,
                             residual_base=residual_base, **STUDENT_OPTIONS)
    observation, _ = env.reset(seed=7)
    start, beyond = np.ones(2, bool), np.zeros(2, bool)
    for k in range(20):
        wanted = teacher.label(observation)
        clipped, _ = loop.predict(observation, episode_start=start)
        base = loop.unclipped_actions()  # the loop's command before the box's clip
        np.testing.assert_array_equal(np.clip(base, -1, 1).astype(np.float32), clipped)
        if residual_base == "saturated":
            base = np.clip(base, -1, 1)
        start[:] = False
        label = np.clip((wanted.astype(np.float32).astype(np.float64) - base) / scale, -1, 1)
        np.testing.assert_array_equal(labels[2 * k:2 * k + 2], label.astype(np.float32))
        np.testing.assert_array_equal(obs[2 * k:2 * k + 2], observation)
        observation, *_ = env.step(label.astype(np.float32))
        reachable = np.abs(wanted - base) < scale  # where the correction is in the residual's range
        assert reachable.all() if (residual_base, scale) == ("saturated", 2.0) else reachable.any()
        beyond |= ~reachable.all(axis=1)
        np.testing.assert_allclose(env.applied_actions()[reachable], wanted[reachable], rtol=0, atol=1e-3)
    if scale < 2.0:  # a bounded residual: somewhere the teacher lies beyond its reach and is labelled at the clip
        assert beyond.any() and (np.abs(labels) == 1.0).any()


def test_a_residual_student_is_a_run_of_the_residual_mode_on_its_loop(tmp_path):
    config = DistillConfig(**{**MIXTURE, "also_tasks": (), "tiers": ("nominal",), "residual_on": "integral"})
    assert config.action_mode == "residual"
    out = tmp_path / "residual"
    result = distill(config, out, teacher=LinearTeacher())
    run = result["run_config"]
    assert (run.action_mode, run.controller_loop) == ("residual", "integral")
    assert run.env_options["residual_space"] == "actuators" and run.env_options["residual_scale"] == 2.0
    record = json.loads((out / DISTILL_FILE).read_text())
    assert record["student"]["action_mode"] == "residual" and record["config"]["residual_on"] == "integral"
    loaded, saved = LearnedPolicy.load(out)
    assert saved.action_mode == "residual" and saved.controller_loop == "integral"
    for r in record["rounds"]:  # the share of labels at the residual's clip, per action channel
        assert len(r["labels_at_clip"]) == 4 and all(0.0 <= v <= 1.0 for v in r["labels_at_clip"])
    # the round's evaluation flew the student in the residual mode (its action space: 4 corrections)
    assert loaded.model.action_space.shape == (4,) and result["record"]["rounds"][0]["evaluation"]["nominal"]
    assert "residual_base" not in run.env_options  # the env's default: the loop's command as computed


def test_a_residual_student_on_the_saturated_base_flies_and_is_evaluated_on_it():
    config = DistillConfig(**{**MIXTURE, "also_tasks": (), "tiers": ("nominal",), "residual_on": "integral",
                              "residual_base": "saturated"})
    assert config.student_env_options["residual_base"] == "saturated"
    assert config.student_env_options["residual_scale"] == 2.0  # the default: full authority
    bounded = DistillConfig(**{**MIXTURE, "tiers": ("nominal",), "residual_on": "integral", "residual_scale": 0.25})
    assert bounded.run_config().env_options["residual_scale"] == 0.25
    assert config.run_config().env_options["residual_base"] == "saturated"
    env = SoftPVTOLVectorEnv(num_envs=1, action_mode=config.action_mode, **{
        k: v for k, v in config.run_config().env_options.items()}, controller_loop="integral")
    assert env.config.residual_base == "saturated"
