"""Does a gait's distance converge in M? Open-loop sinusoids in simulation spaces of growing M.

For each benchmark, every sinusoid of the grid (``controllers.gait_grid``, identity basis,
C = 3) runs open loop for ``--seconds`` in a simulation space of each ``--sim-dims``; the first
modes of B_r are the same in every space (checked), so the same actions are the same forces.
Printed: the three best gaits at the first M, and their distance (body lengths, from
``--start``) at every M, with the trained cubature and with ``forces="exact"`` (every
tetrahedron), which separates the truncation of B_r from the cubature's error.

    python benchmarks/check_m_convergence.py [ENV_ID ...] [--sim-dims 20 40] [--forces cubature]
        [--full-space [--actuation-frame world|body]]

``--full-space`` adds the limit M -> 3N: the same gaits, forces and start in
``softrom_gym.full_space.FullSpaceModel`` (the reduced step, contact and drag with B_r = I).
The actuation there is applied as the reduced model applies it (world-fixed in the linear
frame, turning with the body and torque-free in the floating one: ``FullSpaceModel``'s
``actuation_frame``) unless ``--actuation-frame`` names one.
"""

from __future__ import annotations

import argparse

import gymnasium as gym
import numpy as np

import softrom_gym  # noqa: F401  (registers the envs)
from controllers.gaits import gait_grid
from softrom_gym.full_space import FullSpaceModel
from softrom_gym.rom import build_reduced_model

IDS = ["softrom_gym/CrossSwim-v0", "softrom_gym/CrossWalk-v0", "softrom_gym/BeamWalk-v0"]


def distances(env_id: str, m: int, forces: str, gaits: list, seconds: float, start: float,
              seed: int) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """Body lengths travelled by each gait from ``start``, and B_r."""
    env = gym.make(env_id, sim_dim=m)
    u = env.unwrapped
    if forces == "exact":
        settings = {"dt": float(u.model.dt), "direction": u.direction}
        if u.task == "swim":
            settings.update(contact="none", gravity=[0.0, 0.0, 0.0],
                            fluid_density=float(u.model.fluid_density))  # fmt: skip
        else:
            settings.update(contact=u.model.contact, friction=float(u.model.friction))
        u.model = build_reduced_model(u.robot, m, forces="exact", subspace=u.subspace,
                                      control_basis=u.control_basis, **settings)  # fmt: skip
    env.reset(seed=seed)
    steps, first = round(seconds / u.dt), round(start / u.dt)
    controls = np.stack([g.controls(steps, u.dt, u.action_bound) for g in gaits])
    out = u.rollout(u.get_state(), controls)
    moved = (out["com"][:, -1] - out["com"][:, first - 1]) @ u.direction / u.body_length
    basis = np.asarray(u.subspace.basis)
    env.close()
    return np.where(out["diverged"], np.nan, moved), basis


def full_space_distances(env_id: str, m: int, gaits: list, seconds: float, start: float,
                         seed: int, actuation_frame: str | None = None) -> np.ndarray:  # fmt: skip
    """Body lengths travelled by each gait in the full space (``FullSpaceModel``: the same
    step, contact and drag with B_r = I), from the M-space env's reset state, the same
    forces (fixed in the world, or following the body: ``actuation_frame``)."""
    env = gym.make(env_id, sim_dim=m)
    u = env.unwrapped
    env.reset(seed=seed)
    basis = np.asarray(u.subspace.basis)
    model = FullSpaceModel.matching(u.model, u.robot, basis, actuation_frame=actuation_frame)
    start_state = model.state_from_reduced(basis, u.get_state(), model=u.model)
    steps, first = round(seconds / u.dt), round(start / u.dt)
    k = u.frame_skip
    moved = []
    for gait in gaits:
        controls = np.clip(gait.controls(steps, u.dt, u.action_bound), -u.action_bound,
                           u.action_bound).astype(np.float32).astype(float)  # fmt: skip
        out = model.rollout(start_state, np.repeat(controls, k, axis=0), progress=True)
        com = out["com"][k - 1 :: k]  # after each env step
        moved.append((com[-1] - com[first - 1]) @ u.direction / u.body_length)
    env.close()
    return np.array(moved)


def outside(small: np.ndarray, large: np.ndarray, mass: np.ndarray) -> float:
    """Largest mass-norm of a column of ``small`` outside span(``large``) (mass-orthonormal
    bases: 0 when the smaller simulation space lies inside the larger)."""
    projected = large @ (large.T @ (mass[:, None] * small))
    return float(np.sqrt(np.sum(mass[:, None] * (small - projected) ** 2, axis=0)).max())


