"""FLIP/PIC velocity transfer for the MLS-MPM solver (``solvers.mpm.transfer: flip``).

APIC (the default, in ``solver.py``) sends each particle's affine velocity field to the grid and takes
back the grid's velocity and velocity gradient: it conserves linear and angular momentum and is quiet,
but every round trip filters the particle velocities through the grid's quadratic B-splines, which
damps motion the grid resolves poorly: an elastic body's vibration at a few cells per wavelength loses
most of its energy within seconds (Sulsky's two disks at 20 cells per metre keep about 70% of their
energy at 3 s).

FLIP (Brackbill & Ruppel 1986; the transfer of Sulsky, Chen & Schreyer 1994) instead keeps each
particle's own velocity and adds the grid's *change* of velocity over the substep::

    v_p <- alpha (v_p + sum_i w_ip (v_i^new - v_i^old)) + (1 - alpha) sum_i w_ip v_i^new

with ``alpha = flip_ratio`` (1: pure FLIP, 0: PIC). Positions move with the grid velocity
(x_p <- x_p + dt sum_i w_ip v_i^new), and the deformation gradient with the grid's velocity gradient
C_p = D^-1 sum_i w_ip v_i^new (x_i - x_p)^T exactly as under APIC: F <- (I + dt C_p) F. C_p is *not*
sent back to the grid as momentum (P2G sends w_ip m_p v_p plus the MLS stress impulse), so the
transfer is the classical FLIP of MPM, with MLS-MPM's fused stress.

v_i^old, the grid velocity before the stress and boundary updates, needs the particle momentum without
the stress impulse: P2G writes it into ``dim`` extra channels of each grid copy (after APIC's channels:
the APIC layout and arithmetic are untouched), and the grid update stores the increment per node in
``grid_dv``. Cost under flip: dim more grid channels and one more stencil gather in G2P.
"""

from __future__ import annotations

from typing import Any

from simcli.backend import stdout_to_stderr

with stdout_to_stderr():
    import taichi as ti


@ti.data_oriented
class FlipTransfer:
    """Grid storage and the per-node / per-particle pieces of the FLIP/PIC transfer."""

    def __init__(self, dim: int, dtype: Any, grid_shape: tuple, flip_ratio: float) -> None:
        self.dim = dim
        self.f = dtype
        self.grid_shape = grid_shape
        self.ratio = float(flip_ratio)
        if not 0.0 <= self.ratio <= 1.0:
            raise ValueError(f"flip_ratio must be in [0, 1], not {self.ratio}")
        self.vo = -1
        self.grid_dv = None

    def allocate(self, gdim: int) -> int:
        """Reserve ``dim`` grid channels after the first ``gdim`` (the particle momentum without the
        stress impulse) and the per-node velocity increment; return the new channel count."""
        self.vo = gdim
        self.grid_dv = ti.Vector.field(self.dim, self.f, shape=self.grid_shape)
        return gdim + self.dim

    @ti.func
    def momentum(self, c, weight, mv):
        """Grid channel value c with the weighted particle momentum ``weight m v`` added."""
        for d in ti.static(range(self.dim)):
            c[self.vo + d] = weight * mv[d]
        return c

    @ti.func
    def store(self, node, g, vI):
        """The velocity increment v_new - v_old of this substep at ``node`` (0 on empty nodes)."""
        m = g[self.dim]
        dv = ti.Vector.zero(self.f, self.dim)
        if m > 0:
            for d in ti.static(range(self.dim)):
                dv[d] = vI[d] - g[self.vo + d] / m
        self.grid_dv[node] = dv

    @ti.func
    def gather(self, base, w):
        """sum_i w_ip (v_i^new - v_i^old) over the particle's 3^dim stencil."""
        dv = ti.Vector.zero(self.f, self.dim)
        for off in ti.static(ti.grouped(ti.ndrange(*([3] * self.dim)))):
            weight = ti.cast(1.0, self.f)
            for d in ti.static(range(self.dim)):
                weight *= w[off[d]][d]
            dv += weight * self.grid_dv[base + off]
        return dv

    @ti.func
    def blend(self, v_old, v_grid, dv):
        """The particle's new velocity: alpha FLIP + (1 - alpha) PIC."""
        r = ti.static(self.ratio)
        return r * (v_old + dv) + (1.0 - r) * v_grid
