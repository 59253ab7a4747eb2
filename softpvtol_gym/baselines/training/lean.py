"""LeanMLPPolicy: the deterministic action of a stable-baselines3 MLP policy, computed by a compiled float64
forward pass one observation row at a time, so that a row's action does not depend on the batch around it.

Why. torch's float32 matrix products sum in an order that depends on the batch size (its kernels block the
sums differently for 1, 10 or 100 rows), so the same observation gets actions that differ in the last bits
with the number of episodes evaluated beside it, and a closed loop carries such differences along: a learned
entry's last-half error changed by several per cent between an episode run alone and the same episode in a
batch. Here every row is computed by
the same loops in the same order (no fastmath: no reassociation, no fused multiply-add), alone: its action is
bit for bit the same whatever the batch, and an episode of an evaluation is the same whether it runs alone
or beside others. It is also what a robot runs: one observation through a few small layers, without torch's
per-call overhead.

What it computes: SB3's ``model.predict(obs, deterministic=True)`` on the observations of its env, step by
step (``tests/baselines/test_lean.py`` compares the two on committed checkpoints):

1. the observation as float32; VecNormalize's normalisation, ``clip((obs - mean) / sqrt(var + epsilon),
   -clip_obs, clip_obs)`` in float64, rounded to float32 (``VecNormalize.normalize_obs``);
2. the frame stack (K > 1): each sub-env's last K normalised observations, oldest first, zeros at an episode
   start (SB3's VecFrameStack; :class:`~.stacking.ObservationStack`);
3. the actor's layers in float64 (torch's float32 weights, exactly): PPO and A2C ``mlp_extractor.policy_net``
   then ``action_net`` (the Gaussian's mean, its mode; then tanh with gSDE's ``squash_output``); SAC
   ``actor.latent_pi``, ``actor.mu`` (with gSDE its Hardtanh to +-``clip_mean``), then tanh (the squashed
   Gaussian's mode); TD3 and DDPG ``actor.mu`` (ending with its tanh); for a zero-at-zero PPO policy
   (:mod:`~softpvtol_gym.baselines.training.zero_residual`), minus the same on the observation with its
   tracking errors at zero;
4. SB3's handling of a Box action: a squashed output (SAC, TD3) mapped from [-1, 1] onto [low, high]
   (``unscale_action``), any other clipped to [low, high]; the action in the action space's dtype.

The float64 pass differs from torch's float32 one by float32 rounding (about 1e-7 on the committed
checkpoints' actions). Only the deterministic action is computed (``deterministic=False`` is an error);
Linear, Tanh, ReLU and Hardtanh modules on a flat Box observation are supported (every MlpPolicy this
package trains), anything else (another activation or feature extractor, a Dict observation, a discrete
action) is refused with a message naming it: use ``LearnedPolicy(..., inference="torch")`` for those. The
weights are copied when the policy is built: build it again after training further.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from softpvtol_gym._validation import real_array
from softpvtol_gym.baselines.errors import ConfigError
from softpvtol_gym.baselines.training.stacking import ObservationStack, frame_stack_wrapper

__all__ = ["LeanMLPPolicy", "OPS", "checked_observations"]

_jit = njit(cache=True, fastmath=False, nogil=True, error_model="numpy")

#: the operations of the lean forward pass (kernel codes): ``("linear", weight (out, in), bias (out,) or None)``,
#: ``("tanh",)``, ``("relu",)``, ``("hardtanh", min, max)`` (each activation on the whole current vector)
OPS = {"linear": 0, "tanh": 1, "relu": 2, "hardtanh": 3}
_LINEAR, _TANH, _RELU, _HARDTANH = OPS["linear"], OPS["tanh"], OPS["relu"], OPS["hardtanh"]
#: the end of the message for a model the lean path does not compute (a ConfigError)
_USE_TORCH = "; use LearnedPolicy(..., inference='torch') (softpvtol evaluate --inference torch)"


@_jit
def _normalized(x, mean, scale, clip):
    """VecNormalize's normalisation of one float32 entry: float64 arithmetic, clipped, rounded to float32."""
    v = (np.float64(x) - mean) / scale
    if v < -clip:
        v = -clip
    elif v > clip:
        v = clip
    return np.float64(np.float32(v))


@_jit
def _all_finite(values):
    """Whether every entry of a 1-D array is finite (one compiled pass)."""
    for v in values:
        if not np.isfinite(v):
            return False
    return True


