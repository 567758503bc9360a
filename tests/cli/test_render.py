"""`simcli render` and `simcli plot`: pictures of every kind of entity (particles, tetrahedral meshes, cloth
triangles, rods, 2D and 3D grids) and of the colliders, found where the data puts them; movies; the time
series page; bad requests; and tiny real runs of each family."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from simcli.io import EntityMeta, FrameSink

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def _run(args, timeout=600):
    return subprocess.run(
        [sys.executable, "-m", "simcli", *args], capture_output=True, text=True, timeout=timeout
    )


def _write_run(
    out: Path, dim: int, entities: list[tuple[EntityMeta, list[dict]]], colliders=(), lo=None, hi=None
):
    """A run's output folder written with simcli's own writers: sim.h5 and a resolved scene.yaml."""
    lo = lo or ([0.0, 0.0] if dim == 2 else [0.0, 0.0, 0.0])
    hi = hi or ([1.0, 1.0] if dim == 2 else [1.0, 1.0, 1.0])
    scene = {
        "version": 1,
        "name": "synthetic",
        "sim": {"dim": dim},
        "domain": {"lower": lo, "upper": hi},
        "colliders": list(colliders),
    }
    text = yaml.safe_dump(scene)
    out.mkdir(parents=True, exist_ok=True)
    (out / "scene.yaml").write_text(text)
    n_frames = len(entities[0][1])
    with FrameSink(out, ["hdf5"]) as sink:
        sink.open([m for m, _ in entities], text, {})
        for k in range(n_frames):
            sink.write_frame(k, 10 * k, 0.1 * k, {m.name: frames[k] for m, frames in entities})
    return out


def _block(lo, hi, n):
    axes = [np.linspace(a, b, n) for a, b in zip(lo, hi)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, len(lo))


def _painted(out: Path, k: int | None = None, color="auto"):
    """Draw frame k as `simcli render` does and return (painter, rgb image, data -> pixel (col, row))."""
    from simcli.render.data import open_run, resolve_frame
    from simcli.render.draw import Painter

    run = open_run(out)
    k = resolve_frame(run, k)
    p = Painter(run, [k], color=color, width=640)
    p.draw(k)
    img = p.rgb()
    ax = p.fig.axes[0]
    h = img.shape[0]

    def to_px(pt):
        pt = np.asarray(pt, float)
        if hasattr(ax, "get_proj"):
            from mpl_toolkits.mplot3d import proj3d

            x, y, _ = proj3d.proj_transform(pt[0], pt[1], pt[2], ax.get_proj())
            pt = (x, y)
        c, r = ax.transData.transform(pt)
        return int(round(c)), int(round(h - r))

    return p, img, to_px


def _near(img, px, rgb, radius=3, tol=60):
    """Whether a pixel within `radius` of px has a colour within `tol` (sum of |diff|) of rgb."""
    c, r = px
    patch = img[max(r - radius, 0) : r + radius + 1, max(c - radius, 0) : c + radius + 1].astype(int)
    return bool((np.abs(patch - np.asarray(rgb)[None, None, :]).sum(-1) <= tol).any())


def _check_png(path: Path, min_colours=20):
    from PIL import Image

    data = path.read_bytes()
    assert data[:8] == PNG_SIGNATURE
    im = np.asarray(Image.open(path).convert("RGB"))
    assert im.shape[0] > 100 and im.shape[1] > 100
    assert len(np.unique(im.reshape(-1, 3), axis=0)) >= min_colours  # not one flat colour
    return im


BLUE = (31, 119, 180)  # the first entity colour


def test_render_package_does_not_import_taichi():
    code = (
        "import sys, simcli.render, simcli.render.draw, simcli.render.plot, simcli.render.data;"
        "assert 'taichi' not in sys.modules, 'simcli.render imported taichi'"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr


def test_particles_2d_drawn_where_they_are_with_colliders(tmp_path):
    x = _block([0.1, 0.1], [0.3, 0.3], 12)
    v = np.zeros_like(x)
    frames = [{"position": x + [0.0, 0.05 * k], "velocity": v + [0, 0.5]} for k in range(3)]
    meta = EntityMeta("blob", "particles", len(x), 2, {"position": (2, "m"), "velocity": (2, "m/s")})
    cols = [
        {"type": "Sphere", "center": [0.7, 0.7], "radius": 0.1},
        {"type": "Box", "lower": [0.6, 0.1], "upper": [0.9, 0.2]},
        {"type": "Plane", "point": [0, 0.05], "normal": [0, 1]},
    ]
    out = _write_run(tmp_path / "out", 2, [(meta, frames)], cols)
    p, img, to_px = _painted(out, color="entity")
    centre = x.mean(0) + [0, 0.1]  # last frame
    assert _near(img, to_px(centre), BLUE, tol=30)
    assert not _near(img, to_px([0.2, 0.55]), BLUE, tol=30)  # nothing above the block
    grey = img[to_px([0.7, 0.7])[1], to_px([0.7, 0.7])[0]]
    assert abs(int(grey[0]) - int(grey[2])) < 20 and 120 < grey[0] < 230  # the sphere, grey
    g2 = img[to_px([0.75, 0.15])[1], to_px([0.75, 0.15])[0]]
    assert 120 < g2[0] < 230  # the box
    g3 = img[to_px([0.5, 0.02])[1], to_px([0.5, 0.02])[0]]
    assert 120 < g3[0] < 230  # the solid side of the plane
    assert tuple(img[to_px([0.5, 0.5])[1], to_px([0.5, 0.5])[0]]) == (255, 255, 255)  # empty
    p.close()
    r = _run(["render", str(out), "-o", str(tmp_path / "a.png"), "--frame", "0"])
    assert r.returncode == 0, r.stderr
    _check_png(tmp_path / "a.png")


def test_particles_3d_coloured_by_speed_and_a_sphere(tmp_path):
    x = _block([0.4, 0.4, 0.6], [0.6, 0.6, 0.8], 8)
    v = np.zeros_like(x)
    v[:, 2] = -np.linspace(0, 2, len(x))
    meta = EntityMeta("jelly", "particles", len(x), 3, {"position": (3, "m"), "velocity": (3, "m/s")})
    out = _write_run(
        tmp_path / "out",
        3,
        [(meta, [{"position": x, "velocity": v}] * 2)],
        [{"type": "Sphere", "center": [0.5, 0.5, 0.2], "radius": 0.15}],
    )
    p, img, to_px = _painted(out)
    assert p.color == "speed"
    c, r = to_px([0.5, 0.5, 0.7])
    px = img[r - 2 : r + 3, c - 2 : c + 3].reshape(-1, 3).astype(int)
    # viridis: never grey, never white
    assert (np.abs(px - 255).sum(-1) > 60).all() and (np.ptp(px, axis=1) > 30).any()
    c, r = to_px([0.5, 0.5, 0.2])
    s = img[r, c].astype(int)
    assert np.ptp(s) < 25 and 60 < s[0] < 240  # the sphere: grey
    p.close()


def _cube_tets(lo, hi, n):
    pts = _block(lo, hi, n)
    idx = np.arange(n**3).reshape(n, n, n)
    tets = []
    for i in range(n - 1):
        for j in range(n - 1):
            for k in range(n - 1):
                c = [idx[i + a, j + b, k + d] for a in (0, 1) for b in (0, 1) for d in (0, 1)]
                for t in ((0, 1, 3, 7), (0, 3, 2, 7), (0, 2, 6, 7), (0, 6, 4, 7), (0, 4, 5, 7), (0, 5, 1, 7)):
                    tets.append([c[q] for q in t])
    return pts, np.asarray(tets)


def test_tet_mesh_surface_and_cloth_and_rod_3d(tmp_path):
    from simcli.render.geometry import tet_surface

    pts, tets = _cube_tets([0.2, 0.2, 0.1], [0.4, 0.4, 0.3], 4)
    surf = tet_surface(tets)
    assert len(surf) == 6 * 2 * 3 * 3  # 6 faces of 3x3 squares, 2 triangles each
    u = _block([0.55, 0.2], [0.85, 0.5], 10)
    cloth = np.column_stack([u, np.full(len(u), 0.5)])
    tri = []
    for i in range(9):
        for j in range(9):
            a = i * 10 + j
            tri += [[a, a + 10, a + 11], [a, a + 11, a + 1]]
    rod = np.column_stack([np.full(20, 0.5), np.linspace(0.6, 0.9, 20), np.full(20, 0.8)])
    seg = np.column_stack([np.arange(19), np.arange(1, 20)])
    ents = [
        (
            EntityMeta("body", "tets", len(pts), 3, {"position": (3, "m")}, cells=tets),
            [{"position": pts}] * 2,
        ),
        (
            EntityMeta("cloth", "triangles", len(cloth), 3, {"position": (3, "m")}, cells=np.asarray(tri)),
            [{"position": cloth}] * 2,
        ),
        (EntityMeta("rod", "lines", 20, 3, {"position": (3, "m")}, cells=seg), [{"position": rod}] * 2),
    ]
    out = _write_run(tmp_path / "out", 3, ents)
    p, img, to_px = _painted(out)

    # each entity in its own colour (blue, orange, green), shaded: the hue is kept
    def hue_at(pt):
        c, r = to_px(pt)
        return img[r - 1 : r + 2, c - 1 : c + 2].reshape(-1, 3).astype(int).mean(0)

    b = hue_at([0.3, 0.3, 0.3])  # top face of the body
    assert b[2] > b[0] + 40  # blue
    o = hue_at([0.7, 0.35, 0.5])
    assert o[0] > o[2] + 40  # orange
    g = hue_at([0.5, 0.75, 0.8])
    assert g[1] > g[0] + 20 and g[1] > g[2] + 20  # green
    p.close()


def test_particles_above_a_cloth_are_seen_and_those_under_it_hidden(tmp_path):
    """A ball resting in a sheet (the trampoline) must show: particles and surfaces are depth-sorted
    together, not drawn collection by collection (the sheet used to cover the ball wholesale)."""
    u = _block([0.2, 0.2], [0.8, 0.8], 13)
    sheet = np.column_stack([u, np.full(len(u), 0.5)])
    tri = []
    for i in range(12):
        for j in range(12):
            a = i * 13 + j
            tri += [[a, a + 13, a + 14], [a, a + 14, a + 1]]
    above = _block([0.45, 0.45, 0.55], [0.55, 0.55, 0.65], 5)
    below = _block([0.45, 0.45, 0.35], [0.55, 0.55, 0.45], 5)
    ents = [
        (EntityMeta("ball", "particles", len(above), 3, {"position": (3, "m")}), [{"position": above}] * 2),
        (
            EntityMeta("cloth", "triangles", len(sheet), 3, {"position": (3, "m")}, cells=np.asarray(tri)),
            [{"position": sheet}] * 2,
        ),
        (EntityMeta("under", "particles", len(below), 3, {"position": (3, "m")}), [{"position": below}] * 2),
    ]
    out = _write_run(tmp_path / "out", 3, ents)
    p, img, to_px = _painted(out, color="entity")
    assert _near(img, to_px([0.5, 0.5, 0.6]), BLUE, radius=2, tol=40)  # the ball on top of the sheet
    c, r = to_px([0.5, 0.5, 0.4])  # straight under the sheet: the sheet's orange, not the third colour
    px = img[r - 1 : r + 2, c - 1 : c + 2].reshape(-1, 3).astype(int).mean(0)
    assert px[0] > px[2] + 40  # orange-ish (the green of the third entity would have g > r)
    p.close()


def test_grid_2d_density_image_and_obstacle(tmp_path):
    nx, ny = 32, 64
    d = np.zeros((ny, nx))
    d[8:16, 12:20] = 1.0  # a puff low in the middle
    meta = EntityMeta(
        "smoke",
        "grid",
        nx * ny,
        2,
        {"density": (1, "1"), "velocity": (2, "m/s")},
        grid_shape=(nx, ny),
        origin=(0.0, 0.0),
        spacing=(1 / 32, 1 / 32),
    )
    vel = np.zeros((ny, nx, 2))
    out = _write_run(
        tmp_path / "out",
        2,
        [(meta, [{"density": d, "velocity": vel}] * 2)],
        [{"type": "Sphere", "center": [0.5, 1.5], "radius": 0.1}],
        hi=[1.0, 2.0],
    )
    p, img, to_px = _painted(out)
    bright = img[to_px([0.5, 0.375])[1], to_px([0.5, 0.375])[0]].astype(int)
    dark = img[to_px([0.2, 1.0])[1], to_px([0.2, 1.0])[0]].astype(int)
    assert bright.sum() > 500 and dark.sum() < 60  # inferno: yellow-white where the smoke is, black elsewhere
    s = img[to_px([0.5, 1.5])[1], to_px([0.5, 1.5])[0]].astype(int)
    assert np.ptp(s) < 25 and 60 < s[0] < 200  # the obstacle over the black air
    p.close()


def test_grid_3d_seen_from_the_side(tmp_path):
    n = 16
    d = np.zeros((n, n, n))  # z, y, x
    d[10:14, 6:10, 2:6] = 1.0  # high, on the left
    meta = EntityMeta(
        "smoke",
        "grid",
        n**3,
        3,
        {"density": (1, "1")},
        grid_shape=(n, n, n),
        origin=(0, 0, 0),
        spacing=(1 / n,) * 3,
    )
    out = _write_run(tmp_path / "out", 3, [(meta, [{"density": d}] * 2)])
    p, img, to_px = _painted(out)
    hot = img[to_px([0.25, 0.75])[1], to_px([0.25, 0.75])[0]].astype(int)
    cold = img[to_px([0.75, 0.25])[1], to_px([0.75, 0.25])[0]].astype(int)
    assert hot.sum() > 400 and cold.sum() < 60
    p.close()


def _moving_run(tmp_path, n_frames=6):
    x = _block([0.1, 0.4], [0.2, 0.5], 6)
    frames = [
        {"position": x + [0.12 * k, 0.0], "velocity": np.tile([1.2, 0.0], (len(x), 1))}
        for k in range(n_frames)
    ]
    meta = EntityMeta("blob", "particles", len(x), 2, {"position": (2, "m"), "velocity": (2, "m/s")})
    return _write_run(tmp_path / "out", 2, [(meta, frames)])


def test_movie_gif_every_frame(tmp_path):
    from PIL import Image

    out = _moving_run(tmp_path)
    r = _run(["render", str(out), "-o", str(tmp_path / "m.gif")])
    assert r.returncode == 0, r.stderr
    im = Image.open(tmp_path / "m.gif")
    assert im.n_frames == 6


def test_movie_mp4(tmp_path):
    imageio_ffmpeg = pytest.importorskip("imageio_ffmpeg")
    out = _moving_run(tmp_path)
    r = _run(["render", str(out), "-o", str(tmp_path / "m.mp4"), "--fps", "10"])
    assert r.returncode == 0, r.stderr
    data = (tmp_path / "m.mp4").read_bytes()
    assert data[4:8] == b"ftyp" and len(data) > 2000
    nframes, secs = imageio_ffmpeg.count_frames_and_secs(str(tmp_path / "m.mp4"))
    assert nframes == 6 and secs == pytest.approx(0.6, abs=0.05)


def test_plot_time_series_with_probes_and_run_json(tmp_path):
    out = _moving_run(tmp_path)
    (out / "run.json").write_text(
        json.dumps(
            {
                "status": "done",
                "exit_code": 0,
                "steps_done": 50,
                "sim_time": 0.5,
                "substeps": {"min": 4, "max": 9, "mean": 6.5, "auto": True},
                "throughput": {"steps_per_s": 100.0},
                "timings": {"compile_s": 3.0, "stepping_s": 1.0},
            }
        )
    )
    (out / "probes.csv").write_text("time,h1,p1\n0,0.1,5\n0.1,0.2,6\n0.2,0.25,7\n")
    from simcli.render.data import open_run, read_probes, series

    s = series(open_run(out))["blob"]
    assert s["max_speed"] == pytest.approx(np.full(6, 1.2), rel=1e-6)
    assert s["kinetic_energy_per_kg"] == pytest.approx(np.full(6, 0.72), rel=1e-5)
    head, data = read_probes(out)
    assert head == ["time", "h1", "p1"] and data.shape == (3, 3)
    r = _run(["plot", str(out)])
    assert r.returncode == 0, r.stderr
    _check_png(out / "plot.png")


def test_bad_requests_are_usage_errors(tmp_path):
    out = _moving_run(tmp_path)
    r = _run(["render", str(out), "--frame", "99"])
    assert r.returncode == 2 and "frames 0..5" in r.stderr and "Traceback" not in r.stderr
    r = _run(["render", str(out), "-o", str(tmp_path / "x.jpg")])
    assert r.returncode == 2 and ".png" in r.stderr
    empty = tmp_path / "empty"
    empty.mkdir()
    r = _run(["render", str(empty)])
    assert r.returncode == 2 and "sim.h5: not found" in r.stderr and "Traceback" not in r.stderr
    r = _run(["plot", str(empty)])
    assert r.returncode == 2 and "Traceback" not in r.stderr
    r = _run(["render", str(out), "-o", str(tmp_path / "no" / "such" / "dir" / "a.png")])
    assert r.returncode == 74 and "a.png" in r.stderr and "Traceback" not in r.stderr


# -- real runs: one tiny scene per family ---------------------------------------------------------

TINY = {
    "mpm_2d": """
