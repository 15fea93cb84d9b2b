#!/usr/bin/python3
"""Times OpenVDB's own writer (pyopenvdb.write, OpenVDB 10) on a grid read from a .vdb file.

Usage: /usr/bin/python3 tools/bench_openvdb.py IN.vdb OUT.vdb REPS
Reads every grid of IN.vdb, then writes them REPS times to OUT.vdb with pyopenvdb's default
codec (blosc + active mask: the only one pyopenvdb exposes) and prints one JSON line:
{"library": "10.0.1", "write_ms": [...], "bytes": size of OUT.vdb, "active_voxels": n}.
Run it with the system interpreter (/usr/bin/python3): that is where pyopenvdb lives.
"""
import json
import os
import sys
import time

import pyopenvdb as vdb


def main():
    src, dst, reps = sys.argv[1], sys.argv[2], int(sys.argv[3])
    grids, _meta = vdb.readAll(src)
    times = []
    for _ in range(reps):
        t = time.perf_counter()
        vdb.write(dst, grids=grids)
        times.append((time.perf_counter() - t) * 1000.0)
    print(json.dumps({
        "library": ".".join(str(v) for v in vdb.LIBRARY_VERSION),
        "write_ms": times,
        "bytes": os.path.getsize(dst),
        "active_voxels": sum(g.activeVoxelCount() for g in grids),
    }))


if __name__ == "__main__":
    main()
