"""BatchSim: the state of N envs as packed arrays and their reset and step, shared by the single env
(N = 1) and the vector env."""

from __future__ import annotations

import gymnasium as gym
import numpy as np

from .. import model as MK
from .._parallel import row_ranges, run_split
from .._validation import bounded_number, real_array, short_repr
from ..control import kernels as CK
from ..control.closed_loop import MAX_HELD_CONTROL_PERIOD, PassivityController
from ..references import reference_block
from .config import EnvConfig
from .episodes import MAX_START_ERROR_SCALE, START_SCALE_REASON, apply_options, sample_episodes
from .observation import observe_range
from .packed_state import CONST, ISTATE, SC, STATE, S
from .reset import reset_rows
from .step import (
    STEP_BAD_ACTION,
    STEP_OK,
    kernel_flags,
    serial_step_kernel,
    step_check_actions,
    step_physics_rows,
    step_residual_rows,
)
from .training_aids import TrainingAids

_F64 = np.dtype(np.float64)


class StepBinding:
    """What a BatchSim's step derives from its arrays and config once (not state: rebuilt on unpickling, never
    saved in a checkpoint): ``args``, the serial kernel's arguments after the action (without the base
    controller, whose memory changes every step); ``action`` (1, A), the kernel's action buffer of a single
    env's step, ``action_row`` its row and ``action_shape`` one env's action shape (A,); ``plain``, whether a
    step is one kernel call alone (no training aids, base controller, Python reference or thread split);
    ``F0``, ``I0``, ``obs0``, entry 0's rows (read by the single env)."""

    __slots__ = ("args", "action", "action_row", "action_shape", "plain", "F0", "I0", "obs0")

    def __init__(self, sim: BatchSim):
        self.args = (sim.F, sim.obs, sim.key, sim.I, sim.C, sim.K, sim._ctl, *sim._flags)
        self.action = np.empty((1, sim.action_dim))
        self.action_row, self.action_shape = self.action[0], (sim.action_dim,)
        self.plain = (sim.controller is None and sim.aids is None and not sim._custom_reference
                      and len(sim._ranges) == 1)
        self.F0, self.I0, self.obs0 = sim.F[0], sim.I[0], sim.obs[0]


