"""Physics of the MPM materials beyond elasticity, with stated tolerances.

* energy budget of an elastic body bouncing on a frictionless floor: every joule lost is
  accounted for by the P2G and G2P transfers and the wall condition (a numpy replica of the
  substep measures each term; the remainder, the time integration's, is small);
* sand: a slope just below the friction angle holds, one above it flows;
* snow compacts and hardens on impact, and J_p J_E = J holds for every particle;
* the shear mode of a free viscous liquid slab decays as exp(-nu k^2 t): the viscosity really is
  in Pa s;
* muscle: a constant activation a shortens a free fibre bundle by about a k / E, only in the
  actuated group; a block of lighter solid floats half-submerged in an MPM liquid (one grid,
  several materials);
* restart of plastic, liquid and muscle state is bit-for-bit;
* Poisson-disk sampling keeps its minimum distance and about V / h^d particles.
"""

import math

import numpy as np
import pytest

G = 9.81


def make_scene(**kw):
    from simcli.scene.models import Scene

    return Scene.model_validate(kw)


def build(scene):
    from simcli.geometry.sampling import sample_scene
    from simcli.solvers.mpm import MPMSolver

    bodies = sample_scene(scene)
    solver = MPMSolver(scene, bodies)
    solver.build()
    return solver, bodies


def box(lo, hi):
    return {"type": "Box", "lower": list(lo), "upper": list(hi)}


# ------------------------------------------------------------------------ energy budget


def _weights(x, origin, inv_dx):
    X = (x - origin) * inv_dx
    base = (X - 0.5).astype(np.int64)
    fx = X - base
    w = np.stack(
        [0.5 * (1.5 - fx) ** 2, 0.75 - (fx - 1.0) ** 2, 0.5 * (fx - 0.5) ** 2], axis=1
    )  # (n, 3, dim)
    return base, fx, w


def _polar2(F):
    a = F[:, 0, 0] + F[:, 1, 1]
    b = F[:, 1, 0] - F[:, 0, 1]
    r = np.hypot(a, b)
    c, s = a / r, b / r
    return np.stack([np.stack([c, -s], 1), np.stack([s, c], 1)], 1)


def _p2g(solver, x, v, C, F, m, V0, dt, stress):
    """Grid mass and momentum of one MLS-MPM P2G (2D), with or without the stress impulse."""
    dx, inv_dx = solver.dx, solver.inv_dx
    base, fx, w = _weights(x, solver.origin, inv_dx)
    affine = m[:, None, None] * C
    if stress:
        mu = np.array([solver.materials[k].mu for k in range(len(solver.materials))])[0]
        lam = solver.materials[0].lam
        R = _polar2(F)
        J = np.linalg.det(F)
        tau = 2 * mu * (F - R) @ F.transpose(0, 2, 1) + (lam * (J - 1) * J)[:, None, None] * np.eye(2)
        affine = affine - dt * (V0 * 4.0 * inv_dx * inv_dx)[:, None, None] * tau
    shape = solver.grid_shape
    gm = np.zeros(shape)
    gp = np.zeros(shape + (2,))
    for i in range(3):
        for j in range(3):
            wij = w[:, i, 0] * w[:, j, 1]
            d = (np.array([i, j]) - fx) * dx
            mom = m[:, None] * v + np.einsum("nab,nb->na", affine, d)
            np.add.at(gm, (base[:, 0] + i, base[:, 1] + j), wij * m)
            np.add.at(gp, (base[:, 0] + i, base[:, 1] + j), wij[:, None] * mom)
    return gm, gp


def _apic_ke(m, v, C, dx):
    """Particle kinetic energy including the affine part: sum m/2 (|v|^2 + dx^2/4 |C|^2)."""
    return 0.5 * float((m * ((v * v).sum(1) + 0.25 * dx * dx * (C * C).sum((1, 2)))).sum())


