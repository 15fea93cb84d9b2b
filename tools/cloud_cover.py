#!/usr/bin/python3
"""Cloud cover and separate clouds of nimbus density VDBs (docs/PHYSICS.md "Paper example 1").

Usage: /usr/bin/python3 tools/cloud_cover.py [--domain X,Y,Z] [--threshold F] FILE.vdb...

For each file: the column path of the `density` grid over the ground (x/z), the cover (the
fraction of columns above F times the largest column, default 0.02), the periodic connected
components in x/z, how many hold at least 2% of the cloud, the largest ones (columns, share of
the cloud), and the heights between which the cloud's row profile is above 2% of its peak.
Needs pyopenvdb (Debian python3-openvdb, only under /usr/bin/python3).
"""
import argparse
from collections import deque

import numpy as np
import pyopenvdb as vdb


def column_path(path, domain):
    grid = vdb.read(path, "density")
    (x0, y0, z0), (x1, y1, z1) = grid.evalActiveVoxelBoundingBox()
    if x1 < x0:
        return None
    a = np.zeros((x1 - x0 + 1, y1 - y0 + 1, z1 - z0 + 1), np.float32)
    grid.copyToArray(a, ijk=(x0, y0, z0))
    vs = grid.transform.voxelSize()[0]
    nx, nz = int(round(domain[0] / vs)), int(round(domain[2] / vs))
    col = np.zeros((nx, nz))
    sums = a.sum(axis=1) * vs
    for i in range(a.shape[0]):
        for k in range(a.shape[2]):
            col[(i + x0) % nx, (k + z0) % nz] += sums[i, k]
    prof = a.sum(axis=(0, 2))
    ys = (np.arange(a.shape[1]) + y0 + 0.5) * vs
    heights = ys[prof > 0.02 * prof.max()]
    return col, (heights.min(), heights.max())


def components(mask, col):
    nx, nz = mask.shape
    label = -np.ones(mask.shape, int)
    out = []
    for i in range(nx):
        for k in range(nz):
            if not mask[i, k] or label[i, k] >= 0:
                continue
            label[i, k] = len(out)
            queue, size, mass = deque([(i, k)]), 0, 0.0
            while queue:
                u, v = queue.popleft()
                size += 1
                mass += col[u, v]
                for du, dv in ((1, 0), (-1, 0), (0, 1), (0, -1)):
                    p, q = (u + du) % nx, (v + dv) % nz
                    if mask[p, q] and label[p, q] < 0:
                        label[p, q] = len(out)
                        queue.append((p, q))
            out.append((size, mass))
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("files", nargs="+")
    ap.add_argument("--domain", default="3200,1600,3200", help="domain size x,y,z (m)")
    ap.add_argument("--threshold", type=float, default=0.02)
    args = ap.parse_args()
    domain = [float(v) for v in args.domain.split(",")]
    for path in args.files:
        r = column_path(path, domain)
        if r is None:
            print(f"{path}: no cloud")
            continue
        col, (lo, hi) = r
        mask = col > args.threshold * col.max()
        comps = sorted(components(mask, col), key=lambda c: -c[1])
        total = sum(m for _, m in comps)
        big = sum(1 for _, m in comps if m >= 0.02 * total)
        largest = ", ".join(f"{s} cols {m / total:.2f}" for s, m in comps[:4])
        print(
            f"{path}: cover {mask.mean():.3f}, {len(comps)} components, {big} with >= 2% "
            f"of the cloud ({largest}), cloud {lo:.0f}-{hi:.0f} m"
        )


if __name__ == "__main__":
    main()
