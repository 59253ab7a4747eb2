"""The settings of a distillation run (:class:`DistillConfig`, saved in ``distill.json``), validated on
construction, and the seeds and env options that follow from them."""

from __future__ import annotations

import dataclasses

import numpy as np

from softpvtol_gym.baselines.config.hyperparams import (
    MAX_FRAME_STACK,
    TRAIN_SEED_LIMIT,
    apply_overrides,
    load_hyperparams,
)
from softpvtol_gym.baselines.config.run_config import RunConfig
from softpvtol_gym.baselines.errors import ConfigError
from softpvtol_gym.baselines.training.teachers import RESIDUAL_STUDENT_SCALE, TEACHERS, student_env_options
from softpvtol_gym.control import LOOPS
from softpvtol_gym.envs.config import RESIDUAL_BASES
from softpvtol_gym.envs.tiers import get_tier, registered_tiers
from softpvtol_gym.tasks import registered_tasks

__all__ = ["DistillConfig", "EARLIER_DEFAULTS", "SEED_STRIDE", "MAX_EPISODES_PER_ROUND", "MAX_ROUNDS"]

#: collection episodes of run seed s start at s * SEED_STRIDE (below the training seed limit)
SEED_STRIDE = 10_000
MAX_EPISODES_PER_ROUND = 1_000
MAX_ROUNDS = 50
#: settings added after runs were made, with the value those runs had (a resumed run keeps it)
EARLIER_DEFAULTS = {"wide_fraction": 0.0, "teacher_integral": False, "balance_actions": False, "teacher_share": 0.0,
                    "history": 1, "privileged": False, "teacher_shares": [], "also_tasks": [],
                   "residual_on": None, "residual_base": "unsaturated", "attitude_fraction": 0.0,
                   "residual_scale": RESIDUAL_STUDENT_SCALE}


