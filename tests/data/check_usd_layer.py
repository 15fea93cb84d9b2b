"""Checks a nimbus USD layer with USD itself (pxr, PyPI usd-core) and the VDB files it points at
with pyopenvdb; run by the venv tools/setup.sh makes (Debian's python3 with its system packages).

    check_usd_layer.py LAYER.usda MANIFEST.json

The stage opens and passes USD's compliance checker; its default prim is a Volume; the stage
metadata (metersPerUnit, upAxis, timeCodesPerSecond, framesPerSecond, start and end time codes)
is the manifest's; every field is an OpenVDBAsset whose filePath has one time sample per frame
the manifest records, each resolving to that frame's VDB file, which holds a grid named
fieldName of type fieldDataType; every grid of the VDB files has a field. Prints a JSON summary;
exits 1 with the reason on the first failure.
"""
import json
import os
import sys

import pyopenvdb
from pxr import Usd, UsdGeom, UsdUtils, UsdVol

TYPES = {"float": "float", "vec3s": "float3"}


def fail(msg):
    print(json.dumps({"ok": False, "error": msg}))
    sys.exit(1)


def main():
    layer, manifest_path = sys.argv[1], sys.argv[2]
    m = json.load(open(manifest_path))
    run_dir = os.path.dirname(os.path.abspath(manifest_path))
    frames = {f["frame"]: next(r["path"] for r in f["files"] if r["path"].endswith(".vdb")) for f in m["frames"]}
    stage = Usd.Stage.Open(layer)
    if stage is None:
        fail("the stage does not open")
    checker = UsdUtils.ComplianceChecker(arkit=False, skipARKitRootLayerCheck=False, rootPackageOnly=False, skipVariants=False, verbose=False)
    checker.CheckCompliance(layer)
    if checker.GetErrors() or checker.GetFailedChecks():
        fail(f"compliance: {checker.GetErrors()} {checker.GetFailedChecks()}")

    e = m["export"]
    want = {
        "metersPerUnit": e["scale"],
        "upAxis": e["up_axis"].upper(),
        "timeCodesPerSecond": m["fps"],
        "framesPerSecond": m["fps"],
        "startTimeCode": min(frames),
        "endTimeCode": max(frames),
    }
    got = {
        "metersPerUnit": UsdGeom.GetStageMetersPerUnit(stage),
        "upAxis": UsdGeom.GetStageUpAxis(stage),
        "timeCodesPerSecond": stage.GetTimeCodesPerSecond(),
        "framesPerSecond": stage.GetFramesPerSecond(),
        "startTimeCode": stage.GetStartTimeCode(),
        "endTimeCode": stage.GetEndTimeCode(),
    }
    if got != want:
        fail(f"stage metadata {got} != manifest {want}")

    prim = stage.GetDefaultPrim()
    if not prim or not prim.IsA(UsdVol.Volume):
        fail(f"default prim {prim} is not a Volume")
    volumes = [p for p in stage.Traverse() if p.IsA(UsdVol.Volume)]
    if len(volumes) != 1:
        fail(f"{len(volumes)} Volume prims")
    fields = UsdVol.Volume(prim).GetFieldPaths()
    grids_in_files = None
    samples = 0
    for rel_name, path in sorted(fields.items()):
        asset = UsdVol.OpenVDBAsset(stage.GetPrimAtPath(path))
        if not asset:
            fail(f"field {rel_name}: {path} is not an OpenVDBAsset")
        name = asset.GetFieldNameAttr().Get()
        dtype = asset.GetFieldDataTypeAttr().Get()
        attr = asset.GetFilePathAttr()
        times = [int(t) for t in attr.GetTimeSamples()]
        if times != sorted(frames):
            fail(f"field {name}: samples at {times}, the manifest records {sorted(frames)}")
        for t in times:
            a = attr.Get(Usd.TimeCode(t))
            resolved = a.resolvedPath
            want_file = os.path.realpath(os.path.join(run_dir, frames[t]))
            if not resolved or os.path.realpath(resolved) != want_file or not os.path.isfile(resolved):
                fail(f"field {name} frame {t}: {a.path} resolves to {resolved!r}, not {want_file}")
            grids = {g.name: g.valueTypeName for g in pyopenvdb.readAllGridMetadata(resolved)}
            if name not in grids:
                fail(f"frame {t}: {resolved} has no grid {name} (has {sorted(grids)})")
            value_type = grids[name]
            if TYPES.get(value_type) != dtype:
                fail(f"field {name}: fieldDataType {dtype}, the grid is {value_type}")
            if grids_in_files is None:
                grids_in_files = set(grids)
            samples += 1
    names = {UsdVol.OpenVDBAsset(stage.GetPrimAtPath(p)).GetFieldNameAttr().Get() for p in fields.values()}
    if names != grids_in_files:
        fail(f"fields {sorted(names)} != the VDB files' grids {sorted(grids_in_files)}")
    print(json.dumps({"ok": True, "fields": sorted(names), "frames": len(frames), "samples_checked": samples, "stage": got}))


if __name__ == "__main__":
    main()
