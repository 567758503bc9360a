"""Minimal reader for SPlisHSPlasH's legacy binary (big-endian) particle VTK files."""

import numpy as np


def read_vtk(fn):
    b = open(fn, "rb").read()
    pos = 0
    out = {}

    def line():
        nonlocal pos
        e = b.index(b"\n", pos)
        s = b[pos:e].decode()
        pos = e + 1
        return s

    def arr(count, dt):
        nonlocal pos
        a = np.frombuffer(b, dtype=dt, count=count, offset=pos)
        pos += a.nbytes
        return a

    for _ in range(4):
        line()
    while pos < len(b):
        s = line().strip()
        if not s:
            continue
        t = s.split()
        if t[0] == "POINTS":
            n = int(t[1])
            out["position"] = arr(3 * n, ">f4" if t[2] == "float" else ">f8").reshape(n, 3).astype(float)
        elif t[0] == "CELLS":
            arr(int(t[2]), ">i4")
        elif t[0] == "CELL_TYPES":
            arr(int(t[1]), ">i4")
        elif t[0] == "POINT_DATA":
            n = int(t[1])
        elif t[0] == "SCALARS":
            line()
            out[t[1]] = arr(n, ">u4").astype(int)
        elif t[0] == "FIELD":
            for _ in range(int(t[2])):
                h = line().split()
                while not h:
                    h = line().split()
                name, nc, cnt, typ = h[0], int(h[1]), int(h[2]), h[3]
                dt = {"float": ">f4", "double": ">f8", "unsigned_int": ">u4"}[typ]
                a = arr(nc * cnt, dt).astype(float)
                out[name] = a.reshape(cnt, nc) if nc > 1 else a
    return out