@dataclasses.dataclass(frozen=True)
class DistillConfig:
    """A distillation run (saved in ``distill.json``).

    Args:
        teacher: a name of :data:`TEACHERS`.
        task: the student's task (its run config; ``registered_tasks()``): the episodes fly it and ``also_tasks``.
        tiers: the tiers the episodes fly, each with its randomisation; every round collects ``episodes``
            episodes of each, on each task.
        seed: the run's seed (< 500,000 / 10,000 episodes: collection seeds stay below the training limit).
        net_arch: the student's hidden layers (the actor's; the value net is SB3's default 64, 64).
        rounds: data-collection rounds: 1 is behaviour cloning only, each further one a DAgger round.
        episodes: episodes per task, tier and round (they fly as one vector env).
        epochs: passes over the aggregate dataset per fit.
        batch_size: samples per gradient step.
        learning_rate: Adam's initial learning rate (decayed linearly to 0 over the fit).
        eval_episodes: student and teacher episodes per task and tier after each round (0: none).
        precision_scale: None: every sample weighs the same; s > 0 [m]: a sample of position error e weighs
            in proportion to 1 / (s + |e|) (normalised to a mean of 1), so that the fit spends its accuracy
            where the errors are small, where the teacher's fine corrections decide the steady error.
        wide_fraction: the share of each round's episodes (rounded) that start like track_paper's, far from the
            reference (the env's ``start_distribution="wide"``); the others start as the task does. The student
            then also learns to recover from errors of metres, which the task's own starts never show it.
        attitude_fraction: the share of each round's episodes (rounded) that start near the reference but turned
            (up to 1.2 rad), bent and spinning (the env's ``start_distribution="attitude"``): the states a student
            that has lost its attitude must recover from, which neither the teacher's flights nor the task's starts
            visit. Together with ``wide_fraction`` at most every episode.
        teacher_integral: the student observes the error integrals as a teacher with integral action integrates
            them (:func:`~softpvtol_gym.baselines.training.teachers.student_env_options`); False: as the env
            does by default (raw errors). No effect for a teacher without integral action.
        balance_actions: the fit divides each action channel's squared error by that channel's variance over
            the dataset, so that every actuator weighs the same; False: the squared errors of the actions as
            they are, where the thrusts' spread (about 0.1 of the action range) outweighs the arms' bending
            inputs' (about 0.01) a hundred times.
        teacher_share: p in [0, 1): in DAgger round k (k >= 1) each step of each episode applies the teacher's
            action with probability p ** k and the student's otherwise (the DAgger paper's beta_k = p ** k), so that
            the early students, which may crash within a second, still fly where the teacher goes; the teacher
            labels every step either way. 0: the student flies alone in every DAgger round.
        teacher_shares: the teacher's share of DAgger rounds 1, 2, ... given one by one (``rounds - 1`` shares in
            [0, 1], e.g. (0.5, 0.2, 0.0): a schedule that ends with the student alone), instead of ``teacher_share``'s
            powers; empty: ``teacher_share``.
        history: K, the observations the student sees: its last K, oldest first (``frame_stack`` K of its
            run, SB3's VecFrameStack over VecNormalize; 1: the current one only). With K > 1 the student can tell
            the rates of change its observation lacks (of the error integrals, of what the wind or a parameter
            error does to the motion); its first layer takes K times the inputs.
        privileged: the teacher labels, and in round 0 flies, from the noise-free observation of the true state
            (:meth:`~softpvtol_gym.envs.vector.SoftPVTOLVectorEnv.noise_free_observations`), while the student sees
            the noisy one: learning by cheating. Only tiers with sensor noise make a difference, so at least one
            of ``tiers`` must have it. Where a tier lags the actuators, a teacher with memory of its inputs (the
            MPC) is also told the actuators' true lagged state after each step.
        also_tasks: further tasks the episodes fly besides ``task`` (every round collects ``episodes`` episodes per
            task and tier, and evaluates the student on each): one student for a mixture of tasks, such as hover
            and both tracking tasks.
        residual_on: None: the student commands the actuators. A passivity loop (a name of ``LOOPS`` the residual
            mode takes as its base, e.g. ``"integral"``): the student is a residual on it, the env's residual mode
            with ``residual_space="actuators"`` and ``residual_scale``, and learns the
            correction that turns the loop's command into the teacher's, (teacher - loop) / scale clipped to
            [-1, 1] (the loop computed beside the env on the same observations, clipped to the actuator box). At
            zero correction the student flies the loop itself: the loop's integral action holds the steady state,
            and the fit need not learn millimetres from the teacher's actions.
        residual_base: with ``residual_on``, what the correction is added to (the env's ``residual_base``):
            ``"unsaturated"``, the loop's command as computed (a command far outside the actuator box, such as the
            arm torques a loop computes from noisy rates, leaves labels at the clip), or ``"saturated"``, the command
            clipped to the box, from which a correction in [-1, 1] reaches any command of the box.
        residual_scale: with ``residual_on``, the residual's authority (the env's ``residual_scale`` in the actuator
            space: the correction at +-1 as a fraction of (T_max/2, T_max/2, tau_max, tau_max)), in (0, 100].
            :data:`RESIDUAL_STUDENT_SCALE` (2): a correction reaches any command of the box; below it the student
            may move the loop's command only so far (a bounded residual: the teacher's corrections beyond it are
            labelled at the clip), so that the loop's own robustness bounds what the student can spoil.
    """

    teacher: str = "integral"
    task: str = "track_random"
    tiers: tuple = ("nominal",)
    seed: int = 0
    net_arch: tuple = (256, 256)
    rounds: int = 3
    episodes: int = 16
    epochs: int = 30
    batch_size: int = 1024
    learning_rate: float = 1e-3
    eval_episodes: int = 8
    precision_scale: float | None = None
    wide_fraction: float = 0.0
    teacher_integral: bool = True
    balance_actions: bool = False
    teacher_share: float = 0.0
    history: int = 1
    privileged: bool = False
    teacher_shares: tuple = ()
    also_tasks: tuple = ()
    residual_on: str | None = None
    residual_base: str = "unsaturated"
    attitude_fraction: float = 0.0
    residual_scale: float = RESIDUAL_STUDENT_SCALE

    def __post_init__(self) -> None:
        for name in ("tiers", "net_arch", "teacher_shares", "also_tasks"):
            value = getattr(self, name)
            if isinstance(value, (str, bytes)) or not hasattr(value, "__iter__"):
                raise ConfigError(f"{name} must be a list, got {value!r}")
            object.__setattr__(self, name, tuple(value))
        if self.teacher not in TEACHERS:
            raise ConfigError(f"teacher must be one of {list(TEACHERS)}, got {self.teacher!r}")
        if self.task not in registered_tasks():
            raise ConfigError(f"task must be one of {list(registered_tasks())}, got {self.task!r}")
        bad = [t for t in self.also_tasks if t not in registered_tasks()]
        if bad or len(set(self.tasks)) != len(self.tasks):
            raise ConfigError(f"also_tasks must be distinct names of {list(registered_tasks())} other than task "
                              f"{self.task!r}, got {list(self.also_tasks)}")
        bad = [t for t in self.tiers if t not in registered_tiers()]
        if not self.tiers or bad or len(set(self.tiers)) != len(self.tiers):
            raise ConfigError(f"tiers must be distinct names of {list(registered_tiers())}, got {list(self.tiers)}")
        if not self.net_arch or not all(_is_int(n) and 1 <= n <= 4096 for n in self.net_arch):
            raise ConfigError(f"net_arch must be hidden layer sizes in [1, 4096], got {list(self.net_arch)}")
        for name, lo, hi in (("rounds", 1, MAX_ROUNDS), ("episodes", 1, MAX_EPISODES_PER_ROUND),
                             ("epochs", 1, 10_000), ("batch_size", 1, 1 << 20), ("eval_episodes", 0, 1_000)):
            v = getattr(self, name)
            if not _is_int(v) or not lo <= v <= hi:
                raise ConfigError(f"{name} must be an integer in [{lo}, {hi:,}], got {v!r}")
        if not isinstance(self.learning_rate, (int, float)) or not 0 < self.learning_rate <= 1:
            raise ConfigError(f"learning_rate must be in (0, 1], got {self.learning_rate!r}")
        p = self.precision_scale
        if p is not None and (isinstance(p, bool) or not isinstance(p, (int, float)) or not 0 < p <= 100):
            raise ConfigError(f"precision_scale must be None or a length in (0, 100] m, got {p!r}")
        for name in ("teacher_integral", "balance_actions", "privileged"):
            if not isinstance(getattr(self, name), bool):
                raise ConfigError(f"{name} must be a bool, got {getattr(self, name)!r}")
        for name in ("wide_fraction", "attitude_fraction"):
            w = getattr(self, name)
            if isinstance(w, bool) or not isinstance(w, (int, float)) or not 0.0 <= w <= 1.0:
                raise ConfigError(f"{name} must be a share in [0, 1], got {w!r}")
        if self.wide_episodes() + self.attitude_episodes() > self.episodes:
            raise ConfigError(f"wide_fraction {self.wide_fraction!r} and attitude_fraction {self.attitude_fraction!r} "
                              f"start {self.wide_episodes()} + {self.attitude_episodes()} of the {self.episodes} "
                              f"episodes per round: more than there are; give shares that sum to at most 1")
        p = self.teacher_share
        if isinstance(p, bool) or not isinstance(p, (int, float)) or not 0.0 <= p < 1.0:
            raise ConfigError(f"teacher_share must be a probability in [0, 1), got {p!r}")
        if p and self.rounds == 1:
            raise ConfigError(f"teacher_share={p!r} acts in the DAgger rounds (round 2 on), and rounds=1 is behaviour "
                              f"cloning only: it would change nothing; pass rounds >= 2, or leave teacher_share out")
        shares = self.teacher_shares
        if shares:
            if p:
                raise ConfigError(f"teacher_shares {list(shares)} and teacher_share={p!r} both set the teacher's "
                                  f"share of the DAgger rounds; give one of them")
            if len(shares) != self.rounds - 1 or not all(
                    isinstance(b, (int, float)) and not isinstance(b, bool) and 0.0 <= b <= 1.0 for b in shares):
                raise ConfigError(f"teacher_shares must be one share in [0, 1] per DAgger round ({self.rounds - 1} "
                                  f"with rounds={self.rounds}), got {list(shares)}")
        if self.residual_on is not None and (self.residual_on not in LOOPS or "controller" in LOOPS[self.residual_on]
                                             or self.residual_on == "ideal"):
            bases = [name for name, loop in LOOPS.items() if "controller" not in loop and name != "ideal"]
            raise ConfigError(f"residual_on must be None or a loop the residual mode takes as its base, one of "
                              f"{bases}, got {self.residual_on!r}")
        if self.residual_base not in RESIDUAL_BASES or (self.residual_base != "unsaturated" and
                                                        self.residual_on is None):
            raise ConfigError(f"residual_base must be one of {list(RESIDUAL_BASES)}, and 'saturated' only with "
                              f"residual_on (a residual student), got residual_base={self.residual_base!r} with "
                              f"residual_on={self.residual_on!r}")
        scale = self.residual_scale
        if isinstance(scale, bool) or not isinstance(scale, (int, float)) or not 0.0 < scale <= 100.0:
            raise ConfigError(f"residual_scale must be a number in (0, 100] (the residual's authority as a fraction "
                              f"of the actuator half-ranges), got {scale!r}")
        if scale != RESIDUAL_STUDENT_SCALE and self.residual_on is None:
            raise ConfigError(f"residual_scale={scale!r} sets a residual student's authority, but residual_on is "
                              f"None (the student commands the actuators); give residual_on (e.g. 'integral') or "
                              f"leave residual_scale at {RESIDUAL_STUDENT_SCALE}")
        if self.privileged and not any("noise" in get_tier(t).effects for t in self.tiers):
            raise ConfigError(f"privileged labels differ from the plain ones only under sensor noise, and the tiers "
                              f"{list(self.tiers)} have none: it would change nothing; add a tier with noise "
                              f"(noisy, hard) or leave privileged out")
        if not _is_int(self.history) or not 1 <= self.history <= MAX_FRAME_STACK:
            raise ConfigError(f"history must be an integer in [1, {MAX_FRAME_STACK}] (observations the student sees), "
                              f"got {self.history!r}")
        last = self.seed * SEED_STRIDE + self.collections * self.episodes if _is_int(self.seed) else -1
        if not _is_int(self.seed) or self.seed < 0 or last > TRAIN_SEED_LIMIT or \
                self.collections * self.episodes > SEED_STRIDE:
            raise ConfigError(f"seed must be an integer >= 0 with rounds x tiers x episodes <= {SEED_STRIDE:,} and "
                              f"the collection seeds (from seed x {SEED_STRIDE:,}) below {TRAIN_SEED_LIMIT:,}, got "
                              f"seed {self.seed!r} with {self.collections} collections of {self.episodes} episodes")

    @property
    def tasks(self) -> tuple:
        """The tasks the episodes fly: ``task``, then ``also_tasks``."""
        return (self.task, *self.also_tasks)

    @property
    def collections(self) -> int:
        """The number of collected datasets: one per round, task and tier."""
        return self.rounds * len(self.tasks) * len(self.tiers)

    def collection_seed(self, round_index: int, tier_index: int, task_index: int = 0) -> int:
        """The first episode seed of round ``round_index``'s collection on task ``task_index`` (of :attr:`tasks`)
        and tier ``tier_index``."""
        index = (round_index * len(self.tasks) + task_index) * len(self.tiers) + tier_index
        return self.seed * SEED_STRIDE + index * self.episodes

    def round_teacher_share(self, round_index: int) -> float:
        """The teacher's share of the steps of round ``round_index`` (0: behaviour cloning, the teacher flies)."""
        if round_index == 0:
            return 1.0
        if self.teacher_shares:
            return float(self.teacher_shares[round_index - 1])
        return float(self.teacher_share) ** round_index

    @property
    def env_options(self) -> dict:
        """The student's observation options (the teacher's env has them too)."""
        return student_env_options(self.teacher, self.teacher_integral)

    @property
    def action_mode(self) -> str:
        """The student's action mode: ``"residual"`` on ``residual_on``, else ``"actuators"``."""
        return "actuators" if self.residual_on is None else "residual"

    @property
    def student_env_options(self) -> dict:
        """The student's env options: :attr:`env_options` and, as a residual, its base loop and scale."""
        if self.residual_on is None:
            return self.env_options
        options = {**self.env_options, "controller_loop": self.residual_on, "residual_space": "actuators",
                   "residual_scale": self.residual_scale}
        return options if self.residual_base == "unsaturated" else {**options, "residual_base": self.residual_base}

    def wide_episodes(self) -> int:
        """The episodes of each round and tier that start wide (``wide_fraction`` of ``episodes``, rounded)."""
        return int(round(self.wide_fraction * self.episodes))

    def attitude_episodes(self) -> int:
        """The episodes of each round and tier that start turned (``attitude_fraction`` of ``episodes``, rounded)."""
        return int(round(self.attitude_fraction * self.episodes))

    def run_config(self, dataset_size: int = 1) -> RunConfig:
        """The student's run config: PPO on its action mode (:attr:`action_mode`) with the error integrals
        observed, the actuators entry's hyperparameters with the student's ``net_arch`` (``timesteps``: the
        samples)."""
        hp = load_hyperparams("ppo", "actuators")
        arch = ", ".join(str(n) for n in self.net_arch)
        hp = apply_overrides(hp, [f"policy_kwargs=dict(log_std_init=-1.0, net_arch=dict(pi=[{arch}], vf=[64, 64]))"]
                             + ([f"frame_stack={self.history}"] if self.history > 1 else []))
        options = dict(self.student_env_options)
        return RunConfig(algo="ppo", action_mode=self.action_mode, task=self.task, tier=self.tiers[0],
                         timesteps=max(1, int(dataset_size)), seed=self.seed, n_envs=int(hp.get("n_envs", 16)),
                         hyperparams=hp, controller_loop=options.pop("controller_loop", None), env_options=options)

    def to_dict(self) -> dict:
        return {f.name: (list(v) if isinstance(v := getattr(self, f.name), tuple) else v)
                for f in dataclasses.fields(self)}


def _is_int(v) -> bool:
    return isinstance(v, (int, np.integer)) and not isinstance(v, bool)

