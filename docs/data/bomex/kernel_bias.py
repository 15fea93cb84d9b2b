#!/usr/bin/python3
"""What nimbus's export kernel does to a cloud field, measured on the LES's own field.

    /usr/bin/python3 docs/data/bomex/kernel_bias.py MICROHH_RUN_DIR

A one-off measurement (issue 39), like the MicroHH runs themselves: it reads the restart files
(thl.NNNNNNN, qt.NNNNNNN, every 1800 s) of MicroHH's BOMEX run at 64 x 64 x 75, hours 3-6 (7
snapshots), and measures the cloud statistics of tools/cloud_stats.py twice:
- raw: the LES's cloud water on its own grid (saturation adjustment of theta_l and q_t on the
  hydrostatic pressure of the initial state, Tetens' saturation);
- through nimbus's kernel: the same field sampled by particles on nimbus's 100 m lattice (each
  LES column at the particle heights 50, 150, ... m) and splatted as `export` does for
  `pipelines/bomex.yaml`: an SPH sum of ql_j V_j W(x - x_j, h) with the poly6 kernel, h = 200 m
  (kernel_ratio 2), V_j = 100^3 m^3, on 50 m voxels.
The difference is what the export alone adds to nimbus's statistics measured from its voxels.
"""
import math
import os
import sys

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "..", "tools"))
import cloud_stats as cs  # noqa: E402

run = sys.argv[1]
itot = jtot = 64
ktot = 75
gr = np.fromfile(os.path.join(run, "grid.0000000"), "<f8")
z = gr[2 * itot + 2 * jtot:2 * itot + 2 * jtot + ktot]
p = cs.bomex_pressure(z)  # the initial state's, from 1015 hPa, as the tool's air density
exner = (p / cs.P00) ** (cs.RD / cs.CP)
LV, EP = 2.5e6, cs.RD / 461.5


def qsat(t):
    es = 610.78 * np.exp(17.27 * (t - 273.16) / (t - 35.86))
    return EP * es / (p - (1 - EP) * es)


def cloud_water(thl, qt):
    """Saturation adjustment: T = theta_l exner + L/c_p ql, ql = max(qt - qsat(T), 0), Newton."""
    ql = np.zeros_like(qt)
    for _ in range(20):
        t = thl * exner + LV / cs.CP * ql
        dq = qsat(t) * 17.27 * (273.16 - 35.86) / (t - 35.86) ** 2
        ql = np.maximum(ql + (qt - qsat(t) - ql) / (1 + LV / cs.CP * dq), 0.0)
    return ql


h, vol = 200.0, 100.0 ** 3
c6 = 315.0 / (64 * math.pi * h ** 9)
zp = 50.0 + 100.0 * np.arange(30)  # particle layers
zv = 25.0 + 50.0 * np.arange(60)  # voxel centres
raw = cs.Accumulator(z, np.full(ktot, 40.0), cs.bomex_air_density(z), 100.0, 100.0, 1e-5)
splat = cs.Accumulator(zv, np.full(60, 50.0), cs.bomex_air_density(zv), 50.0, 50.0, 1e-5)
for t in range(10800, 21601, 1800):
    read = lambda name: np.fromfile(os.path.join(run, f"{name}.{t:07d}"), "<f8").reshape(
        ktot, jtot, itot).transpose(2, 1, 0)
    ql = cloud_water(read("thl"), read("qt"))
    raw.add(t, ql)
    qp = np.stack([np.interp(zp, z, ql[i, j]) for i in range(itot) for j in range(jtot)])
    qp = qp.reshape(itot, jtot, 30)
    dens = np.zeros((2 * itot, 2 * jtot, 60))
    # voxel (2 a + pa) has its centre at 25 + 50 pa - 50 - 100 di from particle a - di
    for pa in (0, 1):
        for pb in (0, 1):
            sub = np.zeros((itot, jtot, 60))
            for di in range(-3, 4):
                for dj in range(-3, 4):
                    ox, oy = 25 + 50 * pa - 50 - 100 * di, 25 + 50 * pb - 50 - 100 * dj
                    if ox * ox + oy * oy >= h * h:
                        continue
                    rolled = np.roll(np.roll(qp, di, 0), dj, 1)
                    for k in range(30):
                        r2 = ox * ox + oy * oy + (zv - zp[k]) ** 2
                        w = np.where(r2 < h * h, c6 * (h * h - r2) ** 3, 0.0) * vol
                        sub += rolled[:, :, k:k + 1] * w[None, None, :]
            dens[pa::2, pb::2, :] = sub
    splat.add(t, dens)
keys = ["cloud_base", "cloud_top", "cf_max", "cf_max_height", "cover", "lwp", "lwc_in_cloud",
        "fractal_dimension", "clouds_per_snapshot"]
print("statistic".ljust(22) + "raw".rjust(12) + "through the kernel".rjust(20))
sums = []
for name, acc in (("raw", raw), ("through the kernel", splat)):
    rec = acc.record({"path": run}, (10800, 21600), None)
    sums.append(cs.summarize(rec, 1e-3, 40000.0, None, 24)[0])
for k in keys:
    print(k.ljust(22) + "".join(f"{s[k]:.4g}".rjust(w) for s, w in zip(sums, (12, 20))))
print(f"D rests on {sums[0]['fractal']['clouds']} and {sums[1]['fractal']['clouds']} clouds")
