"""Reading a finished (or running, or killed) run for pictures and plots: OUT/sim.h5 through h5py in
SWMR mode, the resolved OUT/scene.yaml for the domain and colliders, OUT/run.json and OUT/probes.csv.

No Taichi here: rendering must work on a login node or a laptop with only the output folder."""

from __future__ import annotations

import csv
import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml


class RenderError(Exception):
    """A user-facing problem with the output folder or the request (exit 2 / 74 at the CLI)."""


@dataclass
class EntityFrame:
    name: str
    kind: str  # particles | tets | triangles | lines | grid
    dim: int
    position: np.ndarray | None = None  # (n, dim) for non-grids
    velocity: np.ndarray | None = None  # (n, dim) or grid (.., dim)
    cells: np.ndarray | None = None
    grid: dict = field(default_factory=dict)  # origin, spacing, shape (nx, ny[, nz])
    fields: dict = field(default_factory=dict)  # other per-frame arrays of this entity


@dataclass
class Run:
    out: Path
    dim: int
    lower: np.ndarray
    upper: np.ndarray
    colliders: list[dict]
    times: np.ndarray
    entity_names: list[str]
    name: str = ""

    @property
    def n_frames(self) -> int:
        return len(self.times)


def _h5(out: Path):
    from simcli.io.hdf5 import open_frames

    p = out / "sim.h5"
    if not p.exists():
        raise RenderError(f"{p}: not found (run the scene with output.formats including hdf5, the default)")
    try:
        return open_frames(p)
    except OSError as e:
        raise RenderError(f"{p}: cannot open ({e}); if the run was killed, try `simcli repair {out}`") from e


def _scene_dict(out: Path, f) -> dict:
    p = out / "scene.yaml"
    text = p.read_text() if p.exists() else f.attrs.get("scene", "")
    if isinstance(text, bytes):
        text = text.decode()
    try:
        d = yaml.safe_load(text) if text else {}
    except yaml.YAMLError:
        d = {}
    return d if isinstance(d, dict) else {}


def open_run(out: Path | str) -> Run:
    out = Path(out)
    if not out.is_dir():
        raise RenderError(f"{out}: not a folder (give the output folder of a run)")
    with _h5(out) as f:
        times = np.asarray(f["time"][:], dtype=float)
        names = list(f["entities"].keys()) if "entities" in f else []
        dims = [int(f["entities"][n].attrs.get("dim", 3)) for n in names]
        scene = _scene_dict(out, f)
    sim = scene.get("sim") or {}
    dim = int(sim.get("dim") or (dims[0] if dims else 3))
    dom = scene.get("domain") or {}
    lo = dom.get("lower") or ([-0.5, -0.5, 0.0] if dim == 3 else [0.0, 0.0])
    hi = dom.get("upper") or ([0.5, 0.5, 1.0] if dim == 3 else [1.0, 1.0])
    cols = [c for c in (scene.get("colliders") or []) if isinstance(c, dict)]
    if any(c.get("type") == "Mesh" for c in cols):  # a Mesh collider's file is relative to the scene
        try:
            scene_file = Path(json.loads((out / "run.json").read_text())["scene"])
            cols = [
                dict(c, _scene_dir=str(scene_file.parent)) if c.get("type") == "Mesh" else c for c in cols
            ]
        except (OSError, ValueError, KeyError, TypeError):
            pass
    return Run(
        out=out,
        dim=dim,
        lower=np.asarray(lo, float)[:dim],
        upper=np.asarray(hi, float)[:dim],
        colliders=cols,
        times=times,
        entity_names=names,
        name=str(scene.get("name") or out.name),
    )


def resolve_frame(run: Run, frame: int | None) -> int:
    n = run.n_frames
    if n == 0:
        raise RenderError(f"{run.out / 'sim.h5'}: holds no complete frame yet")
    if frame is None:
        return n - 1
    k = frame + n if frame < 0 else frame
    if not 0 <= k < n:
        raise RenderError(f"--frame {frame}: sim.h5 holds frames 0..{n - 1} (negative counts from the end)")
    return k


_GRID_SCALARS = ("density", "dye", "temperature", "smoke", "pressure", "vorticity")


