"""Emitters and sinks inside a particle solver (MPM, SPH, PBD): an active particle count, emission into the
reserved slots and removal with compaction (docs/SCENE_FORMAT.md section 5, scene side in
simcli/scene/sources.py).

Layout. A solver with emitters or sinks allocates its particle fields for every particle it may ever hold:
its entities' particles, then each emitter's ``max_particles`` (its Body, made by
:func:`simcli.scene.sources.emitter_bodies`, holds one more row, the last of which, the array's last
slot, is never active: a *fresh* row whose per-particle state (a law's Jp, quaternion, ...) is the
initial one). The active particles are the slots ``[0, n_active)``, dense; every particle loop of the
solver runs over ``range(count())``, so inactive slots cost nothing per substep. A particle's identity is
its ``pid`` (the writers' order): entity k owns pids ``offsets[k] .. offsets[k + 1]``; an emitter hands
out its pids in order (with ``reuse: true``, freed pids first, so a pid is then a slot, not an identity:
the emission number is).

* **Emission** (before a substep, no host sync: the host knows ``n_active``): layer q of an emitter leaves
  its nozzle at t_q = start + q spacing / speed; the layers due by the substep's start t are written at
  slots ``n_active ..`` as the nozzle's lattice moved ballistically for their age t - t_q (x = c + s +
  n speed a + g a^2 / 2, v = n speed + g a), every other per-particle field copied from the fresh row.
  So the layers lie one spacing apart along the normal (rest spacing, rest density) and the mass flux is
  rho A speed (a lattice of n_layer particles of mass m per layer, speed / spacing layers per second).
  MPM staggers the layers: layer q's lattice is shifted in the nozzle's plane by the q-th point of a
  low-discrepancy sequence over one lattice cell (``layer_shift``). With every layer on the same lattice
  the particles of one lattice column (every layer's) follow one streamline: where the stream spreads
  (a poured heap's impact point) they bunch along a few radial streaks with empty bands between, a
  distribution MPM's F does not see (the spreading is volume-preserving), so the heap is a fan of
  stress-free streaks. SPH and PBD keep the layers stacked (a liquid's inflow at its rest lattice).
* **Sinks** (after a step, one small host read): particles inside a sink are counted; if any, one
  serial pass lists the holes they leave below the new count and the survivors above it, and every
  per-particle field copies the survivors into the holes (parallel: sources and targets are disjoint).
  The serial pass keeps the order deterministic (a resumed run equals an uninterrupted one) and sums the
  removed mass per sink in f64.
* **Slot reuse** (an emitter's ``reuse: true``; SPlisHSPlasH's emitters do the same). Without it a pid is
  handed out once (pid - pid0 = the particle's emission number: layer x particles per layer + lattice
  point), so an emitter stops at ``max_particles`` emitted however many a sink removed. With it the sink's
  serial pass pushes the pid of each removed particle of a reusing emitter onto that emitter's ring of free
  pids (``free``, at the emitter's own pid range; ``ftail`` counts the pushes), and an emission pops the
  ring (from ``head``, which the host keeps) before it takes fresh pids. The emission number then lives in
  ``serial``, indexed by pid: the pid travels with its particle through compaction and SPH's cell sort, so
  no per-slot field is added to the solvers' reorder lists. The layer (MPM's stagger, the SPH inflow
  buffer's age) comes from ``serial``. Only whole layers are emitted; a layer due while too few pids are
  free is skipped (its mass is not counted as emitted; a warning, run.json's ``layers_skipped``). Slots
  (storage) stay dense as before: reuse changes which pid a new particle gets, never the active count's
  compaction. The checkpoint holds the rings, their counters and ``serial``.
"""

import math
from typing import Any

import numpy as np

from simcli.backend import stdout_to_stderr
from simcli.scene.sources import family_spacing_of, nozzle_area, nozzle_frame, nozzle_lattice

with stdout_to_stderr():
    import taichi as ti


