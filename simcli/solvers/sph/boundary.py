"""Boundaries as particles (Akinci et al. 2012, "Versatile rigid-fluid coupling for incompressible SPH"),
sampled volume-correctly: domain walls and colliders become static layers of boundary particles that
enter the liquid's density, pressure and (no-slip) viscosity sums.

Sampling (numpy, at build): each boundary particle stands for a piece of solid of volume ``V_b``.
Walls are ``LAYERS`` lattice layers of spacing ``particle_size`` outside each face of the domain box
(with edges and corners), aligned with the face, so that liquid on a lattice next to a wall sees one
continuous lattice: its density is rho0 to the accuracy of the kernel's lattice sum (1e-4), the
condition Akinci's volume correction approximates for a single layer. Colliders are filled with the
lattice points of their solid that lie within ``LAYERS x particle_size`` of the surface (a Box's lattice
fitted to its size, as the walls', so that each face has its first layer half a spacing inside). Two layers
cover the support radius (2 x particle_size) of a liquid particle at the surface; a larger
``support_factor`` gets as many layers as it needs.

The contact kind of each wall face (``domain.faces``) and collider decides slip or no-slip:
``sticky`` is no-slip (viscous friction with the wall), ``slip`` and ``separate`` are free slip. A
face's velocity (a moving lid) is the velocity of its boundary particles.

As a last guard, ``advect`` clamps particles into the domain and pushes any particle that ended
inside a collider back to its surface (removing the inward normal velocity): with boundary
particles this never acts in a resolved flow, but it makes leaks through thin or fast contacts
impossible.
"""

import math
from dataclasses import dataclass

import numpy as np

from simcli.colliders import inside_normal_np as inside_normal_numpy  # noqa: F401 - the shared SDF
from simcli.colliders import sdf_np as sdf_numpy

LAYERS = 2


@dataclass
class BoundaryParticles:
    x: np.ndarray  # (nb, dim) positions [m]
    volume: np.ndarray  # (nb,) volumes [m^dim]
    velocity: np.ndarray  # (nb, dim) wall velocity [m/s]
    no_slip: np.ndarray  # (nb,) bool
    col: np.ndarray | None = None  # (nb,) collider index, -1 for the domain walls (sample_boundary)

    @property
    def n(self) -> int:
        return int(self.x.shape[0])


