"""Timings of the kernels and their parts, behind the figures of docs/performance.md, each one command:

    SOFTPVTOL_GYM_CACHE_DIR=$(mktemp -d) python benchmarks/kernel_timings.py compile --mode actuators
        # a cold first step: import + reset + step, and the compile of every kernel (a tree, >= 0.25 s)
    python benchmarks/kernel_timings.py draws      # reset uniforms: the compiled loop vs the Python loop
    python benchmarks/kernel_timings.py single     # single env / Pendulum-v1, random actions, resets counted
    python benchmarks/kernel_timings.py policy     # PassivityPolicy.predict for one state (default, integral,
                                                   # extended loops) and PassivityController(), called again and
                                                   # again on one state: the Python around the kernel and a
                                                   # 1-pass algebraic loop (benchmarks/run.py item 3 times the
                                                   # controllers along their closed loops instead)
    python benchmarks/kernel_timings.py vector     # the vector env's step, N = 256 and 4096, random actions
    python benchmarks/kernel_timings.py passes     # the algebraic loop's passes along closed loops, the cost of
                                                   # a pass, the extended loop's law (one thread, N = 4096)
    python benchmarks/kernel_timings.py parts      # the step kernel's parts, N = 4096, one thread, random actions
                                                   # (each part timed as the kernel runs it, in 64-env blocks)
    python benchmarks/kernel_timings.py split      # the step kernel of N = 4096 envs in one thread and split
                                                   # over the threads: when each chunk starts and ends
    python benchmarks/kernel_timings.py bound      # the vector env's step at N = 4096 with every part in one
                                                   # thread, and the bound of a perfect split over two threads,
                                                   # against CartPoleVectorEnv in the same run
    python benchmarks/kernel_timings.py simd       # the RK4 step of a full lane block (SIMD) against lane by
                                                   # lane, and libm's sin and cos (what the lanes cannot vectorise)
    python benchmarks/kernel_timings.py extended   # ExtendedPolicy.predict's parts (one thread, N = 4096): its law
                                                   # alone, predict with one law (held_command="start") and with
                                                   # the midpoint (two laws and an RK4 half step)
    python benchmarks/kernel_timings.py training   # the SB3 adapter's step (step_infos on/off), 128 sub-envs;
                                                   # one periodic evaluation (10 track_random episodes)

For a before/after pair run the same command on the older sources too (e.g. ``git stash`` or
``git checkout <commit> -- softpvtol_gym``), back to back: absolute times on a shared machine drift between runs.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
import warnings
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))


def _median_seconds(prepare, reps: int) -> float:
    """Median wall time of the call that ``prepare()`` returns, prepared anew (untimed) for each of ``reps``
    repetitions: a copy of the state it changes, so that every repetition starts from the same one."""
    times = []
    for _ in range(reps):
        call = prepare()
        t0 = time.perf_counter()
        call()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def time_compile(mode: str) -> None:
    from numba.core import event

    records, stack = [], []

    class Recorder(event.Listener):
        def on_start(self, ev):
            func = getattr(ev.data.get("dispatcher"), "py_func", None)
            stack.append((f"{getattr(func, '__module__', '?')}.{getattr(func, '__name__', '?')}", time.perf_counter(),
                          len(stack)))

        def on_end(self, ev):
            name, t0, depth = stack.pop()
            records.append((depth, name, time.perf_counter() - t0))

    event.register("numba:compile", Recorder())
    t0 = time.perf_counter()
    import numpy as np

    import softpvtol_gym

    env = softpvtol_gym.SoftPVTOLEnv(action_mode=mode)
    env.reset(seed=0)
    t1 = time.perf_counter()
    env.step(np.zeros(env.action_space.shape))
    t2 = time.perf_counter()
    print(f"{mode}: import + reset {t1 - t0:.1f} s, first step {t2 - t1:.1f} s, total {t2 - t0:.1f} s")
    for depth, name, seconds in records:  # (in order of completion: callees before their caller)
        if seconds >= 0.25:
            print(f"{'  ' * depth}{seconds:6.1f} s  {name}")


def time_draws() -> None:
    import timeit

    import numpy as np
    from gymnasium.utils import seeding

    from softpvtol_gym.envs.uniforms import UniformDraws, python_draws

    rngs = [seeding.np_random(i)[0] for i in range(4096)]
    idx = np.arange(0, 4096, 7)
    draws = UniformDraws()
    draws.draw(rngs, idx, 50)
    fast = min(timeit.repeat(lambda: draws.draw(rngs, idx, 50), number=100, repeat=5)) / 100
    slow = min(timeit.repeat(lambda: python_draws(rngs, idx, 50), number=100, repeat=5)) / 100
    print(f"{idx.size} resets of 50 uniforms: compiled loop {fast * 1e6:.0f} us, Python loop {slow * 1e6:.0f} us")


def time_single(reps: int = 21, steps: int = 2000) -> None:
    import gymnasium as gym

    import softpvtol_gym  # noqa: F401  (registers the env)
    from benchmarks._env_speed import _step_timer  # the benchmark's own timer (resets counted)

    warnings.filterwarnings("ignore")
    ours, pendulum = _step_timer(gym.make("SoftPVTOL-v0"), steps, 0), _step_timer(gym.make("Pendulum-v1"), steps, 1)
    ours(), pendulum()
    pairs = [(ours(), pendulum()) for _ in range(reps)]
    ratio = statistics.median(a / b for a, b in pairs)
    ours_us, pendulum_us = (statistics.median(p[i] for p in pairs) * 1e6 for i in (0, 1))
    print(f"SoftPVTOL-v0 / Pendulum-v1 (resets counted, median of {reps} interleaved pairs): {ratio:.3f}x; "
          f"{ours_us:.2f} us vs {pendulum_us:.2f} us")


def time_policy() -> None:
    import timeit

    from softpvtol_gym import PassivityPolicy, SoftPVTOLVectorEnv
    from softpvtol_gym.control import PassivityController

    env = SoftPVTOLVectorEnv(num_envs=1)
    obs = env.reset(seed=0)[0][0]
    for loop in (None, "integral", "extended"):
        policy = PassivityPolicy.from_env(env, loop=loop)
        policy.predict(obs)
        seconds = min(timeit.repeat(lambda p=policy: p.predict(obs), number=20000, repeat=7)) / 20000
        print(f"PassivityPolicy.predict, one state, loop {loop or 'default'}: {seconds * 1e6:.2f} us (best of 7)")
    ctrl = PassivityController.from_loop("exact")  # the residual mode's base controller, as benchmarks/run.py item 3
    sim = env.sim
    args = [x[0].copy() for x in (sim.qm, sim.qdm, sim.qr, sim.qdr, sim.qddr)]
    ctrl(*args)
    seconds = min(timeit.repeat(lambda: ctrl(*args), number=20000, repeat=7)) / 20000
    print(f"PassivityController(), one state: {seconds * 1e6:.2f} us (best of 7)")


def time_vector(reps: int = 7) -> None:
    import gymnasium as gym
    import numpy as np

    import softpvtol_gym  # noqa: F401  (registers the env)

    for n in (256, 4096):
        env = gym.make_vec("SoftPVTOL-v0", num_envs=n, vectorization_mode="vector_entry_point")
        rng = np.random.default_rng(0)
        actions = [rng.uniform(-1, 1, env.action_space.shape).astype(np.float32) for _ in range(4)]
        env.reset(seed=0)
        for i in range(30):  # past the first steps (and their compiles)
            env.step(actions[i & 3])
        steps = max(100, 400_000 // n)
        times = []
        for _ in range(reps):
            t0 = time.perf_counter()
            for i in range(steps):
                env.step(actions[i & 3])
            times.append((time.perf_counter() - t0) / steps)
        t = statistics.median(times)
        print(f"vector env, N = {n}, random actions: {t * 1e6:.1f} us per step, {n / t / 1e6:.2f} M env-steps/s "
              f"(median of {reps})")


def time_passes() -> None:
    import copy

    import numpy as np

    import softpvtol_gym._parallel as parallel
    from softpvtol_gym import PassivityPolicy, SoftPVTOLVectorEnv
    from softpvtol_gym.control import kernels as CK

    for task in ("hover", "track_random"):  # mean passes per block of 100 steps, 512 envs, nominal tier, seed 0
        for loop in ("exact", "integral"):
            env = SoftPVTOLVectorEnv(num_envs=512, task=task, tier="nominal")
            obs = env.reset(seed=0)[0]
            policy = PassivityPolicy.from_env(env, loop=loop)
            passes = []
            for _ in range(1000):
                action, _ = policy.predict(obs)
                passes.append(policy._work[1][:, CK.OUT_LOOP + 1].mean())  # (its kernel's per-row outputs)
                obs = env.step(action)[0]
            blocks = " ".join(f"{np.mean(passes[i:i + 100]):.2f}" for i in range(0, 1000, 100))
            print(f"{task}, loop {loop}: algebraic passes per call, mean by 100 steps: {blocks}")
    parallel.thread_count = lambda: 1  # one thread from here on: costs per env without the split
    n = 4096
    env = SoftPVTOLVectorEnv(num_envs=n, task="hover", tier="nominal")
    obs = env.reset(seed=0)[0]
    policy = PassivityPolicy.from_env(env)
    inputs = []
    for _ in range(130):  # a closed loop's observations, steps 100-129 timed (past the first transient)
        inputs.append(obs.copy())
        obs = env.step(policy.predict(obs)[0])[0]
    actions = np.zeros((n, 4), np.float32)

    def per_env(snapshot, calls) -> float:
        """ns per env of predict on calls, each repetition from a copy of the policy ``snapshot`` (None: the env
        step kernel)."""
        times = []
        for _ in range(5):
            fn = (lambda a: env.sim.step(a, True)) if snapshot is None else copy.deepcopy(snapshot).predict
            t0 = time.perf_counter()
            for c in calls:
                fn(c)
            times.append((time.perf_counter() - t0) / len(calls) / n)
        return 1e9 * statistics.median(times)

    cases = {"env step kernel (actuators, zero actions)": (None, [actions] * 30)}
    for k in (1, 2, 3):  # exactly k passes (tolerance 0), from the loop's state at step 100
        fixed = PassivityPolicy.from_env(env, controller_options=dict(algebraic_iterations=k, algebraic_tolerance=0.0))
        for o in inputs[:100]:
            fixed.predict(o)
        cases[f"PassivityPolicy.predict, exactly {k} pass{'es' if k > 1 else ''}"] = (fixed, inputs[100:])
    for held in ("midpoint", "start"):
        ext = PassivityPolicy.from_env(env, loop="extended")
        ext.controller.held_command = held
        for o in inputs[:100]:
            ext.predict(o)
        cases[f"ExtendedPolicy.predict, held_command={held!r}"] = (ext, inputs[100:])
    for name, (snapshot, calls) in cases.items():
        print(f"one thread, N = {n}, steps 100-129 of a hover loop: {name}: {per_env(snapshot, calls):.0f} ns per "
              "env (median of 5)")


def time_parts(reps: int = 31) -> None:
    """The step kernel's parts for N = 4096 envs in one thread (default env, random actions, after 50 steps):
    a compiled loop over the 64-env blocks runs the kernel's parts up to a given one, as ``_step_block`` does;
    each part's time is the difference to the loop that stops before it. Every repetition steps a copy of the
    same state (untimed copies)."""
    import functools

    import numpy as np
    from numba import njit

    from softpvtol_gym import SoftPVTOLVectorEnv
    from softpvtol_gym import model as MK
    from softpvtol_gym.envs import step as ST
    from softpvtol_gym.envs.diagnostics import diag_lanes
    from softpvtol_gym.envs.packed_state import SC, SK
    from softpvtol_gym.envs.rows import nominal_params, vec5

    n = 4096
    env = SoftPVTOLVectorEnv(num_envs=n)
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    actions = rng.uniform(-1.0, 1.0, (n, 4))
    for _ in range(50):
        env.step(actions.astype(np.float32))
    s = env.sim
    state = (s.F, s.obs, s.key, s.I, s.C, s.K, s._ctl)

    @njit(nogil=True)
    def upto(last, act, F, obs, keys, I, C, K, ctl):
        """The kernel's parts 0 .. last of every block (0: the actions clipped, then as _step_block)."""
        lanes, cmd = np.empty(ST.LANE_BLOCK), np.empty(10)
        ST.clip_actions(0, F.shape[0], act, F, I, K[SK.action_dim])
        for n0 in range(0, F.shape[0], MK.LANES):
            hi = n0 + MK.LANES
            if last >= 1:
                ST._begin_range(n0, hi, F, I, C, K, ctl, lanes, cmd, None)
            if last >= 2:
                MK.rk4_lanes(lanes, C[SC.dt_physics], MK.LANES, K[SK.imap])
            if last >= 3:
                ST._end_range(n0, hi, F, keys, I, C, lanes)
            if last >= 4:
                diag_lanes(lanes, MK.LANES, nominal_params(C), vec5(C, SC.lam), vec5(C, SC.kg))
            if last >= 5:
                ST.observe_range(n0, hi, F, keys, I, C, obs)
            if last >= 6:
                ST._reward_range(n0, hi, F, I, C, K, lanes)

    names = ("actions clipped", "command (clock, reference, scaling, lag; lanes filled)", "RK4 step (lanes, SIMD)",
             "termination, state back from the lanes", "diagnostics (energy, storage; lanes, SIMD)",
             "observation", "reward")
    totals = []
    for last in range(len(names)):
        upto(last, actions, *[a.copy() for a in state])
        totals.append(_median_seconds(lambda k=last: functools.partial(upto, k, actions, *[a.copy() for a in state]),
                                      reps))
    full = _median_seconds(lambda: functools.partial(ST.step_physics_rows, 0, n, actions, *[a.copy() for a in state]),
                           reps)
    print(f"step kernel, N = {n}, one thread, random actions (medians of {reps}):")
    for k, name in enumerate(names):
        part = totals[k] - (totals[k - 1] if k else 0.0)
        print(f"  {name}: {1e6 * part:.0f} us, {1e9 * part / n:.0f} ns per env")
    print(f"  the parts together: {1e6 * totals[-1]:.0f} us; the kernel (step_physics_rows): "
          f"{1e6 * full:.0f} us, {1e9 * full / n:.0f} ns per env")


