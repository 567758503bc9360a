"""MPM configuration: solver options and material models (pydantic, no Taichi).

The kernel half of each material is its constitutive law in ``constitutive.py`` (elastic laws),
``plasticity.py`` (elasto-plastic, sand, snow) and ``fluids_muscle.py`` (liquid, muscle).

Names and defaults follow Genesis (``gs.materials.MPM.*``) where Genesis's are right; where
they differ it is said in the field's description.
"""

from __future__ import annotations

import math
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from simcli.scene.material_base import _Material, _Solid
from simcli.scene.muscle import (  # noqa: F401  (re-exported: MPM.Muscle's groups and signals)
    ConstantSignal,
    MuscleGroup,
    MuscleGroups,
    Signal,
    SineSignal,
    TableSignal,
)

Vec = list[float]


class _Options(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, validate_default=True)


class MPMOptions(_Options):
    grid_density: float = Field(
        64.0, gt=0, description="Grid cells per metre [1/m]; cell size dx = 1/grid_density."
    )
    particle_size: float | None = Field(
        None,
        gt=0,
        description="Particle spacing of the sampling lattice [m]. Default 0.64/grid_density (0.01 m at 64 "
        "cells/m).",
    )
    sampling: Literal["lattice", "jitter", "poisson"] = Field(
        "lattice",
        description="Particle sampling: regular lattice; lattice with a random jitter; or Poisson-disk (blue "
        "noise, no lattice directions: for sand and snow). Poisson-disk samples keep a minimum distance of "
        "0.80 (2D) or 0.87 (3D) particle_size and hold about as many particles as the lattice.",
    )
    thin_parts: Literal["warn", "layer"] = Field(
        "warn",
        description="Mesh morphs: parts thinner than particle_size that the lattice misses (ears, fins, "
        "claws). warn: they get no particles (their mass goes to the others) and a warning says how much "
        "volume that is; layer: they get one layer of particles on their mid-surface (found by rays along "
        "x, y and z).",
    )
    cfl: float = Field(0.3, gt=0, le=1, description="CFL number used by substeps: auto [-].")
    transfer: Literal["apic", "flip"] = Field(
        "apic",
        description="Particle-grid velocity transfer. apic: affine particle-in-cell (Jiang et al. 2015), "
        "quiet and stable, for liquids, sand, snow, plasticity and large deformation; it damps an elastic "
        "body's vibration every substep at coarse resolution. flip: FLIP blended with PIC by flip_ratio "
        "(particles keep their velocity and add the grid's change; Sulsky et al. 1994), for elastic solids "
        "whose vibration and rebound matter: Sulsky's two disks at 20 cells/m and 1 ms steps keep 97% of "
        "their energy with flip_ratio 1 and 30% with apic. See docs/MPM.md, 'Which transfer?'.",
    )
    flip_ratio: float = Field(
        0.99,
        ge=0,
        le=1,
        description="transfer: flip only: weight of FLIP against PIC [-]; 1 is pure FLIP (least damping, "
        "keeps particle noise), 0 is pure PIC (most damping). The PIC share damps every substep: with many "
        "substeps per second use 1 for energy-conserving elastodynamics (on Sulsky's disks 0.999 keeps 91% "
        "where 1 keeps 97%).",
    )

    @property
    def dx(self) -> float:
        return 1.0 / self.grid_density

    @property
    def spacing(self) -> float:
        return self.particle_size if self.particle_size is not None else 0.64 / self.grid_density


# ------------------------------------------------------------------------------ solids


class MPMElastic(_Solid):
    """Hyperelastic MPM solid."""

    type: Literal["MPM.Elastic"]
    model: Literal["corotation", "neohooken"] = Field(
        "corotation",
        description="Constitutive model: 'corotation' (fixed corotated, Stomakhin et al. 2012) or "
        "'neohooken' (compressible Neo-Hookean; Genesis's spelling).",
    )


