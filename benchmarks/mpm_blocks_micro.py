#!/usr/bin/env python3
"""Where MPM's grid work goes when the material is spread out: the box sweep, the block list (what
simcli/solvers/mpm/blocks.py does) and Taichi's own sparse SNodes (bitmasked, pointer), on C2's grid.

    PYTHONPATH=. python benchmarks/mpm_blocks_micro.py [--threads 2] [--substeps 200] [--clusters 30]

Each variant runs the same stand-in substep on a grid of C2's shape (44 x 135 x 167 nodes, 4 channels:
momentum and mass): clear, a P2G scatter of the particles' 27-node stencils (atomic adds), and a node pass
(momentum / mass + gravity) over the nodes the variant visits. The particles (6,510, C2's late window)
sit in ``--clusters`` balls of 3 cm scattered over the domain (the sand flung by the wheels), or in one
ball (``--clusters 1``: a compact body, B1-like). Prints ms per substep and nodes visited.

* ``box``: dense field; clear and node pass over the particles' bounding box (simcli before blocks.py);
* ``blocks``: dense field; zero the last substep's blocks, mark the blocks the stencils touch, compact
  them with an atomic counter, node pass over the list (blocks.py);
* ``bitmasked`` / ``pointer``: ``ti.root.<kind>(ijk, blocks).dense(ijk, 4)``; P2G activates the blocks
  it writes, the node pass is a struct-for over the active cells, the clear ``deactivate_all``.
"""

import argparse
import time

import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--substeps", type=int, default=200)
    ap.add_argument("--clusters", type=int, default=30)
    ap.add_argument("--n", type=int, default=6510)
    ap.add_argument("--variants", default="box,blocks,bitmasked,pointer")
    args = ap.parse_args()

    import taichi as ti

    ti.init(arch=ti.cpu, cpu_max_num_threads=args.threads, default_fp=ti.f32, offline_cache=False)
    shape = (44, 135, 167)
    E = 4
    bshape = tuple(-(-s // E) for s in shape)
    rng = np.random.default_rng(1)
    lo, hi = np.array([3.5, 3.5, 3.5]), np.array(shape) - 4.5
    centres = lo + rng.random((args.clusters, 3)) * (hi - lo)
    k = rng.integers(0, args.clusters, args.n)
    pts = centres[k] + rng.normal(0.0, 0.03 * 64 / 2, (args.n, 3))  # 3 cm balls at 64 nodes per metre
    pts = np.clip(pts, lo, hi).astype(np.float32)
    n = args.n
    x = ti.Vector.field(3, ti.f32, shape=n)
    x.from_numpy(pts)
    box = ti.Vector.field(3, ti.i32, shape=2)
    b0 = np.floor(pts - 0.5).astype(np.int32)
    box.from_numpy(np.stack([b0.min(axis=0), b0.max(axis=0) + 3]))
    box_nodes = int(np.prod(b0.max(axis=0) + 3 - b0.min(axis=0)))
    results = {}

    def scatter(g):
        @ti.func
        def p2g():
            for p in range(n):
                Xp = x[p]
                base = ti.cast(Xp - 0.5, ti.i32)
                fx = Xp - ti.cast(base, ti.f32)
                w = [0.5 * (1.5 - fx) ** 2, 0.75 - (fx - 1.0) ** 2, 0.5 * (fx - 0.5) ** 2]
                for i, j, kk in ti.static(ti.ndrange(3, 3, 3)):
                    wt = w[i][0] * w[j][1] * w[kk][2]
                    g[base + ti.Vector([i, j, kk])] += wt * ti.Vector([1.0, 0.5, -0.5, 1.0])

        return p2g

    @ti.func
    def update(g, I):
        c = g[I]
        if c[3] > 0:
            v = ti.Vector([c[0], c[1], c[2]]) / c[3] + ti.Vector([0.0, 0.0, -9.81e-4])
            g[I] = ti.Vector([v[0], v[1], v[2], c[3]])

    def timeit(name, step, visited):
        step()
        ti.sync()
        t0 = time.perf_counter()
        for _ in range(args.substeps):
            step()
        ti.sync()
        results[name] = (1e3 * (time.perf_counter() - t0) / args.substeps, visited)
        print(f"{name:10s} {results[name][0]:8.3f} ms/substep, {visited:,} nodes visited", flush=True)

    variants = args.variants.split(",")
    if "box" in variants:
        g = ti.Vector.field(4, ti.f32, shape=shape)
        p2g = scatter(g)

        @ti.kernel
        def step_box():
            a, b = box[0], box[1]
            for i, j, kk in ti.ndrange((a[0], b[0]), (a[1], b[1]), (a[2], b[2])):
                g[i, j, kk] = ti.Vector.zero(ti.f32, 4)
            p2g()
            for i, j, kk in ti.ndrange((a[0], b[0]), (a[1], b[1]), (a[2], b[2])):
                update(g, ti.Vector([i, j, kk]))

        timeit("box", step_box, box_nodes)

    if "blocks" in variants:
        g = ti.Vector.field(4, ti.f32, shape=shape)
        flag = ti.field(ti.i32, shape=bshape)
        lst = ti.Vector.field(3, ti.i32, shape=int(np.prod(bshape)))
        cnt = ti.field(ti.i32, shape=())
        p2g = scatter(g)
        BS = E**3

        @ti.func
        def node(q):
            b = lst[q // BS]
            r = q % BS
            I = b * E + ti.Vector([r // (E * E), (r // E) % E, r % E])
            return I, I[0] < shape[0] and I[1] < shape[1] and I[2] < shape[2]

        @ti.kernel
        def step_blocks():
            for q in range(cnt[None] * BS):
                I, ok = node(q)
                if ok:
                    g[I] = ti.Vector.zero(ti.f32, 4)
                if q % BS == 0:
                    flag[lst[q // BS]] = 0
            cnt[None] = 0
            for p in range(n):
                lo_ = ti.cast(x[p] - 0.5, ti.i32)
                hi_ = (lo_ + 2) // E
                lo_ = lo_ // E
                for c in ti.static(range(8)):
                    b = lo_
                    for d in ti.static(range(3)):
                        if ti.static((c >> d) & 1):
                            b[d] = hi_[d]
                    flag[b] = 1
            for b in ti.grouped(flag):
                if flag[b] != 0:
                    lst[ti.atomic_add(cnt[None], 1)] = b
            p2g()
            for q in range(cnt[None] * BS):
                I, ok = node(q)
                if ok:
                    update(g, I)

        step_blocks()
        timeit("blocks", step_blocks, int(cnt[None]) * BS)

    for kind in ("bitmasked", "pointer"):
        if kind not in variants:
            continue
        g = ti.Vector.field(4, ti.f32)
        blk = getattr(ti.root, kind)(ti.ijk, bshape)
        blk.dense(ti.ijk, E).place(g)
        p2g = scatter(g)

        @ti.kernel
        def p2g_update():
            p2g()
            for I in ti.grouped(g):
                update(g, I)

        @ti.kernel
        def count_active() -> ti.i32:
            c = 0
            for _ in ti.grouped(g):
                c += 1
            return c

        def step_sparse(blk=blk, p2g_update=p2g_update):
            blk.deactivate_all()
            p2g_update()

        step_sparse()
        timeit(kind, step_sparse, int(count_active()))


if __name__ == "__main__":
    main()
