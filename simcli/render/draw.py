"""Quick-look pictures and movies of a run with matplotlib's Agg backend (no display, no OpenGL).

One figure per frame: particles as discs coloured by speed (or by entity), meshes as shaded surfaces
(tetrahedral meshes' boundary triangles, cloth triangles, rods as lines), grids as an image of their
density (3D grids seen from the side, integrated along y), colliders in grey, the domain's box."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .data import EntityFrame, RenderError, Run, open_run, read_frame, resolve_frame
from .geometry import collider_outline_2d, collider_triangles, shade, tet_surface
from .moving import collider_poses, pose_outline_2d, pose_points

PALETTE = ["#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#17becf"]
SPEED_CMAP = "viridis"
HEIGHT_CMAP = "copper"
GRID_CMAP = "inferno"
COLLIDER_RGBA = (0.62, 0.62, 0.66, 0.55)
RIGID_RGBA = (0.75, 0.45, 0.2, 0.9)  # rigid bodies: solid, brown
MAX_PARTICLES = 250_000
MIXED_PARTICLES = 40_000  # particles drawn as depth-sorted hexagons beside surfaces (3D)


def _mpl():
    try:
        import matplotlib
    except ImportError as e:  # pragma: no cover - matplotlib is a dependency of the render extra
        raise RenderError(
            "simcli render needs matplotlib: pip install 'simcli[render]' (or pip install matplotlib)"
        ) from e
    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    return matplotlib, plt


# ------------------------------------------------------------------------------------ helpers


def _speed(e: EntityFrame) -> np.ndarray | None:
    if e.velocity is None:
        return None
    v = e.velocity
    return np.sqrt((v * v).sum(axis=-1))


def _spacing(run: Run, name: str, now: np.ndarray) -> float:
    """Particle spacing estimated from frame 0 (a compact block in almost every scene); an entity with
    fewer than 8 particles there (an emitter's, empty until it starts) from the drawn frame ``now``: the
    median distance to the nearest neighbour (an emitted jet is not a compact block, but its particles leave
    the nozzle one spacing apart)."""
    try:
        e0 = [e for e in read_frame(run, 0) if e.name == name][0]
        p = e0.position
    except (IndexError, RenderError):
        p = None
    if p is not None:
        p = p[np.isfinite(p).all(axis=1)]
    if p is None or len(p) < 8:
        q = now[np.isfinite(now).all(axis=1)]
        if len(q) >= 2:
            from scipy.spatial import cKDTree

            d, _ = cKDTree(q).query(q, k=2)
            nn = d[:, 1][d[:, 1] > 0]
            if nn.size:
                return float(np.median(nn))
        ext = float(np.prod(run.upper - run.lower))
        return (ext / max(len(q), 1)) ** (1 / run.dim) * 0.5
    ext = np.ptp(p, axis=0)
    ext = np.where(ext > 0, ext, ext[ext > 0].min() if (ext > 0).any() else 1.0)
    return float((np.prod(ext) / len(p)) ** (1 / run.dim))


def speed_limit(run: Run, frames: list[int]) -> float:
    """A colour scale for speed shared by every frame drawn: the 99th percentile over sampled frames."""
    pick = frames if len(frames) <= 12 else [frames[int(i)] for i in np.linspace(0, len(frames) - 1, 12)]
    hi = 0.0
    for k in pick:
        for e in read_frame(run, k):
            s = _speed(e)
            if s is not None and s.size and e.kind != "grid":
                hi = max(hi, float(np.nanpercentile(s, 99)))
    return hi if hi > 0 else 1.0


def _color_mode(mode: str, ents: list[EntityFrame]) -> str:
    if mode != "auto":
        return mode
    solids = [e for e in ents if e.kind != "grid"]
    return "entity" if len(solids) > 1 else "speed"


def _grid_scalar(e: EntityFrame) -> tuple[np.ndarray, str] | None:
    """What a grid's picture shows: its smoke (or dye, or heat) where it has any, else its speed."""
    for k in ("density", "dye", "smoke", "temperature"):
        if k in e.fields and np.ptp(e.fields[k]) > 0:
            return e.fields[k], k
    s = _speed(e)
    return (s, "speed [m/s]") if s is not None else None


# ------------------------------------------------------------------------------------ drawing


class Painter:
    """Draws frames of one run into one figure; fixed axes and colour scales so frames make a movie."""

    def __init__(self, run: Run, frames: list[int], color: str = "auto", width: int = 800):
        self.mpl, self.plt = _mpl()
        self.run = run
        self.frames = frames
        ents0 = read_frame(run, frames[-1])
        self.color = _color_mode(color, ents0)
        self.auto_height = False
        self.color_meshes = color  # auto: meshes in their entity colour, shaded (their shape reads better)
        self.vmax = speed_limit(run, list(range(run.n_frames)))
        self.names = run.entity_names
        self.has_grid3 = any(e.kind == "grid" and run.dim == 3 for e in ents0)
        self.view3d = run.dim == 3 and not self.has_grid3
        self.grid_vmax: dict[str, float] = {}
        for e in ents0:
            if e.kind == "grid":
                g = _grid_scalar(e)
                if g is not None:
                    self.grid_vmax[e.name] = 0.0
        self.spacing = {}
        for e in ents0:
            if e.kind == "particles" and e.position is not None:
                self.spacing[e.name] = _spacing(run, e.name, np.asarray(e.position, float))
        self.lo, self.hi = self._view_box()
        ext = self.hi - self.lo
        if self.view3d:
            w_in, h_in = width / 100, width / 100 * 0.8
        else:
            keep = [0, 2] if self.has_grid3 else [0, 1]
            aspect = float(ext[keep[1]] / ext[keep[0]])
            w_in = width / 100
            # the axes take about 80 % of the width (a colour bar beside them), titles ~0.8 in
            h_in = float(np.clip(0.8 * w_in * aspect + 0.8, 0.45 * w_in, 1.3 * w_in))
        # even pixel sizes, multiples of 16 (video encoders' macro blocks)
        w_px, h_px = int(round(w_in * 100 / 16)) * 16, int(round(h_in * 100 / 16)) * 16
        self.fig = self.plt.figure(
            figsize=(w_px / 100, h_px / 100), dpi=100, layout=None if self.view3d else "constrained"
        )
        self.size_px = (w_px, h_px)
        self._grid_limits(frames)

    def _view_box(self):
        """The domain, in 3D cropped sideways and above to what is in it (entities at sampled frames,
        bounded colliders) so that a small body in a big domain is not a speck; the floor stays."""
        run = self.run
        lo, hi = run.lower.copy(), run.upper.copy()
        if not self.view3d:
            return (np.append(lo, 0) if run.dim == 2 else lo), (np.append(hi, 0) if run.dim == 2 else hi)
        n = run.n_frames
        pts = []
        for k in sorted({int(i) for i in np.linspace(0, n - 1, min(n, 24))}):
            for e in read_frame(run, k):
                q = None if e.position is None else e.position[np.isfinite(e.position).all(axis=1)]
                if q is not None and len(q):  # (emitters may park unused particles at NaN)
                    pts.append(q.min(axis=0))
                    pts.append(q.max(axis=0))
        for col in run.colliders:
            if col.get("type") != "Plane":
                t = collider_triangles(col, lo, hi)
                if len(t):
                    pts.append(t.reshape(-1, 3).min(axis=0))
                    pts.append(t.reshape(-1, 3).max(axis=0))
        if not pts:
            return lo, hi
        pts = np.asarray(pts)
        a, b = pts.min(axis=0), pts.max(axis=0)
        pad = 0.08 * float((b - a).max())
        a, b = np.maximum(a - pad, lo), np.minimum(b + pad, hi)
        a[2] = lo[2]
        return a, b

    def _grid_limits(self, frames):
        if not self.grid_vmax:
            return
        pick = frames if len(frames) <= 8 else [frames[int(i)] for i in np.linspace(0, len(frames) - 1, 8)]
        for k in pick:
            for e in read_frame(self.run, k):
                if e.name in self.grid_vmax:
                    img = self._grid_image(e)
                    if img is not None:
                        self.grid_vmax[e.name] = max(self.grid_vmax[e.name], float(np.nanmax(img[0])))

    # -- one frame ---------------------------------------------------------------------
    def draw(self, k: int) -> None:
        fig, run = self.fig, self.run
        fig.clf()
        ents = read_frame(run, k)
        self._k = k  # rigid bodies are drawn at their pose of this frame
        t = run.times[k]
        if self.auto_height or (self.color_meshes == "auto" and self.color == "speed"):
            # auto: a settled heap in one colour says nothing; once the particles are at rest
            # (99 % slower than 2 % of the run's speed scale) colour them by height instead
            sp = [_speed(e) for e in ents if e.kind == "particles" and e.velocity is not None]
            sp = np.concatenate(sp) if sp else np.zeros(0)
            rest = sp.size > 0 and float(np.nanpercentile(sp, 99)) < 0.02 * self.vmax
            self.auto_height = bool(rest)
            self.color = "height" if rest else "speed"
        zs = [e.position[:, -1] for e in ents if e.kind == "particles" and e.position is not None]
        z0 = self.lo[run.dim - 1]
        zs = np.concatenate(zs) if zs else np.zeros(0)
        zs = zs[np.isfinite(zs)]
        self._zspan = max(float(zs.max()) - z0, 1e-9) if zs.size else 1.0
        title = f"{run.name}   t = {t:.3f} s   (frame {k}/{run.n_frames - 1})"
        if self.view3d:
            self._draw3d(ents)
        else:
            self._draw2d(ents)
        fig.suptitle(title, fontsize=10, **({"y": 0.985} if self.view3d else {}))

    def _entity_rgb(self, name: str):
        i = self.names.index(name) if name in self.names else 0
        return self.mpl.colors.to_rgb(PALETTE[i % len(PALETTE)])

    def _legend(self, ax, ents):
        if self.color == "entity" or any(e.kind in ("tets", "triangles", "lines") for e in ents):
            from matplotlib.lines import Line2D

            h = [
                Line2D([], [], marker="o", ls="", color=self._entity_rgb(e.name), label=e.name)
                for e in ents
                if e.kind != "grid" and (self.color == "entity" or e.kind != "particles")
            ]
            if h:
                ax.legend(handles=h, loc="upper right", fontsize=8, framealpha=0.7)

    def _speed_bar(self, ax, ents):
        if self.color == "height" and any(e.kind == "particles" for e in ents):
            z0 = self.lo[self.run.dim - 1]
            sm = self.plt.cm.ScalarMappable(
                cmap=HEIGHT_CMAP, norm=self.mpl.colors.Normalize(z0, z0 + self._zspan)
            )
            cb = self.fig.colorbar(sm, ax=ax, shrink=0.6, pad=0.02)
            cb.set_label("height [m] (at rest)" if self.auto_height else "height [m]", fontsize=8)
            cb.ax.tick_params(labelsize=7)
        if self.color == "speed" and any(e.kind == "particles" and e.velocity is not None for e in ents):
            sm = self.plt.cm.ScalarMappable(cmap=SPEED_CMAP, norm=self.mpl.colors.Normalize(0, self.vmax))
            cb = self.fig.colorbar(sm, ax=ax, shrink=0.6, pad=0.02)
            cb.set_label("speed [m/s]", fontsize=8)
            cb.ax.tick_params(labelsize=7)

    def _particle_colors(self, e: EntityFrame):
        if self.color == "height":
            z = e.position[:, -1]
            return self.plt.get_cmap(HEIGHT_CMAP)((z - self.lo[self.run.dim - 1]) / self._zspan)
        if self.color == "speed" and e.velocity is not None:
            return self.plt.get_cmap(SPEED_CMAP)(np.clip(_speed(e) / self.vmax, 0, 1))
        return [self._entity_rgb(e.name)]

    def _marker_area(self, ax, name: str, pts_per_m: float) -> float:
        d = self.spacing.get(name, 0.01) * pts_per_m * 1.15
        return float(np.clip(d * d, 0.3, 400.0))

    # -- 2D (and 3D grids seen from the side) --------------------------------------------
    def _grid_image(self, e: EntityFrame):
        g = _grid_scalar(e)
        if g is None:
            return None
        a, label = g
        o, h = e.grid["origin"], e.grid["spacing"]
        if a.ndim == 3:  # (nz, ny, nx): integrate along y -> (nz, nx)
            a = a.sum(axis=1) * float(h[1])
            label = f"{label} integrated along y"
            ext = (o[0], o[0] + h[0] * a.shape[1], o[2], o[2] + h[2] * a.shape[0])
        else:
            ext = (o[0], o[0] + h[0] * a.shape[1], o[1], o[1] + h[1] * a.shape[0])
        return a, label, ext

    def _draw2d(self, ents):
        run = self.run
        ax = self.fig.add_subplot(111)
        keep = [0, 2] if self.has_grid3 else [0, 1]
        lo, hi = run.lower[keep], run.upper[keep]
        ax.set_xlim(lo[0], hi[0])
        ax.set_ylim(lo[1], hi[1])
        ax.set_aspect("equal")
        ax.set_xlabel("x [m]", fontsize=8)
        ax.set_ylabel(("z" if self.has_grid3 else "y") + " [m]", fontsize=8)
        ax.tick_params(labelsize=7)
        self.fig.canvas.draw()
        p0, p1 = ax.transData.transform([[0, 0], [1, 0]])
        pts_per_m = abs(p1[0] - p0[0]) * 72.0 / self.fig.dpi
        for e in ents:
            if e.kind == "grid":
                im = self._grid_image(e)
                if im is None:
                    continue
                a, label, ext = im
                vmax = self.grid_vmax.get(e.name) or float(np.nanmax(a)) or 1.0
                art = ax.imshow(
                    a, origin="lower", extent=ext, cmap=GRID_CMAP, vmin=0, vmax=vmax, interpolation="bilinear"
                )
                cb = self.fig.colorbar(art, ax=ax, shrink=0.6, pad=0.02)
                cb.set_label(label, fontsize=8)
                cb.ax.tick_params(labelsize=7)
                v = e.velocity
                if label.startswith("speed") and v is not None and v.ndim == 3 and np.abs(v).max() > 0:
                    ny, nx = v.shape[:2]
                    xs = np.linspace(ext[0], ext[1], nx + 1)[:-1] + (ext[1] - ext[0]) / nx / 2
                    ys = np.linspace(ext[2], ext[3], ny + 1)[:-1] + (ext[3] - ext[2]) / ny / 2
                    ax.streamplot(
                        xs, ys, v[..., 0], v[..., 1], color="white", linewidth=0.5, density=1.2, arrowsize=0.6
                    )
            elif e.position is not None:
                p = e.position[:, keep] if e.position.shape[1] > 2 else e.position
                if e.kind == "particles":
                    sel = slice(None)
                    if len(p) > MAX_PARTICLES:
                        sel = np.random.default_rng(0).choice(len(p), MAX_PARTICLES, replace=False)
                    c = self._particle_colors(e)
                    c = c[sel] if len(c) > 1 else c
                    ax.scatter(
                        p[sel, 0], p[sel, 1], s=self._marker_area(ax, e.name, pts_per_m), c=c, linewidths=0
                    )
                elif e.kind in ("triangles", "tets") and e.cells is not None:
                    import matplotlib.tri as mtri

                    tris = e.cells if e.kind == "triangles" else tet_surface(e.cells)
                    tr = mtri.Triangulation(p[:, 0], p[:, 1], tris)
                    ax.triplot(tr, color=self._entity_rgb(e.name), lw=0.3)
                    from matplotlib.collections import PolyCollection

                    ax.add_collection(
                        PolyCollection(p[tris], facecolors=[self._entity_rgb(e.name)], alpha=0.55, lw=0)
                    )
                elif e.kind == "lines" and e.cells is not None:
                    from matplotlib.collections import LineCollection

                    ax.add_collection(LineCollection(p[e.cells], colors=[self._entity_rgb(e.name)], lw=2))
        self._colliders2d(ax, drop=1 if self.has_grid3 else None)
        self._speed_bar(ax, ents)
        self._legend(ax, ents)

    def _collider_poses(self) -> list:
        """Every collider's pose at this frame's time (None: still), from its prescribed motion."""
        if not hasattr(self, "_pose_funcs"):
            self._pose_funcs = collider_poses(self.run)
        t = float(self.run.times[getattr(self, "_k", 0)])
        return [f(t) if f is not None else None for f in self._pose_funcs]

    def _colliders2d(self, ax, drop):
        from matplotlib.patches import Circle, Polygon, Rectangle

        run = self.run
        lo3 = run.lower if run.dim == 3 else np.append(run.lower, 0)
        hi3 = run.upper if run.dim == 3 else np.append(run.upper, 0)
        poses = self._collider_poses() if drop is None else [None] * len(run.colliders)
        for col, pose in zip(run.colliders, poses):
            o = collider_outline_2d(
                col, lo3 if drop is not None else run.lower, hi3 if drop is not None else run.upper, drop
            )
            o = pose_outline_2d(pose, o)  # a moving collider at the frame's time
            kw = dict(facecolor=COLLIDER_RGBA, edgecolor=(0.3, 0.3, 0.33), lw=0.8, zorder=5)
            if o is None:
                continue
            if o[0] == "circle":
                ax.add_patch(Circle(o[1], o[2], **kw))
            elif o[0] == "rect":
                (x0, y0), (x1, y1) = o[1], o[2]
                ax.add_patch(Rectangle((x0, y0), x1 - x0, y1 - y0, **kw))
            elif o[0] == "polygon":
                ax.add_patch(Polygon(o[1], closed=True, **kw))
        if drop is None:  # rigid bodies (2D scenes), at the frame's pose
            from .rigid import rigid_surfaces

            for _name, pts, _cells in rigid_surfaces(run, getattr(self, "_k", 0)):
                ax.add_patch(
                    Polygon(
                        pts, closed=True, facecolor=RIGID_RGBA, edgecolor=(0.3, 0.2, 0.1), lw=0.8, zorder=5
                    )
                )
                c = pts.mean(axis=0)  # a spoke to its first surface point shows the rotation
                ax.plot([c[0], pts[0, 0]], [c[1], pts[0, 1]], color=(0.3, 0.2, 0.1), lw=0.8, zorder=6)

    # -- 3D -----------------------------------------------------------------------------
    def _draw3d(self, ents):
        from mpl_toolkits.mplot3d.art3d import Line3DCollection, Poly3DCollection

        run = self.run
        lo, hi = self.lo, self.hi
        ax = self.fig.add_subplot(111, projection="3d")
        ax.set_xlim(lo[0], hi[0])
        ax.set_ylim(lo[1], hi[1])
        ax.set_zlim(lo[2], hi[2])
        ax.set_box_aspect(tuple(hi - lo))
        ax.view_init(elev=22, azim=-58)
        ax.set_proj_type("persp", focal_length=0.4)
        for a, lab in ((ax.xaxis, "x"), (ax.yaxis, "y"), (ax.zaxis, "z")):
            a.set_pane_color((0.96, 0.96, 0.97, 1.0))
        ax.set_xlabel("x [m]", fontsize=8, labelpad=-4)
        ax.set_ylabel("y [m]", fontsize=8, labelpad=-4)
        ax.set_zlabel("z [m]", fontsize=8, labelpad=-4)
        ax.tick_params(labelsize=6, pad=-2)
        from matplotlib.ticker import MaxNLocator

        for a in (ax.xaxis, ax.yaxis, ax.zaxis):
            a.set_major_locator(MaxNLocator(5))
        self.fig.subplots_adjust(left=0.0, right=0.92, bottom=0.02, top=0.95)
        # the domain's box
        c = np.array([[hi[i] if (k >> i) & 1 else lo[i] for i in range(3)] for k in range(8)])
        edges = [(i, j) for i in range(8) for j in range(i + 1, 8) if bin(i ^ j).count("1") == 1]
        ax.add_collection3d(Line3DCollection([c[[i, j]] for i, j in edges], colors=[(0.5, 0.5, 0.5)], lw=0.5))
        # every surface in one collection, so that faces are depth-sorted against each other
        tris, cols = [], []
        for col, pose in zip(run.colliders, self._collider_poses()):
            t = pose_points(pose, collider_triangles(col, lo, hi))  # planes clipped to the view box
            if len(t):
                tris.append(t)
                f = shade(t)[:, None] * np.asarray(COLLIDER_RGBA[:3])
                cols.append(np.hstack([f, np.full((len(t), 1), COLLIDER_RGBA[3])]))
        from .rigid import rigid_surfaces

        for _name, pts, cells in rigid_surfaces(run, getattr(self, "_k", 0)):  # at the frame's pose
            t = pts[cells]
            tris.append(t)
            f = shade(t)[:, None] * np.asarray(RIGID_RGBA[:3])
            cols.append(np.hstack([f, np.full((len(t), 1), RIGID_RGBA[3])]))
        cmap = self.plt.get_cmap(SPEED_CMAP)
        diag = float(np.linalg.norm(hi - lo))
        pts_per_m = self.fig.get_size_inches()[0] * 72.0 * 0.75 / diag
        for e in ents:
            if e.position is None:
                continue
            p = e.position
            if e.kind in ("triangles", "tets") and e.cells is not None:
                idx = e.cells if e.kind == "triangles" else tet_surface(e.cells)
                t = p[idx]
                if self.color_meshes == "speed" and e.velocity is not None and e.kind == "triangles":
                    base = cmap(np.clip(_speed(e)[idx].mean(axis=1) / self.vmax, 0, 1))[:, :3]
                else:
                    base = np.tile(self._entity_rgb(e.name), (len(t), 1))
                f = shade(t)[:, None] * base
                tris.append(t)
                cols.append(np.hstack([f, np.ones((len(t), 1))]))
            elif e.kind == "lines" and e.cells is not None:
                ax.add_collection3d(Line3DCollection(p[e.cells], colors=[self._entity_rgb(e.name)], lw=2.0))
        # Particles beside surfaces (a ball on a cloth, sand under a rigid body): matplotlib sorts the faces
        # of one collection by depth but draws whole collections in turn, so a scatter and a surface hide
        # each other wholesale. With surfaces present, particles (up to MIXED_PARTICLES) become small
        # camera-facing hexagons in the surfaces' collection and are depth-sorted with them.
        polys = [np.concatenate(tris)] if tris else []
        mixed = set()
        if tris:
            n_part = sum(len(e.position) for e in ents if e.kind == "particles" and e.position is not None)
            if 0 < n_part <= MIXED_PARTICLES:
                el, az = np.radians(22.0), np.radians(-58.0)
                eye = np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
                u = np.array([-np.sin(az), np.cos(az), 0.0])
                w = np.cross(eye, u)
                ang = np.linspace(0.0, 2.0 * np.pi, 7)[:-1]
                ring = np.cos(ang)[:, None] * u + np.sin(ang)[:, None] * w  # (6, 3)
                for e in ents:
                    if e.kind != "particles" or e.position is None:
                        continue
                    p = e.position
                    r = 0.5 * np.sqrt(self._marker_area(ax, e.name, pts_per_m)) / pts_per_m
                    polys.append(p[:, None, :] + r * ring[None, :, :])
                    c = np.asarray(self._particle_colors(e), dtype=float)
                    c = np.broadcast_to(c if len(c) > 1 else c[:1], (len(p), c.shape[1]))[:, :3]
                    cols.append(np.hstack([c, np.ones((len(p), 1))]))
                    mixed.add(e.name)
        if polys:
            fc = np.concatenate(cols)
            faces = [f for block in polys for f in block]
            pc = Poly3DCollection(faces, facecolors=fc, edgecolors=fc, linewidths=0.3)
            ax.add_collection3d(pc)
        for e in ents:
            if e.kind == "particles" and e.position is not None and e.name not in mixed:
                p = e.position
                sel = slice(None)
                if len(p) > MAX_PARTICLES:
                    sel = np.random.default_rng(0).choice(len(p), MAX_PARTICLES, replace=False)
                c = self._particle_colors(e)
                c = c[sel] if len(c) > 1 else c
                ax.scatter(
                    p[sel, 0],
                    p[sel, 1],
                    p[sel, 2],
                    s=self._marker_area(ax, e.name, pts_per_m),
                    c=c,
                    linewidths=0,
                    depthshade=True,
                    alpha=1.0,
                )
        self._speed_bar(ax, ents)
        self._legend(ax, ents)

    # -- output -------------------------------------------------------------------------
    def rgb(self) -> np.ndarray:
        self.fig.canvas.draw()
        a = np.asarray(self.fig.canvas.buffer_rgba())
        return np.ascontiguousarray(a[..., :3])

    def save_png(self, path: Path) -> None:
        self.fig.savefig(path, dpi=self.fig.dpi, format="png")

    def close(self) -> None:
        self.plt.close(self.fig)


def render_picture(out, path, frame: int | None = None, color: str = "auto", width: int = 800) -> Path:
    run = open_run(out)
    k = resolve_frame(run, frame)
    painter = Painter(run, [k], color=color, width=width)
    try:
        painter.draw(k)
        path = Path(path)
        painter.save_png(path)
    finally:
        painter.close()
    return path


def render_movie(
    out, path, every: int = 1, fps: int = 20, color: str = "auto", width: int = 800, progress=None
) -> tuple[Path, int]:
    """Every `every`-th frame into an mp4 (imageio-ffmpeg's ffmpeg) or an animated gif (Pillow)."""
    run = open_run(out)
    resolve_frame(run, None)  # raises if there is no frame
    frames = list(range(0, run.n_frames, max(1, every)))
    if frames[-1] != run.n_frames - 1:
        frames.append(run.n_frames - 1)
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in (".mp4", ".gif"):
        raise RenderError(f"{path}: a movie is .mp4 or .gif (a picture is .png)")
    painter = Painter(run, frames, color=color, width=width)
    try:
        if suffix == ".gif":
            from PIL import Image

            imgs = []
            for i, k in enumerate(frames):
                painter.draw(k)
                imgs.append(Image.fromarray(painter.rgb()).quantize(colors=255))
                if progress:
                    progress(i + 1, len(frames))
            imgs[0].save(path, save_all=True, append_images=imgs[1:], duration=int(1000 / fps), loop=0)
        else:
            try:
                import imageio_ffmpeg
            except ImportError as e:
                raise RenderError(
                    "a .mp4 needs imageio-ffmpeg: pip install 'simcli[render]' (or pip install "
                    "imageio-ffmpeg); a .gif needs nothing more"
                ) from e
            w, h = painter.size_px
            writer = imageio_ffmpeg.write_frames(
                str(path),
                (w, h),
                fps=fps,
                codec="libx264",
                pix_fmt_out="yuv420p",
                macro_block_size=16,
                quality=7,
            )
            writer.send(None)
            try:
                for i, k in enumerate(frames):
                    painter.draw(k)
                    writer.send(painter.rgb())
                    if progress:
                        progress(i + 1, len(frames))
            finally:
                writer.close()
    finally:
        painter.close()
    return path, len(frames)
