"""PBD's memory estimate from the scene alone (no Taichi, no mesh built): its Part of
``simcli.scene.resources`` and the vertex and constraint counts of an entity (also used by
``check_entity`` to decide whether `validate` builds the body)."""

from __future__ import annotations

from simcli.scene.estimate import MIB, Part, fp_factor, out_floats, particle_count

# Peak RSS of `simcli run` with a tiny PBD scene (simcli.scene.resources: the baseline); PBD's many
# constraint kernels compile to the most
BASELINE = 360 * MIB
BASELINE_LIQUID = 530 * MIB  # with a PBD.Liquid entity: the position-based fluid's kernels
FALLBACK = (
    ("solvers", "pbd", "particle_size"),
    "raise solvers.pbd.particle_size or lower the morphs' resolution",
)
DEFAULT_FIELDS = ["position", "velocity", "displacement"]


def baseline(scene) -> int:
    liquid = any(
        e.material.type == "PBD.Liquid" for e in list(scene.entities) + list(getattr(scene, "emitters", []))
    )
    return BASELINE_LIQUID if liquid else BASELINE


# PBD, per vertex at f32: x, v, previous x, rest x, reaction, fixed velocity (3 each), inverse mass,
# radius, drag, body id, two frictions, the contact's position delta (3) and the hash grid's slots (about
# 2 per vertex: count, start, cursor, sorted); per constraint: indices (2 or 4), rest value, compliance,
# lambda, its colour. Host: the mesh (x, mass f64), constraints as int64 pairs and quads, the colouring's
# work arrays. PBD.Liquid adds the neighbour list (64 int32) and 8 scalars per particle.
PBD_VERTEX_BYTES = 4 * (18 + 6 + 3 + 8) + 8 * (3 + 1 + 3)
PBD_CONSTRAINT_BYTES = 4 * (4 + 3 + 1) + 8 * (4 + 1) * 2
PBD_LIQUID_BYTES = 4 * (64 + 1 + 8 + 3)
PBD_HOST_FACTOR = 1.7  # meshes: vertices and constraints
PBD_PARTICLE_HOST_FACTOR = 1.24  # free particles (PBD.Particle, PBD.Liquid)


def pbd_entity_counts(e, opts, scene_dir=None, dim: int = 3) -> tuple[int, int, str]:
    """(vertices, constraints, kind) of a PBD entity, from its morph alone (no mesh built). Mesh files are
    read (memory proportional to the file); every other morph is counted analytically."""
    m = e.morph
    mat = e.material.type
    if mat in ("PBD.Particle", "PBD.Liquid"):
        n = particle_count(m, opts.particle_size, dim, scene_dir)
        return n, 0, "particles"
    if mat == "PBD.Elastic" and m.type != "Line":
        from simcli.geometry.tetmesh import estimate_counts
        from simcli.scene.meshing import Meshing

        # meshed as topology.mesh_for_entity meshes it: a Meshing at solvers.pbd.tet_resolution
        nv, nt = estimate_counts(e, Meshing(resolution=opts.tet_resolution), scene_dir)
        # a Box's 6-tet cells have 7 edges per cell (about 7 / 6 per tet); TetGen's meshes about 1.2
        return nv, nt + int(1.2 * nt), "tets"
    if m.type == "Rectangle":
        nu, nv = ([m.resolution] * 2) if isinstance(m.resolution, int) else list(m.resolution)
        edges = 3 * nu * nv + nu + nv
        quads = 3 * nu * nv - nu - nv
        return (nu + 1) * (nv + 1), edges + quads, "triangles"
    if m.type == "Mesh":  # an open surface: vertices and triangles from the file
        from simcli.solvers.pbd.topology import read_open_surface

        x, tris = read_open_surface(m, scene_dir)
        return len(x), 3 * len(tris), "triangles"
    if m.type == "Line":
        n = (m.segments + 1) if m.segments is not None else len(m.points)
        return n, 2 * n, "lines"
    return 0, 0, "?"


def estimate(scene, scene_dir, lo, hi) -> Part | None:
    opts = scene.solvers.pbd
    fp = fp_factor(scene)
    nv = nc = n_liq = n_free = 0
    big, big_n = None, -1
    for i, e in enumerate(scene.entities):
        if e.family != "PBD":
            continue
        v, c, kind = pbd_entity_counts(e, opts, scene_dir, int(scene.sim.dim))
        nv, nc = nv + v, nc + c
        if kind == "particles":
            n_free += v
        if e.material.type == "PBD.Liquid":
            n_liq += v
        if v > big_n:
            big, big_n = (i, e, kind), v
    for i, em in enumerate(getattr(scene, "emitters", [])):
        if em.family != "PBD":
            continue
        # reserved slots (and the fresh row): allocated up front (simcli/solvers/sources.py)
        v = em.max_particles + 1
        nv, n_free = nv + v, n_free + v
        if em.material.type == "PBD.Liquid":
            n_liq += v
        if v > big_n:
            big, big_n = (i, em, "emitter"), v
    if big is None:
        return None
    meshed = (nv - n_free) * PBD_VERTEX_BYTES * fp + nc * PBD_CONSTRAINT_BYTES
    free = n_free * PBD_VERTEX_BYTES * fp + n_liq * PBD_LIQUID_BYTES * fp
    b = int(meshed * PBD_HOST_FACTOR + free * PBD_PARTICLE_HOST_FACTOR)

    i, e, kind = big
    if kind == "emitter":
        key, advice = ("emitters", i, "max_particles"), f"lower emitters.{i}.max_particles ('{e.name}')"
    elif kind == "particles":
        key, advice = ("solvers", "pbd", "particle_size"), "raise solvers.pbd.particle_size"
    elif kind == "tets":
        key, advice = ("solvers", "pbd", "tet_resolution"), "lower solvers.pbd.tet_resolution"
    elif e.morph.type == "Rectangle":
        key = ("entities", i, "morph", "resolution")
        advice = f"lower entities.{i}.morph.resolution (entity '{e.name}')"
    elif e.morph.type == "Line":
        key = ("entities", i, "morph", "segments")
        advice = f"lower entities.{i}.morph.segments (entity '{e.name}')"
    else:
        key, advice = ("entities", i, "morph", "file"), f"use a coarser mesh for entity '{e.name}'"
    return Part(
        "PBD",
        f"{nv:,} vertices/particles, {nc:,} constraints",
        b,
        key,
        advice,
        out_bytes=nv
        * out_floats(scene, DEFAULT_FIELDS, int(scene.sim.dim))
        * 4,  # output is float32 at either precision
        state_bytes=nv * 4 * fp * 2 * int(scene.sim.dim),  # x, v
    )
