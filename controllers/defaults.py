"""Per-benchmark planner defaults: one table, a reason for every value.

Times are env steps of the 40 Hz control period (dt = 0.025 s): 20 steps = 0.5 s. An env made
with another control period (``frame_skip`` or ``dt``) gets the same times in seconds: pass
its ``dt`` to :func:`planner_for` or :func:`default_planner`.
"""

from __future__ import annotations

import math
import numbers
from typing import Any

from .cost import CostWeights
from .gauss_newton import GaussNewtonSettings, GaussNewtonShooting
from .mppi import MPPI, MPPISettings
from .planner import Planner, PlannerSettings
from .registry import PlannerEntry, _PlannerTable, register_planner, resolve_planner

__all__ = [
    "DEFAULTS",
    "GENERIC",
    "PLANNERS",
    "TUNED_DT",
    "default_planner",
    "default_settings",
    "has_defaults",
    "parse_changes",
    "planner_for",
]

# The control period (s) the times below are tuned for: the envs' default frame_skip = 5 at
# dt = 1/200 s.
TUNED_DT = 0.025

# {name: (planner class, settings class)} of the registered planners, as a read-only view that
# follows controllers.register_planner (an import path package.module:ClassName is accepted
# besides them: controllers.resolve_planner)
PLANNERS = _PlannerTable()

# Shared by every benchmark, with why:
_COMMON: dict[str, Any] = {
    # A gait, not a lean: the plan is one cycle of a periodic spline, repeated over the
    # horizon, and R counts only the cycles after a lead-in cycle (window = horizon - period,
    # set per benchmark below), where a pose held after a first lunge gains nothing. The warm
    # start then carries the gait by advancing its phase.
    "knots": 6,  # per cycle: a sinusoid or a square-ish wave; each knot costs GN C rollouts
    "kind": "cubic",  # smooth controls (C1) that still pass through their knots
    "gait_seed": True,  # start from the best sinusoid at the cycle's frequency, not from rest
    # Walking needs the full bound (every walker's best open-loop gait has A = 1; at 0.5
    # none moves): seeds at the bound and beyond it (clipped: a square-ish wave).
    "seed_amplitudes": (1.0, 1.5),
    "seed_horizon": 60,  # 1.5 s from rest: past the first lunge
    "threads": 2,  # the project's machines have 2 cores
}
# Λ (metres): keep the body upright and on course without outweighing the distance, which
# is a few cm per second: 0.1 rad held 1 s costs 1 mm, a 0.1 m side offset 1 mm, full
# effort on three modes 3 mm; a step lost to a divergence costs 1 m, more than any gait gains.
_WEIGHTS = CostWeights(orientation=0.1, lateral=0.1, effort=1e-3, divergence=1.0)

