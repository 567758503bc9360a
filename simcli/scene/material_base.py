"""Base classes of material configs (the config half of a material; no Taichi)."""

from __future__ import annotations

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
