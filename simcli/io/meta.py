"""``EntityMeta``: the static description of one output entity, what the writers receive once when the
output is opened (array conventions: see ``frames.py``). A leaf module of ``simcli.io``."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

KINDS = ("particles", "tets", "triangles", "lines", "grid")
NODES_PER_CELL = {"tets": 4, "triangles": 3, "lines": 2}


@dataclass
class EntityMeta:
    """Static description of one output entity.

    ``fields`` maps a field name to ``(components, unit)`` or ``(components, unit, dtype)``;
    the dtype defaults to ``EntityMeta.dtype`` (float32) for every field.
    """

    name: str
    kind: str  # "particles" | "tets" | "triangles" | "lines" | "grid"
    n: int  # points (or for grids: cells) count
    dim: int  # 2 or 3
    fields: dict[str, tuple] = field(default_factory=dict)
    cells: np.ndarray | None = None  # static topology (n_cells, nodes per cell) for meshes
    grid_shape: tuple | None = None  # (nx, ny[, nz]) for kind "grid"
    origin: tuple | None = None  # lower corner, x y z order
    spacing: tuple | None = None  # cell size, x y z order
    dtype: str = "float32"  # default storage type of the fields
    cell_fields: tuple = ()  # names in ``fields`` given per cell (n_cells values) of a mesh, not per point
    # particles whose count changes over the run (emitters, sinks): ``n`` is the capacity, a frame gives
    # its live particles (rows <= n); sim.h5 pads the rows past /entities/<name>/count
    variable: bool = False

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"entity {self.name!r}: kind must be one of {KINDS}, got {self.kind!r}")
        if int(self.n) < 1:
            raise ValueError(f"entity {self.name!r}: n must be >= 1, got {self.n!r}")
        self.n = int(self.n)
        if self.dim not in (2, 3):
            raise ValueError(f"entity {self.name!r}: dim must be 2 or 3, got {self.dim!r}")
        if not self.name or "/" in self.name or self.name.startswith("."):
            raise ValueError(f"entity name {self.name!r} is not usable as a group / file name")
        norm: dict[str, tuple[int, str, str]] = {}
        for fname, spec in self.fields.items():
            if isinstance(spec, int):
                spec = (spec, "1")
            comps, unit = int(spec[0]), str(spec[1])
            dtype = str(np.dtype(spec[2] if len(spec) > 2 else self.dtype))
            if comps < 1:
                raise ValueError(f"entity {self.name!r}: field {fname!r} needs >= 1 component")
            norm[fname] = (comps, unit, dtype)
        self.fields = norm  # type: ignore[assignment]
        if self.kind == "grid":
            if self.grid_shape is None or len(self.grid_shape) != self.dim:
                raise ValueError(
                    f"grid entity {self.name!r}: grid_shape needs {self.dim} entries (x, y[, z])"
                )
            self.grid_shape = tuple(int(s) for s in self.grid_shape)
            if int(np.prod(self.grid_shape)) != self.n:
                raise ValueError(
                    f"grid entity {self.name!r}: n={self.n} but grid_shape {self.grid_shape} has "
                    f"{int(np.prod(self.grid_shape))} cells"
                )
            self.origin = tuple(float(v) for v in (self.origin or (0.0,) * self.dim))
            self.spacing = tuple(float(v) for v in (self.spacing or (1.0,) * self.dim))
            if len(self.origin) != self.dim or len(self.spacing) != self.dim:
                raise ValueError(f"grid entity {self.name!r}: origin and spacing need {self.dim} entries")
        else:
            if "position" not in self.fields:
                raise ValueError(f"entity {self.name!r}: a {self.kind} entity needs a 'position' field")
            if self.fields["position"][0] != self.dim:
                raise ValueError(f"entity {self.name!r}: position must have {self.dim} components")
        self.cell_fields = tuple(self.cell_fields)
        for fname in self.cell_fields:
            if fname not in self.fields or fname == "position" or self.kind not in NODES_PER_CELL:
                raise ValueError(
                    f"entity {self.name!r}: cell field {fname!r} needs a declared field of a mesh"
                )
        if self.kind in NODES_PER_CELL:
            if self.cells is None:
                raise ValueError(f"mesh entity {self.name!r} ({self.kind}) needs cells")
            cells = np.ascontiguousarray(self.cells, dtype=np.int64)
            npc = NODES_PER_CELL[self.kind]
            if cells.ndim != 2 or cells.shape[1] != npc:
                raise ValueError(
                    f"entity {self.name!r}: cells must have shape (n_cells, {npc}), got {cells.shape}"
                )
            if cells.size and (cells.min() < 0 or cells.max() >= self.n):
                raise ValueError(f"entity {self.name!r}: cells index outside 0..{self.n - 1}")
            self.cells = cells

    # -- shapes ---------------------------------------------------------------------------
    @property
    def zyx_shape(self) -> tuple[int, ...]:
        """Grid shape in storage order: (nz, ny, nx) or (ny, nx)."""
        assert self.grid_shape is not None
        return tuple(reversed(self.grid_shape))

    def _rows(self, fname: str) -> int:
        """Values per frame of a mesh or particle field: one per cell for cell fields, else one per point."""
        return int(self.cells.shape[0]) if fname in self.cell_fields else self.n

    def frame_shape(self, fname: str) -> tuple[int, ...]:
        """Shape of one frame of a field as stored (without the leading frame axis)."""
        comps = self.fields[fname][0]
        base = self.zyx_shape if self.kind == "grid" else (self._rows(fname),)
        return base + ((comps,) if comps > 1 else ())

    def prepare(self, fname: str, arr) -> np.ndarray:
        """Validate one field array of a frame; return it C-contiguous in storage shape/dtype."""
        comps, _unit, dtype = self.fields[fname]
        a = np.asarray(arr)
        want = self.frame_shape(fname)
        if self.variable:  # any number of rows up to the capacity
            rows = a.shape[0] if a.ndim else -1
            if not 0 <= rows <= self.n or a.size != rows * comps:
                raise ValueError(
                    f"entity {self.name!r} field {fname!r}: expected up to {self.n} rows of {comps}, got "
                    f"{a.shape}"
                )
            return np.ascontiguousarray(a.reshape((rows,) + want[1:]), dtype=dtype)
        if a.shape != want:
            rows = self.n if self.kind == "grid" else self._rows(fname)
            flat = (rows,) + ((comps,) if comps > 1 else ())
            ok = a.size == int(np.prod(want)) and (
                a.shape == flat
                or (self.kind != "grid" and a.shape[:1] == (rows,))  # (n, 1) scalars, (n, 3, 3) tensors
            )
            if not ok:
                hint = " (grids are stored z, y, x: x varies fastest)" if self.kind == "grid" else ""
                raise ValueError(
                    f"entity {self.name!r} field {fname!r}: expected shape {want} or {flat}, "
                    f"got {a.shape}{hint}"
                )
            a = a.reshape(want)
        return np.ascontiguousarray(a, dtype=dtype)