# Per benchmark, from the open-loop grid (benchmarks/baselines_open_loop.py, distance
# t = 2..10 s): the gait cycle (period, env steps) is the grid's best frequency, which is
# sharply better than its neighbours (a resonance of the body: CrossSwim 2 Hz 2.2 body
# lengths vs 0.5 at 1 Hz); the horizon covers at least 1 s and a lead-in cycle before the
# scored window (window = horizon - one period); replanning every one to three cycles,
# because the plan is a whole gait and the phase advance keeps it in step between replans.
# Where replanning less often kept both planners above their targets (3 seeds, t = 2..10 s)
# it is the default: it divides the cost of a simulated second, so MPC runs in real time on
# 2 cores and an RBBO evaluation costs less. MPPI, replanning every cycle -> less often:
# CrossWalk 0.83 -> 0.64 BL (every 2nd), BeamWalk 1.53 -> 1.50 (2nd), 1.47 (3rd), 1.46
# (4th), TripodWalk 1.54 -> 1.34 (2nd); the quadruped fell from 0.54 to 0.21 BL (2nd), so it
# replans every cycle.
# The figures in these comments were measured before cache version 4 fixed the sign of each
# mode of B_r, so their phases name the old modes. The same grid at commit 819502f
# (`baselines_open_loop.py --seeds 0 1 2`) finds: CrossSwim 2 Hz 0/120/240, 2.13 BL; CrossWalk
# 2 Hz 0/180/180, 0.21; BeamWalk 4 Hz 0/0/180, 0.89; QuadrupedWalk 2 Hz 0/240/120, 0.17 (its
# 4 Hz cycle below was the old grid's best); TripodWalk 3 Hz 0/180/180, 0.56. The defaults are
# kept: with them both planners clear those bars on every benchmark by more than their spread
# over seeds (README's table).
DEFAULTS: dict[str, dict[str, Any]] = {
    # best open loop: 2 Hz travelling wave, 2.21 BL; replans every cycle (already 2.8x real
    # time).
    "CrossSwim-v0": {"period": 20, "horizon": 40, "window": 20, "replan_every": 20},
    # best open loop: 2 Hz standing wave (0/180/180), 0.25 BL
    "CrossWalk-v0": {"period": 20, "horizon": 40, "window": 20, "replan_every": 40},
    # best open loop: 4 Hz, all modes in phase, 1.01 BL
    "BeamWalk-v0": {"period": 10, "horizon": 40, "window": 30, "replan_every": 30},
    # best open loop: 4 Hz standing wave (0/180/0), 0.15 BL
    "QuadrupedWalk-v0": {"period": 10, "horizon": 40, "window": 30, "replan_every": 10},
    # best open loop: 3 Hz standing wave (0/180/180), 0.97 BL; 40/3 steps per cycle. The
    # tripod's first lunge lasts past 1.5 s: a seed scored over 60 steps picked a 0/0/0 lunge
    # at A = 1.5 (0.09 BL on seed 0), over 120 steps the standing wave (1.53 BL).
    "TripodWalk-v0": {
        "period": 40 / 3,
        "horizon": 40,
        "window": 27,
        "replan_every": 27,
        "seed_horizon": 120,
    },
}
# Per planner:
_PLANNER: dict[str, dict[str, Any]] = {
    # 16 samples, one round: the most a 2-core replan affords; noise 0.15 of the bound around
    # a gait explores its shape without breaking it; temperature 0.1 of the spread.
    "mppi": {"samples": 16, "noise": 0.15, "temperature": 0.1, "iterations": 1},
    # One iteration per replan (K C + 1 + 4 + 8 rollouts: the differences, the line search
    # and the exploration candidates; 31 for K = 6, C = 3). fd_step 0.1 of the bound: contact
    # makes R kinked in the knots (a foot lands a step earlier or later), and a difference
    # smaller than the kinks' spacing measures one kink, not the slope of the gait. On
    # CrossWalk (t = 2..10 s) fd_step 0.02 walked 0.36 BL (mean of 3 seeds); on seed 0,
    # 0.05 walked 0.49 BL and 0.1 walked 0.60 BL. 8 exploration candidates (noise 0.15, as
    # MPPI's) in the line search's rollout: without them GN kept the seed gait's basin on the
    # quadruped (0.14 BL) and the tripod (0.38 BL); with them 1.52 and 1.05 BL. Tried and
    # dropped on those two (mean of 3 seeds): line-search multipliers 1..1000 (0.03, 1.06),
    # a 0.1 trust region (0.16, 0.89), a 2 s horizon (0.99, 0.88).
    "gn": {"iterations": 1, "fd_step": 0.1, "damping": 0.01, "explore": 8},
}


def _benchmark(env_id: str) -> str:
    if not isinstance(env_id, str):
        raise TypeError(f"env_id must be a str (e.g. 'softrom_gym/CrossWalk-v0'), got {env_id!r}")
    name = env_id.split("/")[-1].split(":")[-1]
    # An id without its version is the latest one, as gym.make reads it (every benchmark has
    # one version): "softrom_gym/CrossWalk" is CrossWalk-v0, and its tuned planner.
    versioned = [b for b in DEFAULTS if b.rsplit("-v", 1)[0] == name]
    if name not in DEFAULTS and len(versioned) == 1:
        name = versioned[0]
    if name not in DEFAULTS:
        raise ValueError(f"no defaults for {env_id!r}; benchmarks: {sorted(DEFAULTS)} (for a "
                         "robot of your own, controllers.planner_for(env_id, planner) takes "
                         "the shared defaults)")  # fmt: skip
    return name


def default_settings(
    env_id: str, planner: str | PlannerEntry, *, dt: float | None = None
) -> tuple[PlannerSettings, int]:
    """The default settings of ``planner`` ("mppi", "gn", another registered name or an
    import path ``package.module:ClassName``, as in :func:`default_planner`) on a benchmark,
    and its replan interval (env steps); ``dt`` as in :func:`default_planner`."""
    entry = resolve_planner(planner)
    return _settings(entry, DEFAULTS[_benchmark(env_id)], dt, {})


def _settings(
    entry: PlannerEntry, row: dict[str, Any], dt: float | None, changes: dict[str, Any]
) -> tuple[PlannerSettings, int]:
    """The settings of a planner from a table row, its times in env steps of ``dt``, and its
    replan interval; ``changes`` (env steps of ``dt``) applied. Every planner, registered or
    shipped, plans the row's gait with the shared objective; ``entry.defaults`` set its own
    settings."""
    times = _rescaled({**_COMMON, **row}, dt, changes)
    replan_every = times.pop("replan_every")
    settings = entry.settings_class(**times, **entry.defaults, weights=_WEIGHTS)
    return _changed(settings, changes), replan_every