def test_energy_budget_of_a_bouncing_elastic_body(ti_f32):
    """An elastic block bounces on a frictionless (slip) floor. Per substep, a numpy replica of
    MLS-MPM measures: the P2G transfer loss (particle APIC kinetic energy minus the grid's), the
    work of stress and gravity on the grid, the loss of the wall condition and the G2P loss. The
    total energy (APIC kinetic + potential + elastic) must drop by the transfer and wall losses
    alone, up to the time integration's share (checked < 10 % of the loss)."""
    E, nu, rho = 1.0e4, 0.3, 1000.0
    scene = make_scene(
        sim={"dim": 2, "dt": 1e-3, "substeps": 2},
        domain={"lower": [0.0, 0.0], "upper": [0.5, 0.4]},
        solvers={"mpm": {"grid_density": 64, "particle_size": 1 / 128}},
        entities=[
            {
                "name": "b",
                "material": {"type": "MPM.Elastic", "E": E, "nu": nu, "rho": rho},
                "morph": box((0.2, 0.06), (0.3, 0.16)),
            }
        ],
    )
    solver, (body,) = build(scene)
    m, V0 = body.mass, body.volume
    mat = scene.entities[0].material
    dt, dx = 5e-4, solver.dx
    g = np.array([0.0, -G])

    def elastic(F):
        R = _polar2(F)
        J = np.linalg.det(F)
        return float((V0 * (mat.mu * ((F - R) ** 2).sum((1, 2)) + 0.5 * mat.lam * (J - 1) ** 2)).sum())

    def total(st):
        return _apic_ke(m, st["v"], st["C"], dx) - float((m * (st["x"] @ g)).sum()) + elastic(st["F"])

    sums = {"p2g": 0.0, "g2p": 0.0, "wall": 0.0}
    st = {k: a.astype(np.float64) for k, a in solver.get_state().items()}
    e0 = total(st)
    lo, hi = solver.lo_node, solver.hi_node
    worst_grid = 0.0
    for _ in range(1200):  # 0.6 s: free fall, impact at 0.13 s, bounces
        x, v, C, F = st["x"], st["v"], st["C"], st["F"]
        gm, gp_t = _p2g(solver, x, v, C, F, m, V0, dt, stress=False)
        _, gp_f = _p2g(solver, x, v, C, F, m, V0, dt, stress=True)
        has = gm > 0
        ke_t = 0.5 * float(((gp_t[has] ** 2).sum(1) / gm[has]).sum())
        vstar = np.zeros_like(gp_f)
        vstar[has] = gp_f[has] / gm[has][:, None] + dt * g
        vbc = vstar.copy()
        vbc[: lo[0] + 1, :, 0] = 0.0  # slip walls: the normal velocity of wall nodes, both ways
        vbc[hi[0] :, :, 0] = 0.0
        vbc[:, : lo[1] + 1, 1] = 0.0
        vbc[:, hi[1] :, 1] = 0.0
        # the wall's loss: the kinetic energy of the transferred motion it takes from the wall nodes
        # (the stress and gravity impulses it also cancels there do no work: the nodes stay put)
        wall = np.zeros(gm.shape, bool)
        wall[: lo[0] + 1], wall[hi[0] :], wall[:, : lo[1] + 1], wall[:, hi[1] :] = True, True, True, True
        vt = np.zeros_like(gp_t)
        vt[has] = gp_t[has] / gm[has][:, None]
        w_has = wall & has
        ke_wall_t = 0.5 * float((gm[w_has] * (vt[w_has] ** 2).sum(1)).sum())
        ke_wall_bc = 0.5 * float((gm[w_has] * (vbc[w_has] ** 2).sum(1)).sum())
        ke_bc = 0.5 * float((gm[has] * (vbc[has] ** 2).sum(1)).sum())
        solver.substep(dt)
        gv = solver.grid_v.to_numpy().astype(np.float64)
        worst_grid = max(worst_grid, float(np.abs(gv[has] - vbc[has]).max()))
        new = {k: a.astype(np.float64) for k, a in solver.get_state().items()}
        sums["p2g"] += _apic_ke(m, v, C, dx) - ke_t
        sums["wall"] += ke_wall_t - ke_wall_bc
        sums["g2p"] += ke_bc - _apic_ke(m, new["v"], new["C"], dx)
        assert _apic_ke(m, v, C, dx) - ke_t >= -1e-6 * e0  # the transfers never create energy
        assert ke_bc - _apic_ke(m, new["v"], new["C"], dx) >= -1e-5 * e0
        st = new
    e1 = total(st)
    lost = e0 - e1
    explained = sums["p2g"] + sums["g2p"] + sums["wall"]
    print(
        f"\nenergy budget over 0.6 s: E0 {e0:.5f} J/m, lost {lost:.3e} ({100 * lost / e0:.2f} %); "
        f"P2G {sums['p2g']:.3e}, G2P {sums['g2p']:.3e}, wall {sums['wall']:.3e}, "
        f"time integration {lost - explained:+.3e}"
    )
    assert worst_grid < 1e-3  # the replica is the solver's substep (f32 vs f64)
    assert st["x"][:, 1].min() > 0.0 and lost > 0
    assert abs(lost - explained) < 0.1 * lost  # the loss is the transfers' and the wall's


# ------------------------------------------------------------------------------- sand


def _tilted(beta_deg):
    b = math.radians(beta_deg)
    return [G * math.sin(b), -G * math.cos(b)]


