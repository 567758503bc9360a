"""Morphs (initial shapes) and regions (for `fixed`)."""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

Vec = list[float]


class _Shape(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, validate_default=True)


class BoxShape(_Shape):
    type: Literal["Box"]
    lower: Vec | None = Field(None, description="Lower corner [m] (with upper), or use center and size.")
    upper: Vec | None = Field(None, description="Upper corner [m].")
    center: Vec | None = Field(None, description="Centre [m] (with size).")
    size: Vec | None = Field(None, description="Edge lengths [m] (with center).")

    @model_validator(mode="after")
    def _check(self):
        corners = self.lower is not None or self.upper is not None
        cs = self.center is not None or self.size is not None
        if corners and cs:
            raise ValueError("give lower/upper or center/size, not both")
        if corners and (self.lower is None or self.upper is None):
            raise ValueError("give both lower and upper")
        if cs and (self.center is None or self.size is None):
            raise ValueError("give both center and size")
        if not corners and not cs:
            raise ValueError("give lower and upper (or center and size)")
        lo, hi = self.bounds()
        if len(lo) != len(hi):
            raise ValueError("lower and upper (center and size) must have the same length")
        for a, b in zip(lo, hi):
            if not a < b:
                raise ValueError(f"lower must be < upper on every axis (got lower {lo}, upper {hi})")
        return self

    def bounds(self) -> tuple[list[float], list[float]]:
        if self.lower is not None:
            return list(self.lower), list(self.upper)
        return (
            [c - s / 2 for c, s in zip(self.center, self.size)],
            [c + s / 2 for c, s in zip(self.center, self.size)],
        )


class SphereShape(_Shape):
    type: Literal["Sphere"]
    center: Vec = Field(description="Centre [m] (a disk in 2D).")
    radius: float = Field(gt=0, description="Radius [m].")

    def bounds(self):
        return [c - self.radius for c in self.center], [c + self.radius for c in self.center]


class CylinderShape(_Shape):
    type: Literal["Cylinder"]
    center: Vec = Field(description="Centre of the axis segment [m].")
    radius: float = Field(gt=0, description="Radius [m].")
    height: float = Field(gt=0, description="Length along the axis [m].")
    axis: Literal["x", "y", "z"] = Field("z", description="Axis direction.")

    def bounds(self):
        ax = "xyz".index(self.axis)
        half = [self.radius] * len(self.center)
        if ax < len(half):
            half[ax] = self.height / 2
        return [c - h for c, h in zip(self.center, half)], [c + h for c, h in zip(self.center, half)]


class MeshShape(_Shape):
    type: Literal["Mesh"]
    file: str = Field(
        description="Closed surface mesh (any format meshio reads), relative to the scene file."
    )
    scale: float | Vec = Field(1.0, description="Scale factor [-] (scalar or per axis), applied first.")
    rotate: Vec = Field(
        default_factory=lambda: [0.0, 0.0, 0.0],
        description="Rotation: Euler angles x, y, z [deg], applied second.",
    )
    translate: Vec = Field(
        default_factory=lambda: [0.0, 0.0, 0.0], description="Translation [m], applied last."
    )


class RectangleShape(_Shape):
    """A flat triangulated sheet (PBD cloth): (resolution[0] + 1) x (resolution[1] + 1) vertices."""

    type: Literal["Rectangle"]
    center: Vec = Field(description="Centre of the sheet [m] (3 components).")
    size: list[float] = Field(
        description="Side lengths [m] along the sheet's two in-plane axes u and v "
        "(2 components). u is the x axis projected onto the sheet (the y axis when the "
        "normal is close to x), v = normal x u.",
        min_length=2,
        max_length=2,
    )
    resolution: int | list[int] = Field(
        20,
        description="Segments along u and v (one number for both, or 2); each grid cell is split into two "
        "triangles, diagonals alternating.",
    )
    normal: Vec = Field(
        default_factory=lambda: [0.0, 0.0, 1.0],
        description="Unit normal of the sheet [-] (normalised on load).",
    )

    @model_validator(mode="after")
    def _check(self):
        if any(not s > 0 for s in self.size):
            raise ValueError(f"size must be > 0 on both in-plane axes (got {self.size})")
        res = [self.resolution] * 2 if isinstance(self.resolution, int) else list(self.resolution)
        if len(res) != 2 or any(r < 1 for r in res):
            raise ValueError(f"resolution must be one integer >= 1 or two (got {self.resolution})")
        if len(self.normal) != 3 or sum(c * c for c in self.normal) == 0:
            raise ValueError(f"normal must be a non-zero 3-vector (got {self.normal})")
        return self

    def bounds(self):
        h = 0.5 * (self.size[0] ** 2 + self.size[1] ** 2) ** 0.5
        return [c - h for c in self.center], [c + h for c in self.center]


class LineShape(_Shape):
    """A rope or chain along a polyline (PBD rods): ``segments`` equal segments along its arc length."""

    type: Literal["Line"]
    points: list[Vec] = Field(
        description="Polyline corners [m] (at least 2); the rest length is the polyline's length.",
        min_length=2,
    )
    segments: int | None = Field(
        None,
        ge=1,
        description="Number of equal-length segments (vertices = segments + 1), spread along the "
        "polyline by arc length (default: one per polyline piece).",
    )
    radius: float = Field(
        0.005,
        gt=0,
        description="Radius of the rod's cross-section [m]: mass = rho x pi "
        "radius^2 x length, and its contact thickness.",
    )

    @model_validator(mode="after")
    def _check(self):
        if len({len(p) for p in self.points}) != 1:
            raise ValueError("every point of a Line needs the same number of components")
        return self

    def bounds(self):
        d = len(self.points[0])
        return (
            [min(p[k] for p in self.points) for k in range(d)],
            [max(p[k] for p in self.points) for k in range(d)],
        )


Morph = Annotated[
    BoxShape | SphereShape | CylinderShape | MeshShape | RectangleShape | LineShape,
    Field(discriminator="type"),
]
Region = Annotated[BoxShape | SphereShape | CylinderShape, Field(discriminator="type")]