sim: {dim: 2, dt: 2.0e-3, substeps: 4, steps: 6}
domain: {lower: [0, 0], upper: [1, 1]}
solvers: {mpm: {grid_density: 32}}
colliders: [{type: Sphere, center: [0.5, 0.15], radius: 0.1}]
entities:
  - {name: blob, material: {type: MPM.Elastic, E: 1.0e4, rho: 1000}, morph: {type: Box, lower: [0.35, 0.4], upper: [0.65, 0.7]},
     velocity: [0, -1]}
output: {every: 2, formats: [hdf5]}
""",  # noqa: E501 - scene lines as a user writes them
    "pbd_3d": """
sim: {dim: 3, dt: 4.0e-3, substeps: 2, steps: 6}
domain: {lower: [-0.5, -0.5, 0], upper: [0.5, 0.5, 1]}
colliders: [{type: Sphere, center: [0, 0, 0.2], radius: 0.15}]
entities:
  - {name: cloth, material: {type: PBD.Cloth, rho: 0.2}, morph: {type: Rectangle, center: [0, 0, 0.5], size: [0.5, 0.5], resolution: 8}}
output: {every: 2, formats: [hdf5]}
""",  # noqa: E501 - scene lines as a user writes them
    "mpm_3d": """
sim: {dim: 3, dt: 2.0e-3, substeps: 4, steps: 4}
domain: {lower: [0, 0, 0], upper: [1, 1, 1]}
solvers: {mpm: {grid_density: 16}}
colliders: [{type: Box, lower: [0.1, 0.1, 0.0], upper: [0.3, 0.3, 0.2]}]
entities:
  - {name: sand, material: {type: MPM.Sand, E: 1.0e5, rho: 1600}, morph: {type: Box, lower: [0.4, 0.4, 0.3], upper: [0.6, 0.6, 0.5]}}
