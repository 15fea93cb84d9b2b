#!/usr/bin/env python3
"""Writes VDB targets for control.target.vdb with the real OpenVDB (pyopenvdb, under
/usr/bin/python3; Debian/Ubuntu package python3-openvdb).

    /usr/bin/python3 tools/make_target_vdb.py                    # samples/target_cumulus.vdb
    /usr/bin/python3 tools/make_target_vdb.py --fixtures DIR     # the test fixtures (tests/data/vdb)
    /usr/bin/python3 tools/make_target_vdb.py --from-obj MESH.obj OUT.vdb SX SY SZ TX TY TZ VOXEL
        # a closed OBJ mesh, scaled then translated (metres), as a level set with VOXEL m voxels
        # (OpenVDB's mesh-to-volume, as a DCC's VDB export makes it)

samples/target_cumulus.vdb, the target of pipelines/target_shape_vdb.yaml: a narrow-band level
set (class "level set", grid "surface") of a cumulus made of four overlapping spheres cut flat at
its base, in metres (20 m voxels): x 50-950 m, y 100-600 m (the flat base at 100 m), z 70-530 m;
all in the positive octant, so the file holds one root child (a small file). Built as a DCC does it: signed distances in a band of 3 voxels either side of the
surface (active), then OpenVDB's signedFloodFill gives the inactive voxels and tiles inside the
sign (-background); the interior holds no active value.

The fixtures (tests/vdb_target.rs reads them; small, committed):
  sphere_ls.vdb    openvdb.createLevelSetSphere: radius 6 m, centre (20, 21, 18.5) m, 0.5 m voxels,
                   half width 3 voxels (grid "surface", class level set).
  sphere_fog.vdb   a fog volume of the same sphere (radius 7 m): 0 at the surface rising to 1
                   over 3 voxels inside, as openvdb::tools::sdfToFogVolume makes it; pruned, so
                   the interior is active 8^3 tiles of 1. Grid "density" (class fog volume), after
                   a bool grid "mask" (a type nimbus skips) and a vec3 grid "vel".
  box_tiles.vdb    grid "density" (no class): a box of active value 2, (0, 0, 8) to (263, 135,
                   255), so whole 128^3 and 8^3 tiles (no leaf), an active root tile (4096^3) of 3
                   from (4096, 4096, 4096), and an inactive 128^3 tile of 5 at (1024, 0, 0).
  vec3_only.vdb    only a vec3 grid "vel" (no float grid: not a usable target).
"""
import math
import os
import sys

import numpy as np
import pyopenvdb as vdb

HALF_WIDTH = 3  # voxels each side of the surface, OpenVDB's default (LEVEL_SET_HALF_WIDTH)

# the cumulus: (centre x, y, z, radius) in metres; base cut at y = 0
CUMULUS = [
    (500.0, 280.0, 300.0, 250.0),
    (230.0, 230.0, 340.0, 180.0),
    (750.0, 250.0, 270.0, 200.0),
    (540.0, 480.0, 320.0, 120.0),
]
CUMULUS_BASE = 100.0
CUMULUS_VOXEL = 20.0
SPHERE_CENTER = (20.0, 21.0, 18.5)


def cumulus():
    vs = CUMULUS_VOXEL
    bg = HALF_WIDTH * vs
    lo = np.array([0.0, 0.0, 0.0])
    hi = np.array([1000.0, 680.0, 600.0])
    n = np.round((hi - lo) / vs).astype(int) + 1
    i0 = np.round(lo / vs).astype(int)
    idx = np.indices(n).astype(np.float64)
    p = [(idx[a] + i0[a]) * vs for a in range(3)]
    d = np.full(tuple(n), np.inf)
    for cx, cy, cz, r in CUMULUS:
        d = np.minimum(d, np.sqrt((p[0] - cx) ** 2 + (p[1] - cy) ** 2 + (p[2] - cz) ** 2) - r)
    d = np.maximum(d, CUMULUS_BASE - p[1])  # cut flat at the base
    # the narrow band only: everything else the background, then the flood fill signs it
    band = np.where(np.abs(d) < bg, d, bg).astype(np.float32)
    g = vdb.FloatGrid(bg)
    g.copyFromArray(band, ijk=tuple(int(x) for x in i0), tolerance=0)
    g.signedFloodFill()
    g.prune()
    g.transform = vdb.createLinearTransform(voxelSize=vs)
    g.gridClass = vdb.GridClass.LEVEL_SET
    g.name = "surface"
    return g


