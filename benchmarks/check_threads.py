"""The core's threads under stress: results that must not depend on who calls or how many.

Cases a, b and f check that rollouts give the same bits whatever the thread count or the
other Python threads doing; c, d and e check only that nothing fails. Together they are the
workload for a ThreadSanitizer build (README: "For work on the core"), where the point is the
sanitizer's reports rather than this script's output:

- ``a``: ``rollout(threads=2)`` of (8, 20, C) controls on each benchmark against one thread,
  and the env's ``rollout`` of a list of states;
- ``b``: one model, ``rollout`` (2 and 1 threads) and ``step`` from four Python threads at once;
- ``c``: settings and B_c assigned from one Python thread while others' rollouts and steps run
  (the core copies what a call reads at entry);
- ``d``: the vector env (``gym.make_vec(..., threads=2)``), and two stepped from two threads;
- ``e``: Ctrl-C (SIGINT) during a two-thread rollout, then the pool used again;
- ``f``: pool sizes 4, 2, 3, 1, 4 in turn, more threads than rollouts, from two threads.

    python benchmarks/check_threads.py                    # every case
    python benchmarks/check_threads.py a b --save s.npz   # also the final states, for another
    python benchmarks/check_threads.py --check s.npz      # build to compare bitwise
"""

from __future__ import annotations

import argparse
import sys
import threading
import time

import gymnasium as gym
import numpy as np

import softrom_gym  # noqa: F401  (registers the envs)

IDS = ["CrossSwim-v0", "CrossWalk-v0", "BeamWalk-v0", "QuadrupedWalk-v0", "TripodWalk-v0"]
_envs = {}


def env_of(name):
    if name not in _envs:
        _envs[name] = gym.make("softrom_gym/" + name).unwrapped
    return _envs[name]


def controls(env, b, h, seed):
    rng = np.random.default_rng(seed)
    c = env.action_space.shape[0]
    return rng.uniform(-1, 1, (b, h, c)) * env.action_bound


def banner(msg):
    print(f"=== {msg}", file=sys.stderr, flush=True)


def case_a():
    for name in IDS:
        env = env_of(name)
        env.reset(seed=0)
        banner(f"a {name} C={env.action_space.shape[0]} dim={env.model.dim}")
        t = time.time()
        out = env.model.rollout(env.get_state(), controls(env, 8, 20, 1), threads=2)
        one = env.model.rollout(env.get_state(), controls(env, 8, 20, 1), threads=1)
        assert np.array_equal(out["q"], one["q"]), name
        # and the env's path (frame_skip, observables), batch of states
        env.rollout([env.get_state()] * 4, controls(env, 4, 2, 2) / env.action_bound, threads=2)
        print(f"a {name}: {time.time() - t:.1f}s diverged={out['diverged'].sum()}", flush=True)


def run_threads(targets):
    errors = []

    def wrap(f):
        def g():
            try:
                f()
            except BaseException as e:  # (re-raised by the caller, in its thread)
                errors.append(e)

        return g

    ts = [threading.Thread(target=wrap(f)) for f in targets]
    for t in ts:
        t.start()
    for t in ts:
        t.join()
    if errors:
        raise errors[0]


def case_b():
    for name in ["QuadrupedWalk-v0", "CrossSwim-v0"]:
        env = env_of(name)
        env.reset(seed=0)
        model, s0 = env.model, env.get_state()
        u = controls(env, 4, 10, 3)
        ref = model.rollout(s0, u, threads=1)
        banner(f"b {name}")

        def roll(nt, model=model, s0=s0, u=u, ref=ref):
            for _ in range(2):
                out = model.rollout(s0, u, threads=nt)
                assert np.array_equal(out["q"], ref["q"])

        def stepper(model=model, s0=s0, u=u, ref=ref):
            s = s0
            for t in range(10):
                s, _ = model.step(s, u[0, t])
            assert np.array_equal(s.q, ref["q"][0])

        run_threads([lambda: roll(2), lambda: roll(2), lambda: roll(1), stepper])
        run_threads([stepper, stepper, stepper])
        print(f"b {name}: ok", flush=True)


def case_c():
    env = env_of("QuadrupedWalk-v0")
    env.reset(seed=0)
    model, s0 = env.model, env.get_state()
    b0 = np.array(model.control_basis)
    rng = np.random.default_rng(5)
    q, _ = np.linalg.qr(rng.standard_normal(b0.shape))
    u = controls(env, 4, 15, 4)
    cfg0 = model.config
    done = threading.Event()
    banner("c settings written during rollouts")

    def writer():
        k = 0
        while not done.is_set():
            model.control_basis = q if k % 2 else b0
            model.friction = 0.5 if k % 2 else 0.8
            model.dt = 1 / 250 if k % 2 else 1 / 200
            model.damping_beta = 0.004 if k % 2 else 0.005
            model.solver = "reference" if k % 5 == 4 else "fast"
            c = model.config
            c.contact_margin = 2e-3 if k % 2 else 1e-3
            model.config = c
            env.set_control_basis(b0)
            k += 1
            time.sleep(0.001)
        print(f"c: {k} writes", flush=True)

    def roller(nt):
        for _ in range(3):
            model.rollout(s0, u, threads=nt)

    def stepper():
        s = s0
        for t in range(15):
            s, _ = model.step(s, u[0, t])

    w = threading.Thread(target=writer)
    w.start()
    try:
        run_threads([lambda: roller(2), lambda: roller(1), stepper])
    finally:
        done.set()
        w.join()
    model.config = cfg0
    model.control_basis = b0
    print("c: ok", flush=True)


