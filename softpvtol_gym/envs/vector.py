"""Native vector env: N Soft-PVTOLs stepped as arrays through the same kernels as the single env."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
from gymnasium.error import ResetNeeded
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from .._validation import choice, seed_value, short_repr
from ..params import SoftPVTOLParams
from .actions import actuator_action
from .batch_sim import BatchSim
from .config import EnvConfig
from .episodes import N_UNIFORMS, check_reset_options
from .info import StepOutputs, batch_info
from .soft_pvtol import make_spaces
from .uniforms import UniformDraws


class SoftPVTOLVectorEnv(VectorEnv):
    """``num_envs`` SoftPVTOL envs in one set of arrays (see :class:`SoftPVTOLEnv` for the env).

    Same arguments as :class:`SoftPVTOLEnv` (its Arguments table) plus ``num_envs`` and ``autoreset_mode``
    (``"NextStep"`` default, as gymnasium's SyncVectorEnv, or ``"SameStep"``/``"Disabled"``).
    Sub-env i has its own ``numpy.random.Generator``; ``reset(seed=s)`` seeds it with s + i exactly as
    SyncVectorEnv does, so with the same actions sub-env i reproduces bit for bit the trajectory of a
    single env reset with seed s + i (resets use one block of uniforms per sub-env; per-step noise is
    counter based). ``step`` has no Python loop over sub-envs except over those being reset.

    Infos are a dict of arrays (gymnasium's vector convention, each with its ``_name`` mask):
    ``reward_terms`` (a dict of arrays), ``total_energy``, ``storage_function``,
    ``curvature_violation``, ``allocation_residual``, ``thrust_saturated``, ``arm_torque_saturated``,
    ``action_clipped``, ``termination_reason`` (object array, None where not done), ``time`` (and, with
    ``residual_gate``, ``residual_gate``; the opt-in reward terms are in ``reward_terms``).
    With SameStep autoreset, ``final_obs``/``final_info`` as in gymnasium. With Disabled autoreset,
    ``reset(options={"reset_mask": mask})`` (a bool array of num_envs) resets the sub-envs where mask
    (gymnasium's convention), and stepping a sub-env that has ended warns once per episode.
    ``step()`` before every sub-env has been reset raises gymnasium's ``ResetNeeded``.
    """

    metadata = {"render_modes": ["rgb_array"], "autoreset_mode": AutoresetMode.NEXT_STEP, "render_fps": 100}

    def __init__(
        self,
        num_envs: int = 1,
        render_mode: str | None = None,
        autoreset_mode: str | AutoresetMode = AutoresetMode.NEXT_STEP,
        *,
        action_mode: str = "actuators",
        task: str = "hover",
        tier: str = "nominal",
        params: SoftPVTOLParams | None = None,
        input_map: str = "paper",
        allocation: str | None = None,
        residual_space: str = "virtual",
        residual_base: str = "unsaturated",
        frame_skip: int = 1,
        max_episode_seconds: float | None = None,
        tier_options: dict | None = None,
        residual_scale: float = 0.2,
        actuator_limits: tuple | None = None,
        controller_loop: str | None = None,
        model: str | None = None,
        observe_error_integral: bool = False,
        error_integral_limit: float = 10.0,
        error_integral_error_limit: float | None = None,
        precision_reward_weight: float = 0.0,
        precision_reward_scale: float = 0.01,
        action_rate_penalty: float = 0.0,
        residual_gate: float | None = None,
        start_error_scale: float = 1.0,
        start_distribution: str = "task",
        **unknown,
    ) -> None:
        if isinstance(num_envs, (bool, np.bool_)) or not isinstance(num_envs, (int, np.integer)) or num_envs < 1:
            raise ValueError(f"num_envs must be an int >= 1, got {short_repr(num_envs)} of type "
                             f"{type(num_envs).__name__}")
        # the arguments of EnvConfig, as SoftPVTOLEnv (one signature for both; a test keeps them equal)
        self.config = EnvConfig.from_init_arguments(locals(), ("num_envs", "render_mode", "autoreset_mode"))
        choice("render_mode", render_mode, (None, "rgb_array"))
        try:
            self.autoreset_mode = AutoresetMode(autoreset_mode)
        except (ValueError, TypeError):
            raise ValueError(
                f"autoreset_mode must be one of {[m.value for m in AutoresetMode]}, got {autoreset_mode!r}"
            ) from None
        self.metadata = dict(self.metadata, autoreset_mode=self.autoreset_mode,
                             render_fps=int(round(1.0 / self.config.dt)))
        self.render_mode = render_mode
        self.num_envs = int(num_envs)
        self.single_observation_space, self.single_action_space = make_spaces(self.config)
        try:  # num_envs has no bound but memory (about 2.3 kB of state per env)
            self.observation_space = batch_space(self.single_observation_space, self.num_envs)
            self.action_space = batch_space(self.single_action_space, self.num_envs)
            self._sim = BatchSim(self.config, self.num_envs)
        except MemoryError as e:
            raise MemoryError(f"num_envs={self.num_envs} does not fit in memory (about 2.3 kB of state per env): "
                              f"{e}; use fewer envs") from None
        self._rngs: list[np.random.Generator] = [seeding.np_random(None)[0] for _ in range(self.num_envs)]
        self._uniforms = UniformDraws()
        self._autoreset = np.zeros(self.num_envs, dtype=bool)
        self._all = np.arange(self.num_envs)
        self._renderer = None
        # step() needs every sub-env reset once; Disabled autoreset: done sub-envs stepped on are warned
        # about once per episode (as CartPole)
        self._fresh = np.ones(self.num_envs, dtype=bool)
        self._needs_reset = True
        self._over = np.zeros(self.num_envs, dtype=bool)
        self._warned = np.zeros(self.num_envs, dtype=bool)

    # ------------------------------------------------------------------------------ seeding
    def _draw(self, idx: np.ndarray) -> np.ndarray:
        """``self._rngs[i].random(N_UNIFORMS)`` for i in idx, stacked (a compiled loop: :mod:`.uniforms`)."""
        return self._uniforms.draw(self._rngs, idx, N_UNIFORMS)

    def reset(self, *, seed: int | list | None = None, options: dict | None = None):
        """Reset every sub-env, or (gymnasium's ``options={"reset_mask": mask}``, a bool array of shape
        (num_envs,)) those where mask; ``seed``: None, an int s (sub-env i seeded with s + i) or a list of
        num_envs ints/None. Arguments are checked before anything changes."""
        seeds = self._seeds(seed)
        state_options = check_reset_options(self.config, options, extra_keys=("reset_mask",))
        mask = self._reset_mask(options["reset_mask"]) if options and "reset_mask" in options else None
        idx = self._all if mask is None else np.flatnonzero(mask)
        if seeds is not None:
            for i in idx.tolist():
                self._rngs[i] = seeding.np_random(seeds[i])[0]
            self._uniforms.invalidate()
            if mask is None or mask[0]:
                self._np_random, self._np_random_seed = seeding.np_random(seeds[0])
        self._sim.reset_entries(idx, self._draw(idx), state_options)
        self._autoreset[idx] = False
        self._over[idx] = False
        self._warned[idx] = False
        self._fresh[idx] = False
        self._needs_reset = bool(self._fresh.any())
        if self._renderer is not None and (mask is None or mask[0]):
            self._renderer.clear_trail()
        out = StepOutputs.of(self._sim)  # the new observations and their infos
        infos = out.info(self._sim)
        if mask is not None:  # infos of the sub-envs reset (gymnasium's masks)
            for k in list(infos):
                if k.startswith("_"):
                    infos[k] = mask.copy()
        return out.obs, infos

    def _seeds(self, seed) -> list | None:
        """The per-sub-env seeds of :meth:`reset` (gymnasium's rules; numpy integers accepted)."""
        n = self.num_envs
        if seed is None:
            return None
        if isinstance(seed, (int, np.integer)) and not isinstance(seed, (bool, np.bool_)):
            s = seed_value(seed)
            return [s + i for i in range(n)]
        if not isinstance(seed, (list, tuple, np.ndarray)):
            raise ValueError(f"seed must be an int >= 0, a list of num_envs={n} ints >= 0 (or None entries), "
                             f"or None; got {short_repr(seed)} of type {type(seed).__name__}")
        seeds = [seed_value(s, f"seed[{i}]") for i, s in enumerate(list(seed))]
        if len(seeds) != n:
            raise ValueError(f"seed list must have num_envs={n} entries, got {len(seeds)}")
        return seeds

    def _reset_mask(self, mask) -> np.ndarray:
        """``options["reset_mask"]`` checked as gymnasium's vector envs do."""
        n = self.num_envs
        if not isinstance(mask, np.ndarray):
            raise TypeError(f"options['reset_mask'] must be a numpy bool array of shape ({n},), got "
                            f"{short_repr(mask)} of type {type(mask).__name__}")
        if mask.shape != (n,):
            raise ValueError(f"options['reset_mask'] must have shape ({n},) (num_envs), got {mask.shape}")
        if mask.dtype != np.bool_:
            raise TypeError(f"options['reset_mask'] must have dtype bool, got {mask.dtype} (use mask.astype(bool))")
        if not mask.any():
            raise ValueError("options['reset_mask'] must be True for at least one sub-env, got all False")
        return mask.copy()

    def step(self, actions):
        if self._needs_reset:
            raise ResetNeeded("Cannot call env.step() before calling env.reset() (every sub-env: a reset_mask "
                              f"reset left sub-envs {np.flatnonzero(self._fresh).tolist()[:8]} never reset)"
                              if not self._fresh.all() else "Cannot call env.step() before calling env.reset()")
        sim = self._sim
        mode = self.autoreset_mode
        if mode == AutoresetMode.DISABLED and self._over.any():
            new = self._over & ~self._warned
            if new.any():
                self._warned |= new
                gym.logger.warn(
                    f"You are calling 'step()' on sub-envs {np.flatnonzero(new).tolist()[:8]} that have already "
                    "returned terminated = True or truncated = True (autoreset_mode='Disabled'). Reset them "
                    "with reset(options={'reset_mask': mask}) -- any further steps are undefined behavior."
                )
        out = StepOutputs(self.num_envs, sim.obs.shape[1])  # what this step returns: fresh arrays
        if mode == AutoresetMode.NEXT_STEP:
            idx = np.flatnonzero(self._autoreset)
            if idx.size:
                # the sub-envs reset at this step draw their uniforms and sample their episodes while the
                # physics runs (in this thread, beside the kernel threads; only once the step can no longer
                # fail, so an error consumes no random numbers); each range's new episodes are then written
                # and its outputs gathered in the thread that stepped it
                pending = []

                def finish(lo: int, hi: int) -> None:
                    sim.write_episodes(idx, pending[0], lo, hi)
                    out.gather(sim, lo, hi)

                sim.step(actions, batched=True, side=lambda: pending.append(sim.prepare_reset(self._draw(idx))),
                         after=finish)
                sim.reset_memory(idx)
            else:
                sim.step(actions, batched=True, after=out.gather_into(sim))
            # (a sub-env reset at this step reports its new episode: reward 0, neither terminated nor truncated)
            self._autoreset = out.terminated | out.truncated
            return out.obs, out.rewards, out.terminated, out.truncated, out.info(sim)
        sim.step(actions, batched=True, after=out.gather_into(sim))
        infos = out.info(sim)
        obs = out.obs
        done = out.terminated | out.truncated
        if mode == AutoresetMode.SAME_STEP:
            idx = np.flatnonzero(done)
            if idx.size:
                final_obs = np.full(self.num_envs, None, dtype=object)
                for i in idx.tolist():
                    final_obs[i] = obs[i].copy()
                infos["final_obs"] = final_obs
                infos["_final_obs"] = done.copy()
                infos["final_info"] = batch_info(sim)
                infos["_final_info"] = done.copy()
                sim.reset_entries(idx, self._draw(idx))
                obs[idx] = sim.obs[idx]
        else:
            self._over |= done
        return obs, out.rewards, out.terminated, out.truncated, infos

    def set_start_error_scale(self, scale: float) -> None:
        """Scale the starting deviations of the next resets (``start_error_scale``, in [0, 10]) that do not
        pass the ``start_error_scale`` reset option, the autoresets included: a curriculum's knob (e.g. from a
        training callback, ``vec_env.env_method("set_start_error_scale", 0.5)``). ValueError outside [0, 10]."""
        self._sim.set_start_error_scale(scale)

    # --------------------------------------------------------------------------------- access
    @property
    def sim(self) -> BatchSim:
        """The batched simulator behind this env: named (num_envs, ...) views of its state (``q``,
        ``qd``, ``qr``, ``qdr``, ``qddr``, ``P``, ``wind``, ``lag``, ``applied``, ...). Read them; do not
        write."""
        return self._sim

    @property
    def state(self) -> tuple[np.ndarray, np.ndarray]:
        return self._sim.q.copy(), self._sim.qd.copy()

    def noise_free_observations(self) -> np.ndarray:
        """The observations of the last reset or step as noise-free sensors would give them (num_envs, obs_dim),
        float32: what a privileged teacher acts on. Equal to the observations where the tier has no sensor
        noise; the error integrals are the env's."""
        return self._sim.noise_free_observation()

    def applied_actions(self) -> np.ndarray:
        """The actuator inputs (T_l, T_r, tau_l, tau_r) the plant received at the last step, after the actuator lag
        where the tier has one, as the normalised actions (num_envs, 4) float64 of ``action_mode="actuators"``
        that command them: what a privileged teacher with memory of its inputs is told. NaN in a row that has not
        stepped since its reset. In every mode whose plant gets actuator inputs (all but ``allocation="ideal"``,
        where it gets tau)."""
        if self.config.resolved_allocation == "ideal":
            raise ValueError("applied_actions(): with allocation='ideal' the plant gets the generalized force tau, "
                             "not actuator inputs; read env.sim.applied for the applied command")
        return actuator_action(self._sim.applied[:, :4], self.config.thrust_max, self.config.arm_torque_max)

    def render(self):
        """rgb_array of sub-env 0."""
        if self.render_mode is None:
            return None
        if self._renderer is None:
            from .rendering import Renderer

            self._renderer = Renderer(self.config, "rgb_array", self.metadata["render_fps"])
        s = self._sim
        return self._renderer.draw(s.q[0], s.qr[0], s.P[0], s.applied[0], s.t[0])

    def close_extras(self, **kwargs):
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
