"""The registry of MPM constitutive laws: law key (:func:`constitutive.law_key`) -> law class, and the
dispatch from a particle to its law's functions (:func:`build_law_dispatch`).

It imports every law module; the law modules import only ``constitutive.py`` (the base classes), so
nothing imports back. The laws themselves: ``constitutive.py`` (base class, elastic), ``plasticity.py``
(return mappings: von Mises, clamp, snow, sand), ``fluid_muscle.py`` (liquid, muscle).
"""

from dataclasses import dataclass
from typing import Any

from simcli.backend import stdout_to_stderr
from simcli.solvers.mpm.constitutive import ConstitutiveLaw, CorotatedLaw, NeoHookeanLaw
from simcli.solvers.mpm.fluid_muscle import (
    LiquidLaw,
    MuscleCorotatedLaw,
    MuscleNeoHookeanLaw,
    ViscousLiquidLaw,
)
from simcli.solvers.mpm.plasticity import ClampLaw, SandLaw, SnowLaw, VonMisesLaw

with stdout_to_stderr():
    import taichi as ti

LAWS: dict[str, type[ConstitutiveLaw]] = {
    law.key: law
    for law in (
        CorotatedLaw,
        NeoHookeanLaw,
        VonMisesLaw,
        ClampLaw,
        SandLaw,
        SnowLaw,
        LiquidLaw,
        ViscousLiquidLaw,
        MuscleCorotatedLaw,
        MuscleNeoHookeanLaw,
    )
}


@dataclass(frozen=True)
class LawDispatch:
    """The per-particle calls into the particle's law, compiled for the laws present only (one law: a
    direct call; several: a run-time branch on ``mat_law_id[mid[p]]`` over a static loop).

    ``kirchhoff(p, F, J, update)``: the Kirchhoff stress (``update``: a law may refresh its per-particle
    cache, e.g. the corotated rotation); ``call_scalar(p, which)``: a per-particle scalar (``plastic_J``,
    ``stiffness_factor``); ``scalar(p, F, J, m, which)``: ``tau_zz`` or ``energy_density``;
    ``scalar_J(p, J, which)``: ``elastic_J`` or ``total_J``. The return mappings are called by G2P
    (``g2p.py``) through the laws' ``return_mapping``.
    """

    kirchhoff: Any
    call_scalar: Any
    scalar: Any
    scalar_J: Any


def build_law_dispatch(dim: int, f: Any, laws: list[ConstitutiveLaw], mid, mat_mu, mat_lam, mat_law_id):
    """``laws``: the solver's laws (index = law id); ``mid`` the particles' material ids; ``mat_mu``,
    ``mat_lam``, ``mat_law_id``: per-material Lame parameters and law id (see fields.MPMFields)."""
    n_laws = len(laws)

    @ti.func
    def kirchhoff(p, Fp, J, update: ti.template()):
        m = mid[p]
        mu = mat_mu[m]
        lam = mat_lam[m]
        tau = ti.Matrix.zero(f, dim, dim)
        if ti.static(n_laws == 1):
            tau = laws[0].kirchhoff(p, Fp, J, mu, lam, update)
        else:
            lid = mat_law_id[m]
            for k in ti.static(range(n_laws)):
                if lid == k:
                    tau = laws[k].kirchhoff(p, Fp, J, mu, lam, update)
        return tau

    @ti.func
    def law_call_scalar(p, which: ti.template()):
        """A per-particle scalar of the particle's law (plastic_J, stiffness_factor)."""
        r = 1.0
        if ti.static(n_laws == 1):
            r = ti.static(getattr(laws[0], which))(p)
        else:
            lid = mat_law_id[mid[p]]
            for k in ti.static(range(n_laws)):
                if lid == k:
                    r = ti.static(getattr(laws[k], which))(p)
        return r

    @ti.func
    def law_scalar(p, Fp, J, m, which: ti.template()):
        """tau_zz or energy_density of the particle's law."""
        r = 0.0
        if ti.static(n_laws == 1):
            r = ti.static(getattr(laws[0], which))(p, Fp, J, mat_mu[m], mat_lam[m])
        else:
            for k in ti.static(range(n_laws)):
                if mat_law_id[m] == k:
                    r = ti.static(getattr(laws[k], which))(p, Fp, J, mat_mu[m], mat_lam[m])
        return r

    @ti.func
    def law_scalar2(p, J, which: ti.template()):
        r = 0.0
        if ti.static(n_laws == 1):
            r = ti.static(getattr(laws[0], which))(p, J)
        else:
            lid = mat_law_id[mid[p]]
            for k in ti.static(range(n_laws)):
                if lid == k:
                    r = ti.static(getattr(laws[k], which))(p, J)
        return r

    return LawDispatch(kirchhoff, law_call_scalar, law_scalar, law_scalar2)