class MPMElastoPlastic(_Solid):
    """Elasto-plastic solid (metal, clay, dough): von Mises or singular-value clamping."""

    type: Literal["MPM.ElastoPlastic"]
    E: float = Field(1.0e6, gt=0, description="Young's modulus [Pa] (Genesis's default 1e6).")
    use_von_mises: bool = Field(
        True,
        description="true: von Mises (J2) plasticity on the Hencky (logarithmic) strain with Hencky "
        "elasticity, radial return; the von Mises equivalent Cauchy stress never exceeds "
        "von_mises_yield_stress (uniaxial stress saturates at it, pure shear at it / sqrt(3)). "
        "false: the singular values of the elastic deformation gradient are clamped into "
        "[1 - yield_lower, 1 + yield_higher] (Stomakhin et al. 2013 without hardening), fixed corotated "
        "elasticity.",
    )
    von_mises_yield_stress: float = Field(
        1.0e4, gt=0, description="Von Mises yield stress [Pa] (uniaxial Cauchy stress at yield)."
    )
    yield_lower: float = Field(
        2.5e-2,
        ge=0,
        lt=1,
        description="Critical compression theta_c [-]: singular values >= 1 - yield_lower "
        "(use_von_mises: false only).",
    )
    yield_higher: float = Field(
        4.5e-3,
        ge=0,
        description="Critical stretch theta_s [-]: singular values <= 1 + yield_higher "
        "(use_von_mises: false only).",
    )


class MuIRheology(_Options):
    """The mu(I) rheology of dense granular flow (GDR MiDi 2004; Jop, Forterre & Pouliquen 2006)."""

    delta_mu: float = Field(
        0.26,
        ge=0,
        description="mu_2 - mu_s [-]: how much the friction coefficient rises from its static value "
        "mu_s = tan(friction_angle) at high inertial number (Jop et al. 2006, glass beads: "
        "0.64 - 0.38 = 0.26).",
    )
    I0: float = Field(
        0.279,
        gt=0,
        description="Inertial number at which the friction is half way from mu_s to mu_2 [-] "
        "(Jop et al. 2006: 0.279).",
    )
    grain_diameter: float = Field(
        5.0e-4,
        gt=0,
        description="Grain diameter d [m] in I = gamma_dot d / sqrt(p / rho_s) (Jop et al. 2006: 0.5 mm).",
    )
    grain_density: float | None = Field(
        None,
        gt=0,
        description="Density of the grains' material rho_s [kg/m^3] in I. Default: the material's rho / 0.6 "
        "(a packing fraction of 0.6).",
    )


