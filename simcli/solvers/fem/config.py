"""FEM configuration: solver options and the tetrahedral solid materials (pydantic, no Taichi).

Names follow Genesis (``gs.options.FEMOptions``, ``gs.materials.FEM.Elastic``): ``E``, ``nu``,
``rho``, ``model`` (linear | linear_corotated | stable_neohookean | neohookean). Where simcli differs it
says so
in the field's description (lumped masses, tolerance-based Newton/PCG stopping).
"""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from simcli.scene.material_base import _Solid
from simcli.scene.meshing import MIN_DIHEDRAL
from simcli.scene.morphs import Region
from simcli.scene.muscle import MuscleGroup, MuscleGroups  # groups and signals shared with MPM.Muscle

Vec = list[float]


class _Options(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, validate_default=True)


class FEMOptions(_Options):
    integrator: Literal["explicit", "implicit", "backward_euler", "implicit_midpoint"] = Field(
        "explicit",
        description="explicit: symplectic Euler with lumped vertex masses (substep limited by the "
        "elastic wave "
        "speed: use substeps: auto). implicit (the same as backward_euler): backward Euler, each substep "
        "minimises the incremental potential with Newton's method, PCG (3x3 block-Jacobi) linear solves and "
        "Armijo back-tracking; first order, damps vibrations and rotations numerically (choose it for "
        "heavily damped, quasi-static and contact-dominated scenes). implicit_midpoint: the second-order, "
        "symplectic implicit midpoint rule, solved as a backward Euler half step (the same Newton-PCG "
        "minimisation) followed by an explicit half step; keeps the energy of undamped motion and the "
        "angular momentum of a free body (choose it for elastic dynamics: vibration, spinning).",
    )
    element: Literal["tet4", "tet10"] = Field(
        "tet4",
        description="FEM.Elastic element: tet4, linear tetrahedra (4 nodes, constant strain; lock in "
        "bending: a slender beam needs many elements); tet10, quadratic tetrahedra (the same mesh with a "
        "node at each edge midpoint, 4-point Gauss quadrature, HRZ lumped mass): far more accurate in "
        "bending per node. tet10 supports FEM.Elastic with every model and integrator, boundary "
        "conditions, colliders and walls; not FEM.Muscle, FEM.Cloth or coupling with other families "
        "(refused by validate).",
    )
    resolution: float = Field(
        20.0,
        gt=0,
        description="Box morphs: cells per metre of the structured tetrahedral subdivision (each cell is "
        "split into 6 tetrahedra); at least one cell per axis.",
    )
    max_volume: float | None = Field(
        None,
        gt=0,
        description="Sphere, Cylinder and surface Mesh morphs: largest tetrahedron volume [m^3] of the "
        "tetrahedralisation (default: about resolution^-3 / 6, i.e. Box-like element sizes).",
    )
    min_dihedral: float = Field(
        MIN_DIHEDRAL,
        ge=0,
        lt=70,
        description="Sphere, Cylinder and surface Mesh morphs: smallest dihedral angle [deg] the "
        "tetrahedraliser aims for (TetGen's -q quality bound).",
    )
    surface_resolution: float | None = Field(
        None,
        gt=0,
        description="Sphere and Cylinder morphs: triangles' edge length per metre on the surface before "
        "tetrahedralisation (default: resolution).",
    )
    newton_tol: float = Field(
        1.0e-4,
        gt=0,
        description="Implicit: Newton stops when the residual (incremental-potential gradient, free "
        "vertices) has fallen below newton_tol times its value at the start of the substep, or below "
        "newton_atol.",
    )
    newton_atol: float = Field(
        1.0e-2,
        gt=0,
        description="Implicit: absolute Newton stop [m/s^2]: largest residual force per vertex mass (1e-2 is "
        "1e-3 g). Newton also stops when the line search finds no decrease (round-off reached; counted).",
    )
    newton_vtol: float = Field(
        0.0,
        ge=0,
        description="FEM.Cloth: Newton also stops when its step's largest vertex displacement divided by the "
        "step, |p| / dt, falls below this velocity [m/s] (the step test of IPC, Li et al. 2020). A speed "
        "for accuracy trade: fewer Newton steps, but the forces are then converged only as far as the "
        "contact's stiffness times |p| (1e-3 m/s: a sheet resting on a sphere reads its weight 9 % high, "
        "docs/FEM.md). 0 (default): newton_tol and newton_atol alone.",
    )
    newton_max_iter: int = Field(
        50,
        ge=1,
        description="Implicit: safety cap on Newton iterations per substep (hitting it is reported).",
    )
    pcg_tol: float = Field(
        1.0e-4, gt=0, description="Implicit: PCG stops at this relative residual ||r|| / ||b|| [-]."
    )
    pcg_max_iter: int = Field(
        1000,
        ge=1,
        description="Implicit: safety cap on PCG iterations per Newton step (hitting it is reported).",
    )
    linear_solver: Literal["auto", "superlu", "cholmod"] = Field(
        "auto",
        description="FEM.Cloth: the sparse direct factorisation of Newton's matrix. superlu: scipy's SuperLU "
        "(symmetric mode, minimum degree), always there. cholmod: CHOLMOD's supernodal Cholesky through the "
        "optional package cvxopt (GPL-3; pip install 'simcli[cholmod]'), 5-7x faster to factor at 4k cloth "
        "vertices (docs/FEM.md). auto (default): cholmod where cvxopt and threadpoolctl are installed, else "
        "superlu. The two give the same Newton directions to round-off; run.json's fem_cloth info names the "
        "one used.",
    )
    preconditioner: Literal["block_jacobi", "rotated_rest"] = Field(
        "rotated_rest",
        description="Implicit: PCG preconditioner. block_jacobi: the exact 3x3 diagonal blocks of the "
        "projected Hessian (three dP/dF applications per element corner each Newton step). rotated_rest: the "
        "rest-shape small-strain stiffness's diagonal blocks turned by each element's rotation R (F = R S), "
        "plus the mass and contact terms: much cheaper to build, a little weaker far from rest.",
    )
    line_search: bool = Field(
        True,
        description="Implicit: Armijo back-tracking line search on the incremental "
        "potential (c = 1e-4, halving, at most 20 halvings).",
    )
    damping: float = Field(
        0.0,
        ge=0,
        description="Stiffness-proportional (Rayleigh beta) damping [s]: viscous stress beta (2 mu sym(L) + "
        "lambda tr(L) I), L the spatial velocity gradient and mu, lambda the material's Lame parameters, "
        "i.e. beta times the small-strain stiffness. Rigid motion, free fall and rigid rotation are not "
        "damped. Both integrators (implicit: L from the substep's displacement and F at its start).",
    )
    mass_damping: float = Field(
        0.0,
        ge=0,
        description="Mass-proportional (Rayleigh alpha) damping [1/s]: force -alpha m v on every vertex. "
        "Unlike damping it also slows rigid motion and free fall (terminal speed g / alpha). Both "
        "integrators; a mode of angular frequency w gets the damping ratio (alpha / w + damping x w) / 2.",
    )
    contact_stiffness: float = Field(
        1.0e3,
        gt=0,
        description="Implicit: floor, wall and collider contact is a penalty in the incremental potential of "
        "stiffness contact_stiffness x vertex mass / substep^2 [-] (penetration about g substep^2 / this).",
    )
    contact_distance: float = Field(
        1.0e-3,
        gt=0,
        description="FEM.Cloth: IPC barrier activation distance dhat [m]: cloth vertices, edges and "
        "triangles closer than this to each other, a collider or a domain wall repel (log barrier); every "
        "step is limited by continuous collision detection, so the cloth never intersects.",
    )
    cfl: float = Field(
        0.4,
        gt=0,
        le=1,
        description="Explicit, substeps: auto: substep = cfl x smallest element height / P-wave speed [-].",
    )


