"""Open-loop sinusoid baselines: the distance a fixed gait covers, the bar MPC must clear.

For each benchmark, every gait of a small grid (frequencies x amplitudes x phase orders, see
:mod:`controllers.gaits`) runs open loop for ``--seconds`` from ``reset(seed)``, all gaits in
one batched rollout. The score is the distance along d between t = ``--start`` and the end
(so that a lean or a first lunge earns nothing), in body lengths (the robot's largest
horizontal rest extent), mean over ``--seeds``. Writes ``open_loop.csv`` (every gait) and
``open_loop.png`` (best distance per frequency) into ``--out`` and prints the best gait per
benchmark.

    python benchmarks/baselines_open_loop.py [--seconds 10] [--seeds 0 1 2] [--json]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import gymnasium as gym
import numpy as np

import softrom_gym
from controllers.gaits import gait_grid

sys.path.insert(0, str(Path(__file__).parent))
from _results import save_figure, write_csv

IDS = [f"softrom_gym/{name}" for name in softrom_gym.BENCHMARKS]


def measure(env_id: str, args: argparse.Namespace) -> list[dict]:
    env = gym.make(env_id, control_dim=args.control_dim, sim_dim=args.sim_dim)
    dt = env.get_wrapper_attr("dt")
    bound = env.get_wrapper_attr("action_bound")
    length = env.get_wrapper_attr("body_length")
    direction = env.unwrapped.direction
    steps = round(args.seconds / dt)
    first = round(args.start / dt)  # distance from the end of env step `first`
    if not 0 < first < steps:
        raise ValueError(f"--start {args.start} must lie inside (0, --seconds {args.seconds})")
    gaits = gait_grid(args.control_dim, tuple(args.frequencies), tuple(args.amplitudes))
    controls = np.stack([g.controls(steps, dt, bound) for g in gaits])
    distance = np.zeros((len(args.seeds), len(gaits)))
    wall = time.perf_counter()
    for i, seed in enumerate(args.seeds):
        env.reset(seed=seed)
        out = env.get_wrapper_attr("rollout")(env.get_wrapper_attr("get_state")(), controls,
                                              threads=args.threads)  # fmt: skip
        gained = (out["com"][:, -1] - out["com"][:, first - 1]) @ direction
        distance[i] = np.where(out["diverged"], np.nan, gained / length)
    wall = time.perf_counter() - wall
    env.close()
    return [
        {
            "env_id": env_id,
            "gait": g.label(),
            "frequency_hz": g.frequency,
            "amplitude": g.amplitude,
            "phases": " ".join(f"{p:.4f}" for p in g.phases),
            "distance_bl": float(np.mean(distance[:, j])),
            "distance_bl_std": float(np.std(distance[:, j])),
            "body_length_m": length,
            "seeds": len(args.seeds),
            "wall_s": wall,
        }
        for j, g in enumerate(gaits)
    ]


def plot(rows: list[dict], path: Path, span: str) -> None:
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        print(f"matplotlib is not installed (pip install matplotlib): no {path.name}")
        return
    fig, ax = plt.subplots(figsize=(6, 4))
    for env_id in dict.fromkeys(r["env_id"] for r in rows):
        mine = [r for r in rows if r["env_id"] == env_id]
        freqs = sorted({r["frequency_hz"] for r in mine})
        best = [
            np.nanmax([r["distance_bl"] for r in mine if r["frequency_hz"] == f]) for f in freqs
        ]
        ax.plot(freqs, best, "o-", label=env_id.split("/")[-1])
    ax.set_xlabel("frequency (Hz)")
    ax.set_ylabel(f"best distance t = {span} s (body lengths)")
    ax.axhline(0.0, color="0.7", lw=0.8)
    ax.legend(fontsize=8)
    fig.tight_layout()
    try:
        save_figure(fig, path, dpi=120)
    finally:
        plt.close(fig)


def main(argv: list[str] | None = None) -> list[dict]:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("env_ids", nargs="*", default=IDS)
    p.add_argument("--seconds", type=float, default=10.0)
    p.add_argument("--start", type=float, default=2.0, help="distance counts from this time (s)")
    p.add_argument("--seeds", type=int, nargs="+", default=[0])
    p.add_argument("--frequencies", type=float, nargs="+", default=[0.5, 1.0, 2.0, 3.0, 4.0])
    p.add_argument("--amplitudes", type=float, nargs="+", default=[0.5, 1.0])
    p.add_argument("--control-dim", type=int, default=3)
    p.add_argument("--sim-dim", type=int, default=20, help="M, the simulation space's modes")
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--out", type=Path, default=Path("runs/open_loop"))
    p.add_argument("--json", action="store_true", help="one JSON object per benchmark's best")
    args = p.parse_args(argv)
    if min(args.seeds) < 0:  # gymnasium's reset refuses it, as a traceback mid-run
        p.error(f"--seeds must be >= 0, got {args.seeds}")
    if not 0 < args.start < args.seconds:
        p.error(f"--start {args.start:g} must lie inside (0, --seconds {args.seconds:g})")
    ids = [i if "/" in i else f"softrom_gym/{i}" for i in args.env_ids]
    if not 1 <= args.control_dim <= args.sim_dim or args.threads < 1:
        p.error(f"need 1 <= --control-dim <= --sim-dim and --threads >= 1, got "
                f"{args.control_dim}, {args.sim_dim}, {args.threads}")  # fmt: skip
    try:  # an unknown id or a bad grid: named now, not as a traceback after other rows ran
        for env_id in ids:
            gym.spec(env_id)
        gait_grid(args.control_dim, tuple(args.frequencies), tuple(args.amplitudes))
    except (ValueError, gym.error.Error) as exc:
        p.error(str(exc))
    rows = [row for env_id in ids for row in measure(env_id, args)]
    write_csv(rows, args.out / "open_loop.csv")
    plot(rows, args.out / "open_loop.png", f"{args.start:g}..{args.seconds:g}")
    best = []
    for env_id in ids:
        mine = [r for r in rows if r["env_id"] == env_id and np.isfinite(r["distance_bl"])]
        best.append(max(mine, key=lambda r: r["distance_bl"]))
    if args.json:
        for r in best:
            print(json.dumps(r))
    else:
        print(f"{'env id':<30} {'best gait':<28} {'distance (BL)':>14} {'(m)':>8}")
        for r in best:
            print(f"{r['env_id']:<30} {r['gait']:<28} {r['distance_bl']:>14.3f} "
                  f"{r['distance_bl'] * r['body_length_m']:>8.3f}")  # fmt: skip
        print(f"distance between t = {args.start:g} s and t = {args.seconds:g} s, mean over "
              f"seeds {args.seeds}; every gait in {args.out / 'open_loop.csv'}")  # fmt: skip
    return best


if __name__ == "__main__":
    main()