class MPMSand(_Solid):
    """Granular material: Drucker-Prager (Klar et al. 2016), Mohr-Coulomb or Matsuoka-Nakai, Hencky strain."""

    type: Literal["MPM.Sand"]
    E: float = Field(
        1.0e6, gt=0, description="Young's modulus [Pa] of the grain skeleton (Genesis's default 1e6)."
    )
    friction_angle: float = Field(
        45.0,
        gt=0,
        lt=90,
        description="Internal friction angle phi [deg] (Genesis's default 45; dry sand 30-35).",
    )
    cohesion: float = Field(
        0.0,
        ge=0,
        description="Cohesion c [Pa] (Mohr-Coulomb): the cone's apex moves to the tensile mean "
        "stress c / tan(phi). 0 = cohesionless sand.",
    )
    volume_correction: bool = Field(
        True,
        description="Keep the volume gained when grains separate and give it back on compression "
        "(Tampubolon et al. 2017, sec. 4.3.2), so piles do not lose volume.",
    )
    cone: Literal["simple_shear", "plane_strain", "compression"] = Field(
        "simple_shear",
        description="How the Drucker-Prager cone |dev tau| + alpha tr(tau) <= 0 is fitted to friction_angle "
        "(with yield_surface: auto in 3D, where the surface is matsuoka_nakai, compression unless given). "
        "simple_shear: a flowing layer (steady simple shear, zero dilatancy) carries tan(friction_angle) "
        "times "
        "its normal stress on its shear planes, so friction_angle is the angle of repose, in 2D and 3D "
        "(sqrt(J2) <= tan(phi) p as in the mu(I) rheology; alpha = sqrt(2) tan(phi) / 3). plane_strain: "
        "Mohr-Coulomb phi under plane strain with sigma_zz the in-plane mean (alpha = sqrt(2) sin(phi) / 3); "
        "with the zero-dilatancy flow a flowing layer then mobilises only tan = sin(phi) (Davis 1968): heaps "
        "settle at atan(sin(phi)), 26.6 deg for 30. compression: Klar et al. 2016 and Genesis, exact in "
        "triaxial compression (alpha = sqrt(2/3) 2 sin(phi) / (3 - sin(phi))); a flowing layer mobilises "
        "tan = 3 alpha / sqrt(2) (34.7 deg for 30).",
    )
    yield_surface: Literal["auto", "drucker_prager", "mohr_coulomb", "matsuoka_nakai"] = Field(
        "auto",
        description="The yield surface's shape in the deviatoric plane, with the same zero-dilatancy "
        "(volume-keeping) flow. auto (default): in 3D matsuoka_nakai, fitted in triaxial compression "
        "(cone: compression) unless cone is given, so friction_angle is its Mohr-Coulomb angle in triaxial "
        "compression and extension (the criterion's usual calibration; poured 3D heaps stand within 1.5 deg "
        "of it); in 2D, with mu_i, or with cone: simple_shear at 45 deg and above, drucker_prager (a plane "
        "flow sits at b = 0.5, where the cone fitted to simple shear carries tan(friction_angle)). "
        "OUT/scene.yaml echoes the surface and fit used. drucker_prager: a circular cone, the same in every "
        "direction, fitted by "
        "`cone`; fitted to simple shear it is, in triaxial compression (the surface flow of a conical heap, "
        "spreading radially), a Mohr-Coulomb material of only 25.4 deg for 30 deg sand. mohr_coulomb: the "
        "hexagonal pyramid (sigma_1 - sigma_3) + (sigma_1 + sigma_3 - 2 a) sin(phi_mc) <= 0 (Kirchhoff, "
        "tension positive; a the apex, as the cone's), whose shear-plane friction does not depend on the "
        "intermediate stress: exact return mapping in principal Hencky strain (main plane, edges, apex; "
        "de Souza Neto, Peric & Owen 2008, ch. 8) with the Tresca flow potential sigma_1 - sigma_3. With "
        "cone: simple_shear phi_mc = asin(tan(friction_angle)) (35.3 deg for 30), so a flowing layer "
        "carries tan(friction_angle) times its normal stress at any Lode angle: in 2D as the drucker_prager "
        "cone does, in 3D also where the flow spreads (phi_mc at most 70 deg: friction_angle <= 43.2); "
        "with plane_strain or compression phi_mc = friction_angle. matsuoka_nakai: the smooth cone "
        "I1 I2 / I3 = K of Matsuoka & Nakai 1974 (principal Kirchhoff stresses measured from the apex, "
        "compression positive), equal to Mohr-Coulomb in triaxial compression and extension and outside "
        "it between them; returned radially in the deviatoric plane (the cone's zero-dilatancy flow, a "
        "scalar cubic per particle). K is fitted by `cone` at b = 0.5, where the steady simple shear of "
        "the volume-keeping flow puts the stress: simple_shear: the Mohr circle there mobilises "
        "sin = tan(friction_angle), so a flowing layer carries tan(friction_angle) as with the other "
        "surfaces, and triaxial compression is then a Mohr-Coulomb material of 31.5 deg for 30 deg sand "
        "(between the cone's 25.4 and the pyramid's 35.3; friction_angle < 45); plane_strain: sin = "
        "sin(friction_angle) at b = 0.5; compression: exact Mohr-Coulomb friction_angle in triaxial "
        "compression and extension.",
    )
    mu_i: MuIRheology | None = Field(
        None,
        description="Rate-dependent friction, the mu(I) rheology: a flowing layer's friction rises "
        "from mu_s = tan(friction_angle) at rest to mu_s + delta_mu as its inertial number I = gamma_dot d / "
        "sqrt(p / rho_s) grows, mu(I) = mu_s + delta_mu I / (I0 + I) (Jop et al. 2006). The return mapping "
        "solves for the plastic shear rate that puts the stress on the cone of mu(I) (a scalar quadratic per "
        "particle). Needs cone: simple_shear. Omitted: rate-independent Drucker-Prager.",
    )

    @model_validator(mode="after")
    def _mu_i_needs_simple_shear(self) -> MPMSand:
        if self.mu_i is not None and self.cone != "simple_shear":
            raise ValueError(
                "mu_i needs cone: simple_shear (the cone on which tan(friction_angle) is a flowing layer's "
                "friction coefficient); remove mu_i or set cone: simple_shear"
            )
        return self

    @model_validator(mode="after")
    def _mohr_coulomb_fit(self) -> MPMSand:
        if self.yield_surface in ("auto", "drucker_prager"):  # auto falls back to the cone where MN can't
            return self
        if self.mu_i is not None:
            raise ValueError(
                "mu_i needs yield_surface: drucker_prager (the mu(I) return mapping is the cone's); remove "
                "mu_i or set yield_surface: drucker_prager"
            )
        if self.cone == "simple_shear" and self.friction_angle >= 45.0:
            given = "friction_angle" in self.model_fields_set
            which = (
                "the sine of the Mohr-Coulomb angle"
                if self.yield_surface == "mohr_coulomb"
                else "the sine of the angle the Matsuoka-Nakai cone mobilises at b = 0.5"
            )
            raise ValueError(
                ("" if given else "friction_angle is not set and its default is 45 deg: ")
                + f"yield_surface: {self.yield_surface} with cone: simple_shear needs friction_angle < 45 (a "
                f"flowing layer's friction tan(phi) = {math.tan(math.radians(self.friction_angle)):.3g} is "
                f"{which}, so it must be below 1); lower friction_angle, or set cone: plane_strain "
                + (
                    "(friction_angle is then the Mohr-Coulomb angle itself)"
                    if self.yield_surface == "mohr_coulomb"
                    else "(friction_angle is then the Mohr-Coulomb angle at b = 0.5) or cone: compression "
                    "(at triaxial compression)"
                )
            )
        if self.yield_surface == "mohr_coulomb" and self.mc_sin_phi > math.sin(math.radians(70.0)):
            # the edge returns solve a 2x2 system of determinant 4 - (1 + sin phi)^2: 0.014 at 85 deg
            raise ValueError(
                f"yield_surface: mohr_coulomb: the Mohr-Coulomb angle is "
                f"{math.degrees(math.asin(min(self.mc_sin_phi, 1.0))):.1f} deg; above 70 deg its edge "
                "returns are ill-conditioned in f32; lower friction_angle (with cone: simple_shear at most "
                "43.2)"
            )
        return self

    def resolved(self, dim: int) -> MPMSand:
        """This material as a ``dim``-dimensional scene uses it: ``yield_surface: auto`` replaced by the
        surface, and for auto's Matsuoka-Nakai the fit (``cone``) when the scene did not give one.

        auto is Matsuoka-Nakai in 3D, fitted in triaxial compression (friction_angle is then its
        Mohr-Coulomb angle in triaxial compression and extension, the criterion's usual calibration): a 3D
        flow that spreads (a conical heap's flank, the bed under an impact) sits near triaxial compression,
        where the circular cone fitted to simple shear carries only 25.4 deg for 30 deg sand, and where
        poured 3D heaps of 30 and 40 deg sand then stand within 1.5 deg of the friction angle
        (docs/VALIDATION.md, granular items 5-10). In 2D the volume-keeping flow puts the stress at b = 0.5,
        where the cone fitted to simple shear carries tan(friction_angle), so the cheaper cone is kept there;
        also with mu_i (the cone's rheology), and with an explicit cone: simple_shear at 45 deg and above
        (no finite Matsuoka-Nakai K)."""
        if self.yield_surface != "auto":
            return self
        if int(dim) == 3 and self.mu_i is None:
            cone = self.cone if "cone" in self.model_fields_set else "compression"
            if not (cone == "simple_shear" and self.friction_angle >= 45.0):
                return self.model_copy(update={"yield_surface": "matsuoka_nakai", "cone": cone})
        return self.model_copy(update={"yield_surface": "drucker_prager"})

    @property
    def mc_sin_phi(self) -> float:
        """sin(phi_mc) of the ``mohr_coulomb`` surface (see ``yield_surface``)."""
        if self.cone == "simple_shear":
            return math.tan(math.radians(self.friction_angle))
        return math.sin(math.radians(self.friction_angle))

    @property
    def mn_k(self) -> float:
        """K = I1 I2 / I3 of the ``matsuoka_nakai`` cone (see ``yield_surface``; Matsuoka & Nakai 1974).

        In triaxial compression (sigma_2 = sigma_3, compression positive) at Mohr-Coulomb angle phi_c,
        K = (9 - sin^2 phi_c) / (1 - sin^2 phi_c); at b = 0.5 (sigma_2 the mean of sigma_1 and sigma_3, the
        Mohr circle's sin phi_b = (sigma_1 - sigma_3) / (sigma_1 + sigma_3) = x), I1 = 3 p, I2 = 3 p^2 - q^2,
        I3 = p (p^2 - q^2), q = x p: K = 3 (3 - x^2) / (1 - x^2)."""
        s = math.sin(math.radians(self.friction_angle))
        if self.cone == "compression":
            return (9.0 - s * s) / (1.0 - s * s)
        x = math.tan(math.radians(self.friction_angle)) if self.cone == "simple_shear" else s
        return 3.0 * (3.0 - x * x) / (1.0 - x * x)

    @property
    def mn_inner_radius(self) -> float:
        """The ``matsuoka_nakai`` cone's smallest deviatoric radius |dev c| / p' (at triaxial extension, w =
        1 / (3 sqrt 6)): the root of (9 - K) + (K - 3) / 2 u^2 + K w u^3 = 0, which falls as w grows. Trial
        states inside it are elastic at any Lode angle (the return skips its cubic for them)."""
        k = self.mn_k
        a, b, c = 9.0 - k, 0.5 * (k - 3.0), k / (3.0 * math.sqrt(6.0))
        u = math.sqrt(
            -a / b
        )  # the root at w = 0, above the wanted one; h convex for w > 0: Newton from above
        for _ in range(100):
            step = (a + b * u * u + c * u**3) / (2.0 * b * u + 3.0 * c * u * u)
            u -= step
            if abs(step) <= 1e-15 * u:
                break
        return u

    @property
    def grain_density(self) -> float:
        """rho_s [kg/m^3] of the mu(I) inertial number (0 without mu_i)."""
        if self.mu_i is None:
            return 0.0
        return self.mu_i.grain_density if self.mu_i.grain_density is not None else self.rho / 0.6

    @property
    def alpha(self) -> float:
        """Drucker-Prager cone slope alpha (see ``cone``)."""
        s = math.sin(math.radians(self.friction_angle))
        if self.cone == "compression":
            return math.sqrt(2.0 / 3.0) * 2.0 * s / (3.0 - s)  # Klar et al. 2016, eq. 25
        if self.cone == "plane_strain":
            # plane strain, sigma_zz the mean in-plane stress at failure, so |dev tau| = sqrt(2) R and
            # tr tau = 3 c (Mohr circle radius R, centre c): R = -(3 alpha / sqrt 2) c = sin(phi) |c|
            return math.sqrt(2.0) * s / 3.0
        # simple shear with the zero-dilatancy (deviatoric, coaxial) flow of the return mapping: the
        # shear planes carry the largest shear stress R and normal stress c (sigma_xx = sigma_yy, and
        # sigma_zz = c once flowing), so tau / sigma_n = R / |c| = 3 alpha / sqrt(2) = tan(phi)
        return math.sqrt(2.0) * math.tan(math.radians(self.friction_angle)) / 3.0