# the pyramid's runs are slow-marked: the default suite keeps the default surface's two (its CI budget)
@pytest.mark.parametrize("surface", ["drucker_prager", pytest.param("mohr_coulomb", marks=pytest.mark.slow)])
@pytest.mark.parametrize("beta,flows", [(27.0, False), (38.0, True)])
def test_sand_slope_holds_below_and_flows_above_the_friction_angle(ti_f32, beta, flows, surface):
    """A sand layer in a box under gravity tilted by beta: its free surface is a slope at beta. With
    friction_angle 30 (the angle of repose, ``cone: simple_shear``) it stays put at 27 deg and
    avalanches at 38 deg. A layer at rest can stand up to the cone's plane-strain Mohr-Coulomb angle
    asin(tan 30) = 35.3 deg (its steepest static slope, above the angle of repose as for real sand);
    the repose angle itself is checked in steady simple shear (test_mpm_return_mapping.py). Both yield
    surfaces (the pyramid has the same static limit, asin(tan 30), whatever sigma_zz)."""
    scene = make_scene(
        sim={"dim": 2, "gravity": _tilted(beta)},
        domain={"lower": [0.0, 0.0], "upper": [0.3, 0.15], "boundary": {"type": "slip", "friction": 0.6}},
        solvers={"mpm": {"grid_density": 64, "particle_size": 1 / 128, "sampling": "jitter"}},
        entities=[
            {
                "name": "s",
                "material": {
                    "type": "MPM.Sand",
                    "friction_angle": 30.0,
                    "rho": 1500.0,
                    "E": 1.0e6,
                    "nu": 0.3,
                    "yield_surface": surface,
                },
                "morph": box((0.0, 0.0), (0.3, 0.06)),
            }
        ],
    )
    solver, _ = build(scene)
    x0 = solver.entity_arrays("s", ["position"])["position"].copy()
    h = min(2e-4, solver.stable_dt())
    for _ in range(int(0.4 / h)):
        solver.substep(h)
    a = solver.entity_arrays("s", ["position", "velocity"])
    moved = np.abs(a["position"] - x0).max()
    assert solver.frame_check()["s"].finite
    if flows:
        assert moved > 0.01  # the layer avalanches towards the low wall
    else:
        assert moved < 0.004 and np.abs(a["velocity"]).max() < 0.02  # elastic settling only


def _flowing_layer_friction_angle(ti_f32, cone, theta=30.0, surface="drucker_prager"):
    """A 4 cm sand layer (5 cells) on a sticky floor under gravity tilted by theta, set flowing at 0.3 m/s:
    the basal friction it mobilises, atan(tan(theta) - a / (g cos(theta))), a the mean downslope
    acceleration of its middle 0.2 m over 0.1-0.3 s (its momentum balance per unit area)."""
    b = math.radians(theta)
    scene = make_scene(
        sim={"dim": 2, "gravity": _tilted(theta)},
        domain={"lower": [0.0, 0.0], "upper": [0.7, 0.06], "faces": {"y-": {"type": "sticky"}}},
        solvers={"mpm": {"grid_density": 128, "particle_size": 1 / 256}},
        entities=[
            {
                "name": "s",
                "material": {
                    "type": "MPM.Sand",
                    "friction_angle": 30.0,
                    "rho": 1500.0,
                    "E": 1.0e6,
                    "nu": 0.3,
                    "cone": cone,
                    "yield_surface": surface,
                },
                "morph": box((0.05, 0.0), (0.55, 0.04)),
                "velocity": [0.3, 0.0],
            }
        ],
    )
    solver, _ = build(scene)
    x0 = solver.entity_arrays("s", ["position"])["position"]
    middle = np.abs(x0[:, 0] - 0.3) < 0.1
    h = solver.stable_dt()
    ts, us = [], []
    for k in range(int(0.3 / h) + 1):
        if k % 100 == 0 and k * h >= 0.1:
            ts.append(k * h)
            us.append(solver.entity_arrays("s", ["velocity"])["velocity"][middle, 0].mean())
        solver.substep(h)
    assert us[-1] > 0.05  # still flowing: the fit reads a sliding layer's friction
    a = np.polyfit(ts, us, 1)[0]
    return math.degrees(math.atan(math.tan(b) - a / (G * math.cos(b))))


@pytest.mark.slow  # two MPM runs of 0.3 s (about 10 CPU s each)
def test_a_flowing_sand_layer_mobilises_the_friction_angle(ti_f32):
    """Issue 23's cone check in a real flow (not one particle): a layer sliding down a 30 deg slope on
    its own shear zone carries tan(friction_angle) of its normal stress with the default simple_shear
    cone (measured 30.4 deg at grid 128; 29.5-30.8 deg at grid 256 for slopes of 28-32 deg), and
    atan(sin(phi)) = 26.6 deg with the plane_strain cone (measured 28.6 deg: the decelerating layer
    adds the transfer's rate-dependent loss)."""
    simple = _flowing_layer_friction_angle(ti_f32, "simple_shear")
    plane = _flowing_layer_friction_angle(ti_f32, "plane_strain")
    assert abs(simple - 30.0) < 1.5
    assert plane < simple - 1.0