def time_split(reps: int = 7) -> None:
    import threading

    import numpy as np

    from softpvtol_gym import SoftPVTOLVectorEnv
    from softpvtol_gym._parallel import row_ranges, run_split
    from softpvtol_gym.envs.step import step_physics_rows

    n = 4096
    env = SoftPVTOLVectorEnv(num_envs=n, task="hover", tier="nominal")
    env.reset(seed=0)
    s = env.sim
    actions = np.array([-1 / 3, -1 / 3, 0.0, 0.0]) + np.random.default_rng(0).uniform(-0.05, 0.05, (n, 4))
    args = (actions, s.F, s.obs, s.key, s.I, s.C, s.K, s._ctl)  # (the kernel's arguments, as BatchSim passes them)
    main, log = threading.get_ident(), []

    def chunk(lo: int, hi: int) -> None:
        t = time.perf_counter()
        step_physics_rows(lo, hi, *args)
        log.append((threading.get_ident() == main, t, time.perf_counter()))

    ranges = row_ranges(n)
    one, split, first_main, first_pool, last_end = [], [], [], [], []
    for _ in range(reps):  # blocks of calls of one kind (a split call leaves half the rows in the other core's cache)
        for _ in range(3):
            step_physics_rows(0, n, *args)
        t0 = time.perf_counter()
        for _ in range(10):
            step_physics_rows(0, n, *args)
        one.append((time.perf_counter() - t0) / 10)
        for k in range(13):
            log.clear()
            t1 = time.perf_counter()
            run_split(chunk, ranges)
            t2 = time.perf_counter()
            if k >= 3:
                split.append(t2 - t1)
                first_main.append(min(t for m, t, _ in log if m) - t1)
                first_pool.append(min((t for m, t, _ in log if not m), default=float("nan")) - t1)
                last_end.append(t2 - max(e for _, _, e in log))
    us = [1e6 * statistics.median(x) for x in (one, split, first_main, first_pool, last_end)]
    print(f"step kernel, N = {n} (hover, near-hover actions; medians of {reps} x 10 calls): one thread "
          f"{us[0]:.0f} us; split over {len(ranges)} chunks and the threads {us[1]:.0f} us (one thread / 2 = "
          f"{us[0] / 2:.0f} us). In the split call: this thread's first chunk starts at {us[2]:.0f} us, the pool's at "
          f"{us[3]:.0f} us, and the call returns {us[4]:.0f} us after the last chunk ends")
    import concurrent.futures

    with concurrent.futures.ThreadPoolExecutor(1) as pool:  # a submit that wakes an idle (sleeping) worker
        pool.submit(int).result()
        submit = []
        for _ in range(200):
            time.sleep(0.0005)
            t0 = time.perf_counter()
            future = pool.submit(int)
            submit.append(time.perf_counter() - t0)
            future.result()
    print(f"ThreadPoolExecutor.submit to an idle worker: {1e6 * statistics.median(submit):.1f} us (median of 200)")


