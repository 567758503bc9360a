"""Per-frame kernels of the MPM solver: the frame statistics (largest speed and non-finite particles per
entity, the largest stiffness factor of a hardening law) and the derived per-particle outputs (J, von Mises
stress, pressure, J_p, elastic energy). Neither is on the substep's path.
"""

from simcli.backend import stdout_to_stderr
from simcli.solvers.mpm.fields import MPMFields, MPMParams
from simcli.solvers.mpm.laws import LawDispatch
from simcli.solvers.taichi_funcs import make_body_of, make_finite

with stdout_to_stderr():
    import taichi as ti


def build_frame_stats(params: MPMParams, fields: MPMFields, laws: list, dispatch: LawDispatch, count):
    """The kernel ``frame_stats()``: per entity the largest particle speed (stat_speed) and the count of
    particles with a non-finite position or velocity (stat_bad); stat_stiff, the largest stiffness factor
    (1 without hardening laws). ``count``: ti.func, the particle loop's bound."""
    nb = params.n_bodies
    N = count
    x, v, pid = fields.x, fields.v, fields.pid
    dynamic = pid is not None
    body_offsets, stat_speed, stat_bad = fields.body_offsets, fields.stat_speed, fields.stat_bad
    stat_stiff = fields.stat_stiff
    finite = make_finite(params.dtype == ti.f64)
    body_of = make_body_of(nb, body_offsets)
    any_hardening = any(law.hardens for law in laws)
    law_call_scalar = dispatch.call_scalar

    @ti.kernel
    def frame_stats():
        for b in range(nb):
            stat_speed[b] = 0.0
            stat_bad[b] = 0
        stat_stiff[None] = 1.0
        for p in range(N()):
            b = body_of(p)
            if ti.static(dynamic):
                b = body_of(pid[p])
            vp = v[p]
            if finite(x[p]) and finite(vp):
                ti.atomic_max(stat_speed[b], vp.norm())
            else:
                ti.atomic_add(stat_bad[b], 1)
            if ti.static(any_hardening):
                ti.atomic_max(stat_stiff[None], law_call_scalar(p, "stiffness_factor"))

    return frame_stats


def build_derive(params: MPMParams, fields: MPMFields, dispatch: LawDispatch, out: tuple):
    """The ti.func ``derive(p)`` writing particle p's (J, von Mises stress, pressure, J_p, elastic energy)
    into ``out``, five per-particle fields (solver.DERIVED_FIELDS). In 2D (plane strain) the stress includes
    the out-of-plane normal stress tau_zz. The frame outputs' kernel runs it over every particle; the probes'
    device path (simcli/probes/device.py) only at the particles a probe reads."""
    dim, f = params.dim, params.dtype
    F, mid, vol = fields.F, fields.mid, fields.vol
    kirchhoff = dispatch.kirchhoff
    law_call_scalar, law_scalar, law_scalar2 = dispatch.call_scalar, dispatch.scalar, dispatch.scalar_J
    out_J, out_vm, out_p, out_jp, out_e = out

    @ti.func
    def derive(p):
        Fp = ti.Matrix.identity(f, dim) + F[p]  # F stores H = F - I
        m = mid[p]
        J = Fp.determinant()
        tau = kirchhoff(p, Fp, J, False)
        Je = law_scalar2(p, J, "elastic_J")
        invJ = 0.0
        if Je != 0:
            invJ = 1.0 / Je
        s = tau * invJ  # Cauchy stress
        vm = 0.0
        pressure = 0.0
        if ti.static(dim == 3):
            pressure = -s.trace() / 3.0
            dev = s + ti.Matrix.identity(f, 3) * pressure
            vm = ti.sqrt(1.5 * (dev * dev).sum())
        else:
            # plane strain: add the out-of-plane normal stress
            szz = law_scalar(p, Fp, J, m, "tau_zz") * invJ
            mean = (s[0, 0] + s[1, 1] + szz) / 3.0
            d0 = s[0, 0] - mean
            d1 = s[1, 1] - mean
            d2 = szz - mean
            vm = ti.sqrt(1.5 * (d0 * d0 + d1 * d1 + d2 * d2 + s[0, 1] * s[0, 1] + s[1, 0] * s[1, 0]))
            pressure = -mean
        jp = law_call_scalar(p, "plastic_J")
        out_J[p] = law_scalar2(p, J, "total_J")  # total volume ratio J = J_p J_E
        out_vm[p] = vm
        out_p[p] = pressure
        out_jp[p] = jp
        out_e[p] = law_scalar(p, Fp, J, m, "energy_density") * vol[p]

    return derive


def build_outputs(params: MPMParams, fields: MPMFields, dispatch: LawDispatch, count, out: tuple):
    """The kernel ``outputs()``: :func:`build_derive`'s derive(p) over every particle."""
    N = count
    derive = build_derive(params, fields, dispatch, out)

    @ti.kernel
    def outputs():
        for p in range(N()):
            derive(p)

    return outputs
