# 2D cubic-kernel lattice sum (support H = 4r = 2 spacings), V = d^2: find the y-stretch sy giving sum V W = 1
import numpy as np

H = 0.01
k = 40 / (7 * np.pi * H * H)
d = 0.005


def W(r):
    q = r / H
    return k * np.where(q <= 0.5, 6 * q**3 - 6 * q**2 + 1, np.where(q <= 1, 2 * (1 - q) ** 3, 0))


def lsum(sx, sy):
    i = np.arange(-4, 5)
    X, Y = np.meshgrid(i * d * sx, i * d * sy)
    return d * d * W(np.hypot(X, Y)).sum()


print("unscaled", lsum(1, 1))
lo, hi = 1.0, 1.01
for _ in range(60):
    m = (lo + hi) / 2
    if lsum(1, m) > 1:
        lo = m
    else:
        hi = m
print("sy", m, lsum(1, m))
lo, hi = 1.0, 1.01
for _ in range(60):
    m2 = (lo + hi) / 2
    if lsum(m2, m2) > 1:
        lo = m2
    else:
        hi = m2
print("isotropic s", m2)