def time_bound(reps: int = 7) -> None:
    """Item 2's vector target at N = 4096 against the best any split over two threads can do.

    An env built with one thread does all of a step's work in this thread: the kernel, the resets' uniforms
    (``side``), the outputs' gather and the new episodes (``after``), and the Python around them. Only the work
    inside ``BatchSim.step`` can be split (the Python of ``SoftPVTOLVectorEnv.step`` around it runs in the calling
    thread), so a perfect split over two threads, with no wake-up and no wait, takes at least
    (env step - BatchSim.step) + BatchSim.step / 2. Timed with item 2's random actions (its seed, its four
    action sets), interleaved with CartPoleVectorEnv and the env with its real threads."""
    import gymnasium as gym
    import numpy as np
    from gymnasium.envs.classic_control.cartpole import CartPoleVectorEnv

    import softpvtol_gym  # noqa: F401  (registers the env)
    import softpvtol_gym._parallel as parallel

    n, steps = 4096, 100
    threads = parallel.thread_count
    parallel.thread_count = lambda: 1
    one = gym.make_vec("SoftPVTOL-v0", num_envs=n, vectorization_mode="vector_entry_point")
    parallel.thread_count = threads
    real = gym.make_vec("SoftPVTOL-v0", num_envs=n, vectorization_mode="vector_entry_point")
    cart = CartPoleVectorEnv(num_envs=n)
    sim = one.unwrapped.sim
    inner = []
    step = sim.step

    def timed_step(*args, **kwargs):
        t0 = time.perf_counter()
        step(*args, **kwargs)
        inner.append(time.perf_counter() - t0)

    sim.step = timed_step  # (an instance attribute: this env only)
    rng = np.random.default_rng(0)
    actions = [rng.uniform(-1.0, 1.0, real.action_space.shape).astype(np.float32) for _ in range(4)]
    pushes = [rng.integers(0, 2, n) for _ in range(4)]
    for env in (one, real, cart):
        env.reset(seed=0)

    def run(env, acts) -> float:
        t0 = time.perf_counter()
        for k in range(steps):
            env.step(acts[k & 3])
        return (time.perf_counter() - t0) / steps

    for env, acts in ((one, actions), (real, actions), (cart, pushes)):
        run(env, acts)  # past the first steps (and their compiles)
    t_one, t_inner, t_real, t_cart = [], [], [], []
    for _ in range(reps):
        inner.clear()
        t_one.append(run(one, actions))
        t_inner.append(statistics.mean(inner))
        t_real.append(run(real, actions))
        t_cart.append(run(cart, pushes))
    one_t, inner_t, real_t, cart_t = (statistics.median(x) for x in (t_one, t_inner, t_real, t_cart))
    ended = 0
    for k in range(steps):  # (after the timing) how many episodes end per step: each is reset at the next step
        _, _, terminated, truncated, _ = real.step(actions[k & 3])
        ended += int((terminated | truncated).sum())
    bound = one_t - inner_t + inner_t / 2
    print(f"N = {n}, item 2's random actions ({ended / steps:.0f} episodes end per step), medians of {reps} x "
          f"{steps} steps, interleaved:")
    print(f"  one thread: {one_t * 1e6:.0f} us per step, of which BatchSim.step {inner_t * 1e6:.0f} us (the kernel, "
          f"resets and outputs) and the Python around it {(one_t - inner_t) * 1e6:.0f} us")
    print(f"  perfect split over 2 threads (no wake-up, no wait): >= {bound * 1e6:.0f} us per step, "
          f"<= {n / bound / 1e6:.2f} M env-steps/s")
    print(f"  the env with its {threads()} threads: {real_t * 1e6:.0f} us per step, "
          f"{n / real_t / 1e6:.2f} M env-steps/s")
    print(f"  CartPoleVectorEnv: {cart_t * 1e6:.0f} us per step, {n / cart_t / 1e6:.2f} M env-steps/s")
    print(f"  ratio to CartPoleVectorEnv (target >= 0.25x): {cart_t / real_t:.3f}x now, <= {cart_t / bound:.3f}x with "
          f"a perfect split; 0.25x needs <= {4 * cart_t * 1e6:.0f} us per step")


