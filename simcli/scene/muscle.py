"""Muscle activation signals and muscle groups (pydantic, no Taichi): what MPM.Muscle and FEM.Muscle
share (``simcli.solvers.mpm.config``, ``simcli.solvers.fem.config``), kept here so that neither family
imports the other."""

from __future__ import annotations

import math
from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from simcli.scene.morphs import Region

Vec = list[float]


class _Signal(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, validate_default=True)


class ConstantSignal(_Signal):
    type: Literal["constant"]
    value: float = Field(0.0, description="Activation [-] (active stress = stiffness x activation).")

    def __call__(self, t: float) -> float:
        return self.value


class SineSignal(_Signal):
    type: Literal["sine"]
    amplitude: float = Field(1.0, description="Amplitude [-] of the activation.")
    frequency: float = Field(1.0, gt=0, description="Frequency [Hz].")
    phase: float = Field(0.0, description="Phase [rad].")
    offset: float = Field(0.0, description="Offset [-] added to the sine.")

    def __call__(self, t: float) -> float:
        return self.offset + self.amplitude * math.sin(2.0 * math.pi * self.frequency * t + self.phase)


class TableSignal(_Signal):
    type: Literal["table"]
    times: Vec = Field(description="Times [s], strictly increasing.")
    values: Vec = Field(description="Activation [-] at each time; piecewise linear between, held outside.")
    periodic: bool = Field(False, description="Repeat the table with period times[-1] - times[0].")

    @model_validator(mode="after")
    def _check(self):
        if len(self.times) != len(self.values) or not self.times:
            raise ValueError("times and values need the same, non-zero length")
        if any(b <= a for a, b in zip(self.times, self.times[1:])):
            raise ValueError("times must be strictly increasing")
        if self.periodic and len(self.times) < 2:
            raise ValueError("a periodic table needs at least two points")
        return self

    def __call__(self, t: float) -> float:
        ts = self.times
        if self.periodic:
            t = ts[0] + math.fmod(t - ts[0], ts[-1] - ts[0])
            if t < ts[0]:
                t += ts[-1] - ts[0]
        if t <= ts[0]:
            return self.values[0]
        if t >= ts[-1]:
            return self.values[-1]
        k = max(i for i in range(len(ts)) if ts[i] <= t)
        a = (t - ts[k]) / (ts[k + 1] - ts[k])
        return (1.0 - a) * self.values[k] + a * self.values[k + 1]


Signal = Annotated[ConstantSignal | SineSignal | TableSignal, Field(discriminator="type")]


class MuscleGroup(_Signal):
    region: Region | list[Region] | None = Field(
        None,
        description="Where this group's particles are (initial positions). A particle belongs to the first "
        "group whose region holds it; a group without a region takes every particle no earlier group took.",
    )
    fiber_direction: Vec | None = Field(
        None,
        description="Fibre direction in the initial configuration [-] (normalised; default the material's).",
    )
    actuation: Signal = Field(
        default_factory=lambda: ConstantSignal(type="constant", value=0.0),
        description="Activation a(t) [-]: constant, sine or piecewise-linear table over time.",
    )

    @property
    def regions(self) -> list:
        if self.region is None:
            return []
        return list(self.region) if isinstance(self.region, list) else [self.region]


class MuscleGroups:
    """What MPM.Muscle and FEM.Muscle share (fields n_groups, fiber_direction, groups, stiffness, E):
    the group checks, the active stiffness, the group list and the bound of the activation signals."""

    def _check_groups(self, need_dim: int | None = None) -> None:
        if self.groups and len(self.groups) != self.n_groups:
            raise ValueError(f"groups has {len(self.groups)} entries but n_groups is {self.n_groups}")
        if not self.groups and self.n_groups != 1:
            raise ValueError("give one entry in groups per muscle group (n_groups > 1)")
        for d in [self.fiber_direction] + [g.fiber_direction for g in self.groups]:
            if d is None:
                continue
            zero = not any(abs(c) > 0 for c in d)
            if need_dim is not None and (len(d) != need_dim or zero):
                raise ValueError(f"fiber_direction needs {need_dim} components, not all zero")
            if zero:
                raise ValueError("fiber_direction must not be zero")

    @property
    def active_stiffness(self) -> float:
        return self.stiffness if self.stiffness is not None else self.E

    def group_list(self) -> list[MuscleGroup]:
        return list(self.groups) if self.groups else [MuscleGroup()]

    def max_activation(self) -> float:
        """Largest |a(t)| any group's signal reaches (the explicit stability bounds use it)."""
        amax = 0.0
        for g in self.group_list():
            sig = g.actuation
            if sig.type == "constant":
                amax = max(amax, abs(sig.value))
            elif sig.type == "sine":
                amax = max(amax, abs(sig.offset) + abs(sig.amplitude))
            else:
                amax = max(amax, max(abs(v) for v in sig.values))
        return amax