# R2 sequence (Roberts 2018): the fractional parts of k / phi_2 and k / phi_2^2 (phi_2 the plastic number)
# cover the unit square evenly for every k; the 2D layers use the golden ratio's 1 / phi
ALPHA = (0.7548776662466927, 0.5698402909980532)
ALPHA_2D = 0.6180339887498949


def is_emitter(body) -> bool:
    return bool(getattr(body.entity, "is_emitter", False))


def has_sources(scene, family: str) -> bool:
    """Whether a solver of ``family`` needs an active count: an emitter of its family or any sink."""
    return bool(getattr(scene, "sinks", None)) or any(
        em.family == family for em in getattr(scene, "emitters", [])
    )


class ActiveSet:
    """The active count, emitters and sinks of one particle solver (see the module docstring).

    ``plan`` (in the solver's __init__, no Taichi), then ``build`` (after the solver's fields exist)."""

    def __init__(self, scene: Any, bodies: list, family: str) -> None:
        self.scene = scene
        self.family = family
        self.dim = int(scene.sim.dim)
        offsets = np.cumsum([0] + [b.n for b in bodies]).astype(np.int64)
        self.n_alloc = int(offsets[-1])
        self.n0 = int(sum(b.n for b in bodies if not is_emitter(b)))
        self.n_active = self.n0
        self.spacing = family_spacing_of(scene, family)
        self.emitters = []
        for k, b in enumerate(bodies):
            if not is_emitter(b):
                continue
            em = b.entity.emitter
            lat = nozzle_lattice(em.shape, self.dim, self.spacing)
            nrm, _axes = nozzle_frame(em.shape.normal, self.dim)
            self.emitters.append(
                {
                    "cfg": em,
                    "body": k,
                    "pid0": int(offsets[k]),
                    "cap": int(em.max_particles),
                    "lattice": lat,
                    "normal": nrm,
                    "layers": 0,  # layers emitted so far
                    "full": False,
                    "mass": 0.0,  # set by the solver (its particle mass)
                    "dt_layer": self.spacing / float(em.speed),  # set by build from the mass flux
                    "area": nozzle_area(em.shape, self.dim),
                    # reuse (see "Slot reuse" above): the free ring's pops (head) and pushes (tail), the
                    # fresh slots handed out, the particles emitted and the layers skipped for want of slots
                    "reuse": bool(getattr(em, "reuse", False)),
                    "head": 0,
                    "tail": 0,
                    "next": 0,
                    "emitted": 0,
                    "skipped": 0,
                }
            )
        self.reuse = any(e["reuse"] for e in self.emitters)
        # MPM: each layer's lattice shifted in the nozzle's plane (layer_shift in build); SPH and PBD keep
        # the layers stacked (a liquid's inflow at its rest lattice)
        self.stagger = family == "MPM"
        self.sinks = list(getattr(scene, "sinks", []))
        self.warnings: list[str] = []
        self.first = 0  # the first slot sinks may remove (build)
        self._built = False

    def live_particles(self) -> int:
        """Particles live now (host, no sync): the active count less the slots before ``first``
        (PBD's meshed vertices)."""
        return self.n_active - self.first

    # ------------------------------------------------------------------ build
    def build(
        self, solver, persistent: list, consts: dict, f, buffer_layers: int = 0, first: int = 0, mass=None
    ) -> None:
        """``persistent``: every per-particle field that carries state (moved by compaction, reset from the
        fresh row on emission), x, v and pid among them (``solver.x``, ``solver.v``, ``solver.pid``);
        ``consts``: field -> per-emitter values (mass, material id, volume) written on emission;
        ``buffer_layers``: the newest layers of each emitter keep the nozzle's prescribed (ballistic) motion,
        an inflow buffer (SPH: the kernel support), see before_substep; ``first``: the first slot a sink
        may remove (PBD: the free particles follow the cloth, rod and soft-body vertices, which stay put)."""
        dim = self.dim
        self.first = int(first)
        self.solver = solver
        self.f = f
        for e in self.emitters:
            # the layers' distance along the normal makes the mass flux rho A speed exactly: n_layer m /
            # (rho A),
            # one spacing where the lattice fills the nozzle (a segment a whole number of spacings long; SPH:
            # times V_rest / spacing^dim, 0.997), a few per cent off it for a coarse circle
            rho = float(e["cfg"].material.rho)
            e["layer_gap"] = len(e["lattice"]) * e["mass"] / (rho * e["area"])
            e["dt_layer"] = e["layer_gap"] / float(e["cfg"].speed)
        self.nact = ti.field(ti.i32, shape=())
        self.nact[None] = self.n_active
        x, v, pid, gravity = solver.x, solver.v, solver.pid, solver.gravity
        ne = max(1, len(self.emitters))
        nsk = max(1, len(self.sinks))
        lat = [e["lattice"] for e in self.emitters] or [np.zeros((1, dim))]
        lat_off = np.cumsum([0] + [len(a) for a in lat]).astype(np.int64)
        self.lat_off = lat_off
        self.lat = ti.Vector.field(dim, f, shape=int(lat_off[-1]))
        npf = np.float64 if f == ti.f64 else np.float32
        self.lat.from_numpy(np.concatenate(lat).astype(npf))
        self.em_i = ti.field(ti.i32, shape=(ne, 3))  # pid0, particles per layer, lattice offset
        self.em_t = ti.field(ti.f64, shape=(ne, 3))  # start, layer interval, buffer age
        for k, e in enumerate(self.emitters):
            self.em_i[k, 0], self.em_i[k, 1], self.em_i[k, 2] = e["pid0"], len(e["lattice"]), int(lat_off[k])
            self.em_t[k, 0], self.em_t[k, 1] = float(e["cfg"].start), e["dt_layer"]
            self.em_t[k, 2] = buffer_layers * e["dt_layer"]
        self.buffer_layers = buffer_layers
        self.em_c = ti.Vector.field(dim, f, shape=ne)
        self.em_u = ti.Vector.field(dim, f, shape=ne)  # normal x speed
        # the staggered layers (MPM, see layer_shift): the nozzle's in-plane axes times the spacing
        self.em_a = ti.Vector.field(dim, f, shape=(ne, 2))
        for k, e in enumerate(self.emitters):
            self.em_c[k] = [float(c) for c in e["cfg"].shape.center]
            self.em_u[k] = [float(c) * float(e["cfg"].speed) for c in e["normal"]]
            _n, axes = nozzle_frame(e["cfg"].shape.normal, dim)
            for j in range(2):
                a = axes[j] * self.spacing if j < len(axes) else np.zeros(dim)
                self.em_a[k, j] = [float(c) for c in a]
        const_fields = []
        for fld, vals in consts.items():
            cf = ti.field(fld.dtype, shape=ne)
            cf.from_numpy(np.asarray(list(vals) or [0], dtype=cf.to_numpy().dtype))
            const_fields.append((fld, cf))
        self.sk_lo = ti.Vector.field(dim, f, shape=nsk)
        self.sk_hi = ti.Vector.field(dim, f, shape=nsk)
        for k, s in enumerate(self.sinks):
            self.sk_lo[k] = [float(c) for c in s.lower]
            self.sk_hi[k] = [float(c) for c in s.upper]
        self.removed = ti.field(ti.f64, shape=nsk)  # mass removed per sink [kg]
        self.removed_n = ti.field(ti.i64, shape=nsk)
        cap = self.n_alloc
        self.holes = ti.field(ti.i32, shape=cap)
        self.movers = ti.field(ti.i32, shape=cap)
        self.nmove = ti.field(ti.i32, shape=())
        fresh = self.n_alloc - 1
        P = list(persistent)
        nP = len(P)
        nC = len(const_fields)
        mass = solver.mass if mass is None else mass  # the per-particle mass field (the sinks' sums)
        nact, lat_f, em_c, em_u, em_a = self.nact, self.lat, self.em_c, self.em_u, self.em_a
        stagger = self.stagger
        a_u = ALPHA_2D if dim == 2 else ALPHA[0]
        sk_lo, sk_hi, removed, removed_n = self.sk_lo, self.sk_hi, self.removed, self.removed_n
        holes, movers, nmove = self.holes, self.movers, self.nmove
        em_i, em_t = self.em_i, self.em_t
        n_sinks = len(self.sinks)
        n_em = len(self.emitters)
        caps = ti.field(ti.i32, shape=ne)
        for k, e in enumerate(self.emitters):
            caps[k] = e["cap"]
        # slot reuse (module docstring): by pid, a particle's emission number (its layer x particles per
        # layer + its lattice point), which moves with the pid through compaction and the SPH cell sort;
        # per emitter a ring of free pids (at the emitter's own pids' index range) and its push count
        reuse = self.reuse
        serial = free = ftail = em_re = None
        if reuse:
            self.serial = serial = ti.field(ti.i32, shape=self.n_alloc)
            self.free = free = ti.field(ti.i32, shape=self.n_alloc)
            self.ftail = ftail = ti.field(ti.i64, shape=ne)
            em_re = ti.field(ti.i32, shape=ne)
            for k, e in enumerate(self.emitters):
                em_re[k] = int(e["reuse"])

        @ti.func
        def layer_shift(e, layer):
            """The in-plane offset of an emitter's layer ``layer`` (0 for the first): a low-discrepancy
            (R2 / golden-ratio) sequence over one lattice cell, so no two layers share a streamline."""
            r = ti.Vector.zero(f, dim)
            if ti.static(stagger):
                lf = ti.cast(layer, ti.f64)
                u = lf * a_u + 0.5
                w = lf * ALPHA[1] + 0.5
                r = ti.cast(u - ti.floor(u) - 0.5, f) * em_a[e, 0]
                if ti.static(dim == 3):
                    r += ti.cast(w - ti.floor(w) - 0.5, f) * em_a[e, 1]
            return r

        @ti.kernel
        def emit(
            slot0: ti.i32,
            pid0: ti.i32,
            k0: ti.i32,
            npl: ti.i32,
            nl: ti.i32,
            age0: f,
            dage: f,
            e: ti.i32,
            serial0: ti.i32,
            ntake: ti.i32,
            head: ti.i64,
        ):
            """``nl`` layers at slots slot0..: emission numbers serial0.. (layer serial0 / npl first); pids
            pid0.., with reuse the first ``ntake`` popped from the emitter's free ring at ``head``."""
            g = gravity[None]
            for q in range(nl * npl):
                s = slot0 + q
                layer = q // npl
                for c in ti.static(range(nP)):
                    P[c][s] = P[c][fresh]
                for c in ti.static(range(nC)):
                    const_fields[c][0][s] = const_fields[c][1][e]
                a = age0 - layer * dage
                x[s] = em_c[e] + lat_f[k0 + q % npl] + a * em_u[e] + (0.5 * a * a) * g
                x[s] += layer_shift(e, (serial0 + q) // npl)
                v[s] = em_u[e] + a * g
                p = pid0 + q
                if ti.static(reuse):
                    if q < ntake:
                        p = free[em_i[e, 0] + ti.cast((head + q) % caps[e], ti.i32)]
                    else:
                        p = pid0 + q - ntake
                    serial[p] = serial0 + q
                pid[s] = p
            nact[None] = slot0 + nl * npl

        @ti.func
        def which_sink(xi):
            k = -1
            for j in range(n_sinks):
                inside = True
                for d in ti.static(range(dim)):
                    inside = inside and sk_lo[j][d] <= xi[d] and xi[d] <= sk_hi[j][d]
                if inside and k < 0:
                    k = j
            return k

        @ti.kernel
        def sink_count() -> ti.i32:
            c = 0
            for i in range(first, nact[None]):
                if which_sink(x[i]) >= 0:
                    c += 1
            return c

        @ti.kernel
        def sink_plan(cnt: ti.i32):
            ti.loop_config(serialize=True)
            for _ in range(1):
                n = nact[None]
                new_n = n - cnt
                h = 0
                m = 0
                for i in range(first, n):
                    k = which_sink(x[i])
                    if k >= 0:
                        removed[k] += ti.cast(mass[i], ti.f64)
                        removed_n[k] += 1
                        if ti.static(reuse):  # a reusing emitter's particle: its pid to the free ring
                            p = pid[i]
                            for e in range(n_em):
                                q = p - em_i[e, 0]
                                if em_re[e] != 0 and 0 <= q and q < caps[e]:
                                    free[em_i[e, 0] + ti.cast(ftail[e] % caps[e], ti.i32)] = p
                                    ftail[e] += 1
                        if i < new_n:
                            holes[h] = i
                            h += 1
                    elif i >= new_n:
                        movers[m] = i
                        m += 1
                nmove[None] = h
                nact[None] = new_n

        @ti.kernel
        def sink_move():
            for j in range(nmove[None]):
                a = holes[j]
                b = movers[j]
                for c in ti.static(range(nP)):
                    P[c][a] = P[c][b]

        @ti.kernel
        def drive(t: ti.f64):
            """The inflow buffer: particles younger than buffer_layers layer intervals move as the nozzle
            prescribes (positions and velocities of ballistic flight from their layer's time)."""
            g = gravity[None]
            for i in range(nact[None]):
                p = pid[i]
                for e in range(n_em):
                    q = p - em_i[e, 0]
                    if 0 <= q and q < caps[e]:
                        if ti.static(reuse):  # the slot's particle's own emission number
                            q = serial[p]
                        npl = em_i[e, 1]
                        a64 = t - (em_t[e, 0] + (q // npl + 0.5) * em_t[e, 1])
                        if a64 < em_t[e, 2]:
                            a = ti.cast(a64, f)
                            x[i] = em_c[e] + lat_f[em_i[e, 2] + q % npl] + a * em_u[e] + (0.5 * a * a) * g
                            x[i] += layer_shift(e, q // npl)
                            v[i] = em_u[e] + a * g

        self._drive = drive
        self._emit, self._sink_count, self._sink_plan, self._sink_move = (
            emit,
            sink_count,
            sink_plan,
            sink_move,
        )
        # compiled now, with the build (run.json's compile time), not at the first emission: no-op launches
        if self.emitters:
            emit(self.n_active, 0, 0, 1, 0, 0.0, 0.0, 0, 0, 0, 0)
            if buffer_layers:
                drive(0.0)
        if self.sinks:
            sink_count()
        self._built = True

    def count_func(self):
        """A Taichi func giving the active count (the solver's loops run over range(count()))."""
        nact = self.nact

        @ti.func
        def count():
            return nact[None]

        return count

    # ------------------------------------------------------------------ stepping
    def before_substep(self, t: float) -> bool:
        """The inflow buffer moved to time t, then the layers due by t emitted; True if the active count
        changed."""
        changed = False
        if self.buffer_layers and self.n_active > self.n0:
            # only while some emitter's youngest layer is still in its buffer (a stopped jet costs nothing)
            if any(
                e["layers"]
                and t - (e["cfg"].start + (e["layers"] - 0.5) * e["dt_layer"])
                < self.buffer_layers * e["dt_layer"]
                for e in self.emitters
            ):
                self._drive(t)
        for k, e in enumerate(self.emitters):
            cfg = e["cfg"]
            if e["full"] or t < cfg.start - 1e-12:
                continue
            if cfg.stop is not None and e["layers"] >= int(
                math.floor((cfg.stop - cfg.start) / e["dt_layer"] + 0.5)
            ):
                continue  # every layer before stop has left
            t_end = t if cfg.stop is None else min(t, cfg.stop)
            dtl = e["dt_layer"]
            # layer q stands for [start + q dtl, start + (q + 1) dtl) and leaves the nozzle at its middle
            due = int(math.floor((t_end - cfg.start) / dtl - 0.5 + 1e-9)) + 1
            if cfg.stop is not None:  # the layers whose middle is before stop
                due = min(due, int(math.floor((cfg.stop - cfg.start) / dtl + 0.5)))
            nl = due - e["layers"]
            if nl <= 0:
                continue
            npl = len(e["lattice"])
            if e["reuse"]:
                changed = self._emit_reusing(k, e, t, nl) or changed
                continue
            room = (e["cap"] - e["layers"] * npl) // npl
            if nl > room:
                nl = room
                e["full"] = True
                self.warnings.append(
                    f"emitter '{cfg.name}' reached max_particles = {e['cap']} at t = {t:.4g} s and stopped "
                    f"emitting ({e['layers'] + nl} layers of {npl}); raise max_particles to emit longer"
                )
            if nl <= 0:
                continue
            age0 = t - (cfg.start + (e["layers"] + 0.5) * dtl)
            self._emit(
                self.n_active,
                e["pid0"] + e["layers"] * npl,
                int(self.lat_off[k]),
                npl,
                nl,
                age0,
                dtl,
                k,
                e["layers"] * npl,
                0,
                0,
            )
            e["layers"] += nl
            e["next"] = e["emitted"] = e["layers"] * npl
            self.n_active += nl * npl
            changed = True
        return changed

    def _emit_reusing(self, k: int, e: dict, t: float, nl: int) -> bool:
        """A reusing emitter's ``nl`` due layers: the oldest that the free slots (the free ring, then the
        fresh ones) hold whole are emitted, the rest skipped (their mass is not emitted; a warning the
        first time). True if any was emitted."""
        cfg, npl, dtl = e["cfg"], len(e["lattice"]), e["dt_layer"]
        if (e["layers"] + nl) * npl >= 2**31 - 1:  # the emission numbers are int32
            nl = max(0, (2**31 - 2) // npl - e["layers"])
            e["full"] = True
            self.warnings.append(
                f"emitter '{cfg.name}' has emitted the most particles an int32 emission number counts "
                f"({e['layers'] * npl}) at t = {t:.4g} s and stopped emitting"
            )
        nfree = e["tail"] - e["head"]
        room = (nfree + e["cap"] - e["next"]) // npl
        ne = min(nl, room)
        if ne < nl:
            if e["skipped"] == 0:
                self.warnings.append(
                    f"emitter '{cfg.name}' (reuse) had no {npl} free slots for a layer at t = {t:.4g} s: "
                    f"{e['next'] - nfree} of its max_particles = {e['cap']} are alive; the layers due "
                    "while none is free are skipped (run.json sources: layers_skipped); raise max_particles"
                )
            e["skipped"] += nl - ne
        if ne > 0:
            n = ne * npl
            take = min(nfree, n)
            age0 = t - (cfg.start + (e["layers"] + 0.5) * dtl)
            self._emit(
                self.n_active,
                e["pid0"] + e["next"],
                int(self.lat_off[k]),
                npl,
                ne,
                age0,
                dtl,
                k,
                e["layers"] * npl,
                take,
                e["head"],
            )
            e["head"] += take
            e["next"] += n - take
            e["emitted"] += n
            self.n_active += n
        e["layers"] += nl
        return ne > 0

    def after_step(self) -> bool:
        """Remove the particles inside sinks (one host read); True if any was removed."""
        if not self.sinks or self.n_active == 0:
            return False
        cnt = int(self._sink_count())
        if cnt == 0:
            return False
        self._sink_plan(cnt)
        self._sink_move()
        self.n_active -= cnt
        if self.reuse:  # the reusing emitters' freed slots (one small read, only when a sink removed any)
            tails = self.ftail.to_numpy()
            for k, e in enumerate(self.emitters):
                e["tail"] = int(tails[k])
        return True

    # ------------------------------------------------------------------ reporting
    def emitted_mass(self) -> dict[str, float]:
        return {e["cfg"].name: e["emitted"] * e["mass"] for e in self.emitters}

    def removed_mass(self) -> dict[str, float]:
        if not self.sinks:
            return {}
        r = self.removed.to_numpy()
        return {s.name: float(r[k]) for k, s in enumerate(self.sinks)}

    def info(self) -> dict:
        d = {}
        for e in self.emitters:
            npl = len(e["lattice"])
            d[e["cfg"].name] = {
                "particles_per_layer": npl,
                "layer_interval_s": e["dt_layer"],
                "layer_gap_m": e.get("layer_gap"),
                "particles_emitted": e["emitted"],
                "capacity": e["cap"],
                "particle_mass_kg": e["mass"],
                "nozzle_area": e["area"],
            }
            if e["reuse"]:
                d[e["cfg"].name].update(
                    reuse=True,
                    slots_reused=e["head"],
                    slots_free=e["tail"] - e["head"] + e["cap"] - e["next"],
                    layers_skipped=e["skipped"],
                )
        return d

    # ------------------------------------------------------------------ output
    def reusing(self, name: str) -> dict | None:
        """The emitter ``name`` if it reuses slots, else None."""
        return next((e for e in self.emitters if e["reuse"] and e["cfg"].name == name), None)

    def emitter_arrays(self, name: str, pid: np.ndarray | None = None) -> dict[str, np.ndarray]:
        """A reusing emitter's per-particle output beside its solver's fields, in the same rows (its live
        particles in pid order): ``emission`` (int64, the particle's number among the particles the
        emitter has let in, 0 for the first: unique over the run, so it tells apart the successive
        particles of one slot) and ``birth_time`` (float64 [s], when it left the nozzle). {} otherwise.
        ``pid``: the solver's pid field on the host, if it has it."""
        e = self.reusing(name)
        if e is None:
            return {}
        if pid is None:
            pid = self.solver.pid.to_numpy()
        pid = np.asarray(pid)[: self.n_active]
        lo = e["pid0"]
        live = np.sort(pid[(pid >= lo) & (pid < lo + e["cap"])])
        num = self.serial.to_numpy()[live].astype(np.int64)
        npl = len(e["lattice"])
        birth = float(e["cfg"].start) + (num // npl + 0.5) * e["dt_layer"]
        return {"emission": num, "birth_time": birth}

    # ------------------------------------------------------------------ state
    def get_state(self) -> dict[str, np.ndarray]:
        d = {
            "src_nact": np.array([self.n_active], dtype=np.int64),
            "src_layers": np.array([e["layers"] for e in self.emitters] + [0], dtype=np.int64),
            "src_full": np.array([int(e["full"]) for e in self.emitters] + [0], dtype=np.int64),
        }
        if self.sinks:
            d["src_removed"] = self.removed.to_numpy()
            d["src_removed_n"] = self.removed_n.to_numpy()
        if self.reuse:  # the free rings, their counters and every pid's emission number
            for key in ("head", "tail", "next", "emitted", "skipped"):
                d[f"src_{key}"] = np.array([e[key] for e in self.emitters] + [0], dtype=np.int64)
            d["src_free"] = self.free.to_numpy()
            d["src_serial"] = self.serial.to_numpy()
        return d

    def set_state(self, state: dict) -> None:
        if "src_nact" not in state:
            raise ValueError("the checkpoint holds no emitter/sink state (written by a scene without them)")
        self.n_active = int(np.asarray(state["src_nact"]).reshape(-1)[0])
        self.nact[None] = self.n_active
        layers = np.asarray(state["src_layers"]).reshape(-1)
        full = np.asarray(state["src_full"]).reshape(-1)
        if len(layers) != len(self.emitters) + 1:
            raise ValueError("the checkpoint's emitters differ from the scene's")
        for k, e in enumerate(self.emitters):
            e["layers"], e["full"] = int(layers[k]), bool(full[k])
            e["next"] = e["emitted"] = e["layers"] * len(e["lattice"])
        if self.reuse:
            if "src_free" not in state:
                raise ValueError(
                    "the checkpoint holds no slot-reuse state (written by a scene without an emitter's "
                    "reuse: true)"
                )
            for key in ("head", "tail", "next", "emitted", "skipped"):
                vals = np.asarray(state[f"src_{key}"]).reshape(-1)
                for k, e in enumerate(self.emitters):
                    e[key] = int(vals[k])
            self.free.from_numpy(np.asarray(state["src_free"], dtype=np.int32))
            self.serial.from_numpy(np.asarray(state["src_serial"], dtype=np.int32))
            self.ftail.from_numpy(np.array([e["tail"] for e in self.emitters] or [0], dtype=np.int64))
        if self.sinks:
            self.removed.from_numpy(np.asarray(state["src_removed"], dtype=np.float64))
            self.removed_n.from_numpy(np.asarray(state["src_removed_n"], dtype=np.int64))


class SourceRun:
    """What the runner calls: every solver's ActiveSet together (None-safe helpers below)."""

    def __init__(self, scene, solvers) -> None:
        self.scene = scene
        self.solvers = [s for s in solvers if s.active_set is not None]
        self._warned = 0

    def before_substep(self, t: float) -> None:
        for s in self.solvers:
            if s.active_set.before_substep(t):
                s.active_changed()

    def after_step(self) -> list[str]:
        """Sinks; returns new warnings (an emitter that filled up)."""
        for s in self.solvers:
            if s.active_set.after_step():
                s.active_changed()
        ws = [w for s in self.solvers for w in s.active_set.warnings]
        new, self._warned = ws[self._warned :], len(ws)
        return new

    def dt_cap(self) -> float:
        """The substep an emitter's jet needs: cfl x spacing / speed of the fastest emitter."""
        cap = math.inf
        for s in self.solvers:
            cfl = float(getattr(s, "cfl", None) or getattr(getattr(s, "opts", None), "cfl", 0.5))
            for e in s.active_set.emitters:
                cap = min(cap, cfl * s.active_set.spacing / float(e["cfg"].speed))
        return cap

    def frame_values(self) -> dict[str, float]:
        """sim.h5 paths -> value at this frame: /emitters/<name>/emitted_mass, /sinks/<name>/removed_mass
        (cumulative [kg], per metre of depth in 2D)."""
        out: dict[str, float] = {}
        for s in self.solvers:
            for name, m in s.active_set.emitted_mass().items():
                out[f"emitters/{name}/emitted_mass"] = m
        for sk in self.scene.sinks:
            out[f"sinks/{sk.name}/removed_mass"] = sum(
                s.active_set.removed_mass().get(sk.name, 0.0) for s in self.solvers
            )
        return out

    def info(self) -> dict:
        vals = self.frame_values()
        d: dict = {"emitters": {}, "sinks": {}}
        for s in self.solvers:
            d["emitters"].update(s.active_set.info())
        for name in d["emitters"]:
            d["emitters"][name]["emitted_mass_kg"] = vals[f"emitters/{name}/emitted_mass"]
        for sk in self.scene.sinks:
            d["sinks"][sk.name] = {"removed_mass_kg": vals[f"sinks/{sk.name}/removed_mass"]}
        return d


def make_source_run(scene, solvers) -> "SourceRun | None":
    if not getattr(scene, "emitters", None) and not getattr(scene, "sinks", None):
        return None
    return SourceRun(scene, solvers)