def time_simd(reps: int = 201) -> None:
    """What a lane block gains: the model's RK4 step of 64 states as SIMD code (``model.rk4_lanes``) against the
    same step lane by lane (``model.rk4_lanes_partial``), and libm's sin and cos, which stay scalar calls (a lane
    block computes them in a loop of their own before its SIMD loop). One thread, random states near hover."""
    import functools
    import math

    import numpy as np
    from numba import njit

    from softpvtol_gym import model as MK
    from softpvtol_gym.params import SoftPVTOLParams

    L = MK.LANES
    rng = np.random.default_rng(0)
    W = np.zeros((MK.LANE_ROWS_RK4, L))
    W[MK.LANE_Q:MK.LANE_Q + 5] = rng.uniform(-0.5, 0.5, (5, L))
    W[MK.LANE_QD:MK.LANE_QD + 5] = rng.uniform(-0.5, 0.5, (5, L))
    W[MK.LANE_U:MK.LANE_U + 4] = rng.uniform(0.0, 1.0, (4, L))
    W[MK.LANE_P:MK.LANE_P + 10] = SoftPVTOLParams().array[:, None]
    W = W.ravel()

    @njit(nogil=True)
    def sincos(x, out):
        for i in range(x.shape[0]):
            out[i] = math.sin(x[i]) + math.cos(x[i])

    x, out = rng.uniform(-3.0, 3.0, 4096), np.empty(4096)
    cases = {"RK4 step, full lane block (SIMD)": (lambda w: MK.rk4_lanes(w, 0.001, L, MK.INPUT_MAP_PAPER), L),
             "RK4 step, lane by lane": (lambda w: MK.rk4_lanes_partial(w, 0.001, L, MK.INPUT_MAP_PAPER), L),
             "libm sin and cos of one value": (lambda w: sincos(x, out), x.shape[0])}
    for name, (fn, per) in cases.items():
        fn(W.copy())
        seconds = _median_seconds(lambda f=fn: functools.partial(f, W.copy()), reps)
        print(f"{name}: {1e9 * seconds / per:.1f} ns per state (median of {reps})")