class BatchSim:
    """State of N envs as arrays and their step/reset.

    The state is ``F`` (N, STATE.size) float64, ``I`` (N, ISTATE.size) int64, ``key`` (N,) uint64 and
    ``obs`` (N, cfg.obs_dim) float32 (18 entries, 21 with ``observe_error_integral``; layouts:
    :mod:`softpvtol_gym.envs.packed_state`); every field of STATE and
    ISTATE is also an attribute, a view into them (``q``, ``qd``, ``qm``, ``qdm``, ``qr``, ``qdr``,
    ``qddr``, ``refp``, ``lag``, ``applied``, ``wind``, ``u`` (the clipped action), ``reward``,
    ``terms``, ``P``, ``t``, the diagnostics, ``counter``, ``steps``, ``reason``, ``clipped``, ...).
    The opt-in training aids' memory is ``aids`` (a :class:`~.training_aids.TrainingAids`, None when every
    aid is off).
    """

    def __init__(self, cfg: EnvConfig, n: int):
        self.cfg = cfg
        self.n = n
        self.task = cfg.task_spec  # resolved once: the registry may change later
        self._custom_reference = not self.task.is_compiled
        self.action_dim = cfg.action_dim
        self.max_steps = cfg.max_steps
        self.dt = cfg.dt
        self.C = cfg.constants()
        self.K = cfg.codes()
        self.F = np.zeros((n, STATE.size))
        self.I = np.zeros((n, ISTATE.size), dtype=np.int64)
        self.key = np.zeros(n, dtype=np.uint64)
        self.obs = np.zeros((n, cfg.obs_dim), dtype=np.float32)
        self.aids = TrainingAids(cfg, n, self.action_dim) if cfg.uses_training_aids else None
        # the start-error scale of the resets without the reset option (set_start_error_scale: a curriculum)
        self.start_error_scale = np.array(float(cfg.start_error_scale))
        self._make_views()
        self.P[:] = cfg.params.array
        self.lag_init[:] = 1
        # the residual mode's base controller: inputs, outputs and error codes of its block driver
        self._ctl_in = np.empty((n, CK.IN_LEN))
        self._ctl = np.empty((n, CK.OUT_LEN))
        self._ctl_err = np.zeros(n, dtype=np.int64)
        self._ranges = row_ranges(n, align=MK.LANES)  # one per thread, whole lane blocks
        self._shape = {True: (n, self.action_dim), False: (self.action_dim,)}
        self._expected = {b: f"an array of shape {shape} in [-1, 1]" for b, shape in self._shape.items()}
        self.controller = None
        if cfg.action_mode == "residual":
            if cfg.dt > MAX_HELD_CONTROL_PERIOD and cfg.resolved_controller_loop != "ideal":
                gym.logger.warn(
                    f"residual mode with a control period of {cfg.dt:g} s (frame_skip={cfg.frame_skip}): the base "
                    f"controller's arm loop diverges when held longer than {MAX_HELD_CONTROL_PERIOD} s, so the "
                    "policy must also stabilise the arms; use frame_skip=1 for a stable base controller")
            self.controller = PassivityController.from_loop(
                cfg.resolved_controller_loop, params=cfg.params, input_map=cfg.input_map, dt=cfg.dt
            )
            self.controller.state_rows(n)
        # the compiled step of one call (compiled on first use, with the controller only in residual mode)
        self._bind_kernel()

    def _make_views(self) -> None:
        self.__dict__.update(STATE.views(self.F))
        self.__dict__.update(ISTATE.views(self.I))
        self.u = self.F[:, S.u:S.u + self.action_dim]

    _VIEWS = tuple(f for f, _ in STATE.fields + ISTATE.fields)
    #: set by _bind_kernel (not pickled: rebuilt from the arrays and the config)
    _BOUND = ("_step_serial", "_flags", "bound")

    def __getstate__(self) -> dict:
        # the views (pickle would turn them into independent copies) and the kernel are rebuilt on unpickling
        state = {k: v for k, v in self.__dict__.items() if k not in self._VIEWS and k not in self._BOUND}
        state["layouts"] = (STATE.signature, ISTATE.signature, CONST.signature)  # C is pickled too
        return state

    def __setstate__(self, state: dict) -> None:
        layouts = state.pop("layouts", (("env_state", 1, None), None))
        STATE.check(layouts[0])
        ISTATE.check(layouts[1])
        # (state saved before the constants' layout was recorded has the constants' version 1)
        CONST.check(layouts[2] if len(layouts) > 2 else ("env_constants", 1, None))
        state.setdefault("aids", None)  # (state saved before the training aids)
        state.setdefault("start_error_scale", np.array(float(state["cfg"].start_error_scale)))
        self.__dict__.update(state)
        self._custom_reference = not self.task.is_compiled
        self._make_views()
        self._bind_kernel()

    # -------------------------------------------------------------------------------- reset
    def set_start_error_scale(self, scale: float) -> None:
        """The start-error scale of the next resets that do not give the ``start_error_scale`` option (the
        autoresets included), in [0, 10]; the config's ``start_error_scale`` until set."""
        self.start_error_scale[()] = bounded_number("start_error_scale", scale, 0.0, MAX_START_ERROR_SCALE,
                                                    START_SCALE_REASON)

    def reset_entries(self, idx: np.ndarray, u: np.ndarray, options: dict | None = None) -> None:
        """Start new episodes in entries ``idx`` from uniforms ``u`` (len(idx), N_UNIFORMS)."""
        self.apply_reset(idx, self.prepare_reset(u, options))

    def prepare_reset(self, u: np.ndarray, options: dict | None = None) -> dict:
        """The new episodes of :meth:`reset_entries` (changes nothing yet)."""
        scale = options.get("start_error_scale") if options else None
        ep = sample_episodes(self.cfg, u, start_error_scale=float(self.start_error_scale) if scale is None else scale)
        if options:
            ep = apply_options(self.cfg, ep, options)
        t0 = np.zeros(u.shape[0])
        if self._custom_reference:
            ep["ref"] = np.ascontiguousarray(np.concatenate(self.task.evaluate(t0, ep["refp"]), axis=1))
        else:  # (the same numbers, without the split into three and the concatenation)
            ep["ref"] = reference_block(self.task.compiled_reference, t0,
                                        np.ascontiguousarray(ep["refp"], dtype=np.float64))
        return ep

    def apply_reset(self, idx: np.ndarray, ep: dict) -> None:
        """Write episodes from :meth:`prepare_reset` into entries ``idx`` (their state and memories)."""
        rows = np.ascontiguousarray(np.atleast_1d(np.arange(self.n)[idx]), dtype=np.int64)
        self.write_episodes(rows, ep)
        self.reset_memory(rows)

    def write_episodes(self, rows: np.ndarray, ep: dict, lo: int = 0, hi: int | None = None) -> None:
        """The state part of :meth:`apply_reset` (state, observation, training aids) for the entries ``rows``
        (sorted int64) in lo .. hi - 1 (all of them by default): ``ep[k][j]`` is entry rows[j]'s.
        Rows of different ranges may be written by different threads at once."""
        whole = hi is None or (lo == 0 and hi == self.n)
        a, b = (0, rows.shape[0]) if whole else np.searchsorted(rows, (lo, hi)).tolist()
        if a == b:
            return
        reset_rows(self.F, self.obs, self.key, self.I, self.C, rows[a:b], ep["q0"][a:b], ep["qd0"][a:b],
                   ep["P"][a:b], ep["key"][a:b], ep["refp"][a:b], ep["ref"][a:b],
                   *self._flags[1:])  # (the consistent flag, if the flags are given)
        if self.aids is not None:
            self.aids.reset(rows[a:b], self.obs)

    def reset_memory(self, rows: np.ndarray) -> None:
        """The memory part of :meth:`apply_reset`: the base controller's memory of the entries ``rows`` reset
        (after a step: its new memory is in place once the step returns)."""
        if self.controller is not None:
            self.controller.reset_rows(rows)

    # --------------------------------------------------------------------------------- step
    def step(self, action, batched: bool, side=None, after=None) -> None:
        """Validate the action (shape, finite), clip it and advance every entry by one control step.

        ``side()``, if given, runs in this thread once the step cannot fail any more, beside the
        kernel threads of a large batch (Python work that overlaps the physics). ``after(lo, hi)``, if
        given, runs once the step is done and ``side()`` has returned, for ranges of rows that cover them
        all: in the kernel threads of a large batch, each range right after its physics (without training
        aids, whose work follows the kernel), else once for all rows at the end."""
        bound = self.bound
        if (not batched and bound.plain and type(action) is np.ndarray and action.dtype.kind == "f"
                and action.shape == bound.action_shape):
            # the single env's common case: the action copied into the kernel's (1, A) float64 buffer, one call
            bound.action_row[:] = action
            code = self._step_serial(bound.action, *bound.args)
            if code == STEP_BAD_ACTION:
                raise self._bad_action(action)
            if side is not None:
                side()
            if after is not None:
                after(0, self.n)
            return
        expected = self._shape[batched]
        a = action
        # the kernels get C-contiguous, writeable float64 (one compiled signature); anything else is
        # converted (real numbers only: str, bool, complex values are refused, never cast)
        if type(a) is np.ndarray and a.dtype.kind == "f":  # the common case (float32 from the action space)
            if not (a.dtype is _F64 and a.flags.c_contiguous and a.flags.writeable):
                a = a.astype(_F64)  # (a C-contiguous copy)
        else:
            a = real_array("action", action, self._expected[batched])
        if a.shape != expected:
            raise ValueError(
                f"action must have shape {expected} (action_mode={self.cfg.action_mode!r}"
                + (f", num_envs={self.n}" if batched else "") + f"), got shape {a.shape}"
            )
        if not batched:
            a = a.reshape(1, self.action_dim)
        if self._custom_reference:  # a registered task: its reference at the end of the step, from Python
            self.qr_custom[:] = np.concatenate(self.task.evaluate((self.steps + 1) * self.dt, self.refp), axis=1)
        aids = self.aids
        given = a
        if aids is not None:
            a = aids.gated(a, self.F)
        ctrl = self.controller
        if ctrl is not None:
            cc, (S_mem, S_new) = ctrl.kernel_constants, ctrl.memory_pair(self.n)
        else:
            cc, S_mem, S_new = self.C, self.F, self.F  # unused (same types: no second compilation)
        split = len(self._ranges) > 1
        in_threads = after if split and aids is None else None
        if split:
            code = self._step_split(a, cc, S_mem, S_new, side, in_threads)
        elif ctrl is None:  # (the serial kernels without the controller take fewer arguments)
            code = self._step_serial(a, *bound.args)
        else:
            code = self._step_serial(a, self.F, self.obs, self.key, self.I, self.C, self.K, cc, S_mem, S_new,
                                     self._ctl_in, self._ctl, self._ctl_err, *self._flags)
        if code == STEP_BAD_ACTION:
            raise self._bad_action(action)
        if ctrl is not None:
            ctrl.swap_memory()
        if aids is not None:
            aids.after_step(given, self.F, self.clipped, self.obs, self.dt)
        if not split and side is not None:
            side()
        if after is not None and in_threads is None:
            after(0, self.n)

    def noise_free_observation(self) -> np.ndarray:
        """(n, obs_dim) float32: the current observation without sensor noise, by the env's own observation
        function on the true state (q, qdot) and the reference; the error integrals (``observe_error_integral``)
        are the env's, integrated from the measured errors. Equal to ``obs`` where the tier has no sensor noise."""
        consts, state, obs = self.C.copy(), self.F.copy(), self.obs.copy()
        consts[SC.noise_on] = 0.0
        observe_range(0, self.n, state, self.key, self.I, consts, obs)
        return obs

    @staticmethod
    def _bad_action(action) -> ValueError:
        return ValueError(f"action must be finite (in [-1, 1]; out-of-range values are clipped), got "
                          f"{short_repr(action)}")

    def _bind_kernel(self) -> None:
        """The serial step kernel, its flags and :class:`StepBinding`."""
        self._step_serial = serial_step_kernel(self.n, self.cfg.action_mode == "residual")
        self._flags = kernel_flags(self.C, self.K)
        self.bound = StepBinding(self)

    def _step_split(self, a, cc, S_mem, S_new, side=None, after=None) -> int:
        """The step of a large batch with its rows split over threads (same result as the serial step)."""
        F, obs, key, I, C, K, X, ctl, err = (self.F, self.obs, self.key, self.I, self.C, self.K, self._ctl_in,
                                             self._ctl, self._ctl_err)
        ok, has_res = step_check_actions(a, K)
        if not ok:
            return STEP_BAD_ACTION
        flags = self._flags
        if self.controller is not None:  # each range: the controller, then the physics
            run_split(lambda lo, hi: step_residual_rows(lo, hi, a, F, obs, key, I, C, K, has_res, cc, S_mem, S_new, X,
                                                        ctl, err, *flags), self._ranges, side, after)
        else:
            run_split(lambda lo, hi: step_physics_rows(lo, hi, a, F, obs, key, I, C, K, ctl, *flags), self._ranges,
                      side, after)
        return STEP_OK
