"""Material models, the config half: a discriminated union on `type`.

The kernel half of each material (its constitutive law) lives with its solver
(e.g. ``simcli/solvers/mpm/constitutive.py``). Only materials implemented by a
solver are listed here, so an unknown or not-yet-available type is a clear
validation error rather than a run-time failure.
"""

from __future__ import annotations

from typing import Annotated, Union

from pydantic import Field

from simcli.scene.material_base import _Material, _Solid  # noqa: F401  (re-exported)
from simcli.solvers.fem.config import MATERIALS as _FEM
from simcli.solvers.mpm.config import MATERIALS as _MPM
from simcli.solvers.pbd.config import MATERIALS as _PBD
from simcli.solvers.sf.config import MATERIALS as _SF
from simcli.solvers.sph.config import MATERIALS as _SPH

# Registry: every material type a solver family implements, from each family's config module.
MATERIAL_TYPES: tuple[type[_Material], ...] = (*_MPM, *_SPH, *_FEM, *_SF, *_PBD)
if len(MATERIAL_TYPES) > 1:
    Material = Annotated[Union[MATERIAL_TYPES], Field(discriminator="type")]  # type: ignore[valid-type]  # noqa: UP007
else:
    Material = MATERIAL_TYPES[0]  # type: ignore[misc]

# Types of the contract that are not implemented yet: named in a clear error.
PLANNED_TYPES: tuple[str, ...] = ()


def material_type_names() -> list[str]:
    return [m.model_fields["type"].annotation.__args__[0] for m in MATERIAL_TYPES]