def time_extended(reps: int = 21) -> None:
    """The parts of ``ExtendedPolicy.predict`` in one thread at N = 4096, from step 100 of a hover loop (nominal
    tier, seed 0): the law alone (``extended_law`` on every row's state, the extension and a zero reference jet),
    predict with one law (``held_command="start"``) and with the default midpoint (the law, the RK4 half step of
    a lane block, the law at the midpoint). Each predict from a copy of the policy at that step."""
    import copy
    import functools

    import numpy as np
    from numba import njit

    import softpvtol_gym._parallel as parallel
    from softpvtol_gym import PassivityPolicy, SoftPVTOLVectorEnv
    from softpvtol_gym.control import extended_kernels as EK

    parallel.thread_count = lambda: 1  # one thread: costs per env without the split
    n = 4096
    env = SoftPVTOLVectorEnv(num_envs=n, task="hover", tier="nominal")
    obs = env.reset(seed=0)[0]
    policy = PassivityPolicy.from_env(env, loop="extended")
    for _ in range(100):
        obs = env.step(policy.predict(obs)[0])[0]

    @njit(nogil=True)
    def laws(obs, theta, xi, p, input_map, k, ref, out):
        for r in range(obs.shape[0]):
            o = obs[r]
            act, u1, _ = EK.extended_law((o[0], o[1], theta[r], o[5], o[6]), (o[7], o[8], o[9], o[10], o[11]),
                                         xi[r, 0], xi[r, 1], ref, p, input_map, k)
            out[r] = act[0] + u1

    o64 = obs.astype(np.float64)
    args = (o64, np.arctan2(o64[:, 3], o64[:, 4]), policy.controller._xi, policy._p, policy._map_code,
            policy._constants, np.zeros((5, 3)), np.empty(n))
    laws(*args)

    print(f"one thread, N = {n}, step 100 of a hover loop (medians of {reps}):")
    ns = 1e9 * _median_seconds(lambda: functools.partial(laws, *args), reps) / n
    print(f"  the law alone: {ns:.0f} ns per env")
    for held in ("start", "midpoint"):
        snapshot = copy.deepcopy(policy)
        snapshot.controller.held_command = held
        copy.deepcopy(snapshot).predict(obs)  # (compiled before the timing)
        ns = 1e9 * _median_seconds(lambda s=snapshot: functools.partial(copy.deepcopy(s).predict, obs), reps) / n
        print(f"  ExtendedPolicy.predict, held_command={held!r}: {ns:.0f} ns per env")