@pytest.mark.slow  # two MPM runs of 0.3 s (about 10 CPU s each)
def test_a_flowing_mohr_coulomb_layer_mobilises_the_friction_angle(ti_f32):
    """The same sliding layer with ``yield_surface: mohr_coulomb`` (sin(phi_mc) = tan(friction_angle)):
    in plane strain the pyramid and the simple_shear cone carry the same friction on the shear plane, so
    the layer mobilises 30 deg as the cone does (within 0.5 deg of it)."""
    cone = _flowing_layer_friction_angle(ti_f32, "simple_shear")
    mc = _flowing_layer_friction_angle(ti_f32, "simple_shear", surface="mohr_coulomb")
    assert abs(mc - 30.0) < 1.5
    assert abs(mc - cone) < 0.5


def test_a_3d_mohr_coulomb_column_spreads_less_than_the_cone(ti_f32):
    """Two 3D sand columns (5 x 5 x 10 cm, 30 deg, grid 64) side by side in one scene, one per yield surface
    (one compiled law, the surface chosen per material), collapse on a rough floor for 0.2 s. They spread
    radially, near triaxial compression, where the simple_shear cone is a Mohr-Coulomb material of only 25.4
    deg and the pyramid keeps tan(30 deg) on its shear planes: the Mohr-Coulomb pile stops narrower and
    taller (measured 4.3 against 5.1 cm from the axis, 2.8 against 1.8 cm high; 99th percentiles)."""
    material = {"type": "MPM.Sand", "friction_angle": 30.0, "rho": 1500.0, "E": 1.0e6, "nu": 0.3}
    axes = {"dp": 0.075, "mc": 0.225}
    scene = make_scene(
        sim={"dim": 3},
        domain={
            "lower": [0.0, 0.0, 0.0],
            "upper": [0.3, 0.15, 0.15],
            "faces": {"z-": {"type": "slip", "friction": 0.5}},
        },
        solvers={"mpm": {"grid_density": 64}},
        entities=[
            {
                "name": name,
                "material": {**material, "yield_surface": surface},
                "morph": box((axes[name] - 0.025, 0.05, 0.0), (axes[name] + 0.025, 0.1, 0.1)),
            }
            for name, surface in (("dp", "drucker_prager"), ("mc", "mohr_coulomb"))
        ],
    )
    solver, _ = build(scene)
    for _ in range(800):
        solver.substep(2.5e-4)  # the CLI's auto substep here (the pile reaches 0.5 m/s)
    spread, height = {}, {}
    for name, cx in axes.items():
        assert solver.frame_check()[name].finite
        x = solver.entity_arrays(name, ["position"])["position"]
        spread[name] = np.percentile(np.maximum(np.abs(x[:, 0] - cx), np.abs(x[:, 1] - 0.075)), 99)
        height[name] = np.percentile(x[:, 2], 99)
    assert spread["mc"] < 0.95 * spread["dp"]
    assert height["mc"] > 1.2 * height["dp"]


# ------------------------------------------------------------------------------- snow


def test_snow_compacts_hardens_and_keeps_jp_je_j(ti_f32):
    scene = make_scene(
        sim={"dim": 2, "gravity": [0.0, 0.0]},
        domain={"lower": [0.0, 0.0], "upper": [0.4, 0.4]},
        solvers={"mpm": {"grid_density": 64, "particle_size": 1 / 128, "sampling": "poisson"}},
        entities=[
            {
                "name": "snow",
                "material": {"type": "MPM.Snow", "E": 1.4e5, "nu": 0.2, "rho": 400.0},
                "morph": {"type": "Sphere", "center": [0.2, 0.15], "radius": 0.05},
                "velocity": [0.0, -6.0],
            }
        ],
    )
    solver, (body,) = build(scene)
    vol0 = body.volume.copy()
    for _ in range(40):  # 0.04 s, with the solver's own stability control (fixed here: 25 us)
        for _ in range(40):
            solver.substep(2.5e-5)
    a = solver.entity_arrays("snow", ["position", "J", "Jp", "stress"])
    assert solver.frame_check()["snow"].finite
    assert a["Jp"].min() < 0.9  # compacted against the floor
    hard = np.exp(10.0 * (1.0 - a["Jp"].min()))
    assert hard > 2.0 and float(solver.stat_stiff[None]) == pytest.approx(hard, rel=1e-3)
    # J_p J_E = J: the total volume ratio from det F_E J_p equals the one from the particle volumes
    # as the grid sees them (checked by mass: sum of J V0 over the particles vs its own J output)
    st = solver.get_state()
    je = np.linalg.det(st["F"].astype(np.float64))
    assert np.allclose(st["snow_Jp"] * je, a["J"], rtol=1e-5)
    assert a["position"][:, 1].min() >= 0.0 and vol0.sum() > 0