output: {every: 2, formats: [hdf5]}
""",  # noqa: E501 - scene lines as a user writes them
    "sph_2d": """
sim: {dim: 2, dt: 1.0e-3, substeps: auto, steps: 4}
domain: {lower: [0, 0], upper: [1, 1]}
solvers: {sph: {particle_size: 0.02}}
entities:
  - {name: water, material: {type: SPH.Liquid, rho: 1000}, morph: {type: Box, lower: [0.4, 0.3], upper: [0.6, 0.5]}}
output: {every: 2, formats: [hdf5]}
""",  # noqa: E501 - scene lines as a user writes them
    "sph_3d": """
sim: {dim: 3, dt: 1.0e-3, substeps: auto, steps: 4}
domain: {lower: [0, 0, 0], upper: [1, 1, 1]}
solvers: {sph: {particle_size: 0.04}}
entities:
  - {name: water, material: {type: SPH.Liquid, rho: 1000}, morph: {type: Box, lower: [0.4, 0.4, 0.3], upper: [0.6, 0.6, 0.5]}}
output: {every: 2, formats: [hdf5]}
""",  # noqa: E501 - scene lines as a user writes them
    "fem_3d": """
sim: {dim: 3, dt: 2.0e-3, substeps: auto, steps: 4}
domain: {lower: [0, 0, 0], upper: [1, 1, 1]}
solvers: {fem: {integrator: explicit, resolution: 20}}
entities:
  - {name: block, material: {type: FEM.Elastic, E: 1.0e4, rho: 1000}, morph: {type: Box, lower: [0.4, 0.4, 0.3], upper: [0.6, 0.6, 0.5]}}