def time_training() -> None:
    import tempfile
    import timeit

    import numpy as np

    import softpvtol_gym.baselines.training.loop as training
    from softpvtol_gym.baselines.config.hyperparams import load_hyperparams
    from softpvtol_gym.baselines.config.run_config import RunConfig
    from softpvtol_gym.baselines.evaluation import run_episodes
    from softpvtol_gym.baselines.training.policy import LearnedPolicy
    from softpvtol_gym.envs.sb3 import SoftPVTOLSB3VecEnv

    for step_infos in (True, False):
        env = SoftPVTOLSB3VecEnv(num_envs=128, action_mode="residual", task="track_random", step_infos=step_infos)
        env.reset()
        action = np.zeros((128, 5), np.float32)

        def step(e=env, action=action):
            e.step_async(action)
            e.step_wait()

        seconds = min(timeit.repeat(step, number=200, repeat=7)) / 200 / 128
        print(f"SB3 adapter step, 128 sub-envs, residual, step_infos={step_infos}: {seconds * 1e6:.2f} us per "
              f"env-step (best of 7)")
    hp = load_hyperparams("ppo", "residual")
    config = RunConfig(algo="ppo", action_mode="residual", task="track_random", tier="nominal", timesteps=1000,
                       seed=0, n_envs=16, hyperparams=hp, overrides=[], checkpoint_freq=1000, eval_freq=1000,
                       eval_episodes=10)
    with tempfile.TemporaryDirectory() as tmp:
        _, vecnorm, model = training.prepare(config, Path(tmp) / "run")
    policy = LearnedPolicy(model, vecnorm)
    run_episodes(policy, "residual", "track_random", "nominal", 10, 0)
    seconds = min(timeit.repeat(lambda: run_episodes(policy, "residual", "track_random", "nominal", 10, 0),
                                number=1, repeat=5))
    print(f"one periodic evaluation (10 track_random episodes, an untrained policy): {seconds:.3f} s (best of 5)")


