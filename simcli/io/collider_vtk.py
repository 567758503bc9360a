"""Colliders as surface meshes per frame: ``OUT/vtk/<name>.pvd`` with one ``.vtp`` (PolyData) per frame,
so that ParaView shows moving colliders with the material. Written for named or moving colliders when the
scene writes ``vtk`` (a still, unnamed collider adds no file, as before). An unnamed moving collider is
called ``collider<k>`` (its index in ``colliders``).

The surface is built once in the collider's body frame (3D: triangles; 2D: a closed polyline in the z = 0
plane; a Plane: a square / segment as large as the domain's diagonal) and moved to the frame's pose
(simcli.motion); a Mesh collider writes its own triangles. Each file carries the surface velocity as point
data ``velocity`` [m/s].
"""

from __future__ import annotations

import math
import re
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any
from xml.sax.saxutils import quoteattr

import numpy as np

from .frames import atomic_write_text, ensure_dir, guard


def collider_surface(spec: Any, dim: int, size: float, n: int = 32) -> tuple[np.ndarray, np.ndarray]:
    """(points (m, dim), cells (k, 3) triangles in 3D or (k, 2) segments in 2D) of a collider spec
    (simcli.colliders.ColliderSpec) in its body frame. ``size``: extent of a Plane's patch [m]. A Mesh
    collider is its own triangles (``spec.mesh``, simcli.collider_mesh.MeshSDF)."""
    if spec.kind == "Mesh":
        return np.asarray(spec.mesh.vertices, float), np.asarray(spec.mesh.triangles, np.int64)
    a = np.asarray(spec.a, float)
    if dim == 2:
        if spec.kind == "Box":
            b = np.asarray(spec.b, float)
            pts = np.array([[a[0], a[1]], [b[0], a[1]], [b[0], b[1]], [a[0], b[1]]])
        elif spec.kind == "Sphere":
            th = np.linspace(0, 2 * math.pi, 4 * n, endpoint=False)
            pts = a + spec.radius * np.stack([np.cos(th), np.sin(th)], axis=1)
        elif spec.kind == "Plane":
            nrm = np.asarray(spec.b, float)
            t = np.array([-nrm[1], nrm[0]])
            pts = np.array([a - 0.5 * size * t, a + 0.5 * size * t])
            return pts, np.array([[0, 1]])
        else:
            raise ValueError(spec.kind)
        k = len(pts)
        return pts, np.stack([np.arange(k), (np.arange(k) + 1) % k], axis=1)
    if spec.kind == "Box":
        b = np.asarray(spec.b, float)
        corners = np.array([[(a, b)[(i >> d) & 1][d] for d in range(3)] for i in range(8)])
        quads = [(0, 2, 3, 1), (4, 5, 7, 6), (0, 1, 5, 4), (2, 6, 7, 3), (0, 4, 6, 2), (1, 3, 7, 5)]
        tris = [t for q in quads for t in ((q[0], q[1], q[2]), (q[0], q[2], q[3]))]
        return corners, np.array(tris)
    if spec.kind == "Plane":
        nrm = np.asarray(spec.b, float)
        u = np.cross(nrm, [1.0, 0, 0] if abs(nrm[0]) < 0.9 else [0, 1.0, 0])
        u /= np.linalg.norm(u)
        v = np.cross(nrm, u)
        h = 0.5 * size
        pts = np.array([a - h * u - h * v, a + h * u - h * v, a + h * u + h * v, a - h * u + h * v])
        return pts, np.array([[0, 1, 2], [0, 2, 3]])
    if spec.kind == "Sphere":
        th = np.linspace(0, math.pi, n + 1)[1:-1]
        ph = np.linspace(0, 2 * math.pi, 2 * n, endpoint=False)
        T, P = np.meshgrid(th, ph, indexing="ij")
        ring = np.stack([np.sin(T) * np.cos(P), np.sin(T) * np.sin(P), np.cos(T)], axis=-1).reshape(-1, 3)
        pts = np.concatenate([[[0, 0, 1.0]], ring, [[0, 0, -1.0]]]) * spec.radius + a
        m = 2 * n
        tris = [(0, 1 + j, 1 + (j + 1) % m) for j in range(m)]
        for i in range(len(th) - 1):
            for j in range(m):
                p0, p1 = 1 + i * m + j, 1 + i * m + (j + 1) % m
                tris += [(p0, p0 + m, p1), (p1, p0 + m, p1 + m)]
        last = len(pts) - 1
        base = 1 + (len(th) - 1) * m
        tris += [(last, base + (j + 1) % m, base + j) for j in range(m)]
        return pts, np.array(tris)
    if spec.kind == "Cylinder":
        ax = spec.axis
        e1, e2 = (ax + 1) % 3, (ax + 2) % 3
        ph = np.linspace(0, 2 * math.pi, 2 * n, endpoint=False)
        m = 2 * n
        pts = []
        for s in (-1.0, 1.0):
            ring = np.zeros((m, 3))
            ring[:, e1] = spec.radius * np.cos(ph)
            ring[:, e2] = spec.radius * np.sin(ph)
            ring[:, ax] = s * spec.half_height
            pts.append(ring)
        caps = np.zeros((2, 3))
        caps[:, ax] = (-spec.half_height, spec.half_height)
        pts = np.concatenate(pts + [caps]) + a
        tris = []
        for j in range(m):
            j1 = (j + 1) % m
            tris += [(j, j1, m + j1), (j, m + j1, m + j), (2 * m, j1, j), (2 * m + 1, m + j, m + j1)]
        return pts, np.array(tris)
    raise ValueError(spec.kind)


