"""The MAC (staggered) grid of the stable-fluids solver: layout, cell flags, face kinds and the
multigrid hierarchy, computed on the host with numpy at build time (no Taichi here).

Layout (``n`` cells per axis, cell size ``dx`` per axis, ``origin`` = the domain's lower corner):

* cell ``I`` (0 <= I_a < n_a) has its centre at ``origin + (I + 1/2) dx``; cell fields (pressure,
  smoke density, temperature) are stored with one ghost layer: indices -1 .. n_a.
* the velocity component ``d`` lives on the faces normal to axis d: face ``I`` lies between cells
  ``I - e_d`` and ``I``, at ``origin + (I + 1/2 - e_d/2) dx``; indices 0 .. n_d along d and, with one
  ghost layer for the wall conditions, -1 .. n_a along every other axis. Every face array is
  allocated with the same padded shape ``n + 3`` (offset -1) so one kernel fits all components.

Why MAC: the discrete divergence of the projected field equals the residual of the pressure
equation exactly, so a projection converged to a tolerance leaves a divergence below that
tolerance, with no checkerboard pressure mode; the normal velocity of a wall or a collider is a
face value, set exactly. (A collocated grid with the compact Laplacian, Genesis's choice, is an
approximate projection: its central-difference divergence does not vanish however long the
Jacobi iteration runs; see docs/SF.md.)

Face kinds (per component, one byte per face) are the single source of truth for the boundary
conditions: the pressure diagonal, the velocity update after the solve and the viscosity
operator are all derived from them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

# cell flags
FLUID, SOLID, OPEN = 0, 1, 2
# face kinds
FREE, OPEN_FACE, SOLID_FACE, WALL_LO, WALL_HI, DUP, NONE = 0, 1, 2, 3, 4, 5, 6
# wall conditions per domain face
W_SLIP, W_STICKY, W_OPEN, W_PERIODIC = 0, 1, 2, 3
_WALL_KIND = {"slip": W_SLIP, "separate": W_SLIP, "sticky": W_STICKY, "open": W_OPEN, "periodic": W_PERIODIC}

COARSEST = 4  # stop coarsening when the coarse grid would have fewer cells than this along an axis


@dataclass
class Level:
    """One multigrid level: cells per axis, Poisson coupling per axis, diagonal (0 = not fluid)."""

    n: tuple
    c: tuple  # coupling coefficient per axis [1/m^2] (Galerkin-scaled on coarse levels)
    diag: np.ndarray  # shape n (no ghosts)


@dataclass
class Layout:
    dim: int
    n: tuple  # cells per axis
    dx: tuple  # cell size per axis [m]
    origin: np.ndarray  # lower corner [m]
    wall: list  # [axis][side] -> W_* kind (side 0 = lower, 1 = upper)
    wall_velocity: np.ndarray  # (dim, 2, dim) velocity of each domain face [m/s]
    periodic: tuple  # per axis
    flags: np.ndarray = field(default=None)  # (n + 2) with ghosts (index shift +1)
    kinds: list = field(default_factory=list)  # per component: (n + 3) face kinds (index shift +1)
    levels: list = field(default_factory=list)

    @property
    def cells(self) -> int:
        return int(math.prod(self.n))

    @property
    def has_open(self) -> bool:
        return any(self.wall[a][s] == W_OPEN for a in range(self.dim) for s in range(2))

    def cell_centres(self) -> list[np.ndarray]:
        """Coordinates of every cell centre, one (n) array per axis (index order x, y[, z])."""
        axes = [self.origin[a] + (np.arange(self.n[a]) + 0.5) * self.dx[a] for a in range(self.dim)]
        return list(np.meshgrid(*axes, indexing="ij"))

    def face_centres(self, d: int) -> list[np.ndarray]:
        """Coordinates of the faces of component d (n + e_d), one array per axis."""
        axes = []
        for a in range(self.dim):
            if a == d:
                axes.append(self.origin[a] + np.arange(self.n[a] + 1) * self.dx[a])
            else:
                axes.append(self.origin[a] + (np.arange(self.n[a]) + 0.5) * self.dx[a])
        return list(np.meshgrid(*axes, indexing="ij"))


def make_layout(scene, opts) -> Layout:
    dim = int(scene.sim.dim)
    lo, hi = scene.domain.bounds(dim)
    n, dx = opts.cells(lo, hi)
    wall, vel = [], np.zeros((dim, 2, dim))
    for a in range(dim):
        row = []
        for s, sign in enumerate("-+"):
            b = scene.domain.face("xyz"[a] + sign)
            row.append(_WALL_KIND[b.type])
            if b.velocity is not None and b.type not in ("open", "periodic"):
                vel[a, s] = b.velocity
        wall.append(row)
    periodic = tuple(wall[a][0] == W_PERIODIC and wall[a][1] == W_PERIODIC for a in range(dim))
    for a in range(dim):
        if (wall[a][0] == W_PERIODIC) != (wall[a][1] == W_PERIODIC):
            raise ValueError(f"domain faces {'xyz'[a]}- and {'xyz'[a]}+ must both be periodic or neither")
        if periodic[a] and n[a] % 2:
            raise ValueError(f"a periodic axis needs an even number of cells ({'xyz'[a]}: {n[a]})")
    return Layout(dim, tuple(n), tuple(dx), np.asarray(lo, dtype=np.float64), wall, vel, periodic)


# ----------------------------------------------------------------------------- colliders


def collider_mask(scene, layout: Layout, scene_dir=None) -> np.ndarray:
    """Cells whose centre lies inside a collider (shape n); ``scene_dir``: Mesh colliders' files are
    relative to it."""
    if not scene.colliders:
        return np.zeros(layout.n, dtype=bool)
    x = np.stack([c.ravel() for c in layout.cell_centres()], axis=1)
    from simcli.colliders import _collider_spec, sdf_np  # the shared collider geometry (numpy half)

    solid = np.zeros(len(x), dtype=bool)
    for c in scene.colliders:
        solid |= sdf_np(_collider_spec(c, layout.dim, scene, scene_dir), x) < 0
    return solid.reshape(layout.n)


# ----------------------------------------------------------------------------- flags, kinds


def _ghost_flags(flags: np.ndarray, layout: Layout, n: tuple) -> np.ndarray:
    """Pad interior flags (shape n) with the ghost layer of the domain faces."""
    dim = layout.dim
    F = np.full(tuple(c + 2 for c in n), SOLID, dtype=np.uint8)
    F[(slice(1, -1),) * dim] = flags
    for a in range(dim):
        for s, idx in ((0, 0), (1, n[a] + 1)):
            sl = [slice(None)] * dim
            sl[a] = idx
            w = layout.wall[a][s]
            if w == W_PERIODIC:
                src = [slice(None)] * dim
                src[a] = n[a] if s == 0 else 1
                F[tuple(sl)] = F[tuple(src)]
            else:
                F[tuple(sl)] = OPEN if w == W_OPEN else SOLID
    return F


def compute_flags(layout: Layout, solid: np.ndarray) -> None:
    interior = np.where(solid, SOLID, FLUID).astype(np.uint8)
    layout.flags = _ghost_flags(interior, layout, layout.n)
    layout.kinds = [face_kinds(layout, d) for d in range(layout.dim)]
    layout.levels = make_levels(layout)


def face_kinds(layout: Layout, d: int) -> np.ndarray:
    """Kind of every face of component d, in the padded (n + 3, offset -1) face layout."""
    dim, n, F = layout.dim, layout.n, layout.flags
    K = np.full(tuple(c + 3 for c in n), NONE, dtype=np.uint8)
    # faces I_d = 0..n_d, I_o = 0..n_o-1: left cell I - e_d, right cell I (padded flag index + 1)
    left = [slice(1, n[a] + 1) for a in range(dim)]
    right = [slice(1, n[a] + 1) for a in range(dim)]
    left[d] = slice(0, n[d] + 1)
    right[d] = slice(1, n[d] + 2)
    fl, fr = F[tuple(left)], F[tuple(right)]
    kind = np.full(fl.shape, FREE, dtype=np.uint8)
    kind[(fl == OPEN) | (fr == OPEN)] = OPEN_FACE
    kind[(fl == SOLID) | (fr == SOLID)] = SOLID_FACE
    sl = [slice(None)] * dim
    if layout.periodic[d]:
        sl[d] = n[d]
        kind[tuple(sl)] = DUP
        # face 0 sits between cell n_d - 1 and cell 0 (the ghost flags hold the wrapped cells)
    else:
        for s, idx, wk in ((0, 0, WALL_LO), (1, n[d], WALL_HI)):
            sl[d] = idx
            if layout.wall[d][s] != W_OPEN:
                kind[tuple(sl)] = wk
    dst = [slice(1, n[a] + 1) for a in range(dim)]
    dst[d] = slice(1, n[d] + 2)
    K[tuple(dst)] = kind
    return K


def face_values(layout: Layout, d: int) -> np.ndarray:
    """Prescribed velocity of every fixed face of component d (padded face layout), 0 elsewhere."""
    K = layout.kinds[d]
    V = np.zeros(K.shape)
    V[K == WALL_LO] = layout.wall_velocity[d, 0, d]
    V[K == WALL_HI] = layout.wall_velocity[d, 1, d]
    return V


def is_fixed(kind: np.ndarray) -> np.ndarray:
    return (kind == SOLID_FACE) | (kind == WALL_LO) | (kind == WALL_HI)


# ----------------------------------------------------------------------------- Poisson


_WEIGHT = {FREE: 1.0, OPEN_FACE: 2.0}


def fine_diagonal(layout: Layout) -> np.ndarray:
    """Diagonal of the pressure operator on the fine grid from the face kinds (0 = not an unknown).

    Each free face couples its two cells with weight c_a = 1/dx_a^2; an open face (pressure 0 on
    the face, half a cell away) weighs 2 c_a; walls and colliders none."""
    dim, n = layout.dim, layout.n
    D = np.zeros(n)
    for a in range(dim):
        K = layout.kinds[a][tuple(slice(1, n[b] + 1) if b != a else slice(1, n[a] + 2) for b in range(dim))]
        w = np.zeros(K.shape)
        w[K == FREE] = 1.0
        w[K == OPEN_FACE] = 2.0
        if layout.periodic[a]:  # face n_a is face 0
            sl = [slice(None)] * dim
            sl[a] = n[a]
            src = [slice(None)] * dim
            src[a] = 0
            w[tuple(sl)] = w[tuple(src)]
        lo = [slice(None)] * dim
        hi = [slice(None)] * dim
        lo[a] = slice(0, n[a])
        hi[a] = slice(1, n[a] + 1)
        D += (w[tuple(lo)] + w[tuple(hi)]) / layout.dx[a] ** 2
    fluid = layout.flags[(slice(1, -1),) * dim] == FLUID
    return np.where(fluid, D, 0.0)


def _level_diagonal(layout: Layout, fluid: np.ndarray, n: tuple, c: tuple) -> np.ndarray:
    dim = layout.dim
    F = _ghost_flags(np.where(fluid, FLUID, SOLID).astype(np.uint8), layout, n)
    D = np.zeros(n)
    for a in range(dim):
        for sh in (0, 2):
            sl = [slice(1, n[b] + 1) for b in range(dim)]
            sl[a] = slice(sh, sh + n[a])
            nb = F[tuple(sl)]
            w = np.where(nb == FLUID, 1.0, np.where(nb == OPEN, 2.0, 0.0))
            D += w * c[a]
    return np.where(fluid, D, 0.0)


def make_levels(layout: Layout) -> list[Level]:
    """The multigrid hierarchy: cell-centred coarsening by 2 (a coarse cell is fluid when any of its
    children is), piecewise-constant transfers, Galerkin-scaled couplings (P^T A P of piecewise
    constant P: 2^(d-1) fine faces cross each coarse face)."""
    dim = layout.dim
    c = tuple(1.0 / h**2 for h in layout.dx)
    D0 = fine_diagonal(layout)
    levels = [Level(layout.n, c, D0)]
    fluid = D0 > 0
    n = layout.n
    while True:
        nc = tuple((k + 1) // 2 for k in n)
        if min(nc) < 2 or max(nc) < COARSEST or any(layout.periodic[a] and n[a] % 2 for a in range(dim)):
            break
        pad = [(0, 2 * nc[a] - n[a]) for a in range(dim)]
        f = np.pad(fluid, pad, constant_values=False)
        f = f.reshape(sum(((nc[a], 2) for a in range(dim)), ())).any(axis=tuple(range(1, 2 * dim, 2)))
        c = tuple(ca * 2 ** (dim - 1) for ca in c)
        levels.append(Level(nc, c, _level_diagonal(layout, f, nc, c)))
        fluid, n = f, nc
    return levels


# ----------------------------------------------------------------------------- viscosity

_BEYOND = 255  # kind of a face outside the grid (the neighbour of an open face)


def viscosity_operator(layout: Layout, d: int) -> tuple[np.ndarray, np.ndarray]:
    """(K, B) of component d in the padded face layout (see the module docstring)."""
    dim, n = layout.dim, layout.n
    valid = tuple(slice(1, n[a] + (2 if a == d else 1)) for a in range(dim))
    kind = layout.kinds[d][valid].copy()
    val = face_values(layout, d)[valid]
    if layout.periodic[d]:  # the unknowns are faces 0 .. n_d - 1; face n_d is face 0
        cut = tuple(slice(0, n[d]) if a == d else slice(None) for a in range(dim))
        kind, val = kind[cut], val[cut]
    free = (kind == FREE) | (kind == OPEN_FACE)
    K = np.zeros(kind.shape)
    B = np.zeros(kind.shape)
    for a in range(dim):
        c = 1.0 / layout.dx[a] ** 2
        for s in (1, -1):
            if layout.periodic[a]:
                nk = np.roll(kind, -s, axis=a)
                nv = np.roll(val, -s, axis=a)
            else:
                pad = [(0, 0)] * dim
                pad[a] = (0, 1) if s > 0 else (1, 0)
                nk = np.pad(kind, pad, constant_values=_BEYOND)
                nv = np.pad(val, pad)
                sl = [slice(None)] * dim
                sl[a] = slice(1, None) if s > 0 else slice(0, -1)
                nk, nv = nk[tuple(sl)], nv[tuple(sl)]
            nfix = is_fixed(nk)
            nfree = (nk == FREE) | (nk == OPEN_FACE)
            K += c * (nfix | nfree)
            B += c * np.where(nfix, nv, 0.0)
            if a != d and not layout.periodic[a]:
                side = 1 if s > 0 else 0
                if layout.wall[a][side] == W_STICKY:
                    beyond = nk == _BEYOND
                    K += 2.0 * c * beyond
                    B += 2.0 * c * layout.wall_velocity[a, side, d] * beyond
    K = np.where(free, K, -1.0)
    B = np.where(free, B, 0.0)
    Kp = np.full(tuple(c + 3 for c in n), -1.0)
    Bp = np.zeros(Kp.shape)
    dst = tuple(slice(1, 1 + k) for k in kind.shape)
    Kp[dst] = K
    Bp[dst] = B
    return Kp, Bp