def read_frame(run: Run, k: int, extra: tuple[str, ...] = ()) -> list[EntityFrame]:
    """Every entity at frame k (only what a picture needs: positions, velocities, cells, one scalar)."""
    res = []
    with _h5(run.out) as f:
        for name in run.entity_names:
            g = f["entities"][name]
            kind = str(g.attrs.get("kind", "particles"))
            dim = int(g.attrs.get("dim", run.dim))
            e = EntityFrame(name=name, kind=kind, dim=dim)
            # emitters and sinks: the live rows of the frame (the rest is padding)
            live = slice(int(g["count"][k])) if "count" in g and g["count"].shape[0] > k else slice(None)
            if "velocity" in g and g["velocity"].shape[0] > k:
                e.velocity = (
                    np.asarray(g["velocity"][k], dtype=float)[live]
                    if kind != "grid"
                    else np.asarray(g["velocity"][k], dtype=float)
                )
            if kind == "grid":
                e.grid = {
                    "origin": np.asarray(g.attrs.get("origin", np.zeros(dim)), float),
                    "spacing": np.asarray(g.attrs.get("spacing", np.ones(dim)), float),
                    "shape": tuple(int(x) for x in g.attrs.get("grid_shape", ())),
                }
                for fname in _GRID_SCALARS + tuple(extra):
                    if fname in g and g[fname].shape[0] > k:
                        e.fields[fname] = np.asarray(g[fname][k], dtype=float)
            else:
                if "position" not in g or g["position"].shape[0] <= k:
                    continue
                e.position = np.asarray(g["position"][k], dtype=float)[live]
                if "cells" in g:
                    e.cells = np.asarray(g["cells"][:], dtype=np.int64)
                for fname in ("material_id",) + tuple(extra):
                    if fname in g and g[fname].shape[0] > k:
                        e.fields[fname] = np.asarray(g[fname][k])[live]
            res.append(e)
    return res


def series(run: Run) -> dict[str, dict[str, np.ndarray]]:
    """Per-entity time series from sim.h5: max and mean speed, kinetic energy (with masses where the file
    has them, else per unit mass), the highest point (particles and meshes); plus collider forces."""
    out: dict[str, dict[str, np.ndarray]] = {}
    with _h5(run.out) as f:
        nt = len(f["time"])
        for name in run.entity_names:
            g = f["entities"][name]
            s: dict[str, np.ndarray] = {}
            if "velocity" in g:
                v = g["velocity"]
                n = min(nt, v.shape[0])
                vmax, vmean, ke = np.zeros(n), np.zeros(n), np.zeros(n)
                mass = None
                for key in ("mass", "m"):
                    if key in g and g[key].ndim >= 2:
                        mass = g[key]
                for k in range(n):
                    a = np.asarray(v[k], dtype=float)
                    sp2 = (a * a).sum(axis=-1).reshape(-1)
                    sp2 = sp2[np.isfinite(sp2)]
                    vmax[k] = np.sqrt(sp2.max()) if sp2.size else 0.0
                    vmean[k] = np.sqrt(sp2).mean() if sp2.size else 0.0
                    if mass is not None:
                        ke[k] = 0.5 * float(
                            np.nansum(np.asarray(mass[k], float).reshape(-1) * (a * a).sum(-1).reshape(-1))
                        )
                    else:
                        ke[k] = 0.5 * float(sp2.mean()) if sp2.size else 0.0
                s["max_speed"], s["mean_speed"] = vmax, vmean
                s["kinetic_energy" if mass is not None else "kinetic_energy_per_kg"] = ke
            if "position" in g and str(g.attrs.get("kind")) != "grid":
                p = g["position"]
                n = min(nt, p.shape[0])
                s["top"] = np.array(
                    [float(np.nanmax(np.asarray(p[k])[:, -1], initial=-np.inf)) for k in range(n)]
                )
            out[name] = s
        if "colliders" in f:
            for cname in f["colliders"]:
                g = f["colliders"][cname]
                if "force" in g:
                    out.setdefault(f"collider {cname}", {})["force"] = np.asarray(g["force"][:], float)
    return out


def read_run_json(out: Path) -> dict:
    p = Path(out) / "run.json"
    if not p.exists():
        return {}
    try:
        return json.loads(p.read_text())
    except (OSError, ValueError):
        return {}


def read_probes(out: Path) -> tuple[list[str], np.ndarray] | None:
    """OUT/probes.csv as (column names, rows); the first column is time."""
    p = Path(out) / "probes.csv"
    if not p.exists():
        return None
    with open(p, newline="") as fh:
        rows = [r for r in csv.reader(fh) if r and not r[0].startswith("#")]
    if len(rows) < 2:
        return None
    head, body = rows[0], rows[1:]
    data = np.full((len(body), len(head)), np.nan)
    for i, r in enumerate(body):
        for j, x in enumerate(r[: len(head)]):
            try:
                data[i, j] = float(x)
            except ValueError:
                pass
    return head, data