class ColliderVtkWriter:
    """``vtk/<name>.pvd`` + ``vtk/<name>/<name>_<frame>.vtp`` for each collider given."""

    def __init__(self, root: Path, items: list[tuple[str, Any, Any]], dim: int, size: float):
        """``items``: (name, ColliderSpec, Motion or None)."""
        self.root = Path(root)
        self.dim = dim
        self.items = []
        for name, spec, motion in items:
            pts, cells = collider_surface(spec, dim, size)
            self.items.append((name, pts, cells, motion))
        self.entries: dict[str, list[tuple[int, float, str]]] = {name: [] for name, *_ in self.items}

    def open(self, resume_frame: int | None) -> None:
        for name, *_ in self.items:
            d = ensure_dir(self.root / name)
            pat = re.compile(rf"^{re.escape(name)}_(\d+)\.vtp$")
            kept: dict[int, float] = {}
            pvd = self.root / f"{name}.pvd"
            if resume_frame is not None and pvd.exists():
                try:
                    for ds in ET.parse(pvd).getroot().iter("DataSet"):
                        m = pat.match(Path(ds.get("file", "")).name)
                        if m and int(m.group(1)) < resume_frame:
                            kept[int(m.group(1))] = float(ds.get("timestep", "nan"))
                except (ET.ParseError, ValueError):
                    kept = {}
            limit = resume_frame or 0
            with guard(d, "clean"):
                for p in d.iterdir():
                    m = pat.match(p.name)
                    if m and int(m.group(1)) >= limit:
                        p.unlink()
            self.entries[name] = [
                (fr, t, f"{name}/{name}_{fr:06d}.vtp")
                for fr, t in sorted(kept.items())
                if (d / f"{name}_{fr:06d}.vtp").exists()
            ]
            self._write_pvd(name)

    def _write_pvd(self, name: str) -> None:
        lines = [
            '<?xml version="1.0"?>\n<VTKFile type="Collection" version="0.1" '
            'byte_order="LittleEndian">\n<Collection>\n'
        ]
        for _fr, t, f in self.entries[name]:
            lines.append(f'<DataSet timestep="{repr(float(t))}" group="" part="0" file={quoteattr(f)}/>\n')
        lines.append("</Collection>\n</VTKFile>\n")
        atomic_write_text(self.root / f"{name}.pvd", "".join(lines))

    def write_frame(self, frame: int, time: float) -> None:
        for name, pts, cells, motion in self.items:
            x, vel = pts, np.zeros_like(pts)
            if motion is not None:
                pose = motion.pose(time)
                x = pose.to_world(pts)
                vel = pose.velocity_at(x)
            rel = f"{name}/{name}_{frame:06d}.vtp"
            atomic_write_text(self.root / rel, self._vtp(x, vel, cells))
            self.entries[name] = [e for e in self.entries[name] if e[0] != frame] + [(frame, time, rel)]
            self._write_pvd(name)

    def _vtp(self, x: np.ndarray, vel: np.ndarray, cells: np.ndarray) -> str:
        def pad3(a):
            return np.concatenate([a, np.zeros((len(a), 3 - a.shape[1]))], axis=1) if a.shape[1] < 3 else a

        def fmt(a):
            return " ".join(repr(float(v)) for v in np.asarray(a, float).ravel())

        kind = "Polys" if self.dim == 3 else "Lines"
        nv = cells.shape[1]
        offsets = np.arange(1, len(cells) + 1) * nv
        counts = {"Polys": 0, "Lines": 0}
        counts[kind] = len(cells)
        return (
            '<?xml version="1.0"?>\n<VTKFile type="PolyData" version="0.1" '
            'byte_order="LittleEndian">\n<PolyData>\n'
            f'<Piece NumberOfPoints="{len(x)}" NumberOfVerts="0" NumberOfLines="{counts["Lines"]}" '
            f'NumberOfStrips="0" NumberOfPolys="{counts["Polys"]}">\n'
            f'<PointData Vectors="velocity">\n<DataArray type="Float64" Name="velocity" '
            f'NumberOfComponents="3" '
            f'format="ascii">{fmt(pad3(vel))}</DataArray>\n</PointData>\n'
            f'<Points>\n<DataArray type="Float64" NumberOfComponents="3" format="ascii">{fmt(pad3(x))}'
            "</DataArray>\n</Points>\n"
            f'<{kind}>\n<DataArray type="Int64" Name="connectivity" format="ascii">'
            f"{' '.join(str(int(i)) for i in cells.ravel())}</DataArray>\n"
            f'<DataArray type="Int64" Name="offsets" format="ascii">{" ".join(str(int(i)) for i in offsets)}'
            f"</DataArray>\n</{kind}>\n</Piece>\n</PolyData>\n</VTKFile>\n"
        )
