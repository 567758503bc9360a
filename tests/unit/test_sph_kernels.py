"""SPH kernel maths: normalisation on a full lattice (sum W V = 1, sum grad W V = 0, first moment
sum V (x_j - x_i) grad W^T = I), the gradient against finite differences, the Taichi funcs against numpy,
and volume-correct boundary sampling (a liquid lattice next to a wall sees rest density)."""

import numpy as np
import pytest

from simcli.solvers.sph.kernels import cubic_gradW, cubic_W, kernel_constant


def lattice(dim, n=6):
    ax = np.arange(-n, n + 1, dtype=np.float64)
    g = np.meshgrid(*[ax] * dim, indexing="ij")
    return np.stack([c.ravel() for c in g], axis=1)


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("factor", [2.0, 3.0])
def test_lattice_normalisation(dim, factor):
    """With spacing 1 and V = 1: sum W = 1 (to 0.4%), sum grad W = 0 (exactly, by symmetry, at a lattice
    point and off it to 1e-3), first moment = I (to 3%)."""
    h = factor
    x = lattice(dim)
    for origin in (np.zeros(dim), np.full(dim, 0.3)):
        d = origin - x  # x_i - x_j
        w = cubic_W(np.linalg.norm(d, axis=1), h, dim)
        assert w.sum() == pytest.approx(1.0, abs=4e-3)
        g = cubic_gradW(d, h, dim)
        assert np.abs(g.sum(axis=0)).max() < (1e-12 if not origin.any() else 2e-2)
        M = ((x - origin)[:, :, None] * g[:, None, :]).sum(axis=0)
        assert np.allclose(M, np.eye(dim), atol=0.03), M


@pytest.mark.parametrize("dim", [2, 3])
def test_kernel_integral_and_support(dim):
    h = 1.0
    # radial integral of W: 2 pi int W r dr (2D), 4 pi int W r^2 dr (3D)
    r = np.linspace(0, h, 200001)
    w = cubic_W(r, h, dim)
    integrand = w * (2 * np.pi * r if dim == 2 else 4 * np.pi * r**2)
    assert np.trapezoid(integrand, r) == pytest.approx(1.0, rel=1e-6)
    assert cubic_W(np.array([h, 1.5 * h]), h, dim).max() == 0.0
    assert cubic_W(np.array([0.0]), h, dim)[0] == pytest.approx(kernel_constant(h, dim))


@pytest.mark.parametrize("dim", [2, 3])
def test_gradient_is_derivative(dim):
    rng = np.random.default_rng(1)
    h = 0.04
    x = rng.uniform(-h, h, size=(200, dim))
    x = x[np.linalg.norm(x, axis=1) > 1e-3]
    g = cubic_gradW(x, h, dim)
    eps = 1e-7
    for a in range(dim):
        e = np.zeros(dim)
        e[a] = eps
        fd = (
            cubic_W(np.linalg.norm(x + e, axis=1), h, dim) - cubic_W(np.linalg.norm(x - e, axis=1), h, dim)
        ) / (2 * eps)
        assert np.allclose(g[:, a], fd, rtol=1e-4, atol=1e-6 * np.abs(fd).max())


@pytest.mark.parametrize("dim", [2, 3])
def test_taichi_kernels_match_numpy(ti_f32, dim):
    import taichi as ti

    from simcli.solvers.sph.kernels import make_kernels

    h = 0.04
    W, gradW, _, W_gradW = make_kernels(h, dim, ti.f32)
    rng = np.random.default_rng(2)
    pts = rng.uniform(-1.1 * h, 1.1 * h, size=(500, dim)).astype(np.float32)
    xs = ti.Vector.field(dim, ti.f32, shape=len(pts))
    ws = ti.field(ti.f32, shape=len(pts))
    gs = ti.Vector.field(dim, ti.f32, shape=len(pts))
    ws2 = ti.field(ti.f32, shape=len(pts))
    gs2 = ti.Vector.field(dim, ti.f32, shape=len(pts))
    xs.from_numpy(pts)

    @ti.kernel
    def run():
        for i in xs:
            r = xs[i].norm()
            ws[i] = W(r)
            gs[i] = gradW(xs[i], r)
            w, g = W_gradW(xs[i], r)
            ws2[i] = w
            gs2[i] = g

    run()
    p64 = pts.astype(np.float64)
    w_ref = cubic_W(np.linalg.norm(p64, axis=1), h, dim)
    assert np.allclose(ws.to_numpy(), w_ref, rtol=1e-4, atol=1e-5 * w_ref.max())
    g_ref = cubic_gradW(p64, h, dim)
    assert np.allclose(gs.to_numpy(), g_ref, rtol=1e-4, atol=1e-5 * np.abs(g_ref).max())
    assert np.allclose(ws2.to_numpy(), ws.to_numpy(), rtol=1e-6) and np.allclose(
        gs2.to_numpy(), gs.to_numpy(), rtol=1e-6
    )