@_jit
def _forward(h, g, codes, sizes, params, weights, biases):
    """The operations ``codes`` (:data:`OPS`) in turn on the current vector ``h``, in place (``g``: scratch for a
    linear layer's sums). Operation i maps a vector of ``sizes[i]`` entries to one of ``sizes[i + 1]``: a linear
    layer sums over its inputs in order k = 0, 1, ... (one accumulator per output; its weights stored input-major:
    entry (k, j) multiplies input k into output j), then adds the bias; hardtanh clips to ``params[i]``."""
    w0 = 0
    b0 = 0
    for i in range(codes.shape[0]):
        code = codes[i]
        din = sizes[i]
        dout = sizes[i + 1]
        if code == _LINEAR:
            for j in range(dout):
                g[j] = 0.0
            for k in range(din):
                hk = h[k]
                # a view of input k's weights: indexed by the loop's own (non-negative) j, the loop needs no
                # negative-index check and is vectorised across outputs (each output's sum keeps its order)
                row = weights[w0 + k * dout: w0 + (k + 1) * dout]
                for j in range(dout):
                    g[j] += row[j] * hk
            for j in range(dout):
                h[j] = g[j] + biases[b0 + j]
            w0 += din * dout
            b0 += dout
        elif code == _TANH:
            for j in range(dout):
                h[j] = np.tanh(h[j])
        elif code == _RELU:
            for j in range(dout):
                if h[j] < 0.0:  # (NaN stays NaN, as torch's relu)
                    h[j] = 0.0
        else:  # _HARDTANH
            lo, hi = params[i, 0], params[i, 1]
            for j in range(dout):
                if h[j] < lo:
                    h[j] = lo
                elif h[j] > hi:
                    h[j] = hi


@_jit
def _scratch(sizes):
    """The vectors a forward pass works in: the current one, the current one at zero error, a layer's sums."""
    width = 0
    for d in sizes:
        width = max(width, d)
    return np.empty(width), np.empty(width), np.empty(width)


@_jit
def _box(h, h0, at_zero, n_out, squash, low, high, out, r):
    """Row ``r`` of ``out``: the actor's output ``h`` (minus ``h0`` with ``at_zero``) through SB3's Box handling:
    ``squash``: low + (y + 1) / 2 (high - low), else y clipped to [low, high]."""
    for j in range(n_out):
        v = h[j] - h0[j] if at_zero else h[j]
        if squash:
            v = low[j] + 0.5 * (v + 1.0) * (high[j] - low[j])
        elif v < low[j]:
            v = low[j]
        elif v > high[j]:
            v = high[j]
        out[r, j] = v


@_jit
def act_rows(obs, mean, scale, clip, zero_index, codes, sizes, params, weights, biases, squash, low, high, out):
    """The actions ``out`` (n, sizes[-1]) of observations ``obs`` (n, sizes[0]), one row after the other.

    Per row: the entries normalised (:func:`_normalized`), then the operations (:func:`_forward`). With
    ``zero_index`` not empty (a zero-at-zero policy): minus the output of the same operations on the row with
    those entries at the normalised value of a raw 0, so that a row whose entries there are 0 gets exactly 0.
    Last SB3's Box handling (:func:`_box`)."""
    h, h0, g = _scratch(sizes)
    n_out = sizes[codes.shape[0]]
    at_zero = zero_index.shape[0] > 0
    for r in range(obs.shape[0]):
        for k in range(sizes[0]):
            h[k] = _normalized(obs[r, k], mean[k], scale[k], clip)
        if at_zero:
            for k in range(sizes[0]):
                h0[k] = h[k]
            for i in range(zero_index.shape[0]):
                k = zero_index[i]
                h0[k] = _normalized(0.0, mean[k], scale[k], clip)
            _forward(h0, g, codes, sizes, params, weights, biases)
        _forward(h, g, codes, sizes, params, weights, biases)
        _box(h, h0, at_zero, n_out, squash, low, high, out, r)


