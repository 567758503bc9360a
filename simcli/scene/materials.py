"""Material models, the config half: a discriminated union on `type`.

The kernel half of each material (its constitutive law) lives with its solver
(e.g. ``simcli/solvers/mpm/constitutive.py``). Only materials implemented by a
solver are listed here, so an unknown or not-yet-available type is a clear
validation error rather than a run-time failure.
"""

from __future__ import annotations

from typing import Annotated, Literal, Union

from pydantic import BaseModel, ConfigDict, Field


class _Material(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, validate_default=True)


class _Solid(_Material):
    E: float = Field(3.0e5, gt=0, description="Young's modulus [Pa].")
    nu: float = Field(0.2, gt=-1.0, lt=0.5, description="Poisson's ratio [-], in (-1, 0.5).")
    rho: float = Field(1000.0, gt=0, description="Density [kg/m^3].")

    @property
    def mu(self) -> float:
        return self.E / (2.0 * (1.0 + self.nu))

    @property
    def lam(self) -> float:
        return self.E * self.nu / ((1.0 + self.nu) * (1.0 - 2.0 * self.nu))


class MPMElastic(_Solid):
    """Hyperelastic MPM solid."""

    type: Literal["MPM.Elastic"]
    model: Literal["corotation", "neohooken"] = Field(
        "corotation",
        description="Constitutive model: 'corotation' (fixed corotated, Stomakhin et al. 2012) or "
        "'neohooken' (compressible Neo-Hookean; Genesis's spelling).",
    )


# Registry: every material type a solver implements. Add new models here.
MATERIAL_TYPES: tuple[type[_Material], ...] = (MPMElastic,)

if len(MATERIAL_TYPES) > 1:
    Material = Annotated[Union[MATERIAL_TYPES], Field(discriminator="type")]  # type: ignore[valid-type]
else:
    Material = MATERIAL_TYPES[0]  # type: ignore[misc]

# Types of the contract that are not implemented yet: named in a clear error.
PLANNED_TYPES = (
    "MPM.ElastoPlastic", "MPM.Sand", "MPM.Snow", "MPM.Liquid", "MPM.Muscle",
    "FEM.Elastic", "FEM.Muscle", "FEM.Cloth",
    "PBD.Cloth", "PBD.Elastic", "PBD.Liquid", "PBD.Particle",
    "SPH.Liquid", "SF.Smoke",
)


def material_type_names() -> list[str]:
    return [m.model_fields["type"].annotation.__args__[0] for m in MATERIAL_TYPES]
