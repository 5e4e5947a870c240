from collections.abc import Sequence
from typing import Literal, TypeAlias

import numpy as np
import numpy.typing as npt
import scipy.sparse

_Positions = npt.ArrayLike  # (N, 3) real array
_FEMSolver: TypeAlias = Literal["supernodal_llt", "simplicial_llt", "simplicial_ldlt", "reference"]

class FEMModel:
    def __init__(
        self,
        nodes: npt.ArrayLike,
        tets: npt.ArrayLike,
        youngs_modulus: float,
        poisson_ratio: float,
        density: float,
    ) -> None: ...
    @property
    def num_nodes(self) -> int: ...
    @property
    def num_tets(self) -> int: ...
    @property
    def mass(self) -> npt.NDArray[np.float64]: ...
    @property
    def volumes(self) -> npt.NDArray[np.float64]: ...
    @property
    def volume(self) -> float: ...
    @property
    def rest_positions(self) -> npt.NDArray[np.float64]: ...
    @property
    def youngs_modulus(self) -> float: ...
    @property
    def poisson_ratio(self) -> float: ...
    @property
    def density(self) -> float: ...
    @property
    def gravity(self) -> list[float]: ...
    @gravity.setter
    def gravity(self, value: Sequence[float] | npt.ArrayLike) -> None: ...
    damping_alpha: float
    damping_beta: float
    newton_tolerance: float
    max_newton_iterations: int
    solver: _FEMSolver
    @property
    def last_step_stats(self) -> dict[str, int | float | bool]: ...
    def energy(self, x: _Positions) -> float: ...
    def forces(self, x: _Positions) -> npt.NDArray[np.float64]: ...
    def stiffness(self, x: _Positions, project: bool = False) -> scipy.sparse.csr_matrix: ...
    def step(
        self,
        x: _Positions,
        v: _Positions,
        dt: float,
        fixed: npt.ArrayLike | None = None,
    ) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]: ...

class ReducedState:
    def __init__(self, q: npt.ArrayLike, qdot: npt.ArrayLike, impulses: npt.ArrayLike) -> None: ...
    @property
    def q(self) -> npt.NDArray[np.float64]: ...
    @property
    def qdot(self) -> npt.NDArray[np.float64]: ...
    @property
    def impulses(self) -> npt.NDArray[np.float64]: ...
    def copy(self) -> ReducedState: ...
    def __copy__(self) -> ReducedState: ...
    def __deepcopy__(self, memo: dict) -> ReducedState: ...

class ReducedModel:
    def __init__(
        self,
        nodes: npt.ArrayLike,
        tets: npt.ArrayLike,
        youngs_modulus: float,
        poisson_ratio: float,
        density: float,
        basis: npt.ArrayLike,
        cubature_elements: npt.ArrayLike,
        cubature_weights: npt.ArrayLike,
        surface_nodes: npt.ArrayLike,
        surface_faces: npt.ArrayLike,
    ) -> None: ...
    @property
    def dim(self) -> int: ...
    @property
    def M(self) -> int: ...
    @property
    def C(self) -> int: ...
    @property
    def num_nodes(self) -> int: ...
    @property
    def total_mass(self) -> float: ...
    @property
    def surface_nodes(self) -> list[int]: ...
    control_basis: npt.NDArray[np.float64]
    dt: float
    gravity: list[float]
    contact: str
    friction: float
    ground_height: float
    contact_margin: float
    penalty_stiffness: float
    fluid_density: float
    drag_coefficient: float
    damping_alpha: float
    damping_beta: float
    newton_tolerance: float
    max_newton_iterations: int
    contact_tolerance: float
    max_stagger_iterations: int
    max_speed: float
    direction: list[float]
    def rest_state(self) -> ReducedState: ...
    def step(
        self, state: ReducedState, f_c: npt.ArrayLike | None = None
    ) -> tuple[ReducedState, dict[str, int | bool]]: ...
    def rollout(
        self,
        state: ReducedState | Sequence[ReducedState],
        controls: npt.ArrayLike,
        threads: int | None = None,
        observe: npt.ArrayLike | None = None,
    ) -> dict[str, npt.NDArray[np.float64] | npt.NDArray[np.bool_]]: ...
    def positions(self, q: npt.ArrayLike) -> npt.NDArray[np.float64]: ...
    def com(self, q: npt.ArrayLike) -> npt.NDArray[np.float64]: ...
    def elastic_energy(self, q_e: npt.ArrayLike) -> float: ...
    def elastic_forces(self, q_e: npt.ArrayLike) -> npt.NDArray[np.float64]: ...
    def elastic_stiffness(
        self, q_e: npt.ArrayLike, project: bool = False
    ) -> npt.NDArray[np.float64]: ...

def reduced_element_forces(
    fem: FEMModel, basis: npt.ArrayLike, poses: npt.ArrayLike
) -> npt.NDArray[np.float64]: ...
