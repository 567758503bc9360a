"""Samples the scene's probes from the solvers' exposed arrays and writes them as they go.

The runner calls :func:`make_recorder` once (None when the scene has no probes: nothing changes for it),
passes :meth:`ProbeRecorder.open`'s result to ``FrameSink.open`` (the sim.h5 datasets
``/probes/<name>/time`` and ``/value`` must exist before the file switches to SWMR mode), and calls
:meth:`ProbeRecorder.sample` after frame 0 and after every step.

``OUT/probes.csv``: a header ``time,<name>[.x|.y|.z],...``, then one row per step at which any probe is
due (a probe not due at that step leaves its cells empty); each row is written and flushed at once, so a
killed run keeps every sample taken. A resumed run first drops the rows after the checkpoint's step
(and the samples after it in sim.h5), so no row is repeated.
"""

from __future__ import annotations

import math
import os
import time
from pathlib import Path

import numpy as np

from simcli.errors import OutputError
from simcli.probes import device, sampling
from simcli.probes.config import (
    UNITS,
    all_entities,
    components,
    height_axis,
    probe_entities,
    probe_every,
    quantity,
)

CSV_NAME = "probes.csv"


def make_recorder(scene, solvers, out_dir: Path, timings: dict | None = None):
    if not getattr(scene, "probes", None):
        return None
    return ProbeRecorder(scene, solvers, out_dir, timings)


def _point_reach(scene, entity) -> float:
    """A point probe's kernel radius in ``entity``'s family (see ProbeRecorder._point)."""
    if entity.family == "SPH":
        return scene.solvers.sph.support_radius
    if entity.family == "MPM":
        return 2.0 * scene.solvers.mpm.spacing
    return 2.0 * scene.solvers.pbd.particle_size


def _fmt(v: float) -> str:
    return "" if v is None else ("nan" if math.isnan(v) else repr(float(v)))