class FEMBoundaryCondition(_Options):
    """A boundary condition on the vertices (or boundary faces) inside a region of the initial shape."""

    region: Region = Field(description="Vertices inside this region (initial positions) are concerned.")
    axes: list[Literal["x", "y", "z"]] | None = Field(
        None,
        description="Held components (rollers: e.g. [x] holds x only). With velocity: the components moved; "
        "default all.",
    )
    velocity: Vec | None = Field(
        None,
        description="Prescribed velocity [m/s] of the held components: the vertices move on the path "
        "x0 + velocity t (default: held in place).",
    )
    traction: Vec | None = Field(
        None,
        description="Instead of holding: a dead-load surface traction [Pa] (force per initial area) on "
        "the boundary faces whose vertices all lie in the region.",
    )

    @model_validator(mode="after")
    def _check(self):
        if self.traction is not None and (self.velocity is not None or self.axes is not None):
            raise ValueError("a traction condition takes no axes or velocity")
        return self


class _FEMSolid(_Solid):
    model: Literal[
        "linear", "linear_corotated", "stable_neohookean", "neohookean", "neohookean_decoupled"
    ] = Field(
        "stable_neohookean",
        description="Constitutive model: 'linear' (small-strain, not rotation invariant), 'linear_corotated' "
        "(linear in the stretch S of F = R S), 'stable_neohookean' (Smith, de Goes and Kim 2018, Lame "
        "parameters reparameterised to match linear elasticity at small strain; robust to inversion), "
        "'neohookean' (the classical compressible neo-Hookean of Bonet and Wood, psi = mu/2 (I1 - "
        "3) - mu ln J "
        "+ lambda/2 (ln J)^2: the model of the reference solutions, e.g. Cook's membrane; undefined for "
        "J <= 0: an inverted element's ln J is taken at J = 1e-4 (docs/FEM.md), so prefer "
        "stable_neohookean where elements may invert), 'neohookean_decoupled' (mu/2 (J^-2/3 I1 - 3) + "
        "kappa/4 (J^2 - 1 - 2 ln J), kappa = lambda + 2 mu / 3: the model of the deal.II code gallery's "
        "Cook membrane, Pelteret and McBride 2016; the same inversion guard).",
    )
    angular_velocity: Vec | None = Field(
        None,
        description="Initial angular velocity [rad/s] about the body's centroid, added to the entity's "
        "velocity (a spinning body).",
    )
    initial_stretch: Vec | None = Field(
        None,
        description="Start deformed: initial vertex positions scaled by these factors [-] per axis about "
        "the body's centroid, the rest shape unchanged (a negative factor starts the body inverted, 0.01 "
        "squashed flat).",
    )
    boundary_conditions: list[FEMBoundaryCondition] = Field(
        default_factory=list,
        description="Rollers, prescribed motion and surface tractions (entity.fixed holds every component).",
    )