@pytest.mark.parametrize("dim", [2, 3])
def test_wall_particles_give_rest_density(dim):
    """A liquid lattice filling a box, plus the wall particles outside it: every liquid particle (corners
    included) sees the density of a full lattice, rho0 to 0.2%; the walls' volume is exactly the shell's."""
    from simcli.solvers.sph.boundary import wall_particles

    ps = 0.1
    h = 2 * ps
    lo, hi = np.zeros(dim), np.ones(dim) * 0.6
    faces = {n: "slip" for n in ("x-", "x+", "y-", "y+", "z-", "z+")}
    vel = {n: np.zeros(dim) for n in faces}
    bp = wall_particles(lo, hi, ps, dim, faces, vel)
    shell = np.prod(hi - lo + 4 * ps) - np.prod(hi - lo)
    assert bp.volume.sum() == pytest.approx(shell, rel=1e-9)
    ax = np.arange(ps / 2, 0.6, ps)
    x = np.stack([c.ravel() for c in np.meshgrid(*[ax] * dim, indexing="ij")], axis=1)
    allx = np.concatenate([x, bp.x])
    allV = np.concatenate([np.full(len(x), ps**dim), bp.volume])
    rho = np.array([(allV * cubic_W(np.linalg.norm(allx - xi, axis=1), h, dim)).sum() for xi in x])
    assert np.allclose(rho, 1.0, atol=2e-3), (rho.min(), rho.max())


@pytest.mark.parametrize("dim", [2, 3])
def test_wall_particles_are_the_padded_lattice_outside_the_domain(dim):
    """The shell is built without enumerating the domain's inside: it must be exactly the points of the
    padded lattice outside the domain, in that lattice's order, each with the kind and velocity of the first
    face (x-, x+, y-, ...) it lies outside of."""
    from simcli.solvers.sph.boundary import _axis_coords, wall_particles

    lo, hi, ps = np.array([-0.3, 0.1, 0.0][:dim]), np.array([0.4, 0.37, 0.5][:dim]), 0.033
    names = ("x-", "x+", "y-", "y+", "z-", "z+")[: 2 * dim]
    faces = {n: ("sticky" if k % 3 == 0 else "slip") for k, n in enumerate(names)}
    vel = {n: np.full(dim, 0.1 * k) for k, n in enumerate(names)}
    bp = wall_particles(lo, hi, ps, dim, faces, vel)
    axes = [_axis_coords(lo[a], hi[a], ps, 2) for a in range(dim)]
    mesh = lambda k: np.stack(
        [g.ravel() for g in np.meshgrid(*[ax[k] for ax in axes], indexing="ij")], axis=1
    )
    x, sp, side = mesh(0), np.prod(mesh(1), axis=1), mesh(2)
    out = np.any(side != 0, axis=1)
    assert np.array_equal(bp.x, x[out]) and np.array_equal(bp.volume, sp[out])
    first = np.argmax(side[out] != 0, axis=1)  # first axis the point is outside on
    name = [names[2 * a + (s > 0)] for a, s in zip(first, side[out][np.arange(out.sum()), first])]
    assert np.array_equal(bp.no_slip, np.array([faces[n] == "sticky" for n in name]))
    assert np.array_equal(bp.velocity, np.array([vel[n] for n in name]))


@pytest.mark.parametrize("width", [0.1, 0.1033, 0.1049])
def test_box_collider_lattice_fits_the_box(width):
    """A Box collider whose size is not a whole number of particle sizes: its lattice is fitted per axis, so
    a liquid particle half a particle size outside the far face sees the same wall density as one outside
    the near face, and within 2% of an aligned box's (anchored at one face, the far face's first layer sat
    anywhere between 0 and one spacing inside: up to 2.4x the density, found in session 7)."""
    from types import SimpleNamespace

    from simcli.solvers.sph.boundary import collider_particles
    from simcli.solvers.sph.kernels import lattice_sum

    ps, h = 0.005, 0.01
    spec = SimpleNamespace(kind="Box", a=[0.2, 0.0], b=[0.2 + width, 0.1], contact="slip")
    bp = collider_particles(spec, [0.0, 0.0], [0.6, 0.5], ps, 2)
    V = bp.volume / lattice_sum(2, 2)

    def wall_density(p):
        return (V * cubic_W(np.linalg.norm(bp.x - np.asarray(p), axis=1), h, 2)).sum()

    near, far = wall_density([0.2 - 0.5 * ps, 0.05]), wall_density([0.2 + width + 0.5 * ps, 0.05])
    assert far == pytest.approx(near, rel=1e-6)
    aligned = collider_particles(
        SimpleNamespace(kind="Box", a=[0.2, 0.0], b=[0.3, 0.1], contact="slip"), [0.0, 0.0], [0.6, 0.5], ps, 2
    )
    ref = (
        aligned.volume / lattice_sum(2, 2) * cubic_W(np.linalg.norm(aligned.x - [0.1975, 0.05], axis=1), h, 2)
    ).sum()
    assert near == pytest.approx(ref, rel=0.02)
    assert np.all(bp.x[:, 0] < 0.2 + width) and np.all(bp.x[:, 0] > 0.2)