def _rescaled(row: dict[str, Any], dt: float | None, changes: dict[str, Any]) -> dict[str, Any]:
    """``row`` with its times (env steps of :data:`TUNED_DT`) in env steps of ``dt``: the same
    seconds, whole steps where the planner needs them."""
    if dt is None:
        return dict(row)
    dt = _control_period(dt)
    if math.isclose(dt, TUNED_DT, rel_tol=1e-9):
        return dict(row)
    f = TUNED_DT / dt
    out = dict(row, period=row["period"] * f)
    for key in ("horizon", "seed_horizon", "replan_every"):
        out[key] = max(1, round(row[key] * f))
    out["window"] = min(out["horizon"], max(1, round(row["window"] * f)))
    if "knots" not in changes and "period" not in changes and out["period"] < out["knots"]:
        # a cycle of fewer env steps than knots: one knot per step, down to two a cycle
        # (the Nyquist rate of the control)
        if out["period"] < 2:
            raise ValueError(
                f"at a control period of {dt:g} s the default gait cycle "
                f"({row['period'] * TUNED_DT:g} s) is {out['period']:.3g} env steps, fewer than "
                "two: give period (and knots) yourself, or a shorter control period "
                "(frame_skip, dt)"
            )
        out["knots"] = math.floor(out["period"])
    if row.get("seed_periods") and "seed_periods" not in changes:
        # the other cycles the gait seed tries, in the env's steps; those shorter than the
        # knots cannot be planned at this control period
        out["seed_periods"] = tuple(p * f for p in row["seed_periods"] if p * f >= out["knots"])
    return out


def _control_period(dt: Any) -> float:
    """``dt`` (None: :data:`TUNED_DT`) as a float, or a ValueError naming it."""
    if dt is None:
        return TUNED_DT
    if (
        isinstance(dt, bool)
        or not isinstance(dt, numbers.Real)
        or not math.isfinite(dt)
        or dt <= 0  # (numbers.Real declares <= and <, not >)
    ):
        raise ValueError(f"dt (the env's control period, s) must be a positive number, got {dt!r}")
    return float(dt)


def default_planner(
    env_id: str, planner: str | PlannerEntry, *, dt: float | None = None, **changes: Any
) -> tuple[Planner, int]:
    """A planner with the benchmark's defaults (``changes`` override settings) and its replan
    interval.

    ``planner`` is "mppi", "gn", a name given to :func:`controllers.register_planner`, or an
    import path ``package.module:ClassName`` of a :class:`~controllers.Planner` subclass
    (:func:`controllers.resolve_planner`; or the :class:`~controllers.PlannerEntry` it gives, or
    :func:`controllers.planner_from_source`). Every planner plans the benchmark's gait with the
    shared objective (its row of :data:`DEFAULTS`); a registered planner's own settings take
    the tuned ``defaults`` it was registered with, an import path's its settings class's own.

    Times (horizon, period, window, seed_horizon, the replan interval) are tuned in env steps
    of the benchmarks' 40 Hz control period (:data:`TUNED_DT`). ``dt``, the env's control
    period in seconds (``env.get_wrapper_attr("dt")``), keeps them the same in seconds for an
    env made with another ``frame_skip`` or ``dt``; None takes 0.025 s. The planner's
    ``reset`` refuses an env with another control period. ``changes`` are in env steps of the
    env. Rollouts run on 2 threads (the benchmarks' machines have 2 cores, and
    ``rbbo`` runs one planner per worker process): ``threads=None`` uses every CPU of this
    process's affinity.
    """
    entry = resolve_planner(planner)
    settings, replan_every = _settings(entry, DEFAULTS[_benchmark(env_id)], dt, changes)
    return entry.planner_class(settings, dt=_control_period(dt)), replan_every


def _changed(settings: PlannerSettings, changes: dict[str, Any]) -> PlannerSettings:
    """``settings`` with ``changes``; a horizon shorter than the default window (which the
    user did not set) is named as such, not as "window exceeds the horizon"."""
    horizon = changes.get("horizon")
    if (
        "window" not in changes
        and isinstance(horizon, int)
        and horizon >= 1  # (below 1 the settings name the horizon itself)
        and settings.window is not None
        and horizon < settings.window
    ):
        raise ValueError(f"horizon = {horizon!r} is shorter than the default window "
                         f"({settings.window} env steps, over which R is counted): give "
                         "window too (window=None for the whole horizon; on a command "
                         "line --mpc window=none, or python -m controllers --window "
                         "all)")  # fmt: skip
    knots = changes.get("knots")
    if "seed_periods" not in changes and isinstance(knots, int) and settings.seed_periods:
        # the defaults' other gait cycles shorter than the knots asked for cannot be planned:
        # dropped, as at another control period (not an error naming a setting not given)
        kept = tuple(p for p in settings.seed_periods if p >= knots)
        changes = {**changes, "seed_periods": kept}
    return settings.replace(**changes) if changes else settings


