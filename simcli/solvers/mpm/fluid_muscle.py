"""MPM liquid and muscle laws.

* ``liquid`` / ``liquid_viscous`` (``MPM.Liquid``): weakly compressible. The return mapping
  keeps only the volume of F (F <- J^(1/d) I: a liquid has no memory of shape), the pressure is
  p = lambda (1 - J) (Kirchhoff tau = lambda J (J - 1) I, Genesis's and Stomakhin et al. 2014's
  equation of state, energy lambda / 2 (J - 1)^2); ``tension: false`` cuts the pressure off at 0 (J - 1
  taken as min(J - 1, 0) in the stress and the energy: a spreading liquid parts instead of pulling back).
  ``viscous: true`` adds the Newtonian
  viscous stress sigma_v = 2 mu dev(D), D = sym(grad v), grad v being the particle's APIC
  affine matrix C (exact for linear velocity fields, Jiang et al. 2015), so mu is a viscosity in
  Pa s, independent of the time step. In 2D, dev takes tr(D) / 3 (plane flow, D_zz = 0).
* ``muscle_neohooken`` / ``muscle_corotation`` (``MPM.Muscle``): the passive elastic law plus
  an active fibre stress tau_a = k a_g(t) (F f0)(F f0)^T (Genesis's form), f0 the fibre direction
  in the initial configuration, a_g(t) the activation of the particle's group g and k the
  active stiffness [Pa] (default E). Groups are assigned from the initial positions by region;
  activations come from the scene's signals and are uploaded before each substep.
"""

from typing import Any, ClassVar

import numpy as np

from simcli.backend import stdout_to_stderr
from simcli.errors import SceneError
from simcli.solvers.mpm.constitutive import ConstitutiveLaw, CorotatedLaw, NeoHookeanLaw, _np_dtype, law_key

with stdout_to_stderr():
    import taichi as ti


@ti.data_oriented
class LiquidLaw(ConstitutiveLaw):
    """Weakly compressible liquid without viscosity."""

    key = "liquid"
    plastic: ClassVar[bool] = True
    viscous: ClassVar[bool] = False
    J_MIN: ClassVar[float] = 0.01  # floor of the stored volume ratio (a collapsed particle)

    def allocate_materials(self, materials: list) -> None:
        self.n_materials = len(materials)
        arr = np.zeros(max(1, len(materials)), _np_dtype(self.dtype))
        cut = np.zeros(max(1, len(materials)), np.int32)
        for k, m in enumerate(materials):
            if law_key(m) == self.key:
                arr[k] = m.mu if self.viscous else 0.0
                cut[k] = 0 if getattr(m, "tension", True) else 1
        self.viscosity = ti.field(self.dtype, shape=max(1, len(materials)))
        self.viscosity.from_numpy(arr)
        # the tensile cutoff (``tension: false``) is compiled in only where a material asks for it, so a
        # scene without it runs the same kernels as before
        self.any_cutoff = bool(cut.any())
        self.cutoff = ti.field(ti.i32, shape=max(1, len(materials)))
        self.cutoff.from_numpy(cut)

    def bind(self, solver: Any) -> None:
        self.C = solver.C
        self.mid = solver.mid

    @ti.func
    def return_mapping(self, p, F, mid, mu, lam):
        J = ti.max(F.determinant(), self.J_MIN)
        return ti.Matrix.identity(self.dtype, self.dim) * ti.pow(J, 1.0 / self.dim)

    @ti.func
    def viscous_tau(self, p, J):
        """J 2 eta dev(sym C): the viscous Kirchhoff stress, and its zz component (2D)."""
        D = 0.5 * (self.C[p] + self.C[p].transpose())
        eta = self.viscosity[self.mid[p]]
        mean = D.trace() / 3.0
        tau = 2.0 * eta * J * (D - ti.Matrix.identity(self.dtype, self.dim) * mean)
        return tau, -2.0 * eta * J * mean

    @ti.func
    def dilation(self, p, J):
        """J - 1, or min(J - 1, 0) for a material without tension (p = lambda max(1 - J, 0))."""
        d = J - 1.0
        if ti.static(self.any_cutoff):
            if self.cutoff[self.mid[p]] != 0:
                d = ti.min(d, 0.0)
        return d

    @ti.func
    def kirchhoff(self, p, F, J, mu, lam, update: ti.template()):
        tau = ti.Matrix.identity(self.dtype, self.dim) * (lam * J * self.dilation(p, J))
        if ti.static(self.viscous):
            tv, _ = self.viscous_tau(p, J)
            tau += tv
        return tau

    @ti.func
    def tau_zz(self, p, F, J, mu, lam):
        tzz = lam * J * self.dilation(p, J)
        if ti.static(self.viscous):
            _, tv = self.viscous_tau(p, J)
            tzz += tv
        return tzz

    @ti.func
    def energy_density(self, p, F, J, mu, lam):
        return 0.5 * lam * self.dilation(p, J) ** 2


@ti.data_oriented
class ViscousLiquidLaw(LiquidLaw):
    key = "liquid_viscous"
    viscous = True


# ----------------------------------------------------------------------------- muscle