# ----------------------------------------------------------------------------- liquid


def test_viscous_liquid_shear_mode_decays_at_nu_k2(ti_f32):
    """A free liquid slab (zero gravity, free surfaces at y = 0 and H, where the shear stress
    vanishes) with the shear mode u_x = U cos(pi y / H): the Navier-Stokes solution is
    u = U cos(k y) exp(-nu k^2 t), k = pi / H, nu = mu / rho, so the decay rate checks that the
    viscosity is in Pa s. 20 cells across H: within 5 % at t = 0.1 s (the transfers add a little)."""
    U, mu, rho, H, y0 = 0.05, 2.0, 1000.0, 0.05, 0.075
    scene = make_scene(
        sim={"dim": 2, "gravity": [0.0, 0.0]},
        domain={"lower": [0.0, 0.0], "upper": [0.5, 0.2]},
        solvers={"mpm": {"grid_density": 400, "particle_size": 0.00125}},
        entities=[
            {
                "name": "w",
                "material": {
                    "type": "MPM.Liquid",
                    "E": 1.0e6,
                    "nu": 0.2,
                    "rho": rho,
                    "viscous": True,
                    "mu": mu,
                },
                "morph": box((0.1, y0), (0.4, y0 + H)),
            }
        ],
    )
    solver, _ = build(scene)
    k = math.pi / H
    st = solver.get_state()
    y = st["x"][:, 1] - y0
    st["v"][:, 0] = U * np.cos(k * y)
    st["C"][:, 0, 1] = -U * k * np.sin(k * y)  # the APIC affine part: du/dy
    solver.set_state(st)
    h, t = 0.5 * solver.stable_dt(), 0.0
    assert h < 0.5 * rho / (4 * mu) * solver.dx**2 * 1.01  # the viscous limit decides
    while t < 0.1 - 1e-12:
        solver.substep(h)
        t += h
    a = solver.entity_arrays("w", ["position", "velocity"])
    mid = np.abs(a["position"][:, 0] - 0.25) < 0.07
    yy = a["position"][mid, 1] - y0
    amp = float((a["velocity"][mid, 0] * np.cos(k * yy)).sum() / (np.cos(k * yy) ** 2).sum())
    exact = U * math.exp(-mu / rho * k * k * t)
    assert amp == pytest.approx(exact, rel=0.05)
    assert amp < 0.5 * U  # it did decay (by exp(-0.79))


# ------------------------------------------------------------------------------ muscle


def test_muscle_group_contracts_along_its_fibres(ti_f32):
    """Two groups of one muscle in zero gravity: the left half actuated with a = 0.05 along x, the
    right half passive. The actuated half shortens along x by a k (1 - nu^2) / E (small-strain
    balance of the active tension and the passive stress, plane strain); the passive half does not."""
    a_act = 0.05
    scene = make_scene(
        sim={"dim": 2, "gravity": [0.0, 0.0]},
        domain={"lower": [0.0, 0.0], "upper": [1.0, 0.5]},
        solvers={"mpm": {"grid_density": 64, "particle_size": 1 / 128}},
        entities=[
            {
                "name": "m",
                "material": {
                    "type": "MPM.Muscle",
                    "E": 1.0e5,
                    "nu": 0.3,
                    "rho": 1000.0,
                    "n_groups": 2,
                    "fiber_direction": [1.0, 0.0],
                    "groups": [
                        {
                            "region": box((0.0, 0.0), (0.5, 0.5)),
                            "actuation": {"type": "constant", "value": a_act},
                        },
                        {"actuation": {"type": "constant", "value": 0.0}},
                    ],
                },
                "morph": box((0.3, 0.2), (0.7, 0.3)),
            }
        ],
    )
    solver, (body,) = build(scene)
    x0 = body.x
    left, right = x0[:, 0] < 0.5, x0[:, 0] > 0.5
    act = left & (np.abs(x0[:, 0] - 0.4) < 0.09)
    pas = right & (np.abs(x0[:, 0] - 0.6) < 0.09)

    def strain(x, sel):
        return (np.percentile(x[sel, 0], 95) - np.percentile(x[sel, 0], 5)) / (
            np.percentile(x0[sel, 0], 95) - np.percentile(x0[sel, 0], 5)
        ) - 1

    h, t, hist = 0.5 * solver.stable_dt(), 0.0, []
    while t < 0.5:
        for _ in range(20):
            solver.substep(h)
            t += h
        if t > 0.1:  # it oscillates about its equilibrium (hardly damped): keep the extremes
            x = solver.entity_arrays("m", ["position"])["position"]
            hist.append((strain(x, act), strain(x, pas)))
    hist = np.array(hist)
    mid_act = 0.5 * (hist[:, 0].max() + hist[:, 0].min())
    mid_pas = 0.5 * (hist[:, 1].max() + hist[:, 1].min())
    # plane strain, free sides: -a k (1 - nu^2) / E (small strain) = -0.0455
    assert mid_act == pytest.approx(-a_act * (1 - 0.3**2), abs=0.01)
    assert abs(mid_pas) < 0.01  # in series with a free end: the passive half carries no stress
    assert solver.frame_check()["m"].finite


