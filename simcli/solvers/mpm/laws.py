"""The registry of MPM constitutive laws: law key (:func:`constitutive.law_key`) -> law class.

It imports every law module; the law modules import only ``constitutive.py`` (the base classes), so
nothing imports back.
"""

from __future__ import annotations

from simcli.solvers.mpm.constitutive import ConstitutiveLaw, CorotatedLaw, NeoHookeanLaw
from simcli.solvers.mpm.fluid_muscle import (
    LiquidLaw,
    MuscleCorotatedLaw,
    MuscleNeoHookeanLaw,
    ViscousLiquidLaw,
)
from simcli.solvers.mpm.plasticity import ClampLaw, SandLaw, SnowLaw, VonMisesLaw

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
