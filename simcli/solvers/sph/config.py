"""SPH configuration: solver options and the liquid material (pydantic, no Taichi).

Names follow Genesis (``gs.options.SPHOptions``, ``gs.materials.SPH.Liquid``): ``particle_size``,
``pressure_solver``, ``stiffness``, ``exponent``, ``mu``, ``gamma``. Unlike Genesis, ``mu`` is the
physical dynamic viscosity [Pa s] and the DFSPH tolerances are those of SPlisHSPlasH.
"""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from simcli.scene.material_base import _Material


class _Options(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, validate_default=True)


class DensityDiffusion(_Options):
    """solvers.sph.density_diffusion: delta-SPH's density diffusion (WCSPH, density: continuity)."""

    model: Literal["molteni_colagrossi", "antuono", "fourtakis"] = Field(
        "antuono",
        description="psi_ij, with x_ij = x_i - x_j. molteni_colagrossi (Molteni & Colagrossi 2009): 2 "
        "(rho_i - rho_j) x_ij / |x_ij|^2, cheapest, but a liquid at rest under gravity diffuses its "
        "hydrostatic density gradient (the surface layer's density drifts). antuono (Antuono et al. 2010; "
        "Marrone et al. 2011): the same minus (<grad rho>_i + <grad rho>_j), the renormalised density "
        "gradients (one more pass over the neighbours), zero for a linear density field. fourtakis "
        "(Fourtakis et al. 2019, DualSPHysics' DDT 2): 2 ((rho_i - rho_j) - rho_ij^H) x_ij / |x_ij|^2 "
        "with rho_ij^H the hydrostatic density difference of the Tait equation, rho0 ((1 + rho0 g . x_ij / "
        "k)^(1 / n) - 1).",
    )
    delta: float = Field(
        0.1, gt=0, le=1, description="Diffusion coefficient delta [-] (0.1 in the delta-SPH literature)."
    )