def _axis_coords(lo: float, hi: float, h: float, layers: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Coordinates along one axis: ``layers`` below lo, an interior lattice spanning [lo, hi], ``layers``
    above hi; with each point's spacing and its side (-1 below, 0 inside, +1 above)."""
    n = max(1, int(np.floor((hi - lo) / h + 0.5)))
    s = (hi - lo) / n
    inner = lo + s * (np.arange(n) + 0.5)
    below = lo - h * (np.arange(layers)[::-1] + 0.5)
    above = hi + h * (np.arange(layers) + 0.5)
    c = np.concatenate([below, inner, above])
    sp = np.concatenate([np.full(layers, h), np.full(n, s), np.full(layers, h)])
    side = np.concatenate([np.full(layers, -1), np.zeros(n, int), np.full(layers, 1)])
    return c, sp, side


def wall_particles(
    lo, hi, h: float, dim: int, face_kind: dict, face_velocity: dict, layers: int = LAYERS
) -> BoundaryParticles:
    """Boundary particles outside the domain box [lo, hi]: every lattice point of the padded box that is
    outside the domain. A point outside several faces (an edge, a corner) takes the first face's kind."""
    axes = [_axis_coords(lo[a], hi[a], h, layers) for a in range(dim)]
    # Only the shell is enumerated (the padded box's lattice has the whole domain inside it: 7 M points for
    # a million-particle scene): the shell's points, grouped by the first axis on which they are outside,
    # then put in the padded lattice's row-major order, so the result is what the full lattice gave.
    parts = []
    for a in range(dim):
        sel = [
            np.flatnonzero(axes[b][2] == 0)
            if b < a
            else np.flatnonzero(axes[b][2] != 0)
            if b == a
            else np.arange(len(axes[b][0]))
            for b in range(dim)
        ]
        parts.append(np.stack([g.ravel() for g in np.meshgrid(*sel, indexing="ij")], axis=1))
    idx = np.concatenate(parts)
    idx = idx[np.argsort(np.ravel_multi_index(tuple(idx.T), [len(ax[0]) for ax in axes]), kind="stable")]
    x = np.stack([axes[a][0][idx[:, a]] for a in range(dim)], axis=1)
    sp = np.prod(np.stack([axes[a][1][idx[:, a]] for a in range(dim)], axis=1), axis=1)
    side = np.stack([axes[a][2][idx[:, a]] for a in range(dim)], axis=1)
    no_slip = np.zeros(len(x), bool)
    vel = np.zeros((len(x), dim))
    assigned = np.zeros(len(x), bool)
    for a in range(dim):
        for s, sign in ((-1, "-"), (1, "+")):
            name = "xyz"[a] + sign
            sel = (side[:, a] == s) & ~assigned
            no_slip[sel] = face_kind[name] == "sticky"
            vel[sel] = face_velocity[name]
            assigned |= sel
    return BoundaryParticles(x, sp, vel, no_slip)


def collider_particles(spec, lo, hi, h: float, dim: int, layers: int = LAYERS) -> BoundaryParticles:
    """Lattice points of the collider's solid within ``layers x h`` of its surface, inside the domain box
    padded by the same depth (the liquid never sees further). A Box gets a lattice fitted to its size, as the
    domain walls do: per axis a whole number of cells of spacing close to h (the box's extent over
    round(extent / h)), points at the cells' centres, volume the product of the spacings, so that every face
    has its first layer half a spacing inside it (a lattice of spacing h anchored at one face left the far
    face's first layer
    anywhere between 0 and h inside: a liquid there saw up to 2.4x the wall density of the near face)."""
    pad = layers * h
    blo = np.asarray(lo, dtype=np.float64) - pad
    bhi = np.asarray(hi, dtype=np.float64) + pad
    empty = BoundaryParticles(np.zeros((0, dim)), np.zeros(0), np.zeros((0, dim)), np.zeros(0, bool))
    if spec.kind == "Box":
        a, b = np.asarray(spec.a, dtype=np.float64), np.asarray(spec.b, dtype=np.float64)
        axes, vol = [], 1.0
        for d in range(dim):
            ax, sp, _ = _axis_coords(a[d], b[d], h, 0)  # the walls' fitted axis, without layers outside
            axes.append(ax[(ax >= blo[d] - 1e-12) & (ax <= bhi[d] + 1e-12)])
            vol *= sp[0]
    else:
        if spec.kind == "Plane":  # align layers with the plane: a lattice point at half a spacing inside
            anchor = np.asarray(spec.a) - 0.5 * h * np.asarray(spec.b)
        else:
            anchor = np.asarray(spec.a) + 0.5 * h
        i0 = np.floor((blo - anchor) / h).astype(np.int64)
        i1 = np.ceil((bhi - anchor) / h).astype(np.int64)
        axes = [anchor[d] + h * np.arange(i0[d], i1[d] + 1) for d in range(dim)]
        axes = [ax[(ax >= blo[d] - 1e-12) & (ax <= bhi[d] + 1e-12)] for d, ax in enumerate(axes)]
        vol = h**dim
    if any(len(ax) == 0 for ax in axes):
        return empty
    grids = np.meshgrid(*axes, indexing="ij")
    x = np.stack([g.ravel() for g in grids], axis=1)
    d = sdf_numpy(spec, x)
    x = x[(d < 0) & (d >= -pad)]
    n = len(x)
    return BoundaryParticles(x, np.full(n, vol), np.zeros((n, dim)), np.full(n, spec.contact == "sticky"))


def sample_boundary(scene, dim: int, h: float, support: float | None = None, specs=None) -> BoundaryParticles:
    """Every boundary particle of the scene: the domain walls, then each collider (``specs``, default the
    scene's: simcli.colliders.collider_specs; a solver may pass more, e.g. rigid bodies driven through
    ColliderPoses), in layers that cover the kernel ``support`` (default 2 h)."""
    layers = LAYERS if support is None else max(LAYERS, math.ceil(support / h - 1e-9))
    from simcli.colliders import collider_specs, wall_specs

    lo, hi = scene.domain.bounds(dim)
    walls = wall_specs(scene, dim)
    kind = {w.name: w.contact for w in walls}
    vel = {w.name: np.asarray(w.velocity, dtype=np.float64) for w in walls}
    parts = [wall_particles(lo, hi, h, dim, kind, vel, layers)]
    for spec in collider_specs(scene, dim) if specs is None else specs:
        if spec.moving:  # its whole shell, in its body frame (simcli.solvers.sph.moving)
            from simcli.solvers.sph.moving import moving_bounds

            parts.append(collider_particles(spec, *moving_bounds(spec, lo, hi), h, dim, layers))
        else:
            parts.append(collider_particles(spec, lo, hi, h, dim, layers))
    return BoundaryParticles(
        np.concatenate([p.x for p in parts]),
        np.concatenate([p.volume for p in parts]),
        np.concatenate([p.velocity for p in parts]),
        np.concatenate([p.no_slip for p in parts]),
        np.concatenate([np.full(p.n, k - 1, np.int32) for k, p in enumerate(parts)]),
    )


def make_pushout(scene, dim: int, f, col_fields, poses=None, specs=None):
    """Taichi func ``pushout(x, v) -> (x, v)``: a particle inside a collider is moved to its surface and
    loses its inward normal velocity (a guard; see the module docstring). A moving collider (``poses``, a
    simcli.colliders.ColliderPoses) is tested in its body frame at the substep's end pose, and the normal
    velocity removed is the one relative to its surface."""
    from simcli.backend import stdout_to_stderr
    from simcli.colliders import collider_specs, sdf_box, sdf_cylinder, sdf_plane, sdf_sphere

    with stdout_to_stderr():
        import taichi as ti

    if specs is None:
        specs = collider_specs(scene, dim)
    nc = len(specs)
    col_a, col_b, col_r, col_hh = col_fields
    moving = [c.moving and poses is not None for c in specs]
    mesh_f = [None] * nc
    if any(c.kind == "Mesh" for c in specs):  # their signed-distance grids (simcli.collider_mesh_kernels)
        from simcli.collider_mesh_kernels import mesh_fields

        mesh_f = mesh_fields(specs, f, normal_below=0.0)  # the guard uses normals inside only

    @ti.func
    def sdf(k: ti.template(), x):
        phi = ti.cast(1.0, f)
        n = x * 0.0
        if ti.static(specs[k].kind == "Plane"):
            phi, n = sdf_plane(x, col_a[k], col_b[k])
        elif ti.static(specs[k].kind == "Sphere"):
            phi, n = sdf_sphere(x, col_a[k], col_r[k])
        elif ti.static(specs[k].kind == "Box"):
            phi, n = sdf_box(x, col_a[k], col_b[k])
        elif ti.static(specs[k].kind == "Cylinder"):
            phi, n = sdf_cylinder(x, col_a[k], col_r[k], col_hh[k], specs[k].axis)
        elif ti.static(specs[k].kind == "Mesh"):
            phi, n = mesh_f[k].sample(x)
        return phi, n

    @ti.func
    def pushout(x, v):
        for k in ti.static(range(nc)):
            if ti.static(moving[k]):
                phi, nb = sdf(k, poses.to_body(k, x, 1))  # the body-frame SDF at the substep's end pose
                if phi < 0:
                    n = poses.normal_to_world(k, nb, 1)
                    x = x - phi * n
                    vw = poses.velocity(k, x, 1)
                    vn = (v - vw).dot(n)
                    if vn < 0:
                        v = v - vn * n
            else:
                phi, n = sdf(k, x)
                if phi < 0:
                    x = x - phi * n
                    vn = v.dot(n)
                    if vn < 0:
                        v = v - vn * n
        return x, v

    def upload():
        npf = np.float64 if f == ti.f64 else np.float32
        m = max(1, nc)
        a = np.zeros((m, dim), npf)
        b = np.zeros((m, dim), npf)
        r = np.zeros(m, npf)
        hh = np.zeros(m, npf)
        for k, c in enumerate(specs):
            a[k], b[k], r[k], hh[k] = c.a, c.b, c.radius, c.half_height
        col_a.from_numpy(a)
        col_b.from_numpy(b)
        col_r.from_numpy(r)
        col_hh.from_numpy(hh)

    return pushout, upload, nc