output: {every: 2, formats: [hdf5]}
""",  # noqa: E501 - scene lines as a user writes them
    "sf_2d": """
sim: {dim: 2, dt: 0.02, substeps: 1, steps: 6}
domain: {lower: [0, 0], upper: [1, 1], faces: {y+: {type: open}}}
solvers: {sf: {resolution: 32}}
entities:
  - name: smoke
    material: {type: SF.Smoke}
    jets: [{position: [0.5, 0.2], radius: 0.1, velocity: [0, 1], density_rate: 5.0}]
output: {every: 2, formats: [hdf5]}
""",
    "sf_3d": """
sim: {dim: 3, dt: 0.02, substeps: 1, steps: 6}
domain: {lower: [0, 0, 0], upper: [1, 1, 1], faces: {z+: {type: open}}}
solvers: {sf: {resolution: 16}}
entities:
  - name: smoke
    material: {type: SF.Smoke}
    jets: [{position: [0.5, 0.5, 0.2], radius: 0.15, velocity: [0, 0, 1], density_rate: 5.0}]
output: {every: 2, formats: [hdf5]}
""",
}


def _tiny_run(tmp_path, key):
    scene = tmp_path / f"{key}.yaml"
    scene.write_text("version: 1\nname: " + key + "\n" + TINY[key])
    out = tmp_path / key
    r = _run(["run", str(scene), "-o", str(out), "-q"])
    assert r.returncode == 0, r.stderr
    return out


_SLOW = pytest.mark.slow  # one compile per family: the default suite keeps two, -m slow runs the rest


@pytest.mark.parametrize(
    "key",
    ["mpm_2d", "pbd_3d"]
    + [pytest.param(k, marks=_SLOW) for k in ("mpm_3d", "sph_2d", "sph_3d", "fem_3d", "sf_2d", "sf_3d")],
)
def test_render_a_real_run(tmp_path, key):
    out = _tiny_run(tmp_path, key)
    r = _run(["render", str(out), "-o", str(tmp_path / "p.png")])
    assert r.returncode == 0, r.stderr
    _check_png(tmp_path / "p.png")
    from simcli.render.data import open_run, read_frame

    run = open_run(out)
    e = read_frame(run, run.n_frames - 1)[0]
    p, img, to_px = _painted(out, color="entity")
    if e.kind == "grid":  # the smoke the jet put in is drawn (bright) near the jet, the far corner is dark
        jet = [0.5, 0.2]  # (x, y) in 2D; (x, z) of the side view of a 3D grid
        hot = img[to_px(jet)[1], to_px(jet)[0]].astype(int)
        cold = img[to_px([0.95, 0.95])[1], to_px([0.95, 0.95])[0]].astype(int)
        assert hot.sum() > 150 and cold.sum() < 60, (hot, cold)
    else:
        centre = e.position.mean(0)
        assert _near(img, to_px(centre), BLUE, radius=4, tol=120)  # the body is drawn where it is
    p.close()


def test_auto_colour_is_height_once_the_particles_rest(tmp_path):
    x = _block([0.3, 0.1], [0.7, 0.3], 10)
    moving = np.tile([0.0, -2.0], (len(x), 1))
    frames = [{"position": x + [0, 0.2], "velocity": moving}, {"position": x, "velocity": 0 * moving}]
    meta = EntityMeta("heap", "particles", len(x), 2, {"position": (2, "m"), "velocity": (2, "m/s")})
    out = _write_run(tmp_path / "out", 2, [(meta, frames)])
    p, img, to_px = _painted(out, k=0)
    assert p.color == "speed"
    p.close()
    p, img, to_px = _painted(out, k=1)
    assert p.color == "height"
    bottom = x[np.argmin(x[:, 1] + np.abs(x[:, 0] - 0.5))]  # particles in the middle column
    top = x[np.argmax(x[:, 1] - np.abs(x[:, 0] - 0.5))]
    low, high = (img[to_px(q)[1], to_px(q)[0]] for q in (bottom, top))
    assert int(high.sum()) > int(low.sum()) + 100  # copper: the top of the heap brighter than its foot
    p.close()


def test_unused_particles_at_nan_are_skipped(tmp_path):
    """An emitter's reserved particles may sit at NaN until emitted: the rest is still drawn."""
    x = _block([0.4, 0.4], [0.6, 0.6], 8)
    x = np.vstack([x, np.full((30, 2), np.nan)])
    v = np.zeros_like(x)
    meta = EntityMeta("jet", "particles", len(x), 2, {"position": (2, "m"), "velocity": (2, "m/s")})
    out = _write_run(tmp_path / "out", 2, [(meta, [{"position": x, "velocity": v}] * 2)])
    p, img, to_px = _painted(out, color="entity")
    assert _near(img, to_px([0.5, 0.5]), BLUE, radius=4, tol=30)
    p.close()
    r = _run(["plot", str(out)])
    assert r.returncode == 0, r.stderr


