"""Building the SB3 pieces of a run from its :class:`~softpvtol_gym.baselines.config.run_config.RunConfig`: the
vector env, the VecNormalize wrapper, the VecFrameStack wrapper and the algorithm. Checkpoint loading builds the same
objects and then fills in the saved weights and state (:mod:`softpvtol_gym.baselines.checkpoints`), so nothing of a
model is ever unpickled."""

from __future__ import annotations

import warnings

from softpvtol_gym.baselines.config.hyperparams import algo_kwargs, frame_stack, normalize_kwargs
from softpvtol_gym.baselines.config.run_config import RunConfig
from softpvtol_gym.baselines.errors import ConfigError


def algo_class(algo: str):
    from stable_baselines3 import PPO, SAC

    try:
        return {"ppo": PPO, "sac": SAC}[algo]
    except KeyError:
        raise ConfigError(f"algo must be 'ppo' or 'sac', got {algo!r}") from None


def make_env(config: RunConfig, n_envs: int | None = None):
    """The SB3 adapter over a native vector env of the run's cell (``n_envs`` sub-envs, default the run's); its
    info dicts are empty while an episode goes on (``step_infos=False``: SB3's PPO and SAC read only a finished
    episode's)."""
    from softpvtol_gym.envs.sb3 import SoftPVTOLSB3VecEnv  # stable-baselines3: imported when a run starts

    return SoftPVTOLSB3VecEnv(num_envs=config.n_envs if n_envs is None else n_envs, step_infos=False,
                              **config.env_kwargs())


def make_vecnorm(config: RunConfig, env, training: bool = True):
    """``VecNormalize(env, **normalize)`` of the run's hyperparameters, or None without normalisation."""
    norm = normalize_kwargs(config.hyperparams)
    if norm is None:
        return None
    from stable_baselines3.common.vec_env import VecNormalize

    return VecNormalize(env, training=training, **norm)


def stack_frames(config: RunConfig, venv):
    """``VecFrameStack(venv, frame_stack)`` of the run's hyperparameters, or ``venv`` itself without stacking.

    The stack goes on top of VecNormalize, as in rl-baselines3-zoo: the normalisation statistics are those
    of one observation (the same ``vecnormalize.json`` with and without stacking), and the zeros that fill
    the stack at the start of an episode are zeros of the normalised observation (its running mean), not
    raw zeros that the statistics would count K - 1 times out of K at every reset."""
    k = frame_stack(config.hyperparams)
    if k == 1:
        return venv
    from stable_baselines3.common.vec_env import VecFrameStack

    return VecFrameStack(venv, n_stack=k)


DEVICES = ("auto", "cpu", "cuda")


def resolve_device(device: str) -> str:
    """``"cpu"`` or ``"cuda"`` for the policy of a run (the env always steps on the CPU): ``"auto"`` is
    ``"cuda"`` where torch sees a CUDA GPU, else ``"cpu"``; ``"cuda"`` without one is a ConfigError."""
    if device not in DEVICES:
        raise ConfigError(f"device must be one of {list(DEVICES)}, got {device!r}")
    if device == "cpu":
        return "cpu"
    import torch

    if torch.cuda.is_available():
        return "cuda"
    if device == "auto":
        return "cpu"
    build = f"built with CUDA {torch.version.cuda}" if torch.version.cuda else "a CPU-only build"
    raise ConfigError(f"--device cuda: torch sees no CUDA GPU (torch {torch.__version__}, {build}; "
                      f"torch.cuda.is_available() is False); use --device cpu or --device auto")


def build_model(config: RunConfig, env, tensorboard_log: str | None = None, verbose: int = 0, device: str = "cpu"):
    """The SB3 algorithm of ``config`` on ``env`` (seeded with the run's seed; the policy on ``device``,
    ``"cpu"`` or ``"cuda"``). What SB3 refuses (an assertion or a bad argument of the policy) becomes a
    ConfigError naming it."""
    cls = algo_class(config.algo)
    hp = config.hyperparams
    policy = hp.get("policy", "MlpPolicy")
    if policy == "ZeroAtZeroPolicy":
        if config.algo != "ppo":
            raise ConfigError(f"policy ZeroAtZeroPolicy is a PPO policy (an actor-critic), got algo {config.algo!r}")
        from softpvtol_gym.baselines.training.zero_residual import ZeroAtZeroPolicy  # stable-baselines3, torch

        policy = ZeroAtZeroPolicy
    try:
        with warnings.catch_warnings():
            # the mini-batch size not dividing the rollout is legal (SB3 warns; train.py says so itself)
            warnings.filterwarnings("ignore", message=".*mini-batch size.*")
            model = cls(policy, env, seed=config.seed, device=device, verbose=verbose,
                        tensorboard_log=tensorboard_log, **algo_kwargs(hp))
        # SB3 seeds the action space only; the observation space's generator (made on first use, recorded in
        # model.json) is seeded too, so that identical runs write identical files
        model.observation_space.seed(config.seed)
        return model
    except (AssertionError, TypeError, ValueError, KeyError) as exc:
        raise ConfigError(f"stable-baselines3 refused the hyperparameters of this {config.algo.upper()} run: "
                          f"{type(exc).__name__}: {exc}") from None
    except RuntimeError as exc:
        if "fused" not in str(exc):
            raise
        import torch

        # torch's fused Adam runs on the CPU from torch 2.4 on (the residual-fast recipe asks for it)
        raise ConfigError(f"torch {torch.__version__} refused the optimizer of this {config.algo.upper()} run "
                          f"({exc}); policy_kwargs asks for optimizer_kwargs=dict(fused=True), which needs torch "
                          f">= 2.4 on the CPU: upgrade torch or override policy_kwargs without it") from None
