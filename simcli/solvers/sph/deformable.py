"""A deformable body's boundary particles: samples of another family's solid (an FEM body, placed by the
coupling phase, simcli/coupling/sph_fem.py) that enter the liquid's sums exactly as a collider's boundary
particles do (Akinci et al. 2012: density, the pressure terms, the extrapolated wall pressure), so that the
liquid next to the body is not a free surface to SPH.

SPH knows only the samples, not the body: where each sample is and how fast it moves (``sx``, ``sv``, written
by the coupling phase at the end of every substep from the body's vertices; moving.make_moving_boundary
copies them onto the boundary particles before the sort), its volume (fixed at build), and where to put the
impulse the liquid's pressure gives it (``simp``, summed in f64 by moving.make_loads with the same pair
impulse as a named collider's load; the coupling phase hands it to the body's vertices and clears it).
The samples are re-sorted into the cells every substep with the moving boundary; ``bsrc`` (per boundary
particle, in cell order) names each one's sample, -1 for walls and colliders.

Several bodies (an FEM body and an MPM body in one liquid) are joined into one set of samples
(``DeformableBoundary.joined``): each part keeps its own numbering, starting at its ``offset`` in the joined
fields, which it shares.
"""

from __future__ import annotations

import numpy as np

from simcli.backend import stdout_to_stderr

with stdout_to_stderr():
    import taichi as ti


class DeformableBoundary:
    """``x`` (n, dim) the samples' positions at the start [m], ``volume`` (n,) their volumes [m^dim],
    ``velocity`` (n, dim) [m/s]; ``name``: the body's family, for messages."""

    def __init__(self, name: str, x: np.ndarray, volume: np.ndarray, velocity: np.ndarray) -> None:
        self.name = name
        self.x = np.asarray(x, dtype=np.float64)
        self.volume = np.asarray(volume, dtype=np.float64)
        self.velocity = np.asarray(velocity, dtype=np.float64)
        self.n = int(self.x.shape[0])
        self.sx = self.sv = self.simp = None
        self.offset = 0  # this body's first sample in the fields (several bodies: ``joined``)
        self.parts = [self]

    @classmethod
    def joined(cls, parts: "list[DeformableBoundary]") -> "DeformableBoundary":
        """One set of samples for several bodies, in order; each part's ``offset`` is its first sample, and
        ``allocate`` hands every part the joined fields."""
        flat = [q for p in parts for q in p.parts]
        db = cls(
            "+".join(q.name for q in flat),
            np.concatenate([q.x for q in flat]),
            np.concatenate([q.volume for q in flat]),
            np.concatenate([q.velocity for q in flat]),
        )
        db.parts = flat
        off = 0
        for q in flat:
            q.offset = off
            off += q.n
        return db

    def allocate(self, dim: int, f, npf) -> None:
        """The fields (SPH's build): positions and velocities in SPH's precision, impulses in f64."""
        n = max(1, self.n)
        self.sx = ti.Vector.field(dim, f, shape=n)
        self.sv = ti.Vector.field(dim, f, shape=n)
        self.simp = ti.Vector.field(dim, ti.f64, shape=n)
        if self.n:
            self.sx.from_numpy(self.x.astype(npf))
            self.sv.from_numpy(self.velocity.astype(npf))
        for q in self.parts:
            if q is not self:
                q.sx, q.sv, q.simp = self.sx, self.sv, self.simp