class SPHOptions(_Options):
    particle_size: float = Field(
        0.02,
        gt=0,
        description="Particle spacing [m]: liquids are sampled on a lattice of this spacing, each particle "
        "carries volume particle_size^dim; the kernel support radius is support_factor x particle_size.",
    )
    support_factor: float = Field(
        2.0,
        ge=1.5,
        le=4.0,
        description="Kernel support radius in particle sizes [-]. 2 (Genesis's and SPlisHSPlasH's choice, "
        "about 33 neighbours in 3D) is fastest; 3 makes the SPH viscosity operator accurate to 3% instead of "
        "30-40% on a lattice (use it where viscous decay matters) at 3.4x the neighbours in 3D.",
    )
    pressure_solver: Literal["WCSPH", "DFSPH"] = Field(
        "WCSPH",
        description="WCSPH: weakly compressible, Tait equation of state (Becker & Teschner 2007). DFSPH: "
        "divergence-free SPH (Bender & Koschier 2015/2017), iterated to the tolerances below.",
    )
    max_density_error_percent: float = Field(
        0.01,
        gt=0,
        description="DFSPH: the density solve iterates until the average density error is at or below this "
        "[% of rho0] (SPlisHSPlasH's default 0.01 %).",
    )
    max_divergence_error_percent: float = Field(
        0.1,
        gt=0,
        description="DFSPH: the divergence solve iterates until the average density change rate times the "
        "substep is at or below this [% of rho0] (SPlisHSPlasH's default 0.1 %).",
    )
    max_density_iterations: int = Field(
        100, ge=1, description="DFSPH: iteration cap of the density solve [-]."
    )
    max_divergence_iterations: int = Field(
        100, ge=1, description="DFSPH: iteration cap of the divergence solve [-]."
    )
    divergence_solve: bool = Field(
        True, description="DFSPH: run the divergence solve (keeps the velocity field divergence-free)."
    )
    warm_start: bool = Field(
        True, description="DFSPH: start both solves from the previous substep's pressure (stiffness) values."
    )
    gradient_correction: bool | Literal["scalar", "auto"] = Field(
        "auto",
        description="DFSPH: kernel gradient correction (Bonet & Lok 1999) in both pressure solves. Each "
        "particle's gradient is grad W_ij times L_i = (sum_j V_j grad W_ij (x_j - x_i)^T, walls "
        "included)^-1, so "
        "the density rate of a linear velocity field is exact on a disordered packing, and the pressure "
        "force is its adjoint, -sum_j V_j (k_i L_i + k_j L_j) grad W_ij (pairwise antisymmetric: momentum "
        "conserving). Without it DFSPH's projection removes part of a smooth vortex every substep as the "
        "packing changes (Taylor-Green: 0.047 1/s of numerical decay at Re = infinity, 0.007 with it). "
        "Particles whose moment matrix has determinant below 0.5 (a deficient neighbourhood: free "
        "surface, splash) keep the plain gradient. For confined flows; validated there only. scalar (since "
        "session 8): L_i = dim / trace(sum_j V_j grad W_ij (x_j - x_i)^T) times the identity, the "
        "isotropic part "
        "only: it corrects the gradient's magnitude on a settled packing (0.98 of the exact in a "
        "tank at rest, "
        "which makes the hydrostatic pressure 2% too steep) without turning it; a DFSPH tank at rest: floor "
        "pressure +0.8% instead of +2.2%, drift 0.41 cm/s instead of 0.57 (true: +0.3%, but 2.0 cm/s); "
        "docs/SPH.md. auto: scalar for DFSPH with a free surface (since session 8), false otherwise.",
    )
    viscosity_operator: Literal["monaghan", "morris"] = Field(
        "monaghan",
        description="Liquid-liquid viscosity term. monaghan: 2 (dim + 2) nu sum_j V_j (v_ij . x_ij) / (r^2 + "
        "0.01 h^2) grad W_ij (Monaghan 2005, SPlisHSPlasH's standard; conserves angular momentum), accurate "
        "on a lattice but 85-103% of the Laplacian on a disordered packing. morris: nu c sum_j V_j (x_ij . "
        "grad W_ij) / (r^2 + 0.01 h^2) v_ij (Morris et al. 1997, each component's Laplacian), c normalised "
        "on the lattice so that it is exact for quadratic fields: 99.6-100% of the Laplacian on the same "
        "packings, but not angular-momentum conserving. Walls use the monaghan form either way.",
    )
    boundary: Literal["particles", "volume_map"] = Field(
        "particles",
        description="How walls and colliders enter the liquid's sums. particles: layers of boundary "
        "particles (Akinci et al. 2012) in the neighbour search. volume_map: no boundary particles; the sums "
        "those particles would give (density, the pressure terms' sum V_b grad W_ib, no-slip viscosity) are "
        "precomputed once per boundary (tables against the distances to the domain's faces, a grid per "
        "collider) and looked up per liquid particle, as SPlisHSPlasH's volume maps (Bender et al. 2019) "
        "and density maps (Koschier & Bender 2017) do. A moving collider's or rigid body's map is built in "
        "its body frame and queried at its pose. wall_pressure: extrapolated (auto with a free surface) "
        "gives the boundary the liquid's pressure next to it (DFSPH: the Shepard average of the particle's "
        "neighbours; WCSPH: the particle's own, relaxing towards it, wall_pressure_relaxation) plus the "
        "hydrostatic difference to it. "
        "docs/SPH.md, volume maps.",
    )
    wall_pressure: Literal["auto", "akinci", "extrapolated"] = Field(
        "auto",
        description="Pressure force between the liquid and walls / colliders (boundary particles). akinci: "
        "-sum_b rho0 V_b (p_i / rho_i^2) grad W_ib (Akinci et al. 2012; SPlisHSPlasH's and Genesis's), the "
        "liquid's own pressure alone: at rest the particles next to a wall then carry 1.7x the hydrostatic "
        "pressure (2.15x in corners). extrapolated: the wall particles "
        "get a pressure of their own, the average of the liquid's next to them plus the hydrostatic "
        "difference "
        "(Adami et al. 2012; Band et al. 2018), and push with p_i / rho_i^2 + p_b / rho_b^2: the "
        "wall layer's "
        "pressure is within 1-2% of the liquid's field; DFSPH: a liquid at rest settles at fine "
        "resolution too, "
        "about 18% more time per substep on benchmark B2; WCSPH: the walls' pressure relaxes towards the "
        "extrapolation (wall_pressure_relaxation; followed at once it made a tank at rest "
        "unstable), docs/SPH.md. "
        "DFSPH's conjugate-gradient solve (clamp_pressure: false) needs Akinci's symmetric term. "
        "auto: extrapolated with a free surface (clamp_pressure: true; for WCSPH since session 8), "
        "akinci for a "
        "confined liquid.",
    )
    wall_pressure_relaxation: float = Field(
        0.2,
        gt=0,
        description="WCSPH with wall_pressure: extrapolated: relaxation time [s] of the walls' "
        "pressure. Each "
        "boundary particle's pressure follows the extrapolation from the liquid next to it as a "
        "first-order lag, "
        "p_b += dt / (tau + dt) (p_extrapolated - p_b) per substep (a newly wetted one starts at the "
        "extrapolation). A wall pressure that followed the liquid's at once is a non-conservative force that "
        "pumped energy into the acoustic noise of a tank at rest (5-9 cm/s); against a pressure that changes "
        "slowly compared with the sound's periods the liquid moves in a nearly fixed potential, and the "
        "pumping falls as 1 / (omega tau). Measured on the hydrostatic tank: 0.01 s unstable (5.6 cm/s), "
        "0.05 s marginal (0.9-1.8 cm/s), 0.2 s as calm as Akinci's walls (docs/SPH.md). During a fast "
        "change (an impact) the wall pushes with the liquid's own pressure (Akinci's term) plus the lagging "
        "part.",
    )
    inside_colliders: Literal["auto", "push_out", "remove"] = Field(
        "auto",
        description="Liquid particles sampled inside a collider (an entity's morph overlapping a collider). "
        "push_out: each is moved onto the collider's surface at the start (the liquid's mass is kept; where "
        "the overlap is deeper than a particle several land on one spot, and the liquid there starts "
        "compressed and expands violently); one whose nearest collider face lies on or beyond a domain wall "
        "cannot be pushed into the domain and is removed, with a warning. remove: they are not simulated (a "
        "warning gives how many and their mass per entity; run.json solvers.sph.removed_inside_colliders). "
        "auto: remove with DFSPH, whose density solve diverges on particles pushed onto one spot "
        "(docs/SPH.md, gaps), push_out with WCSPH (its substep follows the sound speed of the compression).",
    )
    clamp_pressure: bool = Field(
        True,
        description="Free-surface treatment: no negative pressure (density below rho0 gives zero pressure; "
        "DFSPH corrects only compression). Set false for a liquid that fills a closed box (Taylor-Green).",
    )
    background_pressure: float = Field(
        0.0,
        ge=0,
        description="WCSPH: pressure added everywhere [Pa] (with clamp_pressure false, keeps a confined "
        "flow free of tension).",
    )
    shifting: float = Field(
        0.0,
        ge=0,
        le=0.5,
        description="Particle shifting (Xu et al. 2009; Lind et al. 2012) [-]: after each substep a particle "
        "moves by -shifting x particle_size^2 x grad C (C = sum_j V_j W_ij, the particle concentration, "
        "walls included; at most 0.1 particle_size per substep), its velocity unchanged, so particles stay "
        "evenly spread instead of clumping or disordering. Not applied in the deficient support of a free "
        "surface (rho < 0.95 rho0). For confined flows (Taylor-Green: 0.2 with no background pressure); 0 "
        "(off) for liquids at rest under gravity, where it works against the hydrostatic compression.",
    )
    density: Literal["summation", "continuity"] = Field(
        "summation",
        description="WCSPH: how the density is computed. summation: rho_i = sum_j m_j W_ij (walls "
        "included, Akinci et al. 2012), every substep from the positions. continuity: each particle's "
        "density is a state integrated from the continuity equation, d rho_i / dt = rho_i sum_j V_j (v_i - "
        "v_j) . grad W_ij (walls included, with their velocity), as delta-SPH does (Antuono et al. 2010; "
        "Marrone et al. 2011); it starts at the hydrostatic density of a liquid at rest (depth "
        "counted in each connected piece of a column; a piece with nothing under it, a falling drop, at "
        "rho0) and emitted particles at rho0. A splash keeps rho0 instead of the deficient sum of a free "
        "surface. With clamp_pressure: true the density is floored at 0.5 rho0 (nothing else restores a "
        "stretching jet's). Use it with density_diffusion. docs/SPH.md, delta-SPH.",
    )
    density_diffusion: DensityDiffusion | None = Field(
        None,
        description="WCSPH with density: continuity: a density diffusion term added to the continuity "
        "equation, delta h c0 sum_j psi_ij . grad W_ij V_j (h = half the support radius, c0 the material's "
        "sound speed), that removes the high-frequency pressure noise of the continuity density. None: "
        "off.",
    )
    artificial_viscosity: float = Field(
        0.0,
        ge=0,
        le=1,
        description="WCSPH: Monaghan's (1992) artificial viscosity alpha [-] between approaching liquid "
        "particles (beta = 0), a_i = sum_j m_j alpha c0 h (v_ij . x_ij) / ((r^2 + 0.01 h^2) rho_ij) grad "
        "W_ij where v_ij . x_ij < 0 (h = half the support radius), in addition to the physical mu. "
        "delta-SPH's dam breaks use 0.01-0.02 (TrixiParticles' 0.02). 0: off.",
    )
    cfl: float = Field(
        0.4,
        gt=0,
        le=1,
        description="CFL number for substeps: auto [-]: substep <= cfl x particle_size / v, with v the "
        "largest particle speed (plus the sound speed sqrt(stiffness exponent / rho) for WCSPH).",
    )
    max_substep: float = Field(
        5.0e-3,
        gt=0,
        description="Upper bound of the automatic substep [s] (a liquid at rest has no CFL limit). DFSPH "
        "liquids at rest at fine resolution with wall_pressure: akinci may need a smaller bound: a tank at "
        "particle_size 2.5 mm did not settle with 2 ms substeps and did with 1 ms; with wall_pressure: "
        "extrapolated it settled at 2 ms (docs/SPH.md, gaps).",
    )

    wall_standoff: float = Field(
        0.0,
        ge=0.0,
        le=0.5,
        description="How far the domain walls keep particle centres off their faces, in particle sizes [-]: "
        "0 lets a centre reach the face; 0.5, a particle's radius, keeps every particle's volume inside "
        "the domain (where sampling puts the particles next to a wall), as SPlisHSPlasH keeps its "
        "particles one radius off its boundaries. The position guard moves a particle that comes closer "
        "back to that distance and drops its velocity into the wall. On SPlisHSPlasH's dam break 0.5 takes "
        "271 adaptive substeps instead of 323: the fast jets along the walls come from particles that "
        "reach the last half spacing (docs/SPH.md, session 26). Colliders are not affected.",
    )

    @model_validator(mode="after")
    def _dfsph_only(self) -> SPHOptions:
        if self.gradient_correction not in (False, "auto") and self.pressure_solver != "DFSPH":
            raise ValueError(
                "gradient_correction applies to the DFSPH pressure solves: set pressure_solver: DFSPH or "
                "gradient_correction: false"
            )
        if (
            self.wall_pressure == "extrapolated"
            and self.pressure_solver == "DFSPH"
            and not self.clamp_pressure
        ):
            raise ValueError(
                "wall_pressure: extrapolated with DFSPH needs clamp_pressure: true (DFSPH's "
                "conjugate-gradient "
                "solve for clamp_pressure: false needs a symmetric operator): set wall_pressure: akinci"
            )
        if self.pressure_solver == "DFSPH" and (
            self.density != "summation" or self.density_diffusion is not None or self.artificial_viscosity
        ):
            raise ValueError(
                "density: continuity, density_diffusion and artificial_viscosity are WCSPH options (DFSPH "
                "solves for the summed density): set pressure_solver: WCSPH or remove them"
            )
        if self.density_diffusion is not None and self.density != "continuity":
            raise ValueError(
                "density_diffusion diffuses the continuity equation's density: set density: continuity "
                "(or remove density_diffusion)"
            )
        if self.background_pressure > 0 and self.clamp_pressure:
            raise ValueError(
                "background_pressure is for a liquid that fills a closed box (clamp_pressure: false): with a "
                "free surface (clamp_pressure: true) it pushes the surface particles off the liquid. Set "
                "clamp_pressure: false or background_pressure: 0"
            )
        return self

    @property
    def wall_model(self) -> str:
        """The wall pressure model a run uses: ``wall_pressure`` with auto resolved."""
        if self.wall_pressure != "auto":
            return self.wall_pressure
        return "extrapolated" if self.clamp_pressure else "akinci"

    @property
    def gradient_correction_mode(self) -> bool | str:
        """The kernel gradient correction a run uses: ``gradient_correction`` with auto resolved (False,
        True or
        "scalar")."""
        if self.gradient_correction != "auto":
            return self.gradient_correction
        return "scalar" if self.pressure_solver == "DFSPH" and self.clamp_pressure else False

    @property
    def inside_collider_mode(self) -> str:
        """What happens to particles sampled inside a collider: ``inside_colliders`` with auto resolved."""
        if self.inside_colliders != "auto":
            return self.inside_colliders
        return "remove" if self.pressure_solver == "DFSPH" else "push_out"

    @property
    def support_radius(self) -> float:
        return self.support_factor * self.particle_size


