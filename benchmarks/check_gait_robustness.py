"""Is an MPC gait physics or an artefact of the step? Replay it under other numerics.

For each C (identity basis B_c = the first C modes), one closed-loop MPC episode with the
benchmark's default planner; its actions are then replayed open loop in fresh envs that differ
in one numerical or physical choice:

- ``as recorded``: the same env (must give the closed loop's distance: the step is
  deterministic);
- ``dt / 2``: half the physics step, twice the frame skip (the same control period);
- ``reference, tol 1e-5``: the exact Newton solver and a 10x tighter contact tolerance;
- ``penalty contact``: the penalty ground instead of staggered projection;
- ``friction 0.6``: mu = 0.6 instead of the env's default;
- ``M = 40``: twice the simulation space, B_c mapped into it so that the actions are the same
  forces (the M = 20 space lies inside it): is B_r rich enough for this motion?

A gait that the numerics made keeps its distance only in ``as recorded``; a physical one keeps
it (within the spread of a chaotic contact system) in every row. ``--closed-loop-dims 30 40``
also plans a fresh closed-loop episode in each richer simulation space (the same seed and
planner defaults): does the ranking of the C values survive a richer model? Also printed, over the
episode: the smallest det F and the largest principal stretch of any tet (how far the reduced
model is pushed), the deepest penetration, and the fraction of frames with no node within
1 mm of the ground (airborne).

    python benchmarks/check_gait_robustness.py [--env-id softrom_gym/CrossWalk-v0] [--cs 3 4]
"""

from __future__ import annotations

import argparse
from collections.abc import Callable

import gymnasium as gym
import numpy as np

from controllers import default_planner, run_episode
from softrom_gym import map_control_basis

BASIS: np.ndarray | None = None  # --control-basis: B_c (M x C) instead of the first C modes
DEFAULT_M = 20


def make(env_id: str, c: int, **kwargs) -> gym.Env:
    """The env with B_c = the first ``c`` modes or ``BASIS``, both given in the default
    M-mode space. In another simulation space B_c becomes T B_c with T = B'^T M B (B, B' the
    deformation columns of the two spaces): the same full-space actuation field M B B_c f_c,
    exactly, when the default space lies inside the other (they nest; see
    ``check_m_convergence.py``)."""
    m = kwargs.get("sim_dim", DEFAULT_M)
    basis = BASIS if BASIS is not None else np.eye(DEFAULT_M)[:, :c]
    if m != DEFAULT_M or BASIS is not None:
        if m != DEFAULT_M:
            env = gym.make(env_id)
            basis = map_control_basis(basis, env, DEFAULT_M, m)
            env.close()
        kwargs["control_basis"] = basis
    return gym.make(env_id, control_dim=c, **kwargs)


def replay(env_id: str, c: int, actions: np.ndarray, seed: int, start_step: int,
           env_kwargs: dict | None = None,
           adjust: Callable[[gym.Env], None] | None = None) -> float:  # fmt: skip
    """Distance along d from env step ``start_step`` to the end, replaying ``actions``."""
    kwargs = dict(env_kwargs or {})
    if "dt" in kwargs:  # the same control period with a finer physics step
        base = make(env_id, c)
        period = base.unwrapped.dt
        base.close()
        kwargs.setdefault("frame_skip", round(period / kwargs["dt"]))
    env = make(env_id, c, **kwargs)
    try:
        env.reset(seed=seed)
        if adjust is not None:
            adjust(env)
        at_start = 0.0
        info = {"distance": 0.0}
        for t, action in enumerate(actions):
            if t == start_step:
                at_start = info["distance"]
            _, _, terminated, _, info = env.step(action)
            if terminated:
                return float("nan")
        return float(info["distance"] - at_start)
    finally:
        env.close()


def deformation(env: gym.Env, states: list) -> dict[str, float]:
    """Extremes over ``states`` of det F, the principal stretches and the ground clearance."""
    u = env.unwrapped
    nodes, tets = np.asarray(u.robot.nodes), np.asarray(u.robot.tets)
    edges = np.stack([nodes[tets[:, i]] - nodes[tets[:, 0]] for i in (1, 2, 3)], axis=-1)
    rest_inv = np.linalg.inv(edges)
    det_min, stretch_max, z_min, airborne = np.inf, 0.0, np.inf, 0
    for state in states:
        x = np.asarray(u.model.positions(state.q)).reshape(-1, 3)
        f = np.stack([x[tets[:, i]] - x[tets[:, 0]] for i in (1, 2, 3)], axis=-1) @ rest_inv
        det_min = min(det_min, float(np.linalg.det(f).min()))
        stretch_max = max(stretch_max, float(np.linalg.svd(f, compute_uv=False).max()))
        clearance = float(x[:, 2].min() - u.model.ground_height)
        z_min = min(z_min, clearance)
        airborne += clearance > 1e-3
    return {"det_F_min": det_min, "stretch_max": stretch_max, "penetration_mm": -1e3 * z_min,
            "airborne": airborne / len(states)}  # fmt: skip


