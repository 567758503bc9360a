"""Contact of FEM vertices with the domain walls and the colliders (kernel side).

Every obstacle is a signed-distance function (``simcli.colliders``); the domain's faces are planes.
``nearest(x)`` gives the most penetrated obstacle at x: (phi, normal, contact kind id, friction).
The explicit integrator projects penetrating vertices out (``project_out``); the implicit one adds
a penalty to the incremental potential and applies Coulomb friction to the velocity afterwards.
"""

from simcli.backend import stdout_to_stderr
from simcli.colliders import collider_specs, sdf_box, sdf_cylinder, sdf_plane, sdf_sphere, wall_specs

with stdout_to_stderr():
    import taichi as ti

KIND_ID = {"slip": 0, "sticky": 1, "separate": 2}


def make_nearest(scene, dim: int = 3, poses=None, with_restitution: bool = False):
    """A ti.func x -> (phi, n, kind id, friction, obstacle velocity, collider index or -1) over the walls
    and colliders of the scene: the most penetrated one. ``poses`` (simcli.colliders.ColliderPoses): moving
    colliders are evaluated at the substep's end pose (slot 1) in their body frame, with their surface
    velocity; without it (or for still ones) the velocity is zero. ``with_restitution``: a seventh value,
    the collider's normal restitution (0 for walls). Mesh colliders sample their signed-distance grid
    (simcli.collider_mesh)."""
    lo, hi = scene.domain.bounds(dim)
    obstacles = []  # (kind, a, b, radius, half_height, axis, contact, friction)
    for w in wall_specs(scene, dim):
        n = [0.0] * dim
        n[w.axis] = -float(w.side)  # pointing into the domain
        p = [0.0] * dim
        p[w.axis] = lo[w.axis] if w.side < 0 else hi[w.axis]
        obstacles.append(("Plane", tuple(p), tuple(n), 0.0, 0.0, 0, w.contact, w.friction))
    nw = len(obstacles)
    specs = poses.specs if poses is not None else collider_specs(scene, dim)
    from simcli.collider_mesh_kernels import mesh_fields

    mesh_f = [None] * nw + mesh_fields(specs, float)
    rest = [0.0] * nw + [float(c.restitution) for c in specs]
    for c in specs:
        obstacles.append((c.kind, c.a, c.b, c.radius, c.half_height, c.axis, c.contact, c.friction))
    kinds = [o[0] for o in obstacles]
    moving = [False] * nw + [c.moving and poses is not None for c in specs]

    @ti.func
    def nearest(x):
        phi_min = 1e30
        n_min = ti.Vector.zero(float, 3)
        v_min = ti.Vector.zero(float, 3)
        kind = 0
        mu = 0.0
        idx = -1
        e = 0.0
        for k in ti.static(range(len(obstacles))):
            o = ti.static(obstacles[k])
            phi = 0.0
            nrm = ti.Vector.zero(float, 3)
            xq = x
            if ti.static(moving[k]):
                xq = poses.to_body(k - nw, x, 1)
            if ti.static(kinds[k] == "Plane"):
                phi, nrm = sdf_plane(xq, ti.Vector(o[1], float), ti.Vector(o[2], float))
            elif ti.static(kinds[k] == "Sphere"):
                phi, nrm = sdf_sphere(xq, ti.Vector(o[1], float), o[3])
            elif ti.static(kinds[k] == "Box"):
                phi, nrm = sdf_box(xq, ti.Vector(o[1], float), ti.Vector(o[2], float))
            elif ti.static(kinds[k] == "Cylinder"):
                phi, nrm = sdf_cylinder(xq, ti.Vector(o[1], float), o[3], o[4], o[5])
            else:
                phi, nrm = mesh_f[k].sample(xq)
            if phi < phi_min:
                phi_min = phi
                n_min = nrm
                v_min = ti.Vector.zero(float, 3)
                if ti.static(moving[k]):
                    n_min = poses.normal_to_world(k - nw, nrm, 1)
                    v_min = poses.velocity(k - nw, x, 1)
                kind = KIND_ID[o[6]]  # a plain store: `x = ti.static(...)` only rebinds a Python name
                mu = float(o[7])
                idx = k - nw if k >= nw else -1
                if ti.static(with_restitution):
                    e = rest[k]
        if ti.static(with_restitution):
            return phi_min, n_min, kind, mu, v_min, idx, e
        else:
            return phi_min, n_min, kind, mu, v_min, idx

    return nearest


def make_add_load(poses):
    """A ti.func (idx, x, J) adding the impulse J [N s] at x to collider idx when it is named."""
    named = poses.named if poses is not None else ()

    @ti.func
    def add_load(idx, x, J):
        for k in ti.static(range(len(named))):
            if ti.static(named[k]):
                if idx == k:
                    poses.add_load(k, x, J, 1)

    return add_load


@ti.func
def friction_velocity(v, n, kind, mu, dvn):
    """Velocity after contact: the normal part into the obstacle removed (already done by the caller
    through dvn >= 0, the removed normal speed), Coulomb friction mu dvn on the tangential part;
    sticky stops the vertex."""
    vo = v
    if kind == 1:
        vo = v * 0.0
    else:
        vn = v.dot(n)
        vt = v - vn * n
        vtn = vt.norm()
        if vtn > 0 and mu > 0:
            vt *= ti.max(0.0, 1.0 - mu * dvn / vtn)
        vo = vt + vn * n
    return vo
