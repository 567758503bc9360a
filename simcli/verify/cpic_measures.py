"""Measurements of the MPM CPIC plates (docs/MPM.md, CPIC): particles crossing a thin Box collider and the
displacement of the material away from it."""

import numpy as np

from simcli.verify.registry import measurement


def _plate(f, collider):
    """(lower, upper, to_body, thin axis) of the named Box collider or Box rigid body of the run's scene:
    ``to_body(x, i)`` maps world points at frame i into its body frame (a collider: its prescribed motion at
    the frame's time; a rigid body: its pose written in sim.h5 at that frame, about its centre of mass)."""
    from simcli.colliders import _collider_spec
    from simcli.motion import collider_motion, quat_to_matrix
    from simcli.verify.registry import scene_of as _scene_of

    scene = _scene_of(f)
    dim = scene.sim.dim
    t = f["time"][...]
    c = next((c for c in scene.colliders if c.name == collider), None)
    if c is None:
        rb = next((r for r in (scene.rigid_bodies or []) if r.name == collider), None)
        if rb is None or rb.morph.type != "Box":
            raise KeyError(f"no Box collider or Box rigid body named '{collider}' in the run's scene")
        lo, hi = (np.asarray(v, float)[:dim] for v in rb.morph.bounds())
        g = f["rigid_bodies"][collider]
        pos = np.asarray(g["position"][...], float)
        ori = np.asarray(g["orientation"][...], float)
        piv = 0.5 * (lo + hi)

        def to_body(x, i):
            if dim == 2:
                a = float(ori[i, 0])
                R = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
            else:
                R = quat_to_matrix(ori[i])
            return (x - pos[i]) @ R + piv

        return lo, hi, to_body, int(np.argmin(hi - lo))
    if c.type != "Box":
        raise KeyError(f"no Box collider named '{collider}' in the run's scene")
    spec = _collider_spec(c, dim)
    a, b = np.asarray(spec.a, float), np.asarray(spec.b, float)
    motion = collider_motion(c, dim)

    def to_body(x, i):
        return _body(x, motion, t[i])

    return a, b, to_body, int(np.argmin(b - a))


def _body(x, motion, t):
    return x if motion is None else motion.pose(float(t)).to_body(x)


@measurement("plate_crossings")
def plate_crossings(f, entity, collider, **_):
    """Particles of ``entity`` that crossed the named Box collider or Box rigid body (a plate along its
    thinnest axis) so far: between two frames a particle went from one side of its mid-plane to the other
    with both positions within the plate's extent along its other axes (each in the plate's body frame at
    its frame's time)."""
    from simcli.verify.registry import stack_field as _stack

    lo, hi, to_body, ax = _plate(f, collider)
    cen, half = 0.5 * (lo + hi), 0.5 * (hi - lo)
    other = [e for e in range(len(lo)) if e != ax]
    x = _stack(f, entity)
    t = f["time"][...]
    out, n = [0.0], 0
    prev = to_body(x[0], 0) - cen
    for i in range(1, len(t)):
        cur = to_body(x[i], i) - cen
        within = np.all(np.abs(prev[:, other]) <= half[other], axis=1) & np.all(
            np.abs(cur[:, other]) <= half[other], axis=1
        )
        n += int(np.sum(within & ((prev[:, ax] >= 0) != (cur[:, ax] >= 0))))
        out.append(float(n))
        prev = cur
    return t, np.asarray(out)


@measurement("plate_far_drag")
def plate_far_drag(f, entity, collider, distance, **_):
    """Mean displacement [m] since the first frame of the particles of ``entity`` that started more than
    ``distance`` [m] from the named Box collider's mid-plane (its plane at the first frame, along its
    thinnest axis): the material a thin plate moving in its own plane should leave where it is."""
    from simcli.verify.registry import stack_field as _stack

    lo, hi, to_body, ax = _plate(f, collider)
    cen = 0.5 * (lo + hi)
    x = _stack(f, entity)
    t = f["time"][...]
    far = np.abs((to_body(x[0], 0) - cen)[:, ax]) > float(distance)
    if not np.any(far):
        raise ValueError(f"no particle of '{entity}' starts more than {distance} m from '{collider}'")
    return t, np.linalg.norm(x[:, far] - x[0, far], axis=2).mean(axis=1)