class FEMElastic(_FEMSolid):
    """Hyperelastic tetrahedral solid (linear tetrahedra)."""

    type: Literal["FEM.Elastic"]


class FEMMuscle(MuscleGroups, _FEMSolid):
    """Tetrahedral solid with active fibre stress (the groups and actuation signals of MPM.Muscle): per
    element the first Piola-Kirchhoff stress stiffness a_g(t) (F f0) f0^T is added to the passive one, the
    derivative of the energy stiffness a_g(t) |F f0|^2 / 2 (Kirchhoff stress stiffness a (F f0)(F f0)^T,
    Genesis's muscle form); f0 the element's fibre direction in the rest shape, g its group."""

    type: Literal["FEM.Muscle"]
    stiffness: float | None = Field(
        None,
        gt=0,
        description="Active stress per unit activation [Pa] (default E, as in Genesis). Positive "
        "activation is tension along the fibre: the muscle contracts.",
    )
    n_groups: int = Field(1, ge=1, le=64, description="Number of independently actuated groups.")
    fiber_direction: Vec | None = Field(
        None, description="Default fibre direction [-] of every group, in the rest shape (default z)."
    )
    groups: list[MuscleGroup] = Field(
        default_factory=list,
        description="One entry per group (n_groups of them): region (an element belongs "
        "to the first group whose region holds its rest centroid; a group without a region takes every "
        "element no earlier group took), fibre direction and actuation signal (constant, sine or table). "
        "Empty: one group holding the whole body, no actuation.",
    )

    @model_validator(mode="after")
    def _check(self):
        self._check_groups(need_dim=3)
        return self


from simcli.solvers.fem.cloth.config import FEMCloth  # noqa: E402  (thin shells, IPC contact)

# Every FEM material type; the scene's material union is built from these.
MATERIALS = (FEMElastic, FEMMuscle, FEMCloth)