@_jit
def act_stacked_rows(obs, mean, scale, clip, starts, stack, codes, sizes, params, weights, biases, squash, low, high,
                     out):
    """The actions ``out`` (n, sizes[-1]) of a frame-stacked actor for new observations ``obs`` (n, d), updating
    the float32 stacks ``stack`` (n, sizes[0] = K d) in place, one row after the other.

    Per row, VecFrameStack's update (:class:`~.stacking.ObservationStack`): the stack emptied (zeros) where
    ``starts`` is true, else shifted by one observation, oldest out; the new observation normalised
    (:func:`_normalized`, a float32 value) last. Then the operations (:func:`_forward`) on the stack and SB3's
    Box handling (:func:`_box`)."""
    h, h0, g = _scratch(sizes)
    n_out = sizes[codes.shape[0]]
    d = obs.shape[1]
    width = sizes[0]
    for r in range(obs.shape[0]):
        if starts[r]:
            for k in range(width - d):
                stack[r, k] = 0.0
        else:
            for k in range(width - d):
                stack[r, k] = stack[r, k + d]
        for k in range(d):
            stack[r, width - d + k] = _normalized(obs[r, k], mean[k], scale[k], clip)
        for k in range(width):
            h[k] = stack[r, k]
        _forward(h, g, codes, sizes, params, weights, biases)
        _box(h, h0, False, n_out, squash, low, high, out, r)


def _vector(value, name: str, size: int | None = None, infinite: bool = False) -> np.ndarray:
    """``value`` as a 1-D float64 array (of ``size`` entries, if given), finite (``infinite``: +-inf allowed, NaN
    not); ValueError naming it otherwise."""
    arr = np.asarray(value, dtype=np.float64)
    if arr.ndim != 1 or (size is not None and arr.shape[0] != size):
        want = "a vector" if size is None else f"a vector of {size} entries"
        raise ValueError(f"{name} must be {want}, got shape {arr.shape}")
    if np.isnan(arr).any() or not (infinite or np.isfinite(arr).all()):
        raise ValueError(f"{name} must be {'free of NaN' if infinite else 'finite'}, got {arr}")
    return arr