def test_muscle_sine_actuation_uses_the_scene_time(ti_f32):
    from simcli.solvers.mpm.fluid_muscle import MuscleNeoHookeanLaw

    scene = make_scene(
        sim={"dim": 2, "gravity": [0.0, 0.0]},
        domain={"lower": [0.0, 0.0], "upper": [0.5, 0.5]},
        solvers={"mpm": {"grid_density": 32}},
        entities=[
            {
                "name": "m",
                "material": {
                    "type": "MPM.Muscle",
                    "groups": [
                        {"actuation": {"type": "sine", "amplitude": 0.2, "frequency": 2.0, "offset": 0.1}}
                    ],
                },
                "morph": box((0.2, 0.2), (0.3, 0.3)),
            }
        ],
    )
    solver, _ = build(scene)
    law = next(lw for lw in solver.laws if isinstance(lw, MuscleNeoHookeanLaw))
    for _ in range(25):
        solver.substep(1e-3)
    # the activation of the last substep started at t = 24 ms
    assert float(law.actuation[0]) == pytest.approx(0.1 + 0.2 * math.sin(2 * math.pi * 2.0 * 0.024), rel=1e-5)
    assert solver.time == pytest.approx(0.025)


# ---------------------------------------------------------------- several materials, one grid


@pytest.mark.slow
def test_light_block_floats_half_submerged(ti_f32):
    """A soft block of density 500 dropped into water (MPM.Liquid, one shared grid) floats
    (Archimedes: half of its height below the water line). On one grid two materials meet about
    0.85 cell apart (the two-disk collision shows the same gap), so the block displaces a skin of
    that thickness too: 1000 (0.1 + 2 g)(d + g) = 500 x 0.01 with g = 0.85 dx = 8.5 mm gives
    d = 34 mm, a submerged fraction of 0.34 at this resolution (0.5 as dx -> 0)."""
    scene = make_scene(
        sim={"dim": 2},
        domain={"lower": [0.0, 0.0], "upper": [0.4, 0.4]},
        solvers={"mpm": {"grid_density": 100, "particle_size": 0.005}},
        entities=[
            {
                "name": "water",
                "material": {"type": "MPM.Liquid", "E": 1.0e6, "rho": 1000.0, "viscous": True, "mu": 20.0},
                "morph": box((0.0, 0.0), (0.4, 0.15)),
            },
            {
                "name": "block",
                "material": {"type": "MPM.Elastic", "E": 1.0e5, "nu": 0.3, "rho": 500.0},
                "morph": box((0.15, 0.17), (0.25, 0.27)),
            },
        ],
    )
    solver, _ = build(scene)
    h = 0.5 * solver.stable_dt()
    for _ in range(int(3.0 / h)):
        solver.substep(h)
    w = solver.entity_arrays("water", ["position"])["position"]
    b = solver.entity_arrays("block", ["position"])["position"]
    far = np.abs(w[:, 0] - 0.2) > 0.12
    level = np.sort(w[far, 1])[-20:].mean() + 0.0025
    bottom, top = b[:, 1].min() - 0.0025, b[:, 1].max() + 0.0025
    submerged = (level - bottom) / (top - bottom)
    gap = 0.85 * solver.dx
    expected = 500.0 * 0.01 / (1000.0 * (0.1 + 2 * gap)) - gap  # submerged depth with the contact skin
    assert float(level - bottom) == pytest.approx(expected, abs=0.5 * solver.dx)
    assert 0.25 < submerged < 0.5


# ------------------------------------------------------------------------------- restart