class _MuscleHost:
    """Host side of the muscle laws (mixed into an elastic law): groups, fibres, activations."""

    def _muscle_allocate(self, n: int) -> None:
        self.group = ti.field(ti.i32, shape=n)
        self.fiber = ti.Vector.field(self.dim, self.dtype, shape=n)

    def allocate_materials(self, materials: list) -> None:
        self.n_materials = len(materials)
        npf = _np_dtype(self.dtype)
        self.signals: list = []
        self.group_offset = {}
        stiff = np.zeros(max(1, len(materials)), npf)
        for k, m in enumerate(materials):
            if law_key(m) != self.key:
                continue
            self.group_offset[k] = len(self.signals)
            self.signals += [g.actuation for g in m.group_list()]
            stiff[k] = m.active_stiffness
        self.n_groups = max(1, len(self.signals))
        self.stiffness = ti.field(self.dtype, shape=max(1, len(materials)))
        self.stiffness.from_numpy(stiff)
        self.actuation = ti.field(self.dtype, shape=self.n_groups)
        G = self.n_groups

        @ti.kernel
        def set_actuation(a: ti.types.vector(G, self.dtype)):
            for g in ti.static(range(G)):
                self.actuation[g] = a[g]

        self._set_actuation = set_actuation
        self._last_act = None

    def bind(self, solver: Any) -> None:
        from simcli.geometry.regions import points_in_regions

        self.mid = solver.mid
        dim = self.dim
        n = solver.n
        group = np.full(n, -1, np.int32)
        fiber = np.zeros((n, dim), np.float64)
        fiber[:, -1] = 1.0
        for b, k, lo, hi in zip(solver.bodies, solver.body_mid, solver.offsets[:-1], solver.offsets[1:]):
            m = solver.materials[k]
            if law_key(m) != self.key:
                continue
            default = m.fiber_direction if m.fiber_direction is not None else [0.0] * (dim - 1) + [1.0]
            if len(default) != dim:
                raise SceneError(
                    [
                        (
                            f"entity '{b.name}': material.fiber_direction: needs {dim} components "
                            f"for dim {dim} (got {len(default)})"
                        )
                    ]
                )
            taken = np.zeros(b.n, bool)
            gb = np.full(b.n, -1, np.int32)
            fb = np.zeros((b.n, dim))
            for j, grp in enumerate(m.group_list()):
                d = np.asarray(
                    grp.fiber_direction if grp.fiber_direction is not None else default, np.float64
                )
                if d.shape != (dim,):
                    raise SceneError(
                        [
                            (
                                f"entity '{b.name}': material.groups.{j}.fiber_direction: needs {dim} "
                                f"components for dim {dim} (got {d.size})"
                            )
                        ]
                    )
                regions = grp.regions
                sel = ~taken & (points_in_regions(regions, b.x) if regions else True)
                gb[sel] = self.group_offset[k] + j
                fb[sel] = d / np.linalg.norm(d)
                taken |= sel
            group[lo:hi] = gb
            fiber[lo:hi] = np.where(taken[:, None], fb, fiber[lo:hi])
        self.group.from_numpy(group)
        self.fiber.from_numpy(fiber.astype(_np_dtype(self.dtype)))
        self.group_sizes = np.bincount(group[group >= 0], minlength=self.n_groups)

    def host_update(self, t: float, dt: float) -> None:
        a = [float(sig(t)) for sig in self.signals] + [0.0] * (self.n_groups - len(self.signals))
        if a != self._last_act:  # a constant activation is uploaded once
            self._set_actuation(ti.Vector(a, dt=self.dtype))
            self._last_act = a

    def max_wave_factor(self, materials: list) -> float:
        """1 + k max|a| / (lambda + 2 mu) over this law's materials (bounds of the signals)."""
        worst = 1.0
        for m in materials:
            if law_key(m) != self.key:
                continue
            worst = max(worst, 1.0 + m.active_stiffness * m.max_activation() / (m.lam + 2.0 * m.mu))
        return worst


@ti.data_oriented
class MuscleNeoHookeanLaw(_MuscleHost, NeoHookeanLaw):
    key = "muscle_neohooken"

    def allocate(self, n: int) -> None:
        NeoHookeanLaw.allocate(self, n)
        self._muscle_allocate(n)

    @ti.func
    def kirchhoff(self, p, F, J, mu, lam, update: ti.template()):
        I = ti.Matrix.identity(self.dtype, self.dim)
        tau = mu * (F @ F.transpose() - I) + I * (lam * ti.log(ti.max(J, 1.0e-6)))
        g = self.group[p]
        if g >= 0:
            a = F @ self.fiber[p]
            tau += (self.stiffness[self.mid[p]] * self.actuation[g]) * a.outer_product(a)
        return tau


@ti.data_oriented
class MuscleCorotatedLaw(_MuscleHost, CorotatedLaw):
    key = "muscle_corotation"

    def allocate(self, n: int) -> None:
        CorotatedLaw.allocate(self, n)
        self._muscle_allocate(n)

    @ti.func
    def kirchhoff(self, p, F, J, mu, lam, update: ti.template()):
        R = self.rotation(p, F, update)
        tau = 2.0 * mu * (F - R) @ F.transpose() + ti.Matrix.identity(self.dtype, self.dim) * (
            lam * (J - 1.0) * J
        )
        g = self.group[p]
        if g >= 0:
            a = F @ self.fiber[p]
            tau += (self.stiffness[self.mid[p]] * self.actuation[g]) * a.outer_product(a)
        return tau