class LeanMLPPolicy:
    """The deterministic action of an MLP actor, by a compiled float64 forward pass per observation row
    (module docstring), with the ``predict`` interface of every policy of the package.

    Built from plain arrays (no torch needed to act) or from an SB3 model with :meth:`from_sb3`.

    ``ops``: the actor's operations in order (:data:`OPS`), the first a linear layer (weights in torch's
    layout, (out, in)); ``action_low``, ``action_high``: the action space's bounds; ``squash``: SB3's
    ``squash_output``: the last operation's output, in [-1, 1], is mapped onto the bounds (SAC, TD3), else it is
    clipped to them (PPO, A2C). ``obs_mean``, ``obs_var``, ``epsilon``, ``clip_obs``: VecNormalize's
    observation statistics and settings for one observation (None: no normalisation); ``frame_stack``: K, the
    number of stacked observations the first layer takes (its input size is K times the observation's);
    ``action_dtype``: the dtype of the actions returned (the action space's). ``zero_error_index``: the
    observation's tracking-error entries of a zero-at-zero policy
    (:class:`~softpvtol_gym.baselines.training.zero_residual.ZeroAtZeroPolicy`): the action is the actor's
    output minus its output on the observation with those entries at 0 (None: the actor's output).
    """

    def __init__(self, ops, action_low, action_high, squash: bool, obs_mean=None, obs_var=None,
                 epsilon: float = 1e-8, clip_obs: float = 10.0, frame_stack: int = 1, action_dtype=np.float32,
                 zero_error_index=None):
        ops = list(ops)
        for i, op in enumerate(ops):
            if not isinstance(op, (tuple, list)) or not op:
                raise ValueError(f"operation {i} must be a tuple ('name', arguments...), got {op!r}")
        if not ops or ops[0][0] != "linear" or len(ops[0]) != 3:
            raise ValueError(f"ops must be a list of operations starting with ('linear', weight, bias), got "
                             f"{[op[0] for op in ops]}")
        first = np.asarray(ops[0][1])
        codes, sizes, params, weights, biases = [], [first.shape[1] if first.ndim == 2 else -1], [], [], []
        for i, op in enumerate(ops):
            name, args = op[0], op[1:]
            if name not in OPS or len(args) != {"linear": 2, "hardtanh": 2}.get(name, 0):
                raise ValueError(f"operation {i}: expected ('linear', weight, bias), ('tanh',), ('relu',) or "
                                 f"('hardtanh', min, max), got {name!r} with {len(args)} arguments")
            codes.append(OPS[name])
            bounds = (0.0, 0.0)
            if name == "linear":
                w = np.asarray(args[0], dtype=np.float64)
                if w.ndim != 2 or w.shape[1] != sizes[-1]:
                    raise ValueError(f"operation {i}: the weight must be a matrix (out, {sizes[-1]}), got shape "
                                     f"{w.shape}")
                if not np.isfinite(w).all():
                    raise ValueError(f"operation {i}: the weight holds non-finite values")
                weights.append(w.T.ravel())  # input-major, as act_rows reads it
                b = np.zeros(w.shape[0]) if args[1] is None else args[1]
                biases.append(_vector(b, f"operation {i}'s bias", w.shape[0]))
                sizes.append(w.shape[0])
                params.append(bounds)
                continue
            if name == "hardtanh":
                bounds = (float(args[0]), float(args[1]))
                if not bounds[0] <= bounds[1]:
                    raise ValueError(f"operation {i}: hardtanh needs min <= max, got {bounds}")
            sizes.append(sizes[-1])
            params.append(bounds)
        if isinstance(frame_stack, bool) or not isinstance(frame_stack, int) or frame_stack < 1:
            raise ValueError(f"frame_stack must be an integer >= 1, got {frame_stack!r}")
        if sizes[0] % frame_stack:
            raise ValueError(f"the first layer takes {sizes[0]} inputs, not a multiple of frame_stack={frame_stack}")
        self.ops = tuple(op[0] for op in ops)
        self.frame_stack = frame_stack
        self.obs_dim = sizes[0] // frame_stack  # one observation
        self.action_dim = sizes[-1]
        self.squash = bool(squash)
        # (an unbounded action is clipped to nothing; a squashed one is mapped onto finite bounds)
        self.low = _vector(action_low, "action_low", self.action_dim, infinite=not self.squash)
        self.high = _vector(action_high, "action_high", self.action_dim, infinite=not self.squash)
        if not (self.low <= self.high).all():
            raise ValueError(f"action_low must be <= action_high, got {self.low} and {self.high}")
        self.action_dtype = np.dtype(action_dtype)
        flat = np.concatenate(weights)
        narrow = flat.astype(np.float32)
        if np.array_equal(narrow.astype(np.float64), flat):
            # float32 weights (a torch model's) kept as float32: half the memory each pass reads; the kernel
            # widens each to the same float64 value, so the actions are the same bit for bit
            flat = narrow
        self._net = (np.asarray(codes, dtype=np.int64), np.asarray(sizes, dtype=np.int64),
                     np.asarray(params, dtype=np.float64).reshape(-1, 2), flat, np.concatenate(biases))
        if (obs_mean is None) != (obs_var is None):
            raise ValueError("obs_mean and obs_var go together: pass both (normalised observations) or neither")
        self.normalized = obs_mean is not None
        if self.normalized:
            var = _vector(obs_var, "obs_var", self.obs_dim)
            if (var < 0).any() or not epsilon >= 0 or not clip_obs > 0:
                raise ValueError(f"obs_var must be >= 0, epsilon >= 0 and clip_obs > 0, got min(obs_var) "
                                 f"{var.min()}, epsilon {epsilon}, clip_obs {clip_obs}")
            # VecNormalize's very expression for the scale: the same float64 values
            self._norm = (_vector(obs_mean, "obs_mean", self.obs_dim), np.sqrt(var + float(epsilon)), float(clip_obs))
        else:  # the identity: (x - 0) / 1, unclipped, is x
            self._norm = (np.zeros(self.obs_dim), np.ones(self.obs_dim), np.inf)
        zero = np.zeros(0, dtype=np.int64) if zero_error_index is None else np.asarray(zero_error_index)
        if zero.ndim != 1 or zero.dtype.kind not in "iu" or ((zero < 0) | (zero >= self.obs_dim)).any():
            raise ValueError(f"zero_error_index must be a vector of entries of the {self.obs_dim}-entry observation, "
                             f"got {zero_error_index!r}")
        if len(zero) and (frame_stack > 1 or self.squash):
            raise ValueError("a zero-at-zero policy (zero_error_index) takes one observation (frame_stack=1) and "
                             "an unsquashed action")
        self._zero = zero.astype(np.int64)
        self._stack = ObservationStack(frame_stack, sizes[0]) if frame_stack > 1 else None

    @classmethod
    def from_sb3(cls, model, vecnorm=None, frame_stack: int | None = None) -> LeanMLPPolicy:
        """The lean policy of an SB3 model (PPO, A2C, SAC, TD3, DDPG with an MLP policy; an algorithm or its
        ``.policy``) and its VecNormalize (None: no normalisation). ``frame_stack``: K (None: that of the
        VecFrameStack the model's env is wrapped in, 1 without one). ConfigError naming what is not supported."""
        policy = getattr(model, "policy", model)
        ops = sb3_actor(policy)
        zero = getattr(policy, "error_index", None) if is_zero_at_zero(policy) else None
        if frame_stack is None:
            wrapper = frame_stack_wrapper(model.get_env()) if hasattr(model, "get_env") else None
            frame_stack = 1 if wrapper is None else int(wrapper.stacked_obs.n_stack)
        stats = {}
        if vecnorm is not None and vecnorm.norm_obs:
            rms = vecnorm.obs_rms
            if isinstance(rms, dict):
                raise ConfigError(f"the lean path takes one flat observation, the VecNormalize normalises a Dict "
                                  f"observation ({sorted(rms)}){_USE_TORCH}")
            stats = {"obs_mean": rms.mean, "obs_var": rms.var, "epsilon": float(vecnorm.epsilon),
                     "clip_obs": float(vecnorm.clip_obs)}
        space = policy.action_space
        return cls(ops, space.low, space.high, bool(policy.squash_output), frame_stack=frame_stack,
                   action_dtype=space.dtype, zero_error_index=zero, **stats)

    def reset_stack(self) -> None:
        """Forget the stacked observations (the next call starts every sub-env's stack afresh)."""
        if self._stack is not None:
            self._stack.reset()

    def predict(self, observation, state=None, episode_start=None, deterministic: bool = True):
        """(action, state) for observations (obs_dim,) or (n, obs_dim): the deterministic action of each row.
        ``episode_start`` (n bools) empties those sub-envs' frame stacks (a frame-stacked policy: pass it true on
        the first call and after every reset, as ``run_episodes`` does; None continues the stacks after the first
        call); without a frame stack it is not needed."""
        if not deterministic:
            raise ValueError("LeanMLPPolicy computes the deterministic action only, got deterministic=False; sample "
                             "with LearnedPolicy(model, vecnorm, inference='torch')")
        obs = checked_observations(observation, self.obs_dim)
        single = obs.ndim == 1
        if single:
            obs = obs.reshape(1, -1)
        if not obs.flags.c_contiguous:
            obs = np.ascontiguousarray(obs)
        out = np.empty((obs.shape[0], self.action_dim), dtype=self.action_dtype)
        if self._stack is None:
            act_rows(obs, *self._norm, self._zero, *self._net, self.squash, self.low, self.high, out)
        else:  # the stacks updated and the actor run in one compiled call
            starts = self._stack.starts(obs, episode_start)
            act_stacked_rows(obs, *self._norm, starts, self._stack.rows, *self._net, self.squash, self.low, self.high,
                             out)
        return (out[0] if single else out), state


