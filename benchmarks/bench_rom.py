"""Reduced model vs full-space FEM, per benchmark robot, measured side by side in one run.

For each of the five benchmarks (cross swim, cross walk, beam, quadruped, tripod) it prints:

* full-space implicit steps/s (squashed body released, as bench_fem.py: under gravity for the
  walkers, without for the swimmer, no ground or drag) and its Newton iterations per step
  (`full_newton_iterations`), timed in the same alternating rounds as the reduced solvers
  (three, or ``--rounds``), best of each;
* reduced steps/s (M = 20, cubature, one thread, one C++ rollout so that no Python overhead
  is counted) with the task's physics on — staggered-projection ground contact for walkers,
  quadratic drag for the swimmer — under random actuation of 0.5 body weight in the first
  three modes from rest (drawn anew every step; ``--actuation gait`` drives each rollout with
  one open-loop sinusoidal gait instead, as a controller's splines would), for the exact
  ``solver="reference"`` path (`reference_steps_per_s`) and the fast default
  (`reduced_steps_per_s`), and their ratio (`fast_over_reference`; target >= 10 on every
  benchmark); the same with the penalty ground model (`penalty_steps_per_s`, fast solver,
  timed in the same rounds);
* `speedup`: the fast reduced step over the full-space step (reported, whatever it is). The
  two sides do not run the same motion: the full-space body recovers from a 20 % squash (a
  transient of several Newton iterations per step, no contact), the reduced one walks or
  swims under actuation with contact or drag; the full-space side's Newton count says how
  hard its steps were;
* batched rollouts of (64, 100, C) controls: physics steps/s on 2 threads
  (`batched_rollout_steps_per_s`) and its ratio to 1 thread, best of 5 alternating runs
  (`thread_speedup`; target >= 1.8x), and the CPU time of the 2-thread run over the 1-thread
  run (`thread_cpu_ratio`, "cpu 2/1"; 1.0 means the workers do not contend, and a wall ratio
  under 2 is other load on the machine);
* against MuJoCo's own deformable, when the optional `mujoco` package is installed: a
  `flexcomp` of the same tetrahedra, mass and material (E, nu) dropped on a plane from 5 cm,
  with `integrator="discrete"` (MuJoCo 4 runs flex elasticity only there). Each simulator
  runs at the largest time step, from a fixed ladder, at which a 1 s drop stays stable
  (finite, penetration under 1 cm, RMS node speed under 10 m/s at every step for both (the
  reduced model's is mass-weighted, MuJoCo's flex vertices' unweighted), and for MuJoCo no
  solver warning); the comparison is simulated
  seconds per wall second (`mujoco_sim_rate`, `reduced_sim_rate`, ratio `vs_mujoco`), and
  `mujoco_steps_per_s` is MuJoCo's raw rate at its step (all null when not measured; the
  swimmer is not compared, MuJoCo's fluid model being a different one);
* `drop_error_rel`: position error of the reduced model against full space over 1 s of free
  flight under gravity with the lowest modes excited (about 3% deformation),
  ||x_r - x_f|| / ||x_f - x_rigid|| summed over the trajectory. The full-space model has no
  ground, so this compares the deformation dynamics (subspace + cubature), not contact.

It also prints (`kernels` in --json) the instruction set of the fast solver's dense kernels,
`cpp_sim.kernel_instruction_set()`: x86-64-v3 where the CPU has AVX2 + FMA, else the baseline;
run it with ``SOFTROM_KERNELS=baseline`` to measure the baseline set on the same machine.

    python benchmarks/bench_rom.py [--json] [--robots quadruped-walk ...] [--seconds 1.0]
        [--actuation random|gait]
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import sys
import time
from pathlib import Path

import numpy as np

import cpp_sim
from softrom_gym.robots import ROBOTS
from softrom_gym.rom import build_reduced_model, build_subspace

sys.path.insert(0, str(Path(__file__).parent))
from _actuation import BENCHMARKS, KINDS, modal_forces

DT = 1.0 / 200.0


def full_steps_per_s(robot, steps: int, gravity: bool = True) -> tuple[float, float]:
    """Full-space steps/s of a body released from a 20 % squash, and Newton iterations per
    step (after one untimed step that builds the solver)."""
    fem = robot.fem_model()
    if not gravity:
        fem.gravity = [0.0, 0.0, 0.0]
    x = robot.nodes * np.array([1.0, 1.0, 0.8])
    v = np.zeros_like(x)
    x, v = fem.step(x, v, DT)
    iterations = 0
    start = time.perf_counter()
    for _ in range(steps):
        x, v = fem.step(x, v, DT)
        iterations += fem.last_step_stats["iterations"]
    return steps / (time.perf_counter() - start), iterations / steps


def task_model(robot, task: str, contact: str = "staggered", solver: str = "fast"):
    if task == "swim":
        return build_reduced_model(
            robot, contact="none", gravity=[0.0, 0.0, 0.0], fluid_density=1000.0,
            control_basis=np.eye(20)[:, :3], solver=solver,
        )  # fmt: skip
    return build_reduced_model(
        robot, contact=contact, control_basis=np.eye(20)[:, :3], solver=solver
    )


def lifted(model, height: float):
    s = model.rest_state()
    q = s.q
    q[2] = height * np.sqrt(model.total_mass)
    return cpp_sim.ReducedState(q, s.qdot, s.impulses)


def reduced_steps_per_s(model, steps: int, kind: str = "random") -> float:
    """Physics steps/s of one rollout of ``steps`` actuated steps from rest, one thread."""
    controls = modal_forces(model, (1, steps, 3), kind=kind)
    state = model.rest_state()
    model.rollout(state, controls[:, :5], threads=1)  # warm-up
    start = time.perf_counter()
    out = model.rollout(state, controls, threads=1)
    wall = time.perf_counter() - start
    if out["diverged"].any():  # it skipped the rest of its steps: the rate would be wrong
        raise RuntimeError(f"the timed rollout diverged ({model.solver} solver)")
    return steps / wall


def thread_speedup(model, repeats: int = 5, kind: str = "random") -> tuple[float, float, float]:
    """Batched rollouts (64 x 100 steps) on 2 threads vs 1: the ratio of the best of
    ``repeats`` alternating wall times each, the 2-thread throughput in physics steps/s, and
    the CPU seconds the 2-thread run spent per CPU second of the 1-thread run (1.0: the
    workers do not slow each other down, so a wall ratio under 2 is the machine's noise)."""
    controls = modal_forces(model, (64, 100, 3), seed=1, kind=kind)
    state = model.rest_state()
    model.rollout(state, controls[:2, :5], threads=2)  # warm-up
    wall = {1: np.inf, 2: np.inf}
    cpu = {1: np.inf, 2: np.inf}
    for _ in range(repeats):
        for threads in (1, 2):
            start, start_cpu = time.perf_counter(), time.process_time()
            out = model.rollout(state, controls, threads=threads)
            if out["diverged"].any():
                raise RuntimeError(f"{int(out['diverged'].sum())} batched rollouts diverged")
            wall[threads] = min(wall[threads], time.perf_counter() - start)
            cpu[threads] = min(cpu[threads], time.process_time() - start_cpu)
    steps = controls.shape[0] * controls.shape[1]
    return wall[1] / wall[2], steps / wall[2], cpu[2] / cpu[1]


def drop_error(robot, seconds: float) -> float:
    """Relative position error of the reduced model against full space over ``seconds`` of
    free flight under gravity, started with the three lowest deformation columns moving so
    that the body deforms by about 3% of its size (the motions B_r is built to carry)."""
    sub = build_subspace(robot, 20)
    model = build_reduced_model(robot, subspace=sub, contact="none")
    fem = robot.fem_model()
    fem.damping_beta = model.damping_beta
    size = float(np.ptp(robot.nodes, axis=0).max())
    qdot = np.zeros(sub.basis.shape[1])
    for j in range(3):  # the three lowest deformation columns, 6..8
        peak = np.abs(sub.deformation[:, j]).max() / sub.frequencies[j]  # displacement per unit
        qdot[6 + j] = 0.03 * size / (np.sqrt(3.0) * peak)
    q = np.zeros_like(qdot)
    state = cpp_sim.ReducedState(q, qdot, model.rest_state().impulses)
    x = model.positions(q)
    v = (sub.basis @ qdot).reshape(-1, 3)
    err = ref = 0.0
    m = fem.mass
    for _ in range(round(seconds / DT)):
        x, v = fem.step(x, v, DT)
        state, _ = model.step(state)
        xr = model.positions(state.q)
        rigid = robot.nodes + (m @ x - m @ robot.nodes) / m.sum()
        err += np.sum((xr - x) ** 2)
        ref += np.sum((x - rigid) ** 2)
    return float(np.sqrt(err / ref))


# One ladder for both simulators: each runs at the largest step that stays stable.
DT_LADDER = (0.02, 0.01, 0.005, 0.002, 0.001, 0.0005)


def reduced_sim_rate(robot, seconds: float) -> tuple[float, float]:
    """Largest stable dt of the reduced model (staggered contact) and its sim s / wall s."""
    for dt in DT_LADDER:
        model = build_reduced_model(robot, dt=dt, control_basis=np.eye(20)[:, :3])
        state = lifted(model, 0.05)
        zero = np.zeros(3)
        start = time.perf_counter()
        ok = True
        rms_limit = 10.0 * np.sqrt(model.total_mass)  # |qdot| = sqrt(mass) x RMS node speed
        for _ in range(round(seconds / dt)):
            state, info = model.step(state, zero)
            if info["diverged"] or np.linalg.norm(state.qdot) > rms_limit:
                ok = False
                break
        wall = time.perf_counter() - start
        if ok and model.positions(state.q)[:, 2].min() > -0.01:
            return dt, seconds / wall
    return float("nan"), float("nan")


def mujoco_sim_rate(robot, seconds: float) -> tuple[float, float, float] | None:
    """Largest stable dt of MuJoCo's flexcomp, its sim s / wall s and raw steps/s."""
    try:
        import mujoco
    except ImportError:
        return None
    # MuJoCo's default warning handler appends to MUJOCO_LOG.TXT in the working directory;
    # warnings are read from data.warning below instead.
    mujoco.set_mju_user_warning(lambda message: None)
    points = robot.nodes + np.array([0.0, 0.0, 0.05])
    for dt in DT_LADDER:
        xml = f"""<mujoco>
  <option timestep="{dt}" integrator="discrete" gravity="0 0 -9.81"/>
  <worldbody>
    <geom type="plane" size="10 10 0.1"/>
    <flexcomp name="robot" type="direct" dim="3" mass="{robot.mass}" radius="0.001"
      point="{" ".join(f"{p:.9g}" for p in points.ravel())}"
      element="{" ".join(str(i) for i in robot.tets.ravel())}">
      <elasticity young="{robot.youngs_modulus}" poisson="{robot.poisson_ratio}" damping="0.005"/>
      <contact condim="3" friction="0.8" selfcollide="none"/>
    </flexcomp>
  </worldbody>
</mujoco>"""
        model = mujoco.MjModel.from_xml_string(xml)
        data = mujoco.MjData(model)
        steps = round(seconds / dt)
        start = time.perf_counter()
        ok = True
        for _ in range(steps):
            mujoco.mj_step(model, data)
            # The reduced side's test, every step: the RMS over nodes of each node's speed
            # (the RMS of qvel's components is that over sqrt(3), a 17 m/s limit).
            speed = np.sqrt(np.mean(np.sum(data.qvel.reshape(-1, 3) ** 2, axis=1)))
            if not (np.all(np.isfinite(data.flexvert_xpos)) and speed <= 10.0):
                ok = False
                break
        wall = time.perf_counter() - start
        # A run in which MuJoCo itself warned (ill-conditioned flex solve, singular inertia,
        # bad accelerations) does not count as stable, even if it stayed finite.
        warned = any(w.number > 0 for w in data.warning)
        if ok and not warned and data.flexvert_xpos[:, 2].min() > -0.01:
            return dt, seconds / wall, steps / wall
    return None


def measure(
    name: str, full_steps: int, seconds: float, rounds: int = 3, kind: str = "random"
) -> dict:
    robot_name, task = BENCHMARKS[name]
    robot = ROBOTS[robot_name]()
    model = task_model(robot, task)
    reference = task_model(robot, task, solver="reference")
    penalty = task_model(robot, task, contact="penalty") if task == "walk" else None
    steps = round(seconds / DT)
    # Alternate full space and the reduced solvers, best of `rounds` each, so that machine
    # load hits them alike (more rounds: a steadier best on a busy machine). The penalty
    # ground too: timed once after the rounds, its one sample against the others' best read
    # penalty / fast 0.57-0.68 on one machine where best against best was 0.68.
    full = ref_rate = fast_rate = pen_rate = 0.0
    for _ in range(rounds):
        full_rate, full_newton = full_steps_per_s(robot, full_steps, gravity=task == "walk")
        full = max(full, full_rate)
        ref_rate = max(ref_rate, reduced_steps_per_s(reference, steps, kind))
        fast_rate = max(fast_rate, reduced_steps_per_s(model, steps, kind))
        if penalty is not None:
            pen_rate = max(pen_rate, reduced_steps_per_s(penalty, steps, kind))
    row = {
        "kernels": cpp_sim.kernel_instruction_set(),
        "robot": name,
        "nodes": robot.num_nodes,
        "tets": robot.num_tets,
        "contact": "none (drag)" if task == "swim" else model.contact,
        "actuation": kind,
        "full_steps_per_s": full,
        "full_newton_iterations": full_newton,
        "reference_steps_per_s": ref_rate,
        "reduced_steps_per_s": fast_rate,
        "fast_over_reference": fast_rate / ref_rate,
        "speedup": fast_rate / full,
    }
    row["penalty_steps_per_s"] = pen_rate if penalty is not None else None
    row["thread_speedup"], row["batched_rollout_steps_per_s"], row["thread_cpu_ratio"] = (
        thread_speedup(model, kind=kind)
    )
    row.update(
        mujoco_dt=None, mujoco_sim_rate=None, mujoco_steps_per_s=None,
        reduced_dt=None, reduced_sim_rate=None, vs_mujoco=None,
    )  # fmt: skip
    if task == "walk":
        mj = mujoco_sim_rate(robot, seconds)
        if mj is not None:
            ours_dt, ours_rate = reduced_sim_rate(robot, seconds)
            row.update(
                mujoco_dt=mj[0], mujoco_sim_rate=mj[1], mujoco_steps_per_s=mj[2],
                reduced_dt=ours_dt, reduced_sim_rate=ours_rate, vs_mujoco=ours_rate / mj[1],
            )  # fmt: skip
    row["drop_error_rel"] = drop_error(robot, seconds)
    return row


def mj_text(row: dict) -> str:
    if row["vs_mujoco"] is None:
        return "-"
    return f"{row['vs_mujoco']:.0f}x"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", action="store_true", help="one JSON object per line")
    parser.add_argument("--robots", nargs="*", default=list(BENCHMARKS), choices=list(BENCHMARKS))
    parser.add_argument("--seconds", type=float, default=1.0, help="simulated time per test")
    parser.add_argument("--full-steps", type=int, default=20, help="timed full-space steps")
    parser.add_argument(
        "--rounds", type=int, default=3,
        help="alternating timing rounds of full space and the reduced solvers and grounds "
        "(best of each)",
    )  # fmt: skip
    parser.add_argument(
        "--actuation", choices=KINDS, default="random",
        help="the reduced rollouts' modal forces: random each step, or a sinusoidal gait",
    )  # fmt: skip
    args = parser.parse_args()
    if not args.seconds >= 5 * DT or args.full_steps < 1:
        parser.error(f"--seconds must be >= {5 * DT} (5 steps) and --full-steps >= 1")
    if args.rounds < 1:
        parser.error(f"--rounds must be >= 1, got {args.rounds}")
    cols = ("full/s", "ref/s", "fast/s", "fast/ref", "speedup", "penalty/s", "batch2/s",
            "2thr/1thr", "cpu 2/1", "drop err", "vs MuJoCo")  # fmt: skip
    if not args.json:
        print(f"fast solver's dense kernels: {cpp_sim.kernel_instruction_set()}; "
              f"actuation: {args.actuation}")  # fmt: skip
        print(f"{'benchmark':<15} {'nodes':>5} " + " ".join(f"{c:>10}" for c in cols))
    for name in args.robots:
        r = measure(name, args.full_steps, args.seconds, args.rounds, args.actuation)
        if args.json:
            print(json.dumps(r), flush=True)
            continue
        pen = "-" if r["penalty_steps_per_s"] is None else f"{r['penalty_steps_per_s']:.0f}"
        print(
            f"{name:<15} {r['nodes']:>5} {r['full_steps_per_s']:>10.2f} "
            f"{r['reference_steps_per_s']:>10.0f} {r['reduced_steps_per_s']:>10.0f} "
            f"{r['fast_over_reference']:>9.1f}x {r['speedup']:>9.0f}x {pen:>10} "
            f"{r['batched_rollout_steps_per_s']:>10.0f} {r['thread_speedup']:>9.2f}x "
            f"{r['thread_cpu_ratio']:>10.2f} "
            f"{r['drop_error_rel']:>10.3f} {mj_text(r):>10}",
            flush=True,
        )
    if not args.json:
        print("columns = --json keys: full/s full_steps_per_s, ref/s reference_steps_per_s, "
              "fast/s reduced_steps_per_s, fast/ref fast_over_reference, speedup speedup, "
              "penalty/s penalty_steps_per_s, batch2/s batched_rollout_steps_per_s, "
              "2thr/1thr thread_speedup, cpu 2/1 thread_cpu_ratio, drop err drop_error_rel, "
              "vs MuJoCo vs_mujoco")  # fmt: skip
        if importlib.util.find_spec("mujoco") is None:
            print("vs MuJoCo: not measured, the optional mujoco package is not installed "
                  "(.venv/bin/pip install mujoco)")  # fmt: skip


if __name__ == "__main__":
    main()
