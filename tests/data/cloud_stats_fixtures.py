#!/usr/bin/python3
"""Writes the synthetic runs tests/cloud_stats.rs gives tools/cloud_stats.py: OUT/squares and
OUT/lines (nimbus run directories with real OpenVDB files) and OUT/microhh (a MicroHH run
directory: ini, grid file, ql dumps, statistics netCDF, ql_path cross-sections).

nimbus runs: 800 x 3000 x 800 m at 40 m voxels (20 x 75 x 20), so the levels are MicroHH's
BOMEX levels (20, 60, ... 2980 m). Frames 1-4 at 0, 60, 120, 180 s; frame 1 is outside the
test's window (60-180 s) and is cloudy everywhere. Clouds fill levels 3-6 (140-260 m) with
ql = 1e-3 kg/kg; level 0 holds a haze of ql = 5e-6 kg/kg in every column (below the 1e-5
threshold: water, not cloud).
  squares: frames 2-4 hold squares of 2, 3, 4, 5 columns a side (the 5 wraps across x = 0);
           frame 4 adds a second 2 x 2.
  lines:   frames 2-4 hold lines one column wide of 4, 8, 12, 16 columns.
MicroHH run: 20 x 16 x 12 cells of 100 x 100 x 40 m, dumps at 0, 60, 120 s (0 outside the
window); a 3 x 2 and a 2 x 2 cloud (the latter wraps across y = 0) on levels 2-4 with
ql = 1e-3 (1 + i/10) at column i; density 1.1 - 1e-4 z.
"""
import json
import os
import sys

import numpy as np
import pyopenvdb as vdb

VS, NX, NL, NZ = 40.0, 20, 75, 20
QL, HAZE = 1e-3, 5e-6


def squares(frame):
    cells = []
    for size, x0, z0 in ((2, 1, 1), (3, 5, 1), (4, 10, 1), (5, 18, 10)):
        cells += [((x0 + i) % NX, z0 + k) for i in range(size) for k in range(size)]
    if frame == 4:
        cells += [(10 + i, 10 + k) for i in range(2) for k in range(2)]
    return cells


def lines(frame):
    return [(i, row) for n, row in ((4, 1), (8, 4), (12, 7), (16, 10)) for i in range(n)]


def nimbus_run(out, shot, clouds):
    os.makedirs(os.path.join(out, "vdb"))
    frames, stats = [], []
    for frame in range(1, 5):
        field = np.zeros((NX, NL, NZ), np.float32)  # nimbus axes: x, up, z
        if frame == 1:
            field[:] = QL
        else:
            field[:, 0, :] = HAZE
            for x, z in clouds(frame):
                field[x, 3:7, z] = QL
        grid = vdb.FloatGrid()
        grid.copyFromArray(field * 1000.0)  # export.density_scale
        grid.name = "density"
        grid.transform = vdb.createLinearTransform(voxelSize=VS)
        grid.transform.translate((VS / 2, VS / 2, VS / 2))
        rel = f"vdb/{shot}.{frame:04d}.vdb"
        vdb.write(os.path.join(out, rel), grids=[grid])
        frames.append({"frame": frame, "files": [{"path": rel}]})
        stats.append({"frame": frame, "sim_time": 60.0 * (frame - 1)})
    manifest = {
        "shot": shot, "voxel_size": VS, "grid_origin": [VS / 2] * 3, "frames": frames,
        "export": {"scale": 1.0, "up_axis": "y", "frame_seconds": 60.0},
        "config": {"domain": {"size": [NX * VS, NL * VS, NZ * VS]},
                   "export": {"density_scale": 1000.0, "grids": {"density": "density"}}},
    }
    json.dump(manifest, open(os.path.join(out, "manifest.json"), "w"))
    with open(os.path.join(out, "stats.jsonl"), "w") as f:
        for s in stats:
            f.write(json.dumps(s) + "\n")


def microhh_run(out):
    import netCDF4

    it, jt, kt, dx, dz = 20, 16, 12, 100.0, 40.0
    os.makedirs(out)
    with open(os.path.join(out, "bomex.ini"), "w") as f:
        f.write(f"[master]\nnpx=1\n\n[grid]\nitot={it}\njtot={jt}\nktot={kt}\n"
                f"xsize={it * dx}\nysize={jt * dx}\nzsize={kt * dz}\n# a comment\n")
    x = (np.arange(it) + 0.5) * dx
    y = (np.arange(jt) + 0.5) * dx
    z = (np.arange(kt) + 0.5) * dz
    np.concatenate([x, x - dx / 2, y, y - dx / 2, z, z - dz / 2]).astype("<f8").tofile(
        os.path.join(out, "grid.0000000"))
    rho = 1.1 - 1e-4 * z
    times = [0, 60, 120]
    for t in times:
        ql = np.zeros((kt, jt, it))  # MicroHH's layout: z, y, x (x fastest)
        if t == 0:
            ql[:] = QL
        else:
            for i, j in [(i, j) for i in (2, 3, 4) for j in (5, 6)] + \
                        [(i, j) for i in (10, 11) for j in (15, 0)]:
                ql[2:5, j, i] = QL * (1 + i / 10)
        ql.astype("<f8").tofile(os.path.join(out, f"ql.{t:07d}"))
        path = (ql * (rho * dz)[:, None, None]).sum(axis=0)
        path.astype("<f8").tofile(os.path.join(out, f"ql_path.xy.000.{t:07d}"))
    with netCDF4.Dataset(os.path.join(out, "bomex.default.0000000.nc"), "w") as nc:
        nc.createDimension("z", kt)
        nc.createDimension("zh", kt + 1)
        nc.createDimension("time", None)
        nc.createVariable("z", "f8", ("z",))[:] = z
        nc.createVariable("zh", "f8", ("zh",))[:] = np.arange(kt + 1) * dz
        nc.createVariable("time", "f8", ("time",))[:] = times
        nc.createGroup("default").createVariable("rhoref", "f8", ("z",))[:] = rho


if __name__ == "__main__":
    out = sys.argv[1]
    nimbus_run(os.path.join(out, "squares"), "squares", squares)
    nimbus_run(os.path.join(out, "lines"), "lines", lines)
    microhh_run(os.path.join(out, "microhh"))
