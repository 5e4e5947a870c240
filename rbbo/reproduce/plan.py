"""What ``rbbo reproduce`` is set to run (:class:`ReproducePlan`, stored in reproduce.json)
and the paper's numbers it is compared with (:data:`PAPER_TABLE1`)."""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field, fields
from typing import Any

__all__ = ["BENCHMARKS", "PAPER_DIRECTIONS", "PAPER_TABLE1", "ReproducePlan", "check_sessions"]

BENCHMARKS = ("CrossSwim-v0", "CrossWalk-v0", "BeamWalk-v0", "QuadrupedWalk-v0", "TripodWalk-v0")

# The paper's Table I: robot, task, N, M, C, R_init, R*, improvement (%). Its R is the
# distance moved in its own units over its own episode, so only the improvement compares.
PAPER_TABLE1: dict[str, dict[str, Any]] = {
    "CrossSwim-v0": {"robot": "Cross", "task": "Swim", "N": 623, "M": 20, "C": 3,
                     "R_init": 2.24, "R_star": 5.43, "improvement_pct": 142.21},
    "CrossWalk-v0": {"robot": "Cross", "task": "Walk", "N": 623, "M": 20, "C": 3,
                     "R_init": 0.66, "R_star": 4.28, "improvement_pct": 544.32},
    "BeamWalk-v0": {"robot": "Beam", "task": "Walk", "N": 426, "M": 20, "C": 3,
                    "R_init": 1.34, "R_star": 4.52, "improvement_pct": 236.91},
    "QuadrupedWalk-v0": {"robot": "Quadruped", "task": "Walk", "N": 1315, "M": 20, "C": 3,
                         "R_init": 1.86, "R_star": 5.26, "improvement_pct": 183.35},
    "TripodWalk-v0": {"robot": "Tripod", "task": "Walk", "N": 1417, "M": 20, "C": 3,
                      "R_init": 2.16, "R_star": 3.03, "improvement_pct": 40.66},
}  # fmt: skip
# The paper's direction studies (its Figs. 8Dir and DirPerturb).
PAPER_DIRECTIONS = {"min_improvement_pct": 46.45, "max_improvement_pct": 853.50,
                    "fraction_within_10deg": 0.80}  # fmt: skip

_STAGES = ("table", "bo", "transfer", "directions", "perturbation", "studies", "rl")
# What each stage runs besides the optimisation budgets, as the launch line and --status say.
_BESIDES_BUDGETS = {"transfer": "the transfer", "perturbation": "the perturbation study",
                    "studies": "the studies of C", "rl": "the RL baselines"}  # fmt: skip


# What each session record of reproduce.json holds (runner.reproduce writes them), as the
# report and --status read it: a key's value must be one of these types where present.
_SESSION_TYPES: dict[str, tuple[type, ...]] = {
    "command": (str,), "source": (str, type(None)), "machine": (str, type(None)),
    "started": (int, float), "wall_s": (int, float), "budget_s": (int, float),
    "direction_budget_s": (int, float), "workers": (int,), "repeats": (int,),
    "deterministic": (bool,), "stages": (list,),
}  # fmt: skip


def check_sessions(document: dict[str, Any]) -> None:
    """Check the session records of reproduce.json's ``document`` (a missing list is an empty
    one, set in it), so that a hand-edited record is named, not a traceback of the report.

    Raises
    ------
    ValueError
        Naming the session (counted from 1) and the setting that is wrong.
    """
    sessions = document.setdefault("sessions", [])
    if not isinstance(sessions, list):
        raise ValueError(f"'sessions' must be a list, got {sessions!r}")
    for number, session in enumerate(sessions, start=1):
        if not isinstance(session, dict) or not isinstance(session.get("command"), str):
            raise ValueError(f"session {number} is not a record with its command: {session!r}")
        for key, types in _SESSION_TYPES.items():
            value = session.get(key)
            # (bool is an int: a true/false where a count or a time belongs is refused too)
            wrong = isinstance(value, bool) and bool not in types
            if key in session and (wrong or not isinstance(value, types)):
                raise ValueError(f"session {number}'s {key} is {value!r}")
        if "stages" in session and not all(isinstance(x, str) for x in session["stages"]):
            raise ValueError(f"session {number}'s stages is {session['stages']!r}")


