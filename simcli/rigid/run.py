"""What the runner calls for rigid bodies (kept here so that simcli/runner.py only hooks it in):
the substep integration, sim.h5 /rigid_bodies/<name>/<field> per frame (written before the frame's /time,
resized on --resume like the frames), the checkpoint state (``rigid/...``), run.json's summary and the
closing log lines."""

from __future__ import annotations

from typing import Any

import numpy as np

from .world import RigidWorld, release, world_for

FIELDS = (  # name, components in 2D, in 3D, unit
    ("position", 2, 3, "m"),
    ("orientation", 1, 4, "1 (quaternion w, x, y, z; 2D: angle [rad])"),
    ("velocity", 2, 3, "m/s"),
    ("angular_velocity", 1, 3, "rad/s"),
    ("force", 2, 3, "N"),
    ("torque", 1, 3, "N m"),
)


def rigid_run(scene: Any, scene_dir: Any = None) -> RigidRun | None:
    w = world_for(scene, scene_dir)
    return None if w is None else RigidRun(w)


class RigidRun:
    def __init__(self, world: RigidWorld):
        self.world = world
        self._ds: list = []

    def step(self, solvers, dt: float) -> None:
        self.world.step(solvers, dt)

    def open(self, sink: Any, resume_frame: int | None) -> None:
        """Create (or, resuming, cut to ``resume_frame`` frames) /rigid_bodies/<name>/<field> in sim.h5."""
        h5 = getattr(sink, "_h5", None)
        f = getattr(h5, "f", None)
        if f is None:
            return
        dim = self.world.dim
        g = f.require_group("rigid_bodies")
        self._ds = []
        for b in self.world.bodies:
            bg = g.require_group(b.name)
            for name, n2, n3, unit in FIELDS:
                n = n2 if dim == 2 else n3
                if name in bg and resume_frame is not None:
                    d = bg[name]
                    d.resize(min(resume_frame, d.shape[0]), axis=0)
                else:
                    if name in bg:
                        del bg[name]
                    d = bg.create_dataset(name, shape=(0, n), maxshape=(None, n), chunks=(64, n), dtype="f8")
                    d.attrs["unit"] = unit
                self._ds.append((d, b.name, name))
            bg.attrs["mass"] = b.mass
            bg.attrs["shape"] = b.spec.kind
            if b.spec.kind == "Mesh":  # its surface relative to the centre of mass (body frame), for pictures
                for key, arr in (
                    ("surface_points", np.asarray(b.spec.mesh.vertices, "f8") - b.pivot),
                    ("surface_triangles", np.asarray(b.spec.mesh.triangles, "i8")),
                ):
                    if key in bg:
                        del bg[key]
                    bg.create_dataset(key, data=arr)

    def write_frame(self, frame: int) -> None:
        vals = self.world.frame_values()
        for d, bname, name in self._ds:
            d.resize(frame + 1, axis=0)
            d[frame] = np.asarray(vals[bname][name], dtype="f8").reshape(d.shape[1:])

    def get_state(self) -> dict[str, np.ndarray]:
        return {f"rigid/{k}": v for k, v in self.world.get_state().items()}

    def set_state(self, state: dict[str, np.ndarray]) -> None:
        st = {k.split("/", 1)[1]: v for k, v in state.items() if k.startswith("rigid/")}
        if st:
            self.world.set_state(st)

    def summary(self) -> dict:
        return self.world.summary()

    def log_lines(self) -> list[str]:
        def fmt(v):
            return "(" + ", ".join(f"{x:.4g}" for x in v) + ")"

        out = []
        for name, d in self.summary().items():
            out.append(
                f"rigid body '{name}': at {fmt(d['position_m'])} m, velocity {fmt(d['velocity_m_s'])} m/s; "
                f"force {fmt(d['force_N'])} N, torque {fmt(d['torque_Nm'])} N m from the materials at the "
                "last frame"
            )
        return out

    def close(self) -> None:
        release(self.world.scene)