def main(argv: list[str] | None = None) -> list[dict]:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--env-id", default="softrom_gym/CrossWalk-v0")
    p.add_argument(
        "--planner",
        default="mppi",
        metavar="NAME",
        help="mppi, gn, a registered planner, or an import path package.module:ClassName",
    )
    p.add_argument("--cs", type=int, nargs="+", default=[3, 4])
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--seconds", type=float, default=10.0)
    p.add_argument("--start", type=float, default=2.0, help="distance measured from here (s)")
    p.add_argument("--control-basis", type=str, default=None,
                   help="B_c from a .npy (M x C), e.g. an RBBO run's best_basis.npy")  # fmt: skip
    p.add_argument("--closed-loop-dims", type=int, nargs="*", default=[],
                   help="also run the closed loop with these sim_dim (M) values")  # fmt: skip
    args = p.parse_args(argv)
    if not 0 <= args.start < args.seconds or min(args.cs) < 1:
        p.error(f"need 0 <= --start < --seconds and --cs >= 1, got {args.start:g}, "
                f"{args.seconds:g}, {args.cs}")  # fmt: skip
    global BASIS
    if args.control_basis is not None:
        try:
            BASIS = np.load(args.control_basis, allow_pickle=False)
        except (OSError, ValueError) as exc:
            p.error(f"--control-basis {args.control_basis}: {exc}")
        if BASIS.ndim != 2 or BASIS.shape[0] != DEFAULT_M:
            p.error(f"--control-basis must be {DEFAULT_M} x C, got shape {BASIS.shape}")
        args.cs = [BASIS.shape[1]]
    # checked now: a --closed-loop-dims M below C (or a negative seed) was a traceback raised
    # only after each C's closed loop and replays had run (minutes at the defaults)
    if args.seed < 0 or any(m < max(args.cs) for m in args.closed_loop_dims):
        p.error(f"need --seed >= 0 and every --closed-loop-dims >= C = {max(args.cs)}, got "
                f"{args.seed}, {args.closed_loop_dims}")  # fmt: skip

    def numerics(env: gym.Env) -> None:
        env.unwrapped.model.solver = "reference"
        env.unwrapped.model.contact_tolerance = 1e-5

    try:
        probe = gym.make(args.env_id)
    except gym.error.Error as exc:
        p.error(str(exc))
    physics_dt = float(probe.unwrapped.model.dt)
    walking = probe.unwrapped.task == "walk"  # the ground figures mean nothing in a fluid
    probe.close()
    variants: list[tuple[str, dict, Callable | None]] = [
        ("as recorded", {}, None),
        ("dt / 2", {"dt": 0.5 * physics_dt}, None),
        ("reference, tol 1e-5", {}, numerics),
        ("penalty contact", {"contact": "penalty"}, None),
        ("friction 0.6", {"friction": 0.6}, None),
        ("M = 40", {"sim_dim": 40}, None),
    ]
    if not walking:
        variants = [v for v in variants if v[0] not in ("penalty contact", "friction 0.6")]
    rows = []
    for c in args.cs:
        env = make(args.env_id, c)
        planner, every = default_planner(args.env_id, args.planner, threads=1)
        res = run_episode(env, planner, args.seconds, replan_every=every, seed=args.seed,
                          progress=False)  # fmt: skip
        start_step = round(args.start / res.dt)
        closed = res.distance_between(args.start)
        d = deformation(env, res.states)
        env.close()
        ground = (f", penetration <= {d['penetration_mm']:.2f} mm, airborne "
                  f"{100 * d['airborne']:.0f} % of frames" if walking else "")  # fmt: skip
        print(f"C = {c}: closed loop {closed:+.3f} m (t = {args.start:g}..{res.seconds:g} s); "
              f"det F >= {d['det_F_min']:.3f}, stretch <= {d['stretch_max']:.3f}{ground}",
              flush=True)  # fmt: skip
        for name, kwargs, adjust in variants:
            r = replay(args.env_id, c, res.actions, args.seed, start_step, kwargs, adjust)
            rows.append({"C": c, "variant": name, "distance_m": r, "closed_loop_m": closed, **d})
            print(f"  {name:<22} {r:+.3f} m  ({r / closed:.2f} of the closed loop)", flush=True)
        for m in args.closed_loop_dims:
            env = make(args.env_id, c, sim_dim=m)
            planner, every = default_planner(args.env_id, args.planner, threads=1)
            other = run_episode(env, planner, args.seconds, replan_every=every, seed=args.seed,
                                progress=False).distance_between(args.start)  # fmt: skip
            env.close()
            rows.append({"C": c, "variant": f"closed loop, M = {m}", "distance_m": other,
                         "closed_loop_m": closed, **d})  # fmt: skip
            print(f"  closed loop, M = {m:<5} {other:+.3f} m  ({other / closed:.2f})", flush=True)
    return rows


if __name__ == "__main__":
    main()