def _short(env_id: str) -> str:
    return env_id.split("/")[-1]


@dataclass
class ReproducePlan:
    """The settings of one ``rbbo reproduce`` run.

    Attributes
    ----------
    benchmarks : list of str
        Benchmarks of Table I (short names, e.g. "CrossWalk-v0").
    budget_s : float
        Wall-time budget of each benchmark's Table I run (BOCA), seconds; the BO run of the
        BO-vs-BOCA figure gets the same budget.
    repeats : int
        Independent Table I runs per benchmark (stage "table"), run k seeded ``seed + k``.
        Run 0 is Table I's row and the basis the later stages use; with more, the report
        gives the improvement's spread over the runs. The BO run stays one per benchmark.
    iterations : int or None
        Optional cap on the evaluations of each optimisation run.
    workers : int
        Evaluation workers (processes) per run.
    deterministic : bool
        Tell each optimisation run's results in the order they were proposed (``rbbo
        optimize --deterministic``), so that with ``iterations`` set a run repeats bitwise on
        one install whatever order its workers finish in. Under a wall-time budget alone the
        number of evaluations still depends on the machine.
    executor : str
        "process" (default), "serial" or "ray".
    controller : str
        Low-level MPC: "mppi", "gn", another name registered with
        ``controllers.register_planner`` or an import path ``package.module:ClassName``.
    sim_dim, control_dim : int
        M and C.
    t_min, t_max, settle_time : float
        BOCA's shortest and full trajectory lengths and the time R is measured from (s).
    n_init : int
        Random initial points of each run besides the identity.
    confirm_seeds : int
        Fresh MPC seeds on which R_init and R* are measured (>= 2 for an interval; the issue
        asks for >= 5).
    seed : int
        Seeds every run.
    stages : list of str
        Which parts to run: "table" (Table I, BOCA), "bo" (the BO run beside each BOCA run),
        "transfer" (Table I's two bases measured again at M = ``transfer_sim_dim``),
        "directions", "perturbation", "studies", "rl".
    transfer_sim_dim : int
        M' of the transfer stage: a richer simulation space of the same robot (> M).
    direction_env : str
        The robot of the direction studies (the paper: the cross walking).
    directions : int
        Directions of the polar study, evenly spaced from d = +x.
    direction_budget_s : float
        Budget of each direction's RBBO run, seconds.
    perturbations_deg : list of float
        Offsets of the perturbation study, degrees (each is run at + and -).
    cost_cs, reward_cs : list of int
        C values of the cost-vs-C and reward-vs-C studies.
    study_seeds : int
        Seeds per C of the reward-vs-C study.
    study_seconds : float
        Episode length of the reward-vs-C study, seconds.
    rl_benchmarks : list of str
        Benchmarks of the RL baselines (stage "rl").
    rl_algos : list of str
        Stable-Baselines3 algorithms, among "ppo" and "sac".
    rl_steps : int or dict of str to int
        Env steps each RL method trains on each basis (identity and the Table I B_c): one
        number for every method, or one per method (``{"ppo": 500000, "sac": 100000}``).
    planner_kwargs : dict
        Overrides of the controller's default settings (e.g. a tiny horizon for a test).
    timeout_s : float
        Per-evaluation limit, seconds.
    """

    benchmarks: list[str] = field(default_factory=lambda: list(BENCHMARKS))
    budget_s: float = 45 * 60.0
    repeats: int = 1
    iterations: int | None = None
    workers: int = 2
    deterministic: bool = False
    executor: str = "process"
    controller: str = "mppi"
    sim_dim: int = 20
    control_dim: int = 3
    t_min: float = 4.0
    t_max: float = 10.0
    settle_time: float = 2.0
    n_init: int = 5
    confirm_seeds: int = 5
    seed: int = 0
    stages: list[str] = field(default_factory=lambda: list(_STAGES))
    transfer_sim_dim: int = 40
    direction_env: str = "CrossWalk-v0"
    directions: int = 8
    direction_budget_s: float = 15 * 60.0
    perturbations_deg: list[float] = field(default_factory=lambda: [5.0, 10.0, 20.0, 30.0])
    cost_cs: list[int] = field(default_factory=lambda: list(range(1, 21)))
    reward_cs: list[int] = field(default_factory=lambda: list(range(1, 11)))
    study_seeds: int = 3
    study_seconds: float = 10.0
    rl_benchmarks: list[str] = field(default_factory=lambda: ["CrossSwim-v0"])
    rl_algos: list[str] = field(default_factory=lambda: ["ppo", "sac"])
    rl_steps: int | dict[str, int] = 20_000
    planner_kwargs: dict[str, Any] = field(default_factory=dict)
    timeout_s: float = 1800.0

    def __post_init__(self) -> None:
        self.benchmarks = [_short(b) for b in self.benchmarks]
        unknown = [b for b in self.benchmarks if b not in BENCHMARKS]
        if unknown or not self.benchmarks:
            raise ValueError(f"unknown benchmark(s) {unknown or self.benchmarks}; "
                             f"valid: {', '.join(BENCHMARKS)}")  # fmt: skip
        self.rl_benchmarks = [_short(b) for b in self.rl_benchmarks]
        unknown = [b for b in self.rl_benchmarks if b not in BENCHMARKS]
        if unknown:
            raise ValueError(f"unknown RL benchmark(s) {unknown}; valid: {', '.join(BENCHMARKS)}")
        bad = [a for a in self.rl_algos if a not in ("ppo", "sac")]
        if bad or not self.rl_algos:
            raise ValueError(f"unknown RL algorithm(s) {bad or self.rl_algos}; valid: ppo, sac")
        from ..rl import steps_per_algo

        steps_per_algo(self.rl_steps, tuple(self.rl_algos))  # raises on a bad value, by name
        self.direction_env = _short(self.direction_env)
        if self.direction_env not in BENCHMARKS:
            raise ValueError(f"unknown direction_env {self.direction_env!r}")
        bad = [s for s in self.stages if s not in _STAGES]
        if bad:
            raise ValueError(f"unknown stage(s) {bad}; valid: {', '.join(_STAGES)}")
        for name in ("budget_s", "direction_budget_s", "t_max", "timeout_s", "study_seconds"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a positive number, got {value!r}")
        for name, low in (("workers", 1), ("sim_dim", 1), ("control_dim", 1), ("n_init", 0),
                          ("confirm_seeds", 2), ("seed", 0), ("directions", 1),
                          ("study_seeds", 1), ("repeats", 1)):  # fmt: skip
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < low:
                raise ValueError(f"{name} must be an integer >= {low}, got {value!r}")
        if not isinstance(self.deterministic, bool):
            raise ValueError(f"deterministic must be True or False, got {self.deterministic!r}")
        if self.iterations is not None and (not isinstance(self.iterations, int)
                                            or self.iterations < 1):  # fmt: skip
            raise ValueError(f"iterations must be an integer >= 1, got {self.iterations!r}")
        if not 0 <= self.settle_time < self.t_min < self.t_max:
            raise ValueError(f"need 0 <= settle_time < t_min < t_max, got {self.settle_time}, "
                             f"{self.t_min}, {self.t_max}")  # fmt: skip
        if "transfer" in self.stages and (
            isinstance(self.transfer_sim_dim, bool) or not isinstance(self.transfer_sim_dim, int)
            or self.transfer_sim_dim <= self.sim_dim
        ):  # fmt: skip
            raise ValueError(
                f"transfer_sim_dim must be an integer > sim_dim = {self.sim_dim}, got "
                f"{self.transfer_sim_dim!r} (or leave out stage 'transfer')"
            )
        if self.control_dim > self.sim_dim:
            raise ValueError(f"control_dim {self.control_dim} exceeds sim_dim {self.sim_dim}")
        # (RBBOConfig refuses C = M too, but only when a run starts: after reproduce.json)
        searching = [s for s in ("table", "bo", "directions") if s in self.stages]
        if self.control_dim == self.sim_dim and searching:
            raise ValueError(f"control_dim {self.control_dim} must be below sim_dim "
                             f"{self.sim_dim} for the RBBO runs of stage(s) "
                             f"{', '.join(searching)}: Gr(M, M) is one point, nothing to "
                             "search")  # fmt: skip
        if any(not (math.isfinite(p) and 0 < p < 180) for p in self.perturbations_deg):
            raise ValueError(f"perturbations must lie in (0, 180) degrees, got "
                             f"{self.perturbations_deg}")  # fmt: skip
        for name in ("cost_cs", "reward_cs"):
            cs = getattr(self, name)
            if not cs or any(not isinstance(c, int) or not 1 <= c <= self.sim_dim for c in cs):
                raise ValueError(f"{name} must be integers in 1..{self.sim_dim}, got {cs!r}")
        # A name or number given twice was measured (or trained, concurrently in one folder)
        # twice, and counted twice in the tables' averages.
        for name in ("benchmarks", "rl_benchmarks", "rl_algos", "perturbations_deg", "cost_cs",
                     "reward_cs"):  # fmt: skip
            values = getattr(self, name)
            repeated = sorted({v for v in values if values.count(v) > 1}, key=str)
            if repeated:
                raise ValueError(f"{name} lists {', '.join(map(str, repeated))} more than once")
        if "studies" in self.stages and not self.settle_time < self.study_seconds:
            # (the reward-vs-C study measures R from the settle time: it failed after the
            # stages before it, hours in, and the corrected value was then "other settings")
            raise ValueError(f"study_seconds {self.study_seconds} must exceed settle_time "
                             f"{self.settle_time}, from which the reward-vs-C study measures "
                             "R (or leave out stage 'studies')")  # fmt: skip
        if not isinstance(self.controller, str):
            raise TypeError(f"controller must be a planner name (str), got {self.controller!r}")
        if self.controller not in ("mppi", "gn"):
            import controllers

            # a registered name or an import path package.module:ClassName; an unknown one
            # is named with the registered names and the import-path form
            controllers.resolve_planner(self.controller)
        if self.executor not in ("process", "serial", "ray"):
            raise ValueError(f"unknown executor {self.executor!r}")

    # Settings that may change between sessions of one reproduction (how long and how wide
    # it runs); everything else defines the experiment and must stay the same. The RL
    # baselines train in their own folders, each continued from its latest checkpoint, so a
    # later session may train them longer or on more benchmarks; the repeated Table I runs
    # each have their own folder beside run 0, so a later session may add some.
    RESUMABLE = ("budget_s", "direction_budget_s", "iterations", "workers", "deterministic",
                 "executor", "repeats",
                 "timeout_s", "stages", "rl_benchmarks", "rl_algos", "rl_steps")  # fmt: skip

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> ReproducePlan:
        names = {f.name for f in fields(cls)}
        unknown = set(data) - names
        if unknown:
            raise ValueError(f"reproduce.json has unknown settings {sorted(unknown)}")
        return cls(**data)

    def differences(self, other: ReproducePlan) -> list[str]:
        """Names of the experiment-defining settings in which ``other`` differs."""
        # (as stored: reproduce.json holds a tuple setting, --mpc noise=0.3:0.1:0.1, as a
        # list, and the same command compared unequal to its own stored plan)
        mine = json.loads(json.dumps(self.to_dict()))
        theirs = json.loads(json.dumps(other.to_dict()))
        return [k for k in mine if k not in self.RESUMABLE and mine[k] != theirs[k]]

    def ordered_stages(self) -> list[str]:
        """The stages, each once, in the order they run."""
        return [s for s in _STAGES if s in self.stages]

    def on_workers(self) -> str:
        """'1 worker' / 'N workers', as the launch line and --status say it."""
        return f"{self.workers} worker" + ("s" if self.workers != 1 else "")

    def besides_budgets(self) -> str:
        """The work of the planned stages that no optimisation budget bounds, as a phrase
        ("the confirmations, the transfer and the RL baselines"), or "" when there is none."""
        stages = set(self.stages)
        parts = ["the confirmations"] if stages & {"table", "bo", "directions"} else []
        parts += [text for stage, text in _BESIDES_BUDGETS.items() if stage in stages]
        return ", ".join(parts[:-1]) + " and " + parts[-1] if len(parts) > 1 else "".join(parts)

    @staticmethod
    def table_run(benchmark: str, repeat: int = 0) -> str:
        """The folder name (under runs/) of ``benchmark``'s Table I run ``repeat``: run 0 is
        named as before repeats existed, so older reproductions read and resume unchanged."""
        return f"{_short(benchmark)}-boca" + (f"-run{repeat}" if repeat else "")

    def env_id(self, benchmark: str) -> str:
        return f"softrom_gym/{_short(benchmark)}"

    def direction_angles_deg(self) -> list[float]:
        return [360.0 * k / self.directions for k in range(self.directions)]