@pytest.mark.parametrize("dim", [2, 3])
def test_gradient_factor_rebuilds_the_gradient(ti_f32, dim):
    """W_gradW_s (the neighbour lists' factor s, grad W = x s): W and grad W are W_gradW's to the bit, x s is
    grad W to the bit, and s is 0 beyond the support and at r = 0."""
    import taichi as ti

    from simcli.solvers.sph.kernels import make_kernel_factor, make_kernels

    h = 0.04
    _, _, _, W_gradW = make_kernels(h, dim, ti.f32)
    W_gradW_s = make_kernel_factor(h, dim, ti.f32)
    rng = np.random.default_rng(3)
    pts = rng.uniform(-1.1 * h, 1.1 * h, size=(500, dim)).astype(np.float32)
    pts[0] = 0.0
    n = len(pts)
    xs = ti.Vector.field(dim, ti.f32, shape=n)
    out_w = [ti.field(ti.f32, shape=n) for _ in range(2)]
    out_g = [ti.Vector.field(dim, ti.f32, shape=n) for _ in range(3)]
    out_s = ti.field(ti.f32, shape=n)
    xs.from_numpy(pts)

    @ti.kernel
    def run():
        for i in xs:
            r = xs[i].norm()
            w, g = W_gradW(xs[i], r)
            w2, g2, s = W_gradW_s(xs[i], r)
            out_w[0][i], out_g[0][i] = w, g
            out_w[1][i], out_g[1][i], out_s[i] = w2, g2, s
            out_g[2][i] = xs[i] * s

    run()
    np.testing.assert_array_equal(out_w[1].to_numpy(), out_w[0].to_numpy())
    np.testing.assert_array_equal(out_g[1].to_numpy(), out_g[0].to_numpy())
    np.testing.assert_array_equal(out_g[2].to_numpy(), out_g[0].to_numpy())
    s = out_s.to_numpy()
    r = np.linalg.norm(pts.astype(np.float64), axis=1)
    assert s[0] == 0.0 and np.all(s[r > 1.0001 * h] == 0.0) and np.all(s[(r > 0) & (r < 0.999 * h)] < 0)


def test_cohesion_over_r_is_the_cohesion_kernel_over_r(ti_f32):
    """make_cohesion_over_r (the force pass's C(r) / r with the division folded in) against make_kernels'
    C(r) / r on both branches of Akinci's kernel (r <= h / 2 and beyond), to f32 round-off; 0 at r = 0 and
    r >= h."""
    import taichi as ti

    from simcli.solvers.sph.kernels import make_cohesion_over_r, make_kernels

    h = 0.04
    _, _, C, _ = make_kernels(h, 3, ti.f32)
    C_over_r = make_cohesion_over_r(h, ti.f32)
    r_np = np.concatenate([[0.0, h, 1.2 * h, 0.5 * h], np.linspace(1e-3 * h, 0.999 * h, 997)]).astype(
        np.float32
    )
    n = len(r_np)
    rs = ti.field(ti.f32, shape=n)
    ref = ti.field(ti.f32, shape=n)
    got = ti.field(ti.f32, shape=n)
    rs.from_numpy(r_np)

    @ti.kernel
    def run():
        for i in rs:
            r = rs[i]
            c = C(r)
            ref[i] = c / r if r > 0 else 0.0
            got[i] = C_over_r(r)

    run()
    a, b = ref.to_numpy(), got.to_numpy()
    assert b[0] == 0.0 and b[1] == 0.0 and b[2] == 0.0
    scale = np.abs(a).max()
    assert np.abs(a).min() < 0.1 * scale  # both signs and a zero crossing are covered (C < 0 near r = 0)
    np.testing.assert_allclose(b, a, rtol=2e-6, atol=2e-6 * scale)


@pytest.mark.parametrize("n", [1, 2, 3, 7, 8, 16])
def test_tait_power_by_squaring_is_pow(ti_f32, n):
    """WCSPH's equation of state with a whole exponent (make_tait_power, SPHParams.int_exponent) multiplies
    instead of calling pow: the same (rho / rho0)^n to f32 round-off, over compressions and expansions."""
    import taichi as ti

    from simcli.solvers.sph.wcsph import make_tait_power

    mat_n = ti.field(ti.f32, shape=1)
    mat_n[0] = float(n)
    by_squares = make_tait_power(n, ti.f32, mat_n)
    by_pow = make_tait_power(0, ti.f32, mat_n)
    ratios = np.linspace(0.5, 1.5, 1001).astype(np.float32)
    rs = ti.field(ti.f32, shape=len(ratios))
    out = [ti.field(ti.f32, shape=len(ratios)) for _ in range(2)]
    rs.from_numpy(ratios)

    @ti.kernel
    def run():
        for i in rs:
            out[0][i] = by_squares(rs[i], 0)
            out[1][i] = by_pow(rs[i], 0)

    run()
    ref = ratios.astype(np.float64) ** n
    np.testing.assert_allclose(out[0].to_numpy(), ref, rtol=(n.bit_length() + bin(n).count("1")) * 1.2e-7)
    np.testing.assert_allclose(out[1].to_numpy(), ref, rtol=3e-7)