#: the timings without options, by their command's name
TIMINGS = {"draws": time_draws, "single": time_single, "policy": time_policy, "vector": time_vector,
          "parts": time_parts, "split": time_split, "passes": time_passes, "bound": time_bound,
          "simd": time_simd, "extended": time_extended, "training": time_training}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="timing", required=True)
    c = sub.add_parser("compile", help="a cold first step and the compile time of every kernel")
    c.add_argument("--mode", default="actuators", choices=("actuators", "virtual", "residual"))
    sub.add_parser("draws", help="reset uniforms: compiled vs Python loop")
    sub.add_parser("single", help="single env / Pendulum-v1")
    sub.add_parser("policy", help="PassivityPolicy.predict (default, integral, extended) and PassivityController() "
                                  "for one state")
    sub.add_parser("vector", help="the vector env's step at N = 256 and 4096")
    sub.add_parser("passes", help="the algebraic loop's passes, a pass's cost, the extended loop's law")
    sub.add_parser("parts", help="the step kernel's parts, N = 4096, one thread")
    sub.add_parser("split", help="the step kernel of 4096 envs in one thread and split over the threads")
    sub.add_parser("bound", help="the vector env at N = 4096: one thread, and the bound of a perfect split")
    sub.add_parser("simd", help="the RK4 step of a lane block, SIMD and lane by lane; libm sin and cos")
    sub.add_parser("extended", help="ExtendedPolicy.predict's parts: its law, one law, the midpoint")
    sub.add_parser("training", help="the SB3 adapter's step; a periodic evaluation")
    args = ap.parse_args(argv)
    if args.timing == "compile":
        time_compile(args.mode)
    else:
        TIMINGS[args.timing]()
    return 0


if __name__ == "__main__":
    sys.exit(main())