class SPHLiquid(_Material):
    """Liquid simulated by the SPH solver."""

    type: Literal["SPH.Liquid"]
    rho: float = Field(1000.0, gt=0, description="Rest density rho0 [kg/m^3].")
    stiffness: float = Field(
        50000.0,
        gt=0,
        description="WCSPH: Tait stiffness k [Pa] in p = k ((rho / rho0)^exponent - 1); the sound speed is "
        "sqrt(k exponent / rho0) (50 kPa with exponent 7: 18.7 m/s). DFSPH ignores it.",
    )
    exponent: float = Field(7.0, gt=0, description="WCSPH: Tait exponent n [-] (7 for water).")
    mu: float = Field(
        0.001,
        ge=0,
        description="Dynamic viscosity [Pa s] (water at 20 C: 0.001), a physical viscosity (operator: "
        "solvers.sph.viscosity_operator).",
    )
    gamma: float = Field(
        0.0,
        ge=0,
        description="Surface tension / cohesion coefficient gamma of Akinci et al. (2013) (cohesion kernel "
        "plus curvature term; 0 disables it). An empirical coefficient of their force model, not a physical "
        "surface tension in N/m: its effect depends on the particle size (and in 2D on the kernel's "
        "normalisation), so calibrate it against a measured quantity (a drop's oscillation, a contact "
        "angle).",
    )


# Every SPH material type; the scene's material union is built from these.
MATERIALS = (SPHLiquid,)