def sphere_fog(radius, center, vs):
    """Fog of a sphere: 0 at the surface, 1 from HALF_WIDTH voxels inside (sdfToFogVolume)."""
    c = [x / vs for x in center]  # index space (the transform has no translation)
    r = radius / vs
    m = int(math.ceil(r)) + 2
    i0 = [int(math.floor(c[a])) - m for a in range(3)]
    n = 2 * m + 2
    idx = np.indices((n, n, n)).astype(np.float64)
    dist = np.sqrt(sum((idx[a] + i0[a] - c[a]) ** 2 for a in range(3)))
    fog = np.clip((r - dist) / HALF_WIDTH, 0.0, 1.0).astype(np.float32)
    g = vdb.FloatGrid(0.0)
    g.copyFromArray(fog, ijk=tuple(i0), tolerance=0)
    g.prune()  # constant interior leaves become active tiles
    g.transform = vdb.createLinearTransform(voxelSize=vs)
    g.gridClass = vdb.GridClass.FOG_VOLUME
    g.name = "density"
    return g


def fixtures(out):
    os.makedirs(out, exist_ok=True)
    ls = vdb.createLevelSetSphere(radius=6.0, center=SPHERE_CENTER, voxelSize=0.5,
                                  halfWidth=HALF_WIDTH)
    ls.name = "surface"
    vdb.write(os.path.join(out, "sphere_ls.vdb"), grids=[ls])

    fog = sphere_fog(7.0, SPHERE_CENTER, 0.5)
    mask = vdb.BoolGrid(False)
    mask.fill((0, 0, 0), (9, 9, 9), True)
    mask.name = "mask"
    vel = vdb.Vec3SGrid()
    vel.fill((0, 0, 0), (15, 3, 3), (1.0, 0.0, 0.0))
    vel.name = "vel"
    vdb.write(os.path.join(out, "sphere_fog.vdb"), grids=[mask, vel, fog])

    box = vdb.FloatGrid(0.0)
    box.fill((0, 0, 8), (263, 135, 255), 2.0, True)
    box.fill((4096, 4096, 4096), (8191, 8191, 8191), 3.0, True)
    box.fill((1024, 0, 0), (1151, 127, 127), 5.0, False)
    box.name = "density"
    vdb.write(os.path.join(out, "box_tiles.vdb"), grids=[box])

    only = vdb.Vec3SGrid()
    only.fill((0, 0, 0), (7, 7, 7), (0.0, 1.0, 0.0))
    only.name = "vel"
    vdb.write(os.path.join(out, "vec3_only.vdb"), grids=[only])
    for name in sorted(os.listdir(out)):
        print(f"{os.path.join(out, name)}: {os.path.getsize(os.path.join(out, name))} bytes")


def from_obj(path, scale, translate, vs):
    """A closed OBJ mesh (v and f lines; polygons split into fans) as a narrow-band level set."""
    points, tris = [], []
    with open(path) as f:
        for line in f:
            w = line.split()
            if not w:
                continue
            if w[0] == "v":
                points.append([float(w[1 + a]) * scale[a] + translate[a] for a in range(3)])
            elif w[0] == "f":
                idx = [int(t.split("/")[0]) - 1 for t in w[1:]]
                tris += [[idx[0], idx[k], idx[k + 1]] for k in range(1, len(idx) - 1)]
    g = vdb.FloatGrid.createLevelSetFromPolygons(
        np.array(points, dtype=np.float32),
        triangles=np.array(tris, dtype=np.int32),
        transform=vdb.createLinearTransform(voxelSize=vs),
        halfWidth=HALF_WIDTH,
    )
    g.name = "surface"
    return g


def main():
    if len(sys.argv) == 11 and sys.argv[1] == "--from-obj":
        nums = [float(x) for x in sys.argv[4:]]
        g = from_obj(sys.argv[2], nums[0:3], nums[3:6], nums[6])
        out = sys.argv[3]
        vdb.write(out, grids=[g], metadata={"creator": "tools/make_target_vdb.py --from-obj"})
        print(f"{out}: {os.path.getsize(out)} bytes, {g.activeVoxelCount()} active voxels")
        return
    if len(sys.argv) == 3 and sys.argv[1] == "--fixtures":
        fixtures(sys.argv[2])
        return
    if len(sys.argv) > 2:
        raise SystemExit(__doc__)
    out = sys.argv[1] if len(sys.argv) == 2 else "samples/target_cumulus.vdb"
    g = cumulus()
    g.addStatsMetadata()
    vdb.write(out, grids=[g], metadata={"creator": "tools/make_target_vdb.py (public domain)"})
    print(f"{out}: {os.path.getsize(out)} bytes, {g.activeVoxelCount()} active voxels, "
          f"{g.leafCount()} leaves")


if __name__ == "__main__":
    main()
