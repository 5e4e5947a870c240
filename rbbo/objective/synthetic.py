"""The synthetic objective: a noisy two-fidelity objective on Gr(M, C) with a known optimum.

:class:`SyntheticObjective` (ENV_ID ``synthetic[:key=value,...]``) needs neither the
simulator nor the controllers: for tests, benchmarks and trying the CLI.
"""

from __future__ import annotations

import hashlib
import math
import time
from dataclasses import asdict, dataclass, field
from typing import Any, ClassVar

import numpy as np

from ..grassmann import _check_dims, random_points


@dataclass
class SyntheticObjective:
    r"""A noisy two-fidelity objective on Gr(M, C) with a known optimum.

    .. math::
        R(B, T, s) = \|B^T U\|_F^2 / C
                   - b (1 - T / T_{max}) (1/2 + \|B^T V\|_F^2 / C)
                   + \epsilon_s + \epsilon_{s, B}

    U (the optimum, R = 1 at T_max) and V are fixed Haar-random subspaces drawn from
    ``optimum_seed``. The noise has a part common to all bases for a given seed (what common
    random numbers cancel) of scale ``noise`` and a part particular to (seed, B) of scale
    ``noise / 2``, both deterministic functions of their arguments.

    Parameters
    ----------
    sim_dim, control_dim : int
        M and C.
    optimum_seed : int
        Chooses U and V.
    noise : float
        Noise scale.
    bias : float
        Low-fidelity bias b.
    t_max : float
        The target fidelity T_max (seconds): give the run's (``RBBOConfig.t_max``), or the
        optimum's R at the run's T_max is below 1 (``rbbo optimize`` passes its --t-max).
    delay : float
        Sleep ``delay * T / t_max`` seconds per call (cost proportional to T).
    """

    sim_dim: int
    control_dim: int
    optimum_seed: int = 0
    noise: float = 0.0
    bias: float = 0.3
    t_max: float = 10.0
    delay: float = 0.0
    # spec() settings that change an evaluation's cost, not R: a run may go on with another
    # (rbbo.objective.objective_differences)
    COST_ONLY: ClassVar[frozenset[str]] = frozenset({"delay"})
    _u: np.ndarray = field(init=False, repr=False, compare=False)  # (derived from the seed)
    _v: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        # (numpy's numbers as Python's, here and below: spec() goes into config.json)
        self.sim_dim, self.control_dim = _check_dims(self.sim_dim, self.control_dim)
        seed = self.optimum_seed
        if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
            raise ValueError(f"the synthetic seed must be an integer >= 0, got {seed!r}")
        for name in ("noise", "bias", "delay", "t_max"):
            value = getattr(self, name)
            # (math.isfinite raised its own TypeError for a string, and took True as 1)
            if isinstance(value, bool) or not isinstance(value, (int, float, np.number)):
                raise ValueError(f"{name} must be a number, got {value!r}")
        for name in ("noise", "bias", "delay"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"{name} must be finite and >= 0, got {value!r}")
        if not (math.isfinite(self.t_max) and self.t_max > 0):
            raise ValueError(f"t_max must be finite and > 0, got {self.t_max!r}")
        self.optimum_seed = int(seed)
        for name in ("noise", "bias", "delay", "t_max"):
            setattr(self, name, float(getattr(self, name)))
        rng = np.random.default_rng(self.optimum_seed)
        self._u, self._v = random_points(self.sim_dim, self.control_dim, 2, rng)

    @property
    def optimum(self) -> np.ndarray:
        """U: a basis of the best subspace (R = 1 at T_max without noise)."""
        return self._u.copy()

    def value(self, basis: np.ndarray, T: float | None = None) -> float:
        """The noise-free R(B, T) (T defaults to T_max)."""
        b = np.asarray(basis, dtype=float)
        c = self.control_dim
        t = self.t_max if T is None else float(T)
        hit = float(np.sum((b.T @ self._u) ** 2)) / c
        side = float(np.sum((b.T @ self._v) ** 2)) / c
        return hit - self.bias * (1.0 - t / self.t_max) * (0.5 + side)

    def __call__(self, basis: np.ndarray, T: float, seed: int) -> float:
        if self.delay:
            time.sleep(self.delay * float(T) / self.t_max)
        r = self.value(basis, T)
        if self.noise:
            common = np.random.default_rng([int(seed), 0]).standard_normal()
            b = np.asarray(basis, dtype=float)
            # The subspace, not its representative; + 0.0 turns the -0.0 that rounding
            # leaves of a tiny negative entry into 0.0, whose bytes differ.
            key = (np.round(b @ b.T, 8) + 0.0).tobytes()
            digest = int.from_bytes(hashlib.blake2b(key, digest_size=8).digest(), "little")
            own = np.random.default_rng([int(seed), 1, digest]).standard_normal()
            r += self.noise * (common + 0.5 * own)
        return float(r)

    def spec(self) -> dict[str, Any]:
        return {"kind": "synthetic", **{k: v for k, v in asdict(self).items() if k[0] != "_"}}
