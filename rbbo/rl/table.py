"""The results: one row per RL checkpoint and per MPC basis, and their table.

:func:`_row` makes a row (keys: ``_COLUMNS``, the columns of ``baselines.csv``) from the
distances of the evaluation seeds; :func:`format_table` prints the rows as plain text or
markdown, with when each RL method first reached the MPC's distance (:func:`_reached`).
"""

from __future__ import annotations

import math

from .evaluation import t_interval

_COLUMNS = ["env", "method", "basis", "final", "env_steps", "physics_steps", "wall_s", "seeds",
            "distance_m", "ci95_m", "distance_bl", "ci95_bl"]  # fmt: skip


def _row(env_id, method, basis, final, env_steps, physics, wall, distances, body) -> dict:
    mean, half = t_interval(distances)
    return {"env": env_id, "method": method, "basis": basis, "final": final,
            "env_steps": env_steps, "physics_steps": physics, "wall_s": wall,
            "seeds": len(distances), "distance_m": mean, "ci95_m": half,
            "distance_bl": mean / body, "ci95_bl": half / body}  # fmt: skip


def _reached(rows: list[dict]) -> list[str]:
    """Per RL method and basis: the first checkpoint at which it matched the MPC."""
    lines = []
    for ref in (r for r in rows if r["method"] == "mppi"):
        for algo in dict.fromkeys(r["method"] for r in rows if r["method"] != "mppi"):
            mine = [r for r in rows if r["method"] == algo and r["basis"] == ref["basis"]]
            hit = next((r for r in mine if r["distance_m"] >= ref["distance_m"]), None)
            goal = f"the MPC's {ref['distance_m']:.3f} m"
            lines.append(f"{algo} ({ref['basis']}) reached {goal} at {hit['env_steps']} env "
                         "steps" if hit else f"{algo} ({ref['basis']}) did not reach {goal} "
                         f"within {max(r['env_steps'] for r in mine)} env steps")  # fmt: skip
    return lines


def format_table(rows: list[dict], *, markdown: bool = False) -> str:
    """The baselines as a table (plain text: final rows only; markdown: every checkpoint),
    followed by when each RL method first reached the MPC's distance."""

    def pm(mean, half, spec):
        sd = spec.lstrip("+")
        return f"{mean:{spec}} ± {half:{sd}}" if math.isfinite(half) else f"{mean:{spec}}"

    header = ["env", "method", "basis", "env steps", "physics steps", "wall time",
              "distance (m)", "distance (BL)"]  # fmt: skip
    table = [header]
    for r in rows if markdown else [r for r in rows if r["final"]]:
        table.append([r["env"].split("/")[-1], r["method"], r["basis"],
                      str(r["env_steps"]) if r["method"] != "mppi" else "-",
                      f"{round(r['physics_steps']):,}", f"{r['wall_s']:.1f} s",
                      pm(r["distance_m"], r["ci95_m"], "+.3f"),
                      pm(r["distance_bl"], r["ci95_bl"], "+.2f")])  # fmt: skip
    notes = ["RL: training cost; MPC: physics steps (planning + executed) and wall time per "
             "episode", *_reached(rows)]  # fmt: skip
    if markdown:
        text = ["| " + " | ".join(row) + " |" for row in table]
        text.insert(1, "|" + "---|" * len(header))
        return "\n".join(text + [""] + [f"- {n}" for n in notes])
    widths = [max(len(row[i]) for row in table) for i in range(len(header))]
    text = ["  ".join(c.rjust(w) for c, w in zip(row, widths, strict=True)) for row in table]
    text.insert(1, "  ".join("-" * w for w in widths))
    return "\n".join(text + notes)
