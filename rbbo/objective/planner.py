"""A planner's record: what a run, or a cached MPC result, records of the planner that made it.

:func:`planner_record` gives the planner's name, resolved settings and replan interval as
JSON, so that a change of the controllers' defaults cannot change a recorded objective unseen.
"""

from __future__ import annotations

from dataclasses import asdict, is_dataclass
from typing import Any


def planner_record(planner: Any, replan_every: int) -> dict[str, Any]:
    """A planner's name, resolved settings and replan interval as JSON (what a run, or a
    cached MPC result, records of the planner that made it; threads are left out: results do
    not depend on them)."""
    import json

    settings = getattr(planner, "settings", None)
    if is_dataclass(settings) and not isinstance(settings, type):
        record = getattr(settings, "record", None)
        if callable(record):  # controllers.PlannerSettings: less neutral new settings
            settings = record()
        else:
            settings = {k: v for k, v in asdict(settings).items() if k != "threads"}
    else:  # a planner of the user's own without dataclass settings: its name only
        settings = None
    name = getattr(planner, "name", type(planner).__name__)
    return json.loads(json.dumps({"name": name, "replan_every": replan_every,
                                  "settings": settings}, default=repr))  # fmt: skip
