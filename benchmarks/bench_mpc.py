"""MPC speed and locomotion: each planner with its defaults on each benchmark (C = 3).

For every (benchmark, planner): one closed-loop episode of ``--seconds`` per seed with the
defaults of :mod:`controllers.defaults`, on ``--threads`` rollout threads. Reports the mean
wall time of one replan, the real-time factor (simulated seconds advanced per replan / wall
seconds per replan; >= 1 keeps up with the robot), and the distance along d between
t = ``--start`` and the end, per second and in body lengths (mean over seeds). An episode
that diverges counts no distance after it stops, over the same span (as rbbo's R does), and
the row's ``stops`` (CSV and ``--json``) counts why the episodes ended. The real-time factor
is computed from the mean replan wall time. Writes the rows to ``bench_mpc.csv`` in ``--out``
(default ``runs/bench_mpc``), rewritten after each row.

``plan/phys`` (CSV ``plan_over_physics``, with ``physics_wall_s``) is the ratio measured side
by side: the episode's replan wall time over that of its physics floor. Each replan's
rollouts (every control sequence it passed to the env's public ``rollout``, from the same
start state) are replayed right after it, before the env steps on, as one batched
``rollout`` call on the same threads, and timed; the ratio is the replans' total over the
replays' total. 1 would be a planner that costs nothing beyond the physics it asks for; the
excess is its own work (the splines, the cost, Gauss-Newton's linear algebra) and the
splitting of its rollouts into batches that wait on one another (Gauss-Newton's Jacobian
before its line search, MPPI's rounds), each waiting on its slowest thread. The replays do not
change the episode (``rollout`` leaves the env's state as it was) and are not counted in the
replan times or the real-time factor; they make a run take up to twice as long. The two
sides run one after the other, not at once, so a shared machine's load moves a single replay
by up to a quarter either way (1-s runs of two replans read 0.88 to 1.23): read the ratio of
a whole run, whose replans average that out. ``rollout_share`` (CSV and ``--json`` only)
splits it without a second measurement: the share of the replans' wall time spent inside
their own ``rollout`` calls, so 1 - it is the planner's own work, and plan/phys x
rollout_share (those calls over the one batch) the batching's.

    python benchmarks/bench_mpc.py [ENV_ID ...] [--planners mppi gn] [--seconds 10]
        [--seeds 0 1 2] [--mpc KEY=VALUE,...] [--json] [--out runs/bench_mpc]

``--mpc`` changes planner settings from the defaults (e.g. ``--planners gn --mpc
restart_damping=true``); each row records the changes.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

import softrom_gym
from controllers import default_planner, run_episode
from controllers.defaults import parse_changes

sys.path.insert(0, str(Path(__file__).parent))
from _results import write_csv

IDS = [f"softrom_gym/{name}" for name in softrom_gym.BENCHMARKS]


class PhysicsFloor(gym.Wrapper):
    """Passes the planner's ``rollout`` calls through, and before the next ``step`` replays
    the last replan's as one batched ``rollout``, timed (``wall_s``, one per replan; and
    ``inside_s``, the time the replan's own calls took).

    A replan's calls are those from the start state its ``plan`` took: the gait seed at
    reset rolls out from a state of its own and is left out, as it is of the replan times.
    """

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        self.physics = env.get_wrapper_attr("rollout")  # the env's own
        self.calls: list[tuple[Any, np.ndarray, int | None, float]] = []
        self.wall_s: list[float] = []
        self.inside_s: list[float] = []

    def rollout(self, state, controls, threads=None, observe=None) -> dict[str, np.ndarray]:
        start = time.perf_counter()
        out = self.physics(state, controls, threads=threads, observe=observe)
        self.calls.append((state, np.asarray(controls), threads, time.perf_counter() - start))
        return out

    def step(self, action):
        if self.calls:
            self._replay()
        return self.env.step(action)

    def reset(self, **kwargs):
        self.calls.clear()
        return self.env.reset(**kwargs)

    def _replay(self) -> None:
        state, _, threads, _ = self.calls[-1]
        replan = [u for s, u, _, _ in self.calls if s is state]
        self.inside_s.append(sum(t for s, _, _, t in self.calls if s is state))
        self.calls.clear()
        # (one call per horizon: the planners' replans use one, but nothing forbids more)
        batches: dict[int, list[np.ndarray]] = {}
        for u in replan:
            batches.setdefault(u.shape[1], []).append(u)
        start = time.perf_counter()
        for group in batches.values():
            self.physics(state, np.concatenate(group), threads=threads)
        self.wall_s.append(time.perf_counter() - start)


def measure(env_id: str, planner_name: str, args: argparse.Namespace) -> dict:
    walls, physics, distances, lengths = [], [], [], []
    stops: dict[str, int] = {}
    plan_total = physics_total = inside_total = 0.0
    start = time.perf_counter()
    t0 = args.start if args.seconds > args.start else 0.0
    span = args.seconds - t0
    for seed in args.seeds:
        env = PhysicsFloor(gym.make(env_id))
        planner, every = default_planner(env_id, planner_name, threads=args.threads,
                                         **args.changes)  # fmt: skip
        res = run_episode(env, planner, args.seconds, replan_every=every, seed=seed,
                          progress=args.progress)  # fmt: skip
        stops[res.stop_reason] = stops.get(res.stop_reason, 0) + 1
        walls.append(float(np.mean(res.replan_wall_s)))
        # An episode that diverged travelled nothing after it stopped (rbbo's R counts it so):
        # its distance from t0 (none, when it stopped before t0) over the span asked for.
        distances.append(res.distance_between(min(t0, res.seconds)))
        lengths.append(res.body_length)
        if len(env.wall_s) != res.replans:  # every replan is followed by the step that replays it
            raise RuntimeError(f"{res.replans} replans but {len(env.wall_s)} replays")
        physics.append(float(np.mean(env.wall_s)))
        plan_total += float(np.sum(res.replan_wall_s))
        physics_total += float(np.sum(env.wall_s))
        inside_total += float(np.sum(env.inside_s))
        env.close()
    return {
        "env_id": env_id,
        "controller": planner_name,
        "replan_wall_s": float(np.mean(walls)),
        "physics_wall_s": float(np.mean(physics)),
        "plan_over_physics": plan_total / physics_total,
        "rollout_share": inside_total / plan_total,
        # (from the mean wall time, as replan_wall_s is: not the mean of per-seed ratios)
        "realtime_factor": every * res.dt / float(np.mean(walls)),
        "distance_per_s": float(np.mean(distances)) / span,
        "distance_bl": float(np.mean(distances) / lengths[0]),
        "distance_bl_std": float(np.std(distances) / lengths[0]),
        "seconds": args.seconds,
        "start": args.start if args.seconds > args.start else 0.0,
        "seeds": len(args.seeds),
        "stops": ",".join(f"{k}:{v}" for k, v in sorted(stops.items())),
        "replan_every": every,
        "horizon": planner.settings.horizon,
        "threads": args.threads,
        "mpc": ",".join(f"{k}={v}" for k, v in args.changes.items()),
        "wall_s": time.perf_counter() - start,
    }


def main(argv: list[str] | None = None) -> list[dict]:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("env_ids", nargs="*", default=IDS)
    p.add_argument("--planners", nargs="+", default=["mppi", "gn"], metavar="NAME",
                   help="mppi, gn, or a planner of your own as an import path "
                   "package.module:ClassName, e.g. examples.cem_planner:CEM (default: mppi "
                   "gn)")  # fmt: skip
    p.add_argument("--seconds", type=float, default=10.0)
    p.add_argument("--start", type=float, default=2.0, help="distance counts from this time (s)")
    p.add_argument("--seeds", type=int, nargs="+", default=[0])
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--out", type=Path, default=Path("runs/bench_mpc"))
    p.add_argument("--progress", action="store_true", help="progress bars")
    p.add_argument("--mpc", type=parse_changes, action="append", default=[],
                   metavar="KEY=VALUE[,...]",
                   help="planner settings changed from the defaults")  # fmt: skip
    p.add_argument("--json", action="store_true", help="one JSON object per line")
    args = p.parse_args(argv)
    if min(args.seeds) < 0:  # gymnasium's reset refuses it, as a traceback mid-run
        p.error(f"--seeds must be >= 0, got {args.seeds}")
    args.changes = {k: v for part in args.mpc for k, v in part.items()}
    ids = [i if "/" in i else f"softrom_gym/{i}" for i in args.env_ids]
    if not (args.seconds > 0 and args.start >= 0):
        p.error(f"--seconds must be > 0 and --start >= 0, got {args.seconds}, {args.start}")
    for env_id in ids:
        try:  # an unknown id or --mpc setting, or --threads 0: named now, not as a traceback
            spec = gym.spec(env_id)
            for planner in args.planners:
                default_planner(env_id, planner, threads=args.threads, **args.changes)
        except (ValueError, TypeError, gym.error.Error) as exc:
            p.error(str(exc))
        # the registered time limit ends an episode early: the distance per second would be
        # divided by time the robot never walked
        if spec.max_episode_steps is not None:
            period = spec.kwargs.get("frame_skip", 5) * spec.kwargs.get("dt", 1.0 / 200.0)
            limit = spec.max_episode_steps * period
            if args.seconds > limit + 1e-9:
                p.error(f"--seconds {args.seconds:g} exceeds {env_id}'s {limit:g}-s episode")
    if not args.json:
        print(f"{'env id':<30} {'ctrl':<5} {'replan s':>9} {'plan/phys':>10} {'RTF':>7} "
              f"{'m/s':>8} {'BL':>7} {'sd BL':>7}")  # fmt: skip
    rows = []
    for env_id in ids:
        for planner in args.planners:
            row = measure(env_id, planner, args)
            rows.append(row)
            write_csv(rows, args.out / "bench_mpc.csv")  # (each row as it is measured)
            if args.json:
                print(json.dumps(row), flush=True)
            else:
                print(f"{env_id:<30} {planner:<5} {row['replan_wall_s']:>9.3f} "
                      f"{row['plan_over_physics']:>10.2f} {row['realtime_factor']:>7.3f} "
                      f"{row['distance_per_s']:>8.4f} {row['distance_bl']:>7.3f} "
                      f"{row['distance_bl_std']:>7.3f}",
                      flush=True)  # fmt: skip
    return rows


if __name__ == "__main__":
    main()
