"""``Body``: one entity's sampled initial state (numpy), what ``simcli.geometry.sampling`` produces and
the particle solvers consume (re-exported by ``simcli.solvers.base``). No Taichi here."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np


@dataclass
class Body:
    """One entity's sampled initial state (numpy, float64).

    ``x`` (n, dim) positions [m], ``v`` (n, dim) velocities [m/s], ``volume`` (n,)
    particle volumes [m^3], ``mass`` (n,) particle masses [kg] (rho x body volume / n,
    so the total mass is exact), ``fixed`` (n,) bool: held in place.
    """

    name: str
    entity: Any  # a simcli.scene.models.Entity (geometry sits below the scene models)
    x: np.ndarray
    v: np.ndarray
    volume: np.ndarray
    mass: np.ndarray
    fixed: np.ndarray
    warnings: list[str] = field(default_factory=list)  # what sampling changed or doubts (the runner reports)

    def __post_init__(self) -> None:
        self.x = np.ascontiguousarray(self.x, dtype=np.float64)
        n = self.x.shape[0]
        if self.x.ndim != 2:
            raise ValueError(f"Body {self.name!r}: x must be (n, dim), got shape {self.x.shape}")
        dim = self.x.shape[1]
        self.v = np.ascontiguousarray(self.v, dtype=np.float64).reshape(n, dim)
        self.volume = np.ascontiguousarray(self.volume, dtype=np.float64).reshape(n)
        self.mass = np.ascontiguousarray(self.mass, dtype=np.float64).reshape(n)
        self.fixed = np.ascontiguousarray(self.fixed, dtype=bool).reshape(n)

    def kept(self, keep: np.ndarray, x: np.ndarray | None = None, v: np.ndarray | None = None) -> Body:
        """The body with the particles where ``keep`` holds (positions ``x`` and velocities ``v`` instead of
        its own where given, before the selection)."""
        x = self.x if x is None else x
        v = self.v if v is None else v
        return Body(
            name=self.name,
            entity=self.entity,
            x=x[keep],
            v=v[keep],
            volume=self.volume[keep],
            mass=self.mass[keep],
            fixed=self.fixed[keep],
        )

    @property
    def n(self) -> int:
        return int(self.x.shape[0])

    @property
    def dim(self) -> int:
        return int(self.x.shape[1])