class ProbeRecorder:
    def __init__(self, scene, solvers, out_dir: Path, timings: dict | None = None, device: bool = True):
        """``device``: point probes and height gauges of families with a ProbeView read only the particles
        near them on the device (simcli/probes/device.py; the same values); False: every probe copies whole
        fields to the host (entity_arrays), the reference the tests compare with."""
        self.scene = scene
        self.solvers = solvers
        self.device = device
        self._samplers = (
            None  # [(FamilySampler, [(probe index, entity name) per window])], built at first use
        )
        self.dim = scene.sim.dim
        self.dt = scene.sim.dt
        self.path = Path(out_dir) / CSV_NAME
        self.timings = timings if timings is not None else {}
        self.timings.setdefault("probes_s", 0.0)
        self.probes = list(scene.probes)
        self.every = [probe_every(p, scene.output.every) for p in self.probes]
        self.ncomp = [components(p, self.dim) for p in self.probes]
        self.entities = [probe_entities(scene, p) for p in self.probes]
        self.owner = {}
        for e in all_entities(scene):
            self.owner[e.name] = next((s for s in solvers if s.owns(e.name)), None)
        self.columns = ["time"]
        for p, c in zip(self.probes, self.ncomp):
            self.columns += [p.name] if c == 1 else [f"{p.name}.{'xyz'[a]}" for a in range(c)]
        self._mass: dict[str, np.ndarray] = {}
        self._pending: list[tuple[str, float, np.ndarray]] = []  # samples not yet in sim.h5
        self.flush_every = scene.output.every
        self.ckpt_every = scene.checkpoint.every or scene.sim.n_steps + 1
        self.n_steps = scene.sim.n_steps
        self.samples = 0

    # ------------------------------------------------------------------ output
    def series(self) -> dict[str, tuple[int, str]]:
        """name -> (components, unit) of the sim.h5 series."""
        return {p.name: (c, UNITS[quantity(p)]) for p, c in zip(self.probes, self.ncomp)}

    def open(self, resume_step: int | None) -> dict:
        """Start probes.csv (or cut it back to ``resume_step`` on a resume); returns FrameSink.open's probe
        keywords."""
        t0 = time.perf_counter()
        header = ",".join(self.columns) + "\n"
        try:
            if resume_step is not None and self.path.is_file():
                keep = [header]
                with open(self.path, encoding="utf-8") as f:
                    lines = f.readlines()
                if lines and lines[0] == header:
                    for ln in lines[1:]:
                        if not ln.endswith("\n"):  # a row cut short by a kill
                            break
                        try:
                            t = float(ln.split(",", 1)[0])
                        except ValueError:
                            break
                        if round(t / self.dt) > resume_step:
                            break
                        keep.append(ln)
                tmp = self.path.with_name("." + self.path.name + ".tmp")
                with open(tmp, "w", encoding="utf-8") as f:
                    f.writelines(keep)
                    f.flush()
                    os.fsync(f.fileno())
                os.replace(tmp, self.path)
            else:
                with open(self.path, "w", encoding="utf-8") as f:
                    f.write(header)
        except OSError as e:
            raise OutputError(f"cannot write {self.path}: {e.strerror or e}") from None
        self.timings["probes_s"] += time.perf_counter() - t0
        until = None if resume_step is None else (resume_step + 0.5) * self.dt
        return {"series": self.series(), "series_until": until}

    # ------------------------------------------------------------------ sampling
    def _arrays(self, name: str, fields: tuple, cache: dict, i: int | None = None) -> dict:
        """The arrays of entity ``name`` for probe ``i``: its particles near the probe when the device path
        read them (``cache[("device", i, name)]``), else all of them (entity_arrays)."""
        near = cache.get(("device", i, name))
        if near is not None:
            return near
        key = (name, fields)
        if key not in cache:
            cache[key] = self.owner[name].entity_arrays(name, list(fields))
        return cache[key]

    # ------------------------------------------------------------------ device path
    def _device_probe(self, p, ents) -> bool:
        if p.type not in ("point", "height") or not ents:
            return False
        return all(e.family in ("SPH", "MPM") and self.owner[e.name].probe_view() is not None for e in ents)

    def _point_fields(self, p, e) -> list[str]:
        q = p.quantity
        if e.family == "SPH":
            return ["density"] + ([q] if q != "density" else [])
        return ["J"] if q == "density" else [q]

    def _window(self, p, e) -> tuple[np.ndarray, np.ndarray]:
        """A box around what the host-side tests of sampling.py keep, a little larger."""
        dim = self.dim
        if p.type == "point":
            at = np.asarray(p.position, dtype=np.float64)
            r = _point_reach(self.scene, e) * (1.0 + device.MARGIN)
            return at - r, at + r
        ax = height_axis(p, dim)
        r = self._spacing(e) * (1.0 + device.MARGIN)
        lo, hi = np.full(dim, -device.BIG), np.full(dim, device.BIG)
        others = [a for a in range(dim) if a != ax]
        for a, c in zip(others, p.position):
            lo[a], hi[a] = float(c) - r, float(c) + r
        return lo, hi

    def _build_samplers(self) -> list:
        groups: dict[int, tuple] = {}  # id(solver) -> (solver, windows, fields, owners)
        for i, (p, ents) in enumerate(zip(self.probes, self.entities)):
            if not self._device_probe(p, ents):
                continue
            for e in ents:
                s = self.owner[e.name]
                g = groups.setdefault(id(s), (s, [], set(), []))
                lo, hi = self._window(p, e)
                g[1].append((e.name, lo, hi))
                if p.type == "point":
                    g[2].update(self._point_fields(p, e))
                g[3].append((i, e.name))
        out = []
        for s, windows, fields, owners in groups.values():
            fs = device.FamilySampler(s.probe_view(), self.dim, windows, sorted(fields))
            out.append((fs, owners))
        return out

    def _read_device(self, due: list[int], cache: dict) -> None:
        if self._samplers is None:
            self._samplers = self._build_samplers()
        due_set = set(due)
        for fs, owners in self._samplers:
            if not any(i in due_set for i, _ in owners):
                continue
            for (i, name), arrays in zip(owners, fs.read()):
                cache[("device", i, name)] = arrays

    def _masses(self, entity) -> np.ndarray:
        name = entity.name
        m = self._mass.get(name)
        s = self.owner[name]
        varying = s.active_set is not None  # emitters, sinks: the count changes
        if m is not None and not varying:
            return m
        if varying and s.family == "sph":
            n = len(s.entity_arrays(name, ["position"])["position"])
            return np.full(n, entity.material.rho * float(s.V_rest))
        if varying and hasattr(s, "live_masses"):  # PBD: the live particles' masses, in output order
            return np.asarray(s.live_masses(name), dtype=np.float64)
        if "mass" in s.output_fields():  # MPM
            m = s.entity_arrays(name, ["mass"])["mass"]
        elif s.family == "sph":  # every particle carries rho0 x V_rest (simcli.solvers.sph.solver)
            m = np.full(s.entity_size(name), entity.material.rho * float(s.V_rest))
        else:  # FEM lumped vertex masses, PBD particle / vertex masses (host arrays)
            k = s._index[name]
            m = np.asarray(s.mass)[s.offsets[k] : s.offsets[k + 1]]
        m = np.asarray(m, dtype=np.float64).reshape(-1)
        self._mass[name] = m
        return m

    def _spacing(self, entity) -> float:
        sol = self.scene.solvers
        fam = entity.family
        if fam == "SPH":
            return sol.sph.particle_size
        if fam == "MPM":
            return sol.mpm.spacing
        return sol.pbd.particle_size

    def _reach(self, entity) -> float:
        """How far apart two particles of ``entity`` still act on each other: SPH: the kernel's support
        radius; MPM: three grid cells (quadratic B-splines reach 1.5 cells from each particle); PBD: two
        particle sizes. A connected height gauge's gap."""
        sol = self.scene.solvers
        if entity.family == "SPH":
            return sol.sph.support_radius
        if entity.family == "MPM":
            return 3.0 * sol.mpm.dx
        return 2.0 * sol.pbd.particle_size

    def _point(self, p, ents, cache, i=None):
        q = p.quantity
        ent0 = ents[0]
        if ent0.family == "SF":
            s = self.owner[ent0.name]
            _shape, origin, spacing = s.entity_grid(ent0.name)
            data = self._arrays(ent0.name, (q,), cache)[q]
            return sampling.grid_interpolate(data, origin, spacing, p.position)
        num, den = None, 0.0
        for e in ents:
            fam = e.family
            if fam == "SPH":
                field = q
                a = self._arrays(e.name, ("position", "density") + ((q,) if q != "density" else ()), cache, i)
                h = _point_reach(self.scene, e)
                w = e.material.rho / np.maximum(a["density"], 1e-12)  # volume m / rho, up to V_rest
                vals = a[field]
            elif fam == "MPM":
                h = _point_reach(self.scene, e)
                w = None
                if q == "density":  # rho0 / J
                    a = self._arrays(e.name, ("position", "J"), cache, i)
                    vals = e.material.rho / np.maximum(np.asarray(a["J"], dtype=np.float64), 1e-12)
                else:
                    a = self._arrays(e.name, ("position", q), cache, i)
                    vals = a[q]
            else:  # PBD particles
                h = _point_reach(self.scene, e)
                w = None
                a = self._arrays(e.name, ("position", q), cache)
                vals = a[q]
            x = a["position"]
            vals = np.asarray(vals, dtype=np.float64)
            if q == "velocity":
                vals = vals[:, : self.dim]
            else:
                vals = vals.reshape(-1)
            n, d = sampling.kernel_sums(x[:, : self.dim], vals, p.position, h, w)
            num = n if num is None else num + n
            den += d
        return sampling.finish(num, den)

    def _height(self, p, ents, cache, i=None):
        ax = height_axis(p, self.dim)
        best = float("nan")
        for e in ents:
            sp = self._spacing(e)
            x = self._arrays(e.name, ("position",), cache, i)["position"][:, : self.dim]
            gap = self._reach(e) if p.surface == "connected" else None
            h = sampling.surface_height(x, p.position, ax, sp, 0.5 * sp, gap)
            if not math.isnan(h) and (math.isnan(best) or h > best):
                best = h
        return np.asarray(best)

    def _total(self, p, ents, cache):
        q = p.quantity
        acc, mtot = None, 0.0
        for e in ents:
            m = self._masses(e)
            if q == "elastic_energy":
                a = self._arrays(e.name, ("elastic_energy",), cache)
                s, mm = sampling.totals(q, m, energy=a["elastic_energy"])
            elif q == "mass":
                s, mm = sampling.totals(q, m)
            else:
                a = self._arrays(e.name, ("position", "velocity"), cache)
                s, mm = sampling.totals(q, m, x=a["position"][:, : self.dim], v=a["velocity"][:, : self.dim])
            acc = s if acc is None else acc + s
            mtot += mm
        return sampling.finish_total(q, acc, mtot)

    def values(self, due: list[int]) -> dict[int, np.ndarray]:
        """Probe index -> value (scalar or (dim,)) for the probes in ``due``, from the current state."""
        cache: dict = {}
        if self.device:
            self._read_device(due, cache)
        out = {}
        for i in due:
            p, ents = self.probes[i], self.entities[i]
            if p.type == "point":
                v = self._point(p, ents, cache, i)
            elif p.type == "height":
                v = self._height(p, ents, cache, i)
            else:
                v = self._total(p, ents, cache)
            out[i] = (
                np.asarray(v, dtype=np.float64).reshape(self.ncomp[i])
                if self.ncomp[i] > 1
                else np.asarray(float(np.asarray(v).reshape(-1)[0]))
            )
        return out

    def sample(self, step: int, sink=None) -> None:
        """Sample the probes due at ``step`` (step % every == 0): at once into probes.csv (flushed), and into
        sim.h5 at the next frame step, checkpoint step or the last step (:meth:`flush`)."""
        due = [i for i, k in enumerate(self.every) if step % k == 0]
        if due:
            self._sample(step, due)
        frame = step % self.flush_every == 0  # the runner writes (and flushes) a frame right after
        if sink is not None and (frame or step % self.ckpt_every == 0 or step >= self.n_steps):
            self.flush(sink, h5_flush=not frame)

    def _sample(self, step: int, due: list[int]) -> None:
        t0 = time.perf_counter()
        t = step * self.dt
        vals = self.values(due)
        # step x dt without its round-off tail (0.036, not 0.036000000000000004)
        cells = [repr(float(f"{t:.12g}"))]
        for i, c in enumerate(self.ncomp):
            if i in vals:
                cells += [_fmt(x) for x in np.atleast_1d(vals[i])]
            else:
                cells += [""] * c
        try:
            with open(self.path, "a", encoding="utf-8") as f:
                f.write(",".join(cells) + "\n")
        except OSError as e:
            raise OutputError(f"cannot write {self.path}: {e.strerror or e}") from None
        for i in due:
            self._pending.append((self.probes[i].name, t, vals[i]))
        self.samples += 1
        dt = time.perf_counter() - t0
        if self.samples == 1:  # the first sample builds the device path: allocation and kernel compilation
            self.timings["probes_setup_s"] = dt
        self.timings["probes_s"] += dt

    def flush(self, sink, h5_flush: bool = True) -> None:
        """Append the samples taken since the last flush to sim.h5 (at frame writes, checkpoints and the last
        step: one HDF5 flush per frame, not per sample; probes.csv has every sample at once)."""
        pending, self._pending = self._pending, []
        if not pending:
            return
        t0 = time.perf_counter()
        batch: dict[str, list] = {}
        for name, t, v in pending:
            batch.setdefault(name, []).append((t, v))
        sink.write_series(batch, flush=h5_flush)
        self.timings["probes_s"] += time.perf_counter() - t0
