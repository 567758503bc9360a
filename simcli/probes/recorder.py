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
from simcli.probes import sampling
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


def _fmt(v: float) -> str:
    return "" if v is None else ("nan" if math.isnan(v) else repr(float(v)))


class ProbeRecorder:
    def __init__(self, scene, solvers, out_dir: Path, timings: dict | None = None):
        self.scene = scene
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
    def _arrays(self, name: str, fields: tuple, cache: dict) -> dict:
        key = (name, fields)
        if key not in cache:
            cache[key] = self.owner[name].entity_arrays(name, list(fields))
        return cache[key]

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

    def _point(self, p, ents, cache):
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
                a = self._arrays(e.name, ("position", "density") + ((q,) if q != "density" else ()), cache)
                h = self.scene.solvers.sph.support_radius
                w = e.material.rho / np.maximum(a["density"], 1e-12)  # volume m / rho, up to V_rest
                vals = a[field]
            elif fam == "MPM":
                h = 2.0 * self.scene.solvers.mpm.spacing
                w = None
                if q == "density":  # rho0 / J
                    a = self._arrays(e.name, ("position", "J"), cache)
                    vals = e.material.rho / np.maximum(np.asarray(a["J"], dtype=np.float64), 1e-12)
                else:
                    a = self._arrays(e.name, ("position", q), cache)
                    vals = a[q]
            else:  # PBD particles
                h = 2.0 * self.scene.solvers.pbd.particle_size
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

    def _height(self, p, ents, cache):
        ax = height_axis(p, self.dim)
        best = float("nan")
        for e in ents:
            sp = self._spacing(e)
            x = self._arrays(e.name, ("position",), cache)["position"][:, : self.dim]
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
        out = {}
        for i in due:
            p, ents = self.probes[i], self.entities[i]
            if p.type == "point":
                v = self._point(p, ents, cache)
            elif p.type == "height":
                v = self._height(p, ents, cache)
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
        self.timings["probes_s"] += time.perf_counter() - t0

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