def parse_changes(text: str) -> dict[str, Any]:
    """Planner setting overrides as a command line gives them (``--mpc`` of ``python -m
    controllers``, ``rbbo optimize`` and ``rbbo reproduce``): ``'horizon=8,window=none'`` ->
    ``{'horizon': 8, 'window': None}``. Values are ints, floats, true / false / none,
    colon-separated numbers as a tuple (``noise=0.2:0.1:0.05``, one per control dimension;
    ``seed_amplitudes=0.5:1``; a setting that takes a tuple reads one number as a tuple of one,
    ``seed_periods=10``), else strings; the settings name a wrong key or value when the
    planner is made. An argparse ``type`` (a bad item raises ``argparse.ArgumentTypeError``)."""
    import argparse

    out: dict[str, Any] = {}
    for item in filter(None, text.split(",")):
        key, sep, value = item.partition("=")
        if not sep or not key.strip().isidentifier():
            raise argparse.ArgumentTypeError(f"expected key=value pairs, got {item!r}")
        out[key.strip()] = _setting_value(value.strip())
    return out


def _setting_value(text: str) -> Any:
    if ":" in text:
        try:  # (a comma would end the item: --mpc's items are comma-separated)
            return tuple(float(part) for part in text.split(":"))
        except ValueError:
            return text
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    return {"true": True, "false": False, "none": None}.get(text.lower(), text)


def has_defaults(env_id: str) -> bool:
    """Whether ``env_id`` is a benchmark with tuned planner defaults (:data:`DEFAULTS`)."""
    try:
        _benchmark(env_id)
    except ValueError:
        return False
    return True


# A robot of your own (no tuned row): the benchmarks' shared settings around a 2 Hz gait cycle
# (the swimmer's and the cross's resonance; the beam and the quadruped walk at 4 Hz, the
# tripod at 3), replanning every 0.5 s. Measured with MPPI on SoftRobot-v0 (the benchmark
# robots as if they were a user's, t = 2..10 s, body lengths, seeds 0 1 2), against the
# library settings replanning every env step (seeds 0 and 1): beam 0.92 / 0.91 / 0.98 against
# 0.09 / 0.11, quadruped 0.21 / 0.16 / 0.26 against 0.08, cross swimming 2.72 / 2.84 / 2.79
# against 0.53 / 0.34, tripod 0.22 / 0.05 / 0.16 against 0.35 / 0.34 (its lunge outlasts a
# 1.5 s seed); at a twentieth of the cost (3-6 s of wall time a 10 s episode against 46-93 s).
# The gait seed also tries 3 and 4 Hz cycles (the tripod's and the beam's resonances) and the
# plan keeps the best: `benchmarks/check_generic_planner.py` (MPPI, seeds 0-2, body lengths,
# 2 Hz only -> with the choice) beam 0.92 / 0.91 / 0.98 -> 1.46 / 1.42 / 1.44, tripod
# 0.22 / 0.05 / 0.16 -> 1.23 / 1.03 / 0.12, quadruped and cross swimming unchanged (2 Hz
# stays their best seed: 0.21 / 0.16 / 0.26 and 2.72 / 2.84 / 2.79).
GENERIC: dict[str, Any] = {"period": 20, "horizon": 40, "window": 20, "replan_every": 20,
                           "seed_periods": (40 / 3, 10)}  # fmt: skip


def planner_for(
    env_id: str, planner: str | PlannerEntry, *, dt: float | None = None, **changes: Any
) -> tuple[Planner, int]:
    """The benchmark's tuned planner (:func:`default_planner`) where ``env_id`` has defaults;
    elsewhere (a robot of your own) the shared defaults, whose gait seed picks a 2, 3 or 4 Hz
    cycle (:data:`GENERIC`),
    ``changes`` applied. ``dt`` is the env's control period, s, as in :func:`default_planner`.
    Returns the planner and its replan interval (env steps)."""
    entry = resolve_planner(planner)
    row = DEFAULTS[_benchmark(env_id)] if has_defaults(env_id) else GENERIC
    settings, replan_every = _settings(entry, row, dt, changes)
    return entry.planner_class(settings, dt=_control_period(dt)), replan_every


# (last: register_planner checks their defaults against the shared rows above)
register_planner("mppi", MPPI, MPPISettings, defaults=_PLANNER["mppi"])
register_planner("gn", GaussNewtonShooting, GaussNewtonSettings, defaults=_PLANNER["gn"])