class MPMSnow(_Solid):
    """Snow (Stomakhin et al. 2013): clamped singular values, hardening exp(xi (1 - J_p))."""

    type: Literal["MPM.Snow"]
    E: float = Field(
        1.0e6,
        gt=0,
        description="Young's modulus [Pa] (Genesis's default 1e6; Stomakhin et al. 2013 use 1.4e5).",
    )
    yield_lower: float = Field(
        2.5e-2,
        ge=0,
        lt=1,
        description="Critical compression theta_c [-]: singular values >= 1 - yield_lower.",
    )
    yield_higher: float = Field(
        4.5e-3,
        ge=0,
        description="Critical stretch theta_s [-]: singular values <= 1 + yield_higher "
        "(Stomakhin et al. use 7.5e-3).",
    )
    hardening: float = Field(
        10.0,
        ge=0,
        description="Hardening coefficient xi [-]: mu and lambda are scaled by exp(xi (1 - J_p)), "
        "J_p the plastic volume ratio (Stomakhin et al. 2013: 10; Genesis hard-codes 10).",
    )


# ------------------------------------------------------------------------------ liquid


class MPMLiquid(_Material):
    """Weakly compressible liquid: only J of F is kept; optional Newtonian viscosity."""

    type: Literal["MPM.Liquid"]
    E: float = Field(
        1.0e6,
        gt=0,
        description="Young's modulus [Pa] (Genesis's parametrisation): with nu it sets the bulk "
        "modulus lambda = E nu / ((1 + nu)(1 - 2 nu)) of the equation of state p = lambda (1 - J); "
        "speed of sound sqrt(lambda / rho).",
    )
    nu: float = Field(0.2, gt=-1.0, lt=0.5, description="Poisson's ratio [-]; only sets lambda with E.")
    rho: float = Field(1000.0, gt=0, description="Rest density [kg/m^3].")
    viscous: bool = Field(
        False,
        description="Add the Newtonian viscous stress 2 mu dev(D), D the symmetric velocity gradient "
        "(Genesis's 'viscous' adds an elastic shear term whose viscosity depends on the time step instead).",
    )
    mu: float = Field(1.0e-3, ge=0, description="Dynamic viscosity [Pa s] (water 1e-3), used when viscous.")
    tension: bool = Field(
        True,
        description="Whether the liquid carries tension (J > 1: p = lambda (1 - J) < 0, Genesis's equation "
        "of state). false: p = lambda max(1 - J, 0), a tensile cutoff: where the liquid spreads (a dam-break "
        "front, a splash) its particles part instead of pulling each other back; J is still tracked, so a "
        "parted liquid that closes up again returns to zero pressure, not above it. Experimental: J drifts "
        "in a splash (particles that settle with J > 1 carry no pressure and the pool compacts), "
        "docs/MPM.md.",
    )

    @property
    def lam(self) -> float:
        return self.E * self.nu / ((1.0 + self.nu) * (1.0 - 2.0 * self.nu))

    @property
    def bulk_modulus(self) -> float:
        """dp/dJ at rest [Pa]."""
        return self.lam


