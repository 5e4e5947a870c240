"""The settings every planner shares (:class:`PlannerSettings`, times in env steps) and the
checks the planners' own settings reuse; each refuses a bad value by name."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, fields
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from .cost import CostWeights
from .spline import KINDS

if TYPE_CHECKING:
    from typing_extensions import Self  # (typing's from Python 3.11)

__all__ = ["PlannerSettings"]


def _check_int(name: str, value: Any, low: int = 1) -> None:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < low:
        raise ValueError(f"{name} must be an integer >= {low}, got {value!r}")


def _check_positive(name: str, value: Any, allow_zero: bool = False) -> None:
    ok = isinstance(value, (int, float, np.number)) and not isinstance(value, bool)
    ok = ok and np.isfinite(value) and (value >= 0 if allow_zero else value > 0)
    if not ok:
        bound = ">= 0" if allow_zero else "> 0"
        raise ValueError(f"{name} must be a finite number {bound}, got {value!r}")


def _real_tuple(settings: Any, name: str) -> np.ndarray:
    """Settings field ``name``, a sequence of numbers (or one number: a sequence of one, which
    a command line's ``seed_periods=10`` gives), stored as a tuple (the settings stay hashable,
    as a frozen dataclass's should) and returned as an array; anything else named."""
    value = getattr(settings, name)
    if isinstance(value, (int, float, np.number)) and not isinstance(value, (bool, np.bool_)):
        value = (value,)
    try:
        numbers = tuple(float(v) for v in value if not isinstance(v, (bool, str)))
        ok = len(numbers) == len(value)
    except TypeError:
        ok = False
    if not ok:
        raise ValueError(f"{name} must be a sequence of numbers, got {value!r}")
    object.__setattr__(settings, name, numbers)
    return np.asarray(numbers)


@dataclass(frozen=True)
class PlannerSettings:
    """Settings shared by the planners (times in env steps of the control period dt).

    Attributes
    ----------
    horizon : int
        H, env steps planned ahead.
    knots : int
        K, spline knots per control dimension (over the horizon, or over one period).
    period : float or None
        P, env steps of one gait cycle for a periodic plan (the H steps repeat it; 1 / (P dt)
        is the gait's frequency); None for an open plan whose knots span the horizon.
    kind : {"cubic", "linear"}
        Spline between the knots.
    window : int or None
        Count R over the last ``window`` steps of the horizon only (None: all of it).
    weights : CostWeights
        Λ's weights.
    gait_seed : bool
        At reset, seed the plan with the best sinusoid gait (phase orders x
        ``seed_amplitudes``, at the period's frequency) scored by R - Λ over
        ``seed_horizon`` steps from the reset state, all in one batched rollout. Needs a period.
    seed_amplitudes : tuple of float
        Fractions of the bound tried by the gait seed.
    seed_horizon : int or None
        Steps from the reset state over which seeds are scored (None: the horizon); R counts
        the last ``window`` of them, as in a replan.
    seed_periods : tuple of float
        Other gait cycles (env steps, each at least ``knots``) the gait seed tries beside
        ``period``; the best seed's cycle becomes the plan's period for the episode. For a
        robot whose resonance is not known (the benchmarks' are tuned: empty). The settings
        stay as given (as scikit-learn's parameters do): the cycle chosen is the planner's
        ``plan_.period`` and ``seed_["period"]``.
    threads : int or None
        C++ rollout threads (None: the CPUs this process may run on, its affinity).
        Results do not depend on it.
    """

    horizon: int = 40
    knots: int = 6
    period: float | None = None
    kind: str = "cubic"
    window: int | None = None
    weights: CostWeights = field(default_factory=CostWeights)
    gait_seed: bool = False
    seed_amplitudes: tuple[float, ...] = (0.5, 1.0)
    seed_horizon: int | None = None
    seed_periods: tuple[float, ...] = ()
    threads: int | None = None

    def __post_init__(self) -> None:
        _check_int("horizon", self.horizon)
        _check_int("knots", self.knots)
        if self.period is not None:
            _check_positive("period", self.period)
            if self.knots > self.period:
                raise ValueError(f"knots = {self.knots} exceeds the period ({self.period} steps)")
        elif self.knots > self.horizon:
            raise ValueError(f"knots = {self.knots} exceeds the horizon ({self.horizon} steps)")
        if self.kind not in KINDS:
            raise ValueError(f"kind must be one of {list(KINDS)}, got {self.kind!r}")
        if self.window is not None:
            _check_int("window", self.window)
            if self.window > self.horizon:
                raise ValueError(f"window = {self.window} exceeds the horizon ({self.horizon})")
        if not isinstance(self.weights, CostWeights):
            # (a command line's --mpc reads weights=... as a number or a string: say where
            # they can be given instead)
            raise TypeError(
                "weights must be a controllers.CostWeights(orientation=, lateral=, effort=, "
                f"divergence=, velocity=), got {self.weights!r}; a command line's --mpc cannot "
                "set them (give a planner CostWeights in Python: default_planner(env_id, "
                "planner, weights=CostWeights(...)))"
            )
        if not isinstance(self.gait_seed, (bool, np.bool_)):
            raise TypeError(f"gait_seed must be True or False, got {self.gait_seed!r}")
        if self.gait_seed and self.period is None:
            raise ValueError("gait_seed needs a periodic plan: set period (env steps per cycle)")
        amps = _real_tuple(self, "seed_amplitudes")
        if amps.size == 0 or not np.all(np.isfinite(amps) & (amps > 0)):
            raise ValueError(
                f"seed_amplitudes must be positive numbers, got {self.seed_amplitudes}"
            )
        if self.seed_horizon is not None:
            _check_int("seed_horizon", self.seed_horizon)
        periods = _real_tuple(self, "seed_periods")
        if periods.size and not (np.all(np.isfinite(periods)) and np.all(periods >= self.knots)):
            raise ValueError(f"seed_periods must be numbers of env steps >= knots = {self.knots}, "
                             f"got {self.seed_periods}")  # fmt: skip
        if periods.size and not self.gait_seed:
            raise ValueError("seed_periods are tried by the gait seed: set gait_seed=True")
        if self.threads is not None:
            _check_int("threads", self.threads)

    # Settings added after runs began recording their planner (rbbo compares a resumed run's
    # record with the planner's), each with the value at which the planner plans as it did
    # before the setting existed. A subclass that adds one lists it here, so that
    # :meth:`record` leaves it out at that value and a run recorded before it still resumes.
    _neutral_since_records: ClassVar[dict[str, Any]] = {}

    def record(self) -> dict[str, Any]:
        """The settings as a run records them: every field but ``threads`` (results do not
        depend on it), less any setting added since records began that is at its neutral
        value (the record of a planner that plans as before it)."""
        neutral = self._neutral_since_records
        return {
            name: value
            for name, value in asdict(self).items()
            if name != "threads" and not (name in neutral and value == neutral[name])
        }

    def check_control_dim(self, control_dim: int) -> None:
        """Raise ValueError if these settings cannot plan C = ``control_dim`` dimensions (a
        per-dimension setting of another length); the planner checks it at reset."""

    @classmethod
    def from_shared(cls, settings: PlannerSettings, **changes: Any) -> Self:
        """Settings of this class with the shared settings (the fields of
        :class:`PlannerSettings`: horizon, knots, period, window, weights, gait seed, ...) of
        ``settings``, and ``changes`` (validated as the constructor validates them).

        For a planner of one's own compared with MPPI on the same plan and objective:
        ``CEMSettings.from_shared(default_settings(env_id, "mppi")[0], samples=32)``. Only the
        shared fields are copied: another planner's own settings (MPPI's ``samples``,
        ``noise``) keep this class's defaults even where a name is the same, as their meaning
        may not be. The times are env steps of the control period ``settings`` were made
        for: make the planner with that ``dt`` too (``CEM(own, dt=mppi.dt)``), so that its
        ``reset`` refuses an env of another period as the source planner's does.
        """
        if not isinstance(settings, PlannerSettings):
            raise TypeError(f"settings must be a PlannerSettings, got {type(settings).__name__}")
        own = {f.name for f in fields(cls)}
        unknown = sorted(set(changes) - own)
        if unknown:
            raise TypeError(f"unknown {cls.__name__} setting {unknown[0]!r}; valid: {sorted(own)}")
        shared = {f.name: getattr(settings, f.name) for f in fields(PlannerSettings)}
        return cls(**{**shared, **changes})

    def replace(self, **changes: Any) -> Self:
        """A copy with some fields changed (validated again)."""
        values = {f.name: getattr(self, f.name) for f in fields(self)}
        unknown = sorted(set(changes) - set(values))
        if unknown:
            raise TypeError(
                f"unknown {type(self).__name__} setting {unknown[0]!r}; valid: {sorted(values)}"
            )
        values.update(changes)
        return type(self)(**values)