def case_d():
    banner("d vector env")
    for name in ["QuadrupedWalk-v0", "CrossSwim-v0"]:
        venv = gym.make_vec("softrom_gym/" + name, num_envs=4,
                            vectorization_mode="vector_entry_point", threads=2)  # fmt: skip
        venv.reset(seed=0)
        rng = np.random.default_rng(0)
        for _ in range(6):
            venv.step(rng.uniform(-1, 1, venv.action_space.shape) * venv.unwrapped.env.action_bound)
        venv.close()
    # two vector envs stepped from two Python threads at once
    vs = [
        gym.make_vec(
            "softrom_gym/CrossWalk-v0",
            num_envs=3,
            vectorization_mode="vector_entry_point",
            threads=2,
        )
        for _ in range(2)
    ]

    def stepv(v):
        v.reset(seed=1)
        for _ in range(6):
            v.step(np.full(v.action_space.shape, 0.5 * v.unwrapped.env.action_bound))

    run_threads([lambda: stepv(vs[0]), lambda: stepv(vs[1])])
    print("d: ok", flush=True)


def finals():
    res = {}
    for name in IDS:
        env = env_of(name)
        env.reset(seed=0)
        out = env.model.rollout(env.get_state(), controls(env, 4, 20, 7), threads=2)
        for k in ("q", "qdot", "impulses", "rewards"):
            res[f"{name}/{k}"] = out[k]
    return res


def case_e():
    """Ctrl-C while a 2-thread rollout runs on the main thread: the pool's poll path."""
    import os
    import signal

    env = env_of("QuadrupedWalk-v0")
    env.reset(seed=0)
    banner("e SIGINT during a threads=2 rollout")
    timer = threading.Timer(2.0, os.kill, (os.getpid(), signal.SIGINT))
    timer.start()
    t = time.time()
    try:
        env.model.rollout(env.get_state(), controls(env, 2, 100000, 9), threads=2)
        print("e: NOT interrupted", flush=True)
    except KeyboardInterrupt:
        print(f"e: interrupted after {time.time() - t:.1f}s", flush=True)
    out = env.model.rollout(env.get_state(), controls(env, 4, 5, 9), threads=2)  # pool reusable
    print("e: ok", out["q"].shape, flush=True)


def case_f():
    """The pool's growth and partial participation: thread counts 4, 2, 3, 1, 4 in turn (and
    more threads than rollouts), from the main thread and two Python threads at once."""
    env = env_of("CrossWalk-v0")
    env.reset(seed=0)
    model, s0 = env.model, env.get_state()
    banner("f pool sizes")
    u = controls(env, 5, 6, 11)
    ref = model.rollout(s0, u, threads=1)

    def go(counts):
        for nt in counts:
            assert np.array_equal(model.rollout(s0, u, threads=nt)["q"], ref["q"])
            model.rollout(s0, u[:2], threads=nt)

    go([4, 2, 3, 1, 4])
    run_threads([lambda: go([2, 4, 3]), lambda: go([3, 2, 4])])
    print("f: ok", flush=True)


CASES = {"a": case_a, "b": case_b, "c": case_c, "d": case_d, "e": case_e, "f": case_f}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("cases", nargs="*", metavar="CASE",
                   help=f"cases to run, of {' '.join(CASES)} (default: all; the docstring "
                   "says what each does)")  # fmt: skip
    p.add_argument("--save", metavar="NPZ", help="write the final states of 4 rollouts per "
                   "benchmark, to compare with another build")  # fmt: skip
    p.add_argument("--check", metavar="NPZ", help="compare them with those --save wrote")
    args = p.parse_args()
    unknown = [c for c in args.cases if c not in CASES]
    if unknown:
        p.error(f"unknown case {', '.join(unknown)}; cases: {' '.join(CASES)}")
    for case in args.cases or list(CASES):
        CASES[case]()
    if args.save:
        np.savez(args.save, **finals())
    if args.check:
        ref = np.load(args.check)
        now = finals()
        bad = [k for k in ref.files if not np.array_equal(ref[k], now[k])]
        print("bitwise:", "identical" if not bad else f"DIFFER {bad}", f"({len(ref.files)} arrays)")
        if bad:
            sys.exit(1)


if __name__ == "__main__":
    main()