def test_restart_of_plastic_liquid_and_muscle_state_is_bit_for_bit(ti_f32):
    scene = make_scene(
        sim={"dim": 2},
        domain={"lower": [0.0, 0.0], "upper": [1.0, 0.5]},
        solvers={"mpm": {"grid_density": 48}},
        entities=[
            {"name": "sand", "material": {"type": "MPM.Sand"}, "morph": box((0.05, 0.05), (0.2, 0.2))},
            {"name": "snow", "material": {"type": "MPM.Snow"}, "morph": box((0.25, 0.05), (0.4, 0.2))},
            {
                "name": "vm",
                "material": {"type": "MPM.ElastoPlastic", "von_mises_yield_stress": 500.0},
                "morph": box((0.45, 0.05), (0.6, 0.2)),
            },
            {
                "name": "water",
                "material": {"type": "MPM.Liquid", "viscous": True, "mu": 0.1},
                "morph": box((0.65, 0.05), (0.8, 0.2)),
            },
            {
                "name": "muscle",
                "material": {
                    "type": "MPM.Muscle",
                    "groups": [{"actuation": {"type": "sine", "amplitude": 0.3, "frequency": 3.0}}],
                },
                "morph": box((0.82, 0.05), (0.95, 0.2)),
            },
        ],
    )
    solver, _ = build(scene)
    h = 2e-4
    for _ in range(300):
        solver.substep(h)
    saved = {k: v.copy() for k, v in solver.get_state().items()}
    assert {"sand_vc", "sand_Jp", "snow_Jp", "von_mises_ezz", "time"} <= set(saved)
    for _ in range(200):
        solver.substep(h)
    first = solver.get_state()
    solver.set_state(saved)
    for _ in range(200):
        solver.substep(h)
    second = solver.get_state()
    for k in first:
        assert np.array_equal(first[k], second[k]), k
    assert all(s.finite for s in solver.frame_check().values())


# ------------------------------------------------------------------------------ sampling


@pytest.mark.parametrize("dim", [2, 3])
def test_poisson_disk_sampling(dim):
    from simcli.geometry.sampling import POISSON_RADIUS, sample_entity

    h, R = 0.01, (0.12 if dim == 2 else 0.07)
    morph = {"type": "Sphere", "center": [0.0] * (dim - 1) + [0.5], "radius": R}
    scene = make_scene(
        sim={"dim": dim, "seed": 3},
        domain={"lower": [-0.5] * (dim - 1) + [0.0], "upper": [0.5] * (dim - 1) + [1.0]},
        solvers={"mpm": {"particle_size": h, "sampling": "poisson"}},
        entities=[{"name": "s", "material": {"type": "MPM.Sand"}, "morph": morph}],
    )
    a = sample_entity(scene.entities[0], scene)
    b = sample_entity(scene.entities[0], scene)
    x = a.x
    assert np.array_equal(x, b.x)  # reproducible for a seed
    d = np.sqrt(((x[:, None, :] - x[None, :, :]) ** 2).sum(-1))
    np.fill_diagonal(d, np.inf)
    assert d.min() >= POISSON_RADIUS[dim] * h * (1 - 1e-9)
    assert np.all(np.linalg.norm(x - np.asarray(morph["center"]), axis=1) <= R)
    vol = math.pi * R**2 if dim == 2 else 4 / 3 * math.pi * R**3
    assert 0.85 < len(x) * h**dim / vol < 1.05  # about V / h^d (the 0.15 h margin from the surface)
    assert a.mass.sum() == pytest.approx(1000.0 * vol)  # total mass exact
    # blue noise: no lattice rows (the positions modulo the spacing are spread evenly)
    frac = np.histogram(np.mod(x[:, 0] / h, 1.0), bins=10, range=(0, 1))[0]
    assert frac.max() < 1.5 * frac.mean()


# ------------------------------------------------------------------------- real meshes

BUNNY = __import__("pathlib").Path(__file__).resolve().parents[2] / "configs" / "meshes" / "bunny.ply"


@pytest.mark.parametrize("thin", ["warn", "layer"])
def test_bunny_mesh_fills(thin):
    """The Stanford bunny (85k triangles, z up) at 0.2 m: lattice points inside the surface, about
    V / h^3 of them, exact mass; at a spacing that misses the ears' tips, thin_parts: layer gives
    the missed ray intervals one layer of particles (all inside the surface)."""
    from simcli.geometry.mesh import load_mesh_morph, points_inside_mesh
    from simcli.geometry.sampling import sample_entity

    h = 0.02
    scene = make_scene(
        solvers={"mpm": {"particle_size": h, "thin_parts": thin}},
        entities=[
            {
                "name": "b",
                "material": {"type": "MPM.Elastic"},
                "morph": {"type": "Mesh", "file": str(BUNNY), "scale": 0.2, "translate": [0.0, 0.0, 0.3]},
            }
        ],
    )
    body = sample_entity(scene.entities[0], scene)
    mesh = load_mesh_morph(scene.entities[0].morph)
    assert points_inside_mesh(mesh, body.x).all()
    assert body.mass.sum() == pytest.approx(1000.0 * mesh.volume)
    assert 0.9 < body.n * h**3 / mesh.volume < 1.25
    assert mesh.volume == pytest.approx(1.6e-3, rel=0.05)


