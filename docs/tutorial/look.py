"""A first look at a run without ParaView (docs/TUTORIAL.md): what sim.h5 holds, in numbers.

    python docs/tutorial/look.py out/first

For every entity: the number of frames and particles, the centre of mass at the first and last frame,
the final extent along each axis and the final largest speed. Units are SI (m, s, m/s).
"""

import sys
from pathlib import Path

import h5py
import numpy as np

out = Path(sys.argv[1] if len(sys.argv) > 1 else "out/first")
with h5py.File(out / "sim.h5", "r") as f:  # SWMR-safe: works while a run is still writing
    t = f["time"][:]
    print(f"{out}/sim.h5: {len(t)} frames, t = {t[0]:g} .. {t[-1]:g} s")
    for name, g in f["entities"].items():
        x = g["position"]  # (frames, particles, dim) [m]
        first, last = x[0], x[-1]
        v = g["velocity"][-1]  # (particles, dim) [m/s]
        axes = "xyz"[: x.shape[2]]
        print(f"  {name}: {x.shape[1]} particles, datasets {sorted(g.keys())}")
        print(f"    centre of mass  first {np.round(first.mean(0), 4)} m, last {np.round(last.mean(0), 4)} m")
        for k, a in enumerate(axes):
            print(f"    final {a} range   {last[:, k].min():.4f} .. {last[:, k].max():.4f} m")
        print(f"    final max speed {np.linalg.norm(v, axis=1).max():.4f} m/s")
