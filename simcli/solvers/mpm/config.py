"""MPM configuration: solver options and material models (pydantic, no Taichi).

The kernel half of each material is its constitutive law in ``constitutive.py``.
"""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

from simcli.scene.material_base import _Solid


class _Options(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, validate_default=True)


class MPMOptions(_Options):
    grid_density: float = Field(64.0, gt=0, description="Grid cells per metre [1/m]; cell size dx = 1/grid_density.")
    particle_size: float | None = Field(
        None,
        gt=0,
        description="Particle spacing of the sampling lattice [m]. Default 0.64/grid_density (0.01 m at 64 cells/m).",
    )
    sampling: Literal["lattice", "jitter"] = Field(
        "lattice", description="Particle sampling: regular lattice, or lattice with a random jitter."
    )
    cfl: float = Field(0.3, gt=0, le=1, description="CFL number used by substeps: auto [-].")

    @property
    def dx(self) -> float:
        return 1.0 / self.grid_density

    @property
    def spacing(self) -> float:
        return self.particle_size if self.particle_size is not None else 0.64 / self.grid_density


class MPMElastic(_Solid):
    """Hyperelastic MPM solid."""

    type: Literal["MPM.Elastic"]
    model: Literal["corotation", "neohooken"] = Field(
        "corotation",
        description="Constitutive model: 'corotation' (fixed corotated, Stomakhin et al. 2012) or "
        "'neohooken' (compressible Neo-Hookean; Genesis's spelling).",
    )


# Every MPM material type; the scene's material union is built from these.
MATERIALS = (MPMElastic,)