def main(argv: list[str] | None = None) -> list[dict]:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("env_ids", nargs="*", default=IDS)
    p.add_argument("--sim-dims", type=int, nargs="+", default=[20, 40])
    p.add_argument("--frequencies", type=float, nargs="+", default=[1.0, 2.0, 3.0, 4.0])
    p.add_argument("--amplitudes", type=float, nargs="+", default=[1.0])
    p.add_argument("--seconds", type=float, default=10.0)
    p.add_argument("--start", type=float, default=2.0)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--forces", nargs="+", choices=["cubature", "exact"],
                   default=["cubature", "exact"],
                   help="force models (exact, every tetrahedron, is slow at large M)")  # fmt: skip
    p.add_argument("--full-space", action="store_true",
                   help="also run the three best gaits in the full space (FullSpaceModel; "
                        "slow: the beam's three took 21 min on 2 shared cores)")  # fmt: skip
    p.add_argument("--actuation-frame", choices=["world", "body"], default=None,
                   help="--full-space's actuation: fixed in the world, or turning with the "
                        "body, torque-free (default: as the reduced model applies it, world "
                        "in the linear frame, body in the floating one)")  # fmt: skip
    args = p.parse_args(argv)
    if args.seed < 0:  # gymnasium's reset refuses it, as a traceback
        p.error(f"--seed must be >= 0, got {args.seed}")
    if min(args.sim_dims) < 3:
        p.error(f"--sim-dims must be >= C = 3, got {args.sim_dims}")
    for env_id in args.env_ids:
        try:
            spec = gym.spec(env_id)
        except gym.error.Error as exc:
            p.error(str(exc))
        period = spec.kwargs.get("frame_skip", 5) * spec.kwargs.get("dt", 1.0 / 200.0)
        # --start must round to an env step after 0 and before the end (else the distance is
        # the end's position minus itself)
        if not 1 <= round(args.start / period) < round(args.seconds / period):
            p.error(
                f"--start {args.start:g} and --seconds {args.seconds:g} must round to at "
                f"least one control period ({period:g} s) from 0 and from each other"
            )
    gaits = gait_grid(3, tuple(args.frequencies), tuple(args.amplitudes))
    rows = []
    for env_id in args.env_ids:
        table: dict[tuple[int, str], np.ndarray] = {}
        first_basis = None
        probe = gym.make(env_id)
        mass = np.repeat(probe.unwrapped.robot.fem_model().mass, 3)
        probe.close()
        for m in args.sim_dims:
            for forces in args.forces:
                moved, basis = distances(env_id, m, forces, gaits, args.seconds, args.start,
                                         args.seed)  # fmt: skip
                table[(m, forces)] = moved
            if first_basis is None:
                first_basis = basis
                continue
            modes, reference = basis[:, :9], first_basis[:, :9]
            norms = np.linalg.norm(modes, axis=0) * np.linalg.norm(reference, axis=0)
            same = np.all(np.sum(modes * reference, axis=0) / norms > 1.0 - 1e-9)
            verdict = "the same" if same else "NOT the same (other forces)"
            print(f"{env_id}: M = {args.sim_dims[0]}'s space lies outside M = {m}'s by at "
                  f"most {outside(first_basis, basis, mass):.1e} (mass norm); rigid and first "
                  f"three modes {verdict}")  # fmt: skip
        first = table[(args.sim_dims[0], args.forces[0])]
        best = np.argsort(-np.nan_to_num(first, nan=-np.inf))[:3]
        full = None
        full_head = "  full-b" if args.actuation_frame == "body" else "    full"
        if args.full_space:
            full = full_space_distances(env_id, args.sim_dims[0], [gaits[j] for j in best],
                                        args.seconds, args.start, args.seed,
                                        args.actuation_frame)  # fmt: skip
        print(f"{env_id} (body lengths, t = {args.start:g}..{args.seconds:g} s, seed {args.seed})")
        names = {"cubature": "cub", "exact": "exact"}
        print(f"  {'gait':<28}" + "".join(
            f"  M={m:<3}" + "".join(f" {names[f]:>6}" for f in args.forces)
            for m in args.sim_dims) + (full_head if full is not None else ""))  # fmt: skip
        for i, j in enumerate(best):
            # each M's values under its header's force names, past its "  M=20 " label
            cells = "".join(" " * 7 + "".join(f" {table[(m, f)][j]:+6.3f}" for f in args.forces)
                            for m in args.sim_dims)  # fmt: skip
            if full is not None:
                cells += f"  {full[i]:+6.3f}"
            print(f"  {gaits[j].label():<28}{cells}", flush=True)
            rows.append({"env_id": env_id, "gait": gaits[j].label(),
                         **{f"M{m}_{f}": float(table[(m, f)][j]) for m in args.sim_dims
                            for f in args.forces},
                         **({} if full is None else {"full": float(full[i])})})  # fmt: skip
    return rows


if __name__ == "__main__":
    main()