def test_an_emitter_empty_at_frame_0_is_drawn_at_its_particle_spacing(tmp_path):
    """An emitter's entity has no particle at frame 0, so its spacing cannot come from there: it is the
    median nearest-neighbour distance of the drawn frame, the pool's spacing for a jet of the same
    particle size (the old guess, half the side of the domain's volume shared among the entity's rows,
    drew this jet's markers at 0.079 m, four times too large)."""
    xs, ys = np.arange(0.01, 1.0, 0.02), np.arange(0.01, 0.1, 0.02)
    pool = np.stack(np.meshgrid(xs, ys, indexing="ij"), -1).reshape(-1, 2)
    jet_now = np.stack(np.meshgrid([0.49, 0.51], np.arange(0.3, 0.54, 0.02), indexing="ij"), -1).reshape(
        -1, 2
    )
    jet0 = np.full((40, 2), np.nan)
    jet1 = np.vstack([jet_now, np.full((40 - len(jet_now), 2), np.nan)])
    fields = {"position": (2, "m"), "velocity": (2, "m/s")}
    m_pool = EntityMeta("pool", "particles", len(pool), 2, fields)
    m_jet = EntityMeta("jet", "particles", 40, 2, fields)
    frames_pool = [{"position": pool, "velocity": np.zeros_like(pool)}] * 2
    frames_jet = [{"position": p, "velocity": np.zeros_like(p)} for p in (jet0, jet1)]
    out = _write_run(tmp_path / "out", 2, [(m_pool, frames_pool), (m_jet, frames_jet)])
    p, _img, _to_px = _painted(out, color="entity")
    assert p.spacing["jet"] == pytest.approx(0.02, rel=1e-6)
    assert p.spacing["pool"] == pytest.approx(p.spacing["jet"], rel=0.15)  # (a block's estimate: its extent)
    p.close()