def checked_observations(observation, obs_dim: int) -> np.ndarray:
    """``observation`` as float32 (obs_dim,) or (n >= 1, obs_dim), refusing what a learned policy cannot act on
    (as the analytic policies do): values that are not real numbers (bool, complex, strings, ragged lists), another
    shape, NaN or inf (also after the cast to float32); a ValueError that says what was received."""
    expected = f"an array of shape ({obs_dim},) or (n, {obs_dim}) with n >= 1"
    raw = observation
    if not (isinstance(raw, np.ndarray) and raw.dtype.kind == "f"):  # the env's float32 passes as it is
        raw = real_array("observations", observation, expected)  # refuses bool, complex, strings, ragged lists
    if raw.ndim not in (1, 2) or raw.shape[-1] != obs_dim or raw.size == 0:
        raise ValueError(f"observations must be {expected}, got shape {raw.shape}")
    obs = raw.astype(np.float32, copy=False)
    if not _all_finite(obs.reshape(-1)):
        bad = np.argwhere(~np.isfinite(obs.reshape(-1, obs_dim)))[0]
        value = raw.reshape(-1, obs_dim)[bad[0], bad[1]]
        raise ValueError(f"observations must be finite (as float32), got {float(value)!r} at "
                         f"{bad[1] if raw.ndim == 1 else tuple(int(i) for i in bad)}")
    return obs


