#!/usr/bin/env python3
"""The look of a cloud, measured from a run and its render (docs/RENDERING.md "The look,
measured"):

  /usr/bin/python3 tools/cloud_look.py RUN_DIR [--frame N] [--render-summary SUMMARY.json]
      [--boundary 0.1] [--json]

- optical depth through the core (the density-weighted centroid) along the camera's view and
  along the sun, with the density grid's physical extinction: from the render's summary
  (tools/render_blender.py --summary-json; its camera and sun), else along the render's default
  sun and a horizontal view;
- liquid water content (g/m^3): mean over the voxels holding at least 0.01 g/m^3, and maximum;
- the cloud base's spread: the lowest cloudy voxel of each column of the footprint, 5th to 95th
  percentile, as a fraction of the cloud's depth;
- the boundary's 10%-90% thickness along the density gradient (voxels and scene units), from the
  iso-surface at `--boundary` (density units), across one particle spacing either side;
- the luminance of the render's cloud pixels (5th, 50th, 95th percentile and 95th / 5th), from
  the summary.

Needs numpy and pyopenvdb (Debian: python3-numpy python3-openvdb; use /usr/bin/python3).
"""
import argparse
import json
import math
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import nimbus_look  # noqa: E402


def main():
    p = argparse.ArgumentParser(prog="cloud_look.py")
    p.add_argument("run", help="nimbus run directory")
    p.add_argument("--frame", type=int, default=None, help="frame (default: the last one)")
    p.add_argument("--render-summary", default=None, help="tools/render_blender.py --summary-json file")
    p.add_argument("--boundary", type=float, default=0.1, help="boundary level, density units")
    p.add_argument("--json", action="store_true", help="print JSON only")
    a = p.parse_args()

    with open(os.path.join(a.run, "manifest.json")) as f:
        man = json.load(f)
    frames = [fr for fr in man["frames"] if any(x["path"].endswith(".vdb") for x in fr["files"])]
    if not frames:
        sys.exit(f"{a.run}: no frame with a VDB")
    rec = frames[-1] if a.frame is None else next((fr for fr in frames if fr["frame"] == a.frame), None)
    if rec is None:
        sys.exit(f"{a.run}: frame {a.frame} is not in the manifest")
    vdb = os.path.join(a.run, next(x["path"] for x in rec["files"] if x["path"].endswith(".vdb")))
    exp = man.get("export") or {}
    optics = exp.get("optics") or {}
    cfg = man.get("config", {})
    density_scale = float(cfg.get("export", {}).get("density_scale", 1000.0))
    scale = float(exp.get("scale", 1.0))
    k = float(optics.get("extinction_per_unit") or nimbus_look.default_extinction_per_unit(density_scale, scale))
    lwc_per_unit = float(optics.get("lwc_per_unit") or nimbus_look.DEFAULT_AIR_DENSITY / density_scale)
    up = exp.get("up_axis", "y")
    spacing = float(cfg.get("domain", {}).get("spacing", 0.0)) / scale

    grid, lo, voxel, origin, _ = nimbus_look.read_density(vdb)
    out = {"run": os.path.abspath(a.run), "frame": rec["frame"], "vdb": vdb, "voxel_size": voxel,
           "extinction_per_unit": k}
    c = nimbus_look.centroid(grid)
    if c is None:
        sys.exit(f"{vdb}: the density grid is empty")

    summary = None
    if a.render_summary:
        with open(a.render_summary) as f:
            summary = json.load(f)
    # directions in the file's frame; Blender's world is z-up, a y-up file was rotated
    def to_file(v):
        return [v[0], v[2], -v[1]] if up == "y" else list(v)

    def to_world(v):
        return [v[0], -v[2], v[1]] if up == "y" else list(v)

    core = origin + (lo + c) * voxel
    if summary and summary.get("camera_position") and summary.get("sun_direction"):
        view = np.array(to_world(core)) - np.array(summary["camera_position"])
        sun = summary["sun_direction"]
        out["directions_from"] = "render summary"
    else:
        # render_blender.py's sun, and a level view from its side (-y in Blender)
        el, rot = math.radians(40.0), math.radians(110.0)
        sun = [math.cos(el) * math.sin(rot), math.cos(el) * math.cos(rot), math.sin(el)]
        view = np.array([0.25, 1.0, 0.0])
        out["directions_from"] = "render_blender.py's defaults (no --render-summary)"
    out["optical_depth"] = {
        "view": nimbus_look.optical_depth(grid, voxel, k, c, to_file(view)),
        "sun": nimbus_look.optical_depth(grid, voxel, k, c, to_file(sun)),
        "core": [float(v) for v in core],
    }
    out["lwc_g_m3"] = nimbus_look.lwc_figures(grid, lwc_per_unit)
    ax = {"x": 0, "y": 1, "z": 2}[up]
    out["cloud_base"] = nimbus_look.base_spread(
        grid, voxel, up, lwc_per_unit, height0=float(origin[ax] + lo[ax] * voxel)
    )
    if spacing > 0:
        t = nimbus_look.boundary_thickness(grid, a.boundary, spacing / voxel)
        if len(t):
            q = np.percentile(t, [25, 50, 75])
            out["boundary_thickness"] = {
                "level": a.boundary,
                "voxels_p25_p50_p75": [float(v) for v in q],
                "scene_units_median": float(q[1] * voxel),
                "surface_voxels": int(len(t)),
            }
    if summary:
        out["cloud_luminance"] = summary.get("cloud_luminance")
        out["render"] = summary.get("output")
    if a.json:
        print(json.dumps(out, indent=1, sort_keys=True))
        return
    od = out["optical_depth"]
    print(f"frame {out['frame']} of {out['run']}")
    print(f"  optical depth through the core: view {od['view']:.1f}, sun {od['sun']:.1f} ({out['directions_from']})")
    lw = out["lwc_g_m3"]
    print(f"  liquid water content: mean {lw['mean']:.3f} g/m^3, max {lw['max']:.3f} g/m^3 ({lw['voxels']} voxels >= {lw['floor']})")
    b = out["cloud_base"]
    if b:
        print(f"  cloud base: {b['base_p5']:.0f}-{b['base_p95']:.0f} (5-95%), depth {b['depth']:.0f}: spread {b['spread_fraction']:.3f} of the depth")
    bt = out.get("boundary_thickness")
    if bt:
        v = bt["voxels_p25_p50_p75"]
        print(f"  boundary 10-90% thickness: median {v[1]:.2f} voxels ({bt['scene_units_median']:.1f} units), quartiles {v[0]:.2f}-{v[2]:.2f}")
    cl = out.get("cloud_luminance")
    if cl:
        print(f"  cloud pixels' luminance: p5 {cl['p5']:.3f}, p50 {cl['p50']:.3f}, p95 {cl['p95']:.3f}, p95/p5 {cl['ratio_95_5']:.2f} (sRGB-encoded {cl.get('ratio_95_5_srgb', float('nan')):.2f})")
    print(json.dumps(out, sort_keys=True))


if __name__ == "__main__":
    main()