def test_obj_files_meshio_refuses_and_duplicate_faces(tmp_path):
    """A textured OBJ whose texture coordinates are counted per corner (meshio raises on it) is read
    by the fallback reader; a face exported twice and a zero-volume fin (a face and its reverse)
    are dropped so the surface counts as closed."""
    from simcli.geometry.mesh import read_surface

    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 1]], float)
    faces = [(1, 3, 2), (1, 2, 4), (1, 4, 3), (2, 3, 4)]  # a tetrahedron, outward
    lines = [f"v {a} {b} {c}" for a, b, c in v]
    lines += [f"vt {0.1 * k} 0.5" for k in range(7)]  # more vt than v
    lines += [f"f {a}/{a} {b}/{b} {c}/{c}" for a, b, c in faces]
    lines += ["f 1 2 3", "f 1 3 2"]  # a fin: the face (1, 2, 3)'s reverse, twice more
    lines += [f"f {faces[0][0]} {faces[0][1]} {faces[0][2]}"]  # face 1 again
    p = tmp_path / "textured.obj"
    p.write_text("\n".join(lines) + "\n")
    pts, tris = read_surface(p)
    assert tris.shape == (4, 3) and pts.shape == (4, 3)


def test_restart_of_3d_plastic_state_with_the_warm_start_rotation_is_bit_for_bit(ti_f32):
    """3D plastic laws keep each particle's last U (the warm start of the decomposition) as state: a
    restart from the saved state continues bit for bit, and a state without it (a checkpoint from before
    the warm start) is accepted and gives the same motion but for round-off, which the turning grains
    amplify (measured 9e-7 m after 100 substeps; bound 1e-5 m, 0.06% of a cell). Each block starts spinning
    about its own vertical axis at 4 rev/s (its velocities set through set_state), which turns the grains.
    Until 2026-11-27 a moving paddle (a rotating frictionless Box collider) turned them: the same assertions,
    but its collider code made the fused substep kernel cost 424 CPU s to compile cold against 39 CPU s
    now (docs/PERFORMANCE.md, 'The 3D plastic restart test's compile'); restarts with moving colliders are
    covered by tests/unit/test_rigid.py and tests/cli/test_run.py."""
    scene = make_scene(
        domain={"lower": [0.0, 0.0, 0.0], "upper": [0.2, 0.2, 0.1]},
        solvers={"mpm": {"grid_density": 60}},
        entities=[
            {
                "name": "sand",
                "material": {"type": "MPM.Sand"},
                "morph": box((0.0, 0.0, 0.0), (0.09, 0.2, 0.06)),
            },
            {
                "name": "snow",
                "material": {"type": "MPM.Snow"},
                "morph": box((0.11, 0.0, 0.0), (0.2, 0.2, 0.06)),
            },
        ],
    )
    solver, _ = build(scene)
    start = solver.get_state()
    x = start["x"].astype(np.float64)
    centre = np.where(x[:, :1] < 0.1, [[0.045, 0.1]], [[0.155, 0.1]])  # each block's own axis
    w = 8 * math.pi
    spin = start["v"].copy()
    spin[:, 0] = -w * (x[:, 1] - centre[:, 1])
    spin[:, 1] = w * (x[:, 0] - centre[:, 0])
    solver.set_state(dict(start, v=spin.astype(start["v"].dtype)))
    h = 2e-4
    for _ in range(100):
        solver.substep(h)
    saved = {k: v.copy() for k, v in solver.get_state().items()}
    assert {"sand_Uq", "snow_Uq"} <= set(saved)
    for key in ("sand_Uq", "snow_Uq"):  # the grains have turned: not the identity
        assert np.abs(saved[key][:, 0]).min() < 0.99, key
    for _ in range(100):
        solver.substep(h)
    first = solver.get_state()
    solver.set_state(saved)
    for _ in range(100):
        solver.substep(h)
    second = solver.get_state()
    for k in first:
        assert np.array_equal(first[k], second[k]), k
    solver.set_state({k: v for k, v in saved.items() if not k.endswith("_Uq")})  # started cold
    for _ in range(100):
        solver.substep(h)
    third = solver.get_state()
    np.testing.assert_allclose(third["x"], first["x"], rtol=0, atol=1e-5)
