"""Measurements of the MPM CPIC plates (docs/MPM.md, CPIC): particles crossing a thin Box collider and the
displacement of the material away from it."""

import numpy as np

from simcli.verify.registry import measurement


def _plate(f, collider):
    """(spec, motion, thin axis) of the named Box collider of the run's scene."""
    from simcli.colliders import _collider_spec
    from simcli.motion import collider_motion
    from simcli.verify.registry import scene_of as _scene_of

    scene = _scene_of(f)
    dim = scene.sim.dim
    c = next((c for c in scene.colliders if c.name == collider), None)
    if c is None or c.type != "Box":
        raise KeyError(f"no Box collider named '{collider}' in the run's scene")
    spec = _collider_spec(c, dim)
    a, b = np.asarray(spec.a, float), np.asarray(spec.b, float)
    return a, b, collider_motion(c, dim), int(np.argmin(b - a))


def _body(x, motion, t):
    return x if motion is None else motion.pose(float(t)).to_body(x)


@measurement("plate_crossings")
def plate_crossings(f, entity, collider, **_):
    """Particles of ``entity`` that crossed the named Box collider (a plate along its thinnest axis) so far:
    between two frames a particle went from one side of its mid-plane to the other with both positions
    within the plate's extent along its other axes (each in the plate's body frame at its frame's time)."""
    from simcli.verify.registry import stack_field as _stack

    lo, hi, motion, ax = _plate(f, collider)
    cen, half = 0.5 * (lo + hi), 0.5 * (hi - lo)
    other = [e for e in range(len(lo)) if e != ax]
    x = _stack(f, entity)
    t = f["time"][...]
    out, n = [0.0], 0
    prev = _body(x[0], motion, t[0]) - cen
    for i in range(1, len(t)):
        cur = _body(x[i], motion, t[i]) - cen
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

    lo, hi, motion, ax = _plate(f, collider)
    cen = 0.5 * (lo + hi)
    x = _stack(f, entity)
    t = f["time"][...]
    far = np.abs((_body(x[0], motion, t[0]) - cen)[:, ax]) > float(distance)
    if not np.any(far):
        raise ValueError(f"no particle of '{entity}' starts more than {distance} m from '{collider}'")
    return t, np.linalg.norm(x[:, far] - x[0, far], axis=2).mean(axis=1)
