"""Table I measured again in a richer simulation space (stage "transfer").

RBBO searches B_c inside one simulation space (M = 20); a B_c can win there by exploiting
what those M modes cannot represent (the README's known limit: walking distances are not
converged in M). This stage carries R_init's and R*'s control spaces into the
``transfer_sim_dim``-mode model of the same robot with
:func:`softrom_gym.map_control_basis` (T B_c, T = B'^T M B: the same full-space actuation
field, exactly, since our simulation spaces nest) and measures both again on the run's fresh
seeds with the same MPC and episode. A gain that survives the richer model is less likely
the truncation's; one that vanishes was. The richer model is not converged either (distances
keep changing with M), so this is a robustness check, not the full-space answer.

Rows go to ``transfer.csv`` one measurement at a time (resumable), keyed by benchmark, basis
("identity" or "best") and M.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from .plan import ReproducePlan
from .tables import _interval, _num, basis_digest, compare_seeds, read_rows

__all__ = ["current_rows", "format_transfer_markdown", "measure_transfer", "transfer_rows"]

BASES = ("identity", "best")


def measure_transfer(out: Path, plan: ReproducePlan, benchmark: str, run_dir: Path,
                     log: Callable[[str], None]) -> Path:  # fmt: skip
    """Measure the identity and the best B_c of ``run_dir`` at M = ``plan.transfer_sim_dim``
    on the run's fresh seeds, appending to ``out / "transfer.csv"``."""
    import gymnasium as gym

    from softrom_gym import map_control_basis
    from softrom_gym.envs import SoftRobotEnv

    from ..optimizer import RBBO
    from ..store import RunDirectoryError
    from .runner import _append_row, _evaluate_seeds, _objective, _run_spec, _supersede
    from .stages import _has_failed_seed

    path = out / "transfer.csv"
    m_to = plan.transfer_sim_dim
    best_file = run_dir / "best_basis.npy"
    digest = basis_digest(np.load(best_file)) if best_file.exists() else ""
    # A best-B_c row of another B_c (the Table I run searched on under a larger budget) is
    # kept aside and measured again; rows without a digest predate it.
    moved = _supersede(path, lambda r: r["benchmark"] == benchmark and r["basis"] == "best"
                       and r.get("basis_digest", "") not in ("", digest))  # fmt: skip
    if moved:
        log(f"[transfer] {benchmark}: the best B_c changed since it was measured; the old "
            "row is in transfer-superseded.csv")  # fmt: skip
    # A row with a failed seed (a timeout, a crashed worker) was recorded as done: measured
    # again instead.
    failed = _supersede(path, lambda r: r["benchmark"] == benchmark and _has_failed_seed(r))
    if failed:
        log(f"[transfer] {benchmark}: {failed} rows with a failed seed moved to "
            "transfer-superseded.csv; measuring them again")  # fmt: skip
    done = {(r["benchmark"], r["basis"]) for r in read_rows(path) if int(r["M"]) == m_to}
    todo = [b for b in BASES if (benchmark, b) not in done]
    if not todo:
        return path
    opt = RBBO.resume(run_dir, read_only=True)
    assert opt.store is not None  # (resume opens the run's store)
    best = opt.store.best_basis()
    if best is None:
        raise RunDirectoryError(f"{run_dir} has no best basis yet: run its 'table' stage first")
    m_from, c = opt.config.sim_dim, opt.config.control_dim
    # map_control_basis reads B_r at M = m_from as built now: it must be the run's
    _objective(plan, benchmark, sim_dim=m_from).expect_simulation_space(
        _run_spec(opt).get("simulation_space")
    )
    bases = {"identity": np.eye(m_from)[:, :c], "best": np.asarray(best)}
    env = gym.make(plan.env_id(benchmark))
    unwrapped = env.unwrapped
    assert isinstance(unwrapped, SoftRobotEnv)  # (a softrom benchmark)
    robot = unwrapped.robot
    env.close()
    objective = _objective(plan, benchmark, sim_dim=m_to)
    seeds = opt.config.fresh_seeds
    for name in todo:
        mapped = map_control_basis(bases[name], robot, m_from, m_to)
        start = time.perf_counter()
        values = _evaluate_seeds(plan, objective, mapped, seeds, log)
        if any(np.isnan(values)):
            log(f"[transfer] {benchmark} {name} B_c at M = {m_to}: "
                f"{int(np.isnan(values).sum())} of {len(values)} seeds failed (their errors "
                "above); not recorded, measured again by the next "
                "session")  # fmt: skip
            continue
        _append_row(path, {"benchmark": benchmark, "basis": name, "M": m_to,
                           "R_mean": float(np.mean(values)),
                           "R_seeds": " ".join(f"{v:.6g}" for v in values),
                           "seeds": " ".join(str(s) for s in seeds),
                           "wall_s": time.perf_counter() - start,
                           "run": str(run_dir),
                           "basis_digest": basis_digest(bases[name])})  # fmt: skip
        log(f"[transfer] {benchmark} {name} B_c at M = {m_to}: R = {np.mean(values):.4g}")
    return path


