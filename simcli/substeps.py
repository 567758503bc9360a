"""The substep policy (docs/ARCHITECTURE.md, "Substep phase order"): every substep size of a run is decided
here, from the scene's settings and what the families report (their stable substeps). No Taichi and no
solver: numbers in, numbers out, so that it can be read and tested alone. The runner asks it; no family
reads output settings or rescales itself to steer another layer."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

AUTO_MAX_SUBSTEPS = 100_000  # substeps: auto never takes more than this per step (nor one below dt / this)

StableFn = Callable[[float], float]  # fallback substep -> the smallest stable substep the families report


@dataclass(frozen=True)
class SubstepPolicy:
    """``sim.substeps`` fixed: ``dt / substeps`` always. ``substeps: auto`` with ``auto_check: frame``: the
    count chosen at each frame's first step from the families' stable substep, kept for the frame. With
    ``auto_check: substep``: before every substep, as large as the limits allow, the rest of the step made
    of equal substeps so that it ends on its boundary without a sliver."""

    dt: float  # sim.dt [s]
    substeps: int | str  # sim.substeps: a count or "auto"
    auto_check: str  # sim.auto_check: "frame" | "substep"
    every: int  # output.every: steps per frame

    @classmethod
    def of(cls, scene) -> SubstepPolicy:
        sim = scene.sim
        return cls(float(sim.dt), sim.substeps, sim.auto_check, int(scene.output.every))

    @property
    def auto(self) -> bool:
        return self.substeps == "auto"

    @property
    def adaptive(self) -> bool:
        """The substep chosen before every substep (auto_check: substep)."""
        return self.auto and self.auto_check == "substep"

    def fixed(self) -> int | None:
        """The fixed substep count, None with substeps: auto."""
        return None if self.auto else int(self.substeps)

    def horizon(self, last_substep: float | None) -> float:
        """How long the substep chosen now will be kept [s], so that a family can bound what gravity adds
        to its speeds meanwhile: a frame (dt x output.every) when the substep is fixed or chosen once per
        frame; the last substep taken when it is chosen before each one (a frame before the first)."""
        if self.adaptive and last_substep is not None:
            return last_substep
        return self.dt * self.every

    def step_substeps(self, step: int, substeps_now: int | None, stable: StableFn) -> int | None:
        """The substep count of step ``step`` (auto_check: frame: chosen at a frame's first step, or when
        none is chosen yet; otherwise the current one)."""
        if self.auto and not self.adaptive and (step % self.every == 0 or substeps_now is None):
            s = max(stable(self.dt / (substeps_now or 1)), self.dt / AUTO_MAX_SUBSTEPS)
            return min(AUTO_MAX_SUBSTEPS, max(1, int(math.ceil(self.dt / s))))
        return substeps_now

    def next_substep(
        self, k: int, done_t: float, substeps_now: int | None, last: float, stable: StableFn
    ) -> tuple[float, int]:
        """(the next substep [s], the substeps left in this step, it included) after ``k`` substeps that
        took ``done_t`` of the step; ``last`` is the previous substep (dt at a step's start)."""
        if self.adaptive:
            rem = self.dt - done_t
            s = max(stable(last), self.dt / AUTO_MAX_SUBSTEPS)
            n_left = max(1, int(math.ceil(rem / s * (1.0 - 1e-9))))
            return rem / n_left, n_left
        return self.dt / substeps_now, substeps_now - k

    @staticmethod
    def split(dt: float, stable: float) -> int:
        """How many equal pieces a family that must stay under its own stable substep inside the common one
        (MPM with hardening under substeps: auto) cuts ``dt`` into."""
        return max(1, math.ceil(dt / stable - 1e-9))
