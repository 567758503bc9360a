"""Cook's membrane (configs/validation/fem_cook.yaml) as a one-layer tetrahedral slab, lengths in m: the
trapezoid (0,0), (48,44), (48,60), (0,44) mm, 1 mm thick along z, n elements per edge, each hexahedron split
into 6 tetrahedra (Kuhn split, conforming). Usage: python make_cook_membrane.py 32 cook_membrane_32.msh"""

import itertools
import sys

import meshio
import numpy as np


def cook_membrane(n: int) -> tuple[np.ndarray, np.ndarray]:
    xi = np.linspace(0, 1, n + 1)

    def idx(i, j, k):
        return (i * (n + 1) + j) * 2 + k

    pts = []
    for i in range(n + 1):
        for j in range(n + 1):
            for k in range(2):
                s, t = xi[i], xi[j]
                yb, yt = 44.0 * s, 44.0 + 16.0 * s
                pts.append([48.0 * s * 1e-3, (yb + t * (yt - yb)) * 1e-3, k * 1e-3])
    pts = np.array(pts)
    tets = []
    for i in range(n):
        for j in range(n):
            for perm in itertools.permutations(range(3)):
                c = [0, 0, 0]
                v = [idx(i, j, 0)]
                for ax in perm:
                    c[ax] += 1
                    v.append(idx(i + c[0], j + c[1], c[2]))
                a, b, cc, d = pts[v]
                if np.linalg.det(np.array([b - a, cc - a, d - a])) < 0:
                    v[2], v[3] = v[3], v[2]
                tets.append(v)
    return pts, np.array(tets)


if __name__ == "__main__":
    pts, tets = cook_membrane(int(sys.argv[1]))
    meshio.write(sys.argv[2], meshio.Mesh(pts, [("tetra", tets)]), binary=True)
    print(len(pts), "vertices", len(tets), "tets")