# ------------------------------------------------------------------------------ muscle
# The activation signals and muscle groups are shared with FEM.Muscle: simcli.scene.muscle.


class MPMMuscle(MuscleGroups, _Solid):
    """Elastic solid with active fibre stress: tau_active = stiffness a(t) (F f0)(F f0)^T."""

    type: Literal["MPM.Muscle"]
    E: float = Field(1.0e6, gt=0, description="Young's modulus [Pa] (Genesis's default 1e6).")
    model: Literal["corotation", "neohooken"] = Field(
        "neohooken", description="Passive elastic model (Genesis's default for muscle: neohooken)."
    )
    stiffness: float | None = Field(
        None,
        gt=0,
        description="Active stress per unit activation [Pa] (default E, as in Genesis). Positive "
        "activation is tension along the fibre: the muscle contracts.",
    )
    n_groups: int = Field(1, ge=1, le=64, description="Number of independently actuated groups.")
    fiber_direction: Vec | None = Field(
        None,
        description="Default fibre direction [-] of every group (default the last axis: z in 3D, y in 2D).",
    )
    groups: list[MuscleGroup] = Field(
        default_factory=list,
        description="One entry per group (n_groups of them): region, fibre direction and "
        "actuation signal. Empty: one group holding the whole body, no actuation.",
    )

    @model_validator(mode="after")
    def _check(self):
        self._check_groups()
        return self


# Every MPM material type; the scene's material union is built from these.
MATERIALS = (MPMElastic, MPMElastoPlastic, MPMSand, MPMSnow, MPMLiquid, MPMMuscle)