def _seeds(row: dict[str, str]) -> list[float]:
    return [float(v) for v in row["R_seeds"].split()]


def current_rows(out: Path, sim_dim: int) -> list[dict[str, str]]:
    """transfer.csv's rows at M = ``sim_dim`` that still measure Table I's bases: a "best" row
    of a B_c its run no longer recommends (it searched on since) is left out, as the stage
    will measure the new one (rows without a digest predate it and are kept)."""
    digests: dict[str, str] = {}
    rows = []
    for r in read_rows(out / "transfer.csv"):
        if int(r["M"]) != sim_dim:
            continue
        if r["basis"] == "best" and r.get("basis_digest", ""):
            bench = r["benchmark"]
            if bench not in digests:
                best = out / "runs" / ReproducePlan.table_run(bench) / "best_basis.npy"
                digests[bench] = basis_digest(np.load(best)) if best.exists() else ""
            if digests[bench] not in ("", r["basis_digest"]):
                continue
        rows.append(r)
    return rows


def transfer_rows(out: Path, table: list[dict[str, Any]], sim_dim: int) -> list[dict[str, Any]]:
    """Per Table I row with both measurements at M = ``sim_dim``: R_init and R* there (mean,
    95 % half-width), the improvement, the paired gain and whether the intervals are apart."""
    measured = {(r["benchmark"], r["basis"]): _seeds(r) for r in current_rows(out, sim_dim)}
    rows = []
    for t in table:
        init, best = measured.get((t["benchmark"], "identity")), measured.get((t["benchmark"],
                                                                               "best"))  # fmt: skip
        if init is None or best is None:
            continue
        rows.append({"benchmark": t["benchmark"], "M_from": t["M"], "M": sim_dim,
                     "R_init_from": t["R_init"], "R_star_from": t["R_star"],
                     "improvement_from_pct": t["improvement_pct"],
                     **compare_seeds(init, best)})  # fmt: skip
    return rows


def format_transfer_markdown(rows: list[dict[str, Any]]) -> str:
    """The transfer table: Table I's improvement beside the same bases measured at M'."""
    m_from, m_to = rows[0]["M_from"], rows[0]["M"]
    head = ["benchmark", f"improvement at M = {m_from}", f"R_init at M = {m_to}",
            f"R* at M = {m_to}", f"improvement at M = {m_to}", "R* - R_init (paired)",
            "apart"]  # fmt: skip
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        cells = [r["benchmark"], _num(r["improvement_from_pct"], "+.1f") + " %",
                 _interval(r["R_init"], r["R_init_ci95"]), _interval(r["R_star"], r["R_star_ci95"]),
                 _num(r["improvement_pct"], "+.1f") + " %", _interval(r["delta"], r["delta_ci95"]),
                 "yes" if r["apart"] else "no"]  # fmt: skip
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)
