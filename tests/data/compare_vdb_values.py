"""Compares two OpenVDB files voxel by voxel with pyopenvdb (run by /usr/bin/python3).

    compare_vdb_values.py REFERENCE.vdb OTHER.vdb SPEC_JSON

SPEC_JSON maps grid names to {"bits": null | 4 | 8 | 16, "tolerance": null | float}: null and
null means bit for bit; "bits" checks every active voxel against half the quantum of NanoVDB's
per-leaf quantiser ((max - min) / (2^bits - 1) over the leaf's 512 values, inactive ones at the
background); "tolerance" (FpN) checks against the absolute tolerance or, for leaves that needed
16 bits, half their 16-bit quantum. Every grid of SPEC must be in both files with the same active
voxels. Prints one JSON line per grid and exits 1 on the first failure.
"""
import json
import sys

import numpy as np
import pyopenvdb as vdb


def grids(path):
    return {g.name: g for g in vdb.readAll(path)[0]}


def active(g):
    return {it["min"]: it["value"] for it in g.citerOnValues() if it["count"] == 1}


def leaf_range(acc, origin, bg):
    vals = [
        acc.getValue((origin[0] + x, origin[1] + y, origin[2] + z))
        for x in range(8)
        for y in range(8)
        for z in range(8)
    ]
    a = np.array(vals, dtype=np.float32)
    return a.min(), a.max()


def main():
    ref, other = grids(sys.argv[1]), grids(sys.argv[2])
    spec = json.loads(sys.argv[3])
    for name, rule in spec.items():
        if name not in ref or name not in other:
            print(json.dumps({"grid": name, "error": "missing", "ref": sorted(ref), "other": sorted(other)}))
            return 1
        a, b = active(ref[name]), active(other[name])
        if a.keys() != b.keys():
            print(json.dumps({"grid": name, "error": "active voxels differ", "ref": len(a), "other": len(b)}))
            return 1
        bits, tol = rule.get("bits"), rule.get("tolerance")
        acc = ref[name].getConstAccessor()
        ranges = {}
        worst, bad = 0.0, None
        for ijk, v in a.items():
            w = b[ijk]
            if bits is None and tol is None:
                if np.asarray(v, dtype=np.float32).tobytes() != np.asarray(w, dtype=np.float32).tobytes():
                    bad = {"voxel": ijk, "ref": v, "other": w}
                    break
                continue
            origin = tuple(c & ~7 for c in ijk)
            if origin not in ranges:
                ranges[origin] = leaf_range(acc, origin, ref[name].background)
            lo, hi = ranges[origin]
            err = abs(float(np.float32(w)) - float(np.float32(v)))
            slack = 4.0 * float(np.spacing(max(abs(lo), abs(hi), np.float32(1e-30))))
            q16 = float(np.float32(hi - lo) / np.float32(65535.0))
            if bits is not None:
                bound = float(np.float32(hi - lo) / np.float32(2**bits - 1)) * 0.5 + slack
            else:
                bound = max(tol, q16 * 0.5) + slack
            worst = max(worst, err / bound if bound > 0 else (0.0 if err == 0 else float("inf")))
            if err > bound:
                bad = {"voxel": ijk, "ref": v, "other": w, "err": err, "bound": bound}
                break
        print(json.dumps({"grid": name, "voxels": len(a), "worst_over_bound": worst, "error": bad}))
        if bad is not None:
            return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