def is_zero_at_zero(policy) -> bool:
    """Whether an SB3 policy is a :class:`~softpvtol_gym.baselines.training.zero_residual.ZeroAtZeroPolicy`."""
    from softpvtol_gym.baselines.training.zero_residual import ZeroAtZeroPolicy  # stable-baselines3

    return isinstance(policy, ZeroAtZeroPolicy)


def _torch_ops(modules, where: str) -> list[tuple]:
    """The operations (:data:`OPS`) of a sequence of torch modules (Linear, Tanh, ReLU, Hardtanh, Sequential);
    ConfigError naming any other module."""
    import torch
    from torch import nn

    ops = []
    for m in modules:
        if type(m) is nn.Sequential:
            ops += _torch_ops(list(m), where)
        elif type(m) is nn.Linear:
            bias = None if m.bias is None else m.bias.detach().to("cpu", torch.float64).numpy()
            ops.append(("linear", m.weight.detach().to("cpu", torch.float64).numpy(), bias))
        elif type(m) in (nn.Tanh, nn.ReLU):
            ops.append(("tanh" if type(m) is nn.Tanh else "relu",))
        elif type(m) is nn.Hardtanh:
            ops.append(("hardtanh", float(m.min_val), float(m.max_val)))
        else:
            raise ConfigError(f"{where}: the lean path computes Linear, Tanh, ReLU and Hardtanh modules, got the "
                              f"module {type(m).__name__}{_USE_TORCH}")
    return ops


def sb3_actor(policy) -> list[tuple]:
    """The operations (:data:`OPS`) of the deterministic actor of an SB3 policy, up to SB3's Box handling (module
    docstring, step 3). ConfigError naming what the lean path does not compute."""
    from stable_baselines3.common.distributions import (
        DiagGaussianDistribution,
        SquashedDiagGaussianDistribution,
        StateDependentNoiseDistribution,
    )
    from stable_baselines3.common.policies import ActorCriticPolicy
    from stable_baselines3.common.torch_layers import FlattenExtractor
    from stable_baselines3.sac.policies import SACPolicy
    from stable_baselines3.td3.policies import TD3Policy

    kind = type(policy).__name__
    if isinstance(policy, ActorCriticPolicy):  # PPO, A2C: the Gaussian's mean (its tanh with gSDE's squashing)
        dist = policy.action_dist
        if type(dist) not in (DiagGaussianDistribution, StateDependentNoiseDistribution):
            raise ConfigError(f"the lean path computes the mode of a Gaussian policy, this {kind} has a "
                              f"{type(dist).__name__} (a non-Box action){_USE_TORCH}")
        extractor = policy.pi_features_extractor
        ops = _torch_ops([*policy.mlp_extractor.policy_net, policy.action_net], f"{kind} actor")
        squashed = getattr(dist, "bijector", None) is not None
    elif isinstance(policy, SACPolicy):  # tanh of the Gaussian's mean (mu clipped first with gSDE's clip_mean)
        actor = policy.actor
        dist = actor.action_dist
        if type(dist) not in (SquashedDiagGaussianDistribution, StateDependentNoiseDistribution):
            raise ConfigError(f"the lean path computes the mode of SAC's squashed Gaussian, this actor has a "
                              f"{type(dist).__name__}{_USE_TORCH}")
        extractor = actor.features_extractor
        ops = _torch_ops([*actor.latent_pi, actor.mu], f"{kind} actor")
        squashed = type(dist) is SquashedDiagGaussianDistribution or dist.bijector is not None
    elif isinstance(policy, TD3Policy):  # TD3, DDPG: mu ends with its tanh
        extractor, squashed = policy.actor.features_extractor, False
        ops = _torch_ops(list(policy.actor.mu), f"{kind} actor")
    else:
        raise ConfigError(f"the lean path computes the actors of PPO, A2C, SAC, TD3 and DDPG MLP policies, got a "
                          f"{kind}{_USE_TORCH}")
    if type(extractor) is not FlattenExtractor or len(policy.observation_space.shape) != 1:
        raise ConfigError(f"the lean path takes a flat Box observation through SB3's FlattenExtractor, this {kind} "
                          f"has a {type(extractor).__name__} on observations of shape "
                          f"{policy.observation_space.shape}{_USE_TORCH}")
    return ops + [("tanh",)] if squashed else ops
