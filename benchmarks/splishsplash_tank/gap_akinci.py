# Akinci2012 (single boundary line, spacing 0.2/46 as sampled by SPlisHSPlasH) equilibrium gap for a lattice
# stretched by sy in y: density of the row/column next to the wall = rho0
import numpy as np

H = 0.01
k = 40 / (7 * np.pi * H * H)
d = 0.005
sy = 1.0008514038524843


def W(r):
    q = r / H
    return k * np.where(q <= 0.5, 6 * q**3 - 6 * q**2 + 1, np.where(q <= 1, 2 * (1 - q) ** 3, 0))


sb = 0.2 / 46
bx = np.arange(-60, 61) * sb


def wall_rho(g, dn, dt):  # dn: lattice spacing normal to the wall, dt: tangential
    B = np.c_[bx, np.zeros_like(bx)]
    Vb = 1 / W(np.linalg.norm(B[60] - B, axis=1)).sum()
    F = np.array([(i * dt, g + j * dn) for j in range(6) for i in range(-10, 11)])
    P = np.array([0.0, g])
    return (
        1000 * d * d * W(np.linalg.norm(F - P, axis=1)).sum()
        + 1000 * Vb * W(np.linalg.norm(B - P, axis=1)).sum()
    )


for name, dn, dt in [("floor", d * sy, d), ("side", d, d * sy)]:
    lo, hi = 0.004, 0.008
    for _ in range(50):
        m = (lo + hi) / 2
        if wall_rho(m, dn, dt) > 1000:
            lo = m
        else:
            hi = m
    print(name, "gap", m)
