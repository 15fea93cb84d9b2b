#!/usr/bin/python3
"""Done-when figures of the art-direction shots (docs/ART_DIRECTION.md), from a run's density VDB.

Usage: /usr/bin/python3 tools/shot_checks.py RUN_DIR [--frame N] [--source K] [--json]

Reads RUN_DIR/manifest.json (the resolved config: domain, kernel radius, sources, wind) and the
`density` grid of frame N (default: the last frame written). Every active voxel with density
above 0 counts as cloud, weighted by its density (cloud water). Prints, and with --json as one
JSON line:

hero (physics.sources[K], default the first disc or ellipse, K for another):
  footprint_ratio   largest horizontal (periodic) distance of a cloud voxel centre from the
                    source's centre, over its radius (the larger semi-axis of an ellipse);
                    done when <= 1.5 (the footprint widened by 50%)
  outside_fraction  share of the cloud water beyond 1.5 radii
  face_fraction     share within one kernel radius h0 of a periodic face (done when 0)
  top10_fraction    share in the top 10% of the domain height (done when 0)

lean (with physics.wind):
  base / top        mass-weighted horizontal centroids of the lowest and the highest fifth of
                    the cloud's height range (periodic means), and their heights
  downwind          unit vector of the shear between those heights, U(top) - U(base), from the
                    wind profile (the wind at the top where there is no shear)
  lean              (top - base) . downwind, minimum image (m)
  base_radius       sqrt(A / pi) of the area A of the ground columns holding cloud in the base
                    fifth (m); done when lean >= base_radius

The text output shows the figures that decide; --json has all of them.
--side-view PNG also writes the cloud seen from the side (water summed along z; x right, y up;
the lean's centroids marked). --check hero|lean chooses which figures decide the exit status (default: lean when the shot has a
wind, else hero). Exit status 1 when they fail, 2 on unreadable input.
Needs pyopenvdb (Debian python3-openvdb, only under /usr/bin/python3).
"""
import argparse
import json
import math
import os
import struct
import sys
import zlib

import numpy as np
import pyopenvdb as vdb


def fail(msg):
    print(f"shot_checks: {msg}", file=sys.stderr)
    sys.exit(2)


def cloud_voxels(path):
    """(positions N x 3 in metres, density N, voxel size) of the voxels above 0."""
    grid = vdb.read(path, "density")
    vs = grid.transform.voxelSize()[0]
    (x0, y0, z0), (x1, y1, z1) = grid.evalActiveVoxelBoundingBox()
    if x1 < x0:
        return np.zeros((0, 3)), np.zeros(0), vs
    a = np.zeros((x1 - x0 + 1, y1 - y0 + 1, z1 - z0 + 1), np.float32)
    grid.copyToArray(a, ijk=(x0, y0, z0))
    idx = np.argwhere(a > 0)
    dens = a[a > 0].astype(np.float64)
    origin = np.array(grid.transform.indexToWorld((x0, y0, z0)))
    return origin + idx * vs, dens, vs


def write_side_view(path, pos, dens, vs, size, marks, scale=4):
    """Greyscale PNG of the cloud water summed along z (x to the right, y up), `scale` pixels a
    voxel; `marks` (x, y) in metres drawn as small crosses (the lean's centroids)."""
    nx, ny = int(round(size[0] / vs)), int(round(size[1] / vs))
    img = np.zeros((ny, nx))
    ix = np.clip((pos[:, 0] / vs).astype(int), 0, nx - 1)
    iy = np.clip((pos[:, 1] / vs).astype(int), 0, ny - 1)
    np.add.at(img, (iy, ix), dens)
    img = 230.0 * (1.0 - np.exp(-img / (0.3 * img.max() + 1e-30)))
    img = np.kron(img, np.ones((scale, scale)))
    for x, y in marks:
        i, j = int(x / vs * scale), int(y / vs * scale)
        for d in range(-3 * scale, 3 * scale + 1):
            for a, b in ((j + d, i), (j, i + d)):
                if 0 <= a < img.shape[0] and 0 <= b < img.shape[1]:
                    img[a, b] = 255.0
    a = img[::-1].astype(np.uint8)
    h, w = a.shape
    raw = b"".join(b"\x00" + a[k].tobytes() for k in range(h))

    def chunk(t, d):
        return struct.pack(">I", len(d)) + t + d + struct.pack(">I", zlib.crc32(t + d) & 0xFFFFFFFF)

    with open(path, "wb") as f:
        f.write(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 0, 0, 0, 0))
                + chunk(b"IDAT", zlib.compress(raw, 9)) + chunk(b"IEND", b""))


def wrap(d, size, periodic):
    return d - size * np.round(d / size) if periodic else d


def periodic_mean(x, w, size, periodic):
    if not periodic:
        return float(np.sum(w * x) / np.sum(w))
    ang = 2 * math.pi * x / size
    a = math.atan2(np.sum(w * np.sin(ang)), np.sum(w * np.cos(ang)))
    return (a % (2 * math.pi)) * size / (2 * math.pi)


def wind_at(profile, y):
    """(u_x, u_z) of the profile at y: speed and direction linear between levels (the short
    way round), constant outside, as sim::wind and thermo.wgsl."""
    rows, heading, prev = [], 0.0, None
    for lv in profile:
        a = math.radians(lv.get("direction", 0.0))
        heading = a if prev is None else heading + (a - prev) - 2 * math.pi * round((a - prev) / (2 * math.pi))
        prev = a
        rows.append((lv["height"], lv["speed"], heading))
    lo, hi = rows[0], rows[0]
    for r in rows[1:]:
        hi = r
        if y < r[0]:
            break
        lo = r
    t = 0.0 if hi[0] <= lo[0] else min(max((y - lo[0]) / (hi[0] - lo[0]), 0.0), 1.0)
    s = lo[1] + (hi[1] - lo[1]) * t
    h = lo[2] + (hi[2] - lo[2]) * t
    return np.array([s * math.cos(h), s * math.sin(h)])


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run_dir")
    ap.add_argument("--frame", type=int)
    ap.add_argument("--source", type=int)
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--side-view", metavar="PNG",
                    help="also write the cloud seen from the side: water summed along z, x right, "
                    "y up (with a wind: the base and top centroids marked)")
    ap.add_argument("--check", choices=["auto", "hero", "lean"], default="auto",
                    help="which figures decide the exit status (auto: lean with a wind, else hero)")
    args = ap.parse_args()
    try:
        with open(os.path.join(args.run_dir, "manifest.json")) as f:
            man = json.load(f)
    except (OSError, ValueError) as e:
        fail(f"{args.run_dir}: cannot read manifest.json: {e}")
    cfg = man["config"]
    exp = man.get("export") or {}
    if exp.get("scale", 1.0) != 1.0 or exp.get("up_axis", "y") != "y":
        fail("the run's VDBs are not in metres, y up (export.scale / export.up_axis)")
    frames = [f for f in man["frames"] if any(x["path"].endswith(".vdb") for x in f["files"])]
    if not frames:
        fail("the manifest lists no VDB frame")
    rec = frames[-1] if args.frame is None else next((f for f in frames if f["frame"] == args.frame), None)
    if rec is None:
        fail(f"frame {args.frame} has no VDB in the manifest")
    path = os.path.join(args.run_dir, next(x["path"] for x in rec["files"] if x["path"].endswith(".vdb")))
    dom = cfg["domain"]
    size = dom["size"]
    per = [a in dom.get("periodic", ["x", "z"]) for a in ("x", "z")]
    h0 = dom["spacing"] * dom.get("kernel_ratio", 2.0)
    pos, dens, vs = cloud_voxels(path)
    out = {"frame": rec["frame"], "file": path, "cloud_voxels": int(len(dens))}
    ok = True
    if len(dens) == 0:
        out["error"] = "no cloud"
        print(json.dumps(out) if args.json else f"{path}: no cloud")
        sys.exit(1)
    total = dens.sum()
    phys = cfg.get("physics", {})
    srcs = phys.get("sources", [])
    k = args.source
    if k is None:
        k = next((i for i, s in enumerate(srcs) if s["shape"] in ("disc", "ellipse")), None)
    if k is not None:
        s = srcs[k]
        radius = s.get("radius") or max(s.get("radii") or [0.0])
        dx = wrap(pos[:, 0] - s["center"][0], size[0], per[0])
        dz = wrap(pos[:, 2] - s["center"][-1], size[2], per[1])
        r = np.sqrt(dx * dx + dz * dz) / radius
        near_face = np.zeros(len(dens), bool)
        for a, ax in ((0, 0), (1, 2)):
            if per[a]:
                near_face |= (pos[:, ax] < h0) | (pos[:, ax] > size[ax] - h0)
        top10 = pos[:, 1] > 0.9 * size[1]
        out["hero"] = {
            "source": k,
            "footprint_ratio": float(r.max()),
            "outside_fraction": float(dens[r > 1.5].sum() / total),
            "face_fraction": float(dens[near_face].sum() / total),
            "top10_fraction": float(dens[top10].sum() / total),
        }
        h = out["hero"]
        h["ok"] = h["footprint_ratio"] <= 1.5 and h["face_fraction"] == 0 and h["top10_fraction"] == 0
    wind = phys.get("wind")
    if wind:
        y = pos[:, 1]
        lo, hi = y.min(), y.max()
        fifth = 0.2 * (hi - lo)
        base, top = y <= lo + fifth, y >= hi - fifth
        c = {}
        for name, sel in (("base", base), ("top", top)):
            c[name] = np.array([
                periodic_mean(pos[sel, 0], dens[sel], size[0], per[0]),
                periodic_mean(pos[sel, 2], dens[sel], size[2], per[1]),
            ])
        yb = float(np.sum(dens[base] * y[base]) / dens[base].sum())
        yt = float(np.sum(dens[top] * y[top]) / dens[top].sum())
        shear = wind_at(wind["profile"], yt) - wind_at(wind["profile"], yb)
        if np.linalg.norm(shear) < 1e-9:
            shear = wind_at(wind["profile"], yt)
        down = shear / max(np.linalg.norm(shear), 1e-300)
        d = np.array([wrap(c["top"][0] - c["base"][0], size[0], per[0]),
                      wrap(c["top"][1] - c["base"][1], size[2], per[1])])
        cols = {(round(p[0] / vs), round(p[2] / vs)) for p in pos[base]}
        base_radius = math.sqrt(len(cols) * vs * vs / math.pi)
        out["lean"] = {
            "base": [round(v, 1) for v in c["base"]] + [round(yb, 1)],
            "top": [round(v, 1) for v in c["top"]] + [round(yt, 1)],
            "downwind": [round(v, 4) for v in down],
            "lean": float(d @ down),
            "base_radius": base_radius,
            "ok": bool(d @ down >= base_radius),
        }
    if args.side_view:
        marks = []
        if "lean" in out:
            marks = [(c["base"][0], yb), (c["top"][0], yt)]
        write_side_view(args.side_view, pos, dens, vs, size, marks)
    check = args.check if args.check != "auto" else ("lean" if wind else "hero")
    ok = check in out and out[check]["ok"]
    out["check"] = check
    out["ok"] = ok
    if args.json:
        print(json.dumps(out))
    else:
        print(f"{path}: {len(dens)} cloud voxels")
        if "hero" in out and check == "hero":
            h = out["hero"]
            print(
                f"  hero (source {h['source']}): cloud out to {h['footprint_ratio']:.3f} radii "
                f"(done when <= 1.5; {h['outside_fraction']:.2%} of the water beyond), "
                f"near a periodic face {h['face_fraction']:.2%}, top 10% {h['top10_fraction']:.2%}: "
                f"{'ok' if h['ok'] else 'NOT MET'}"
            )
        if "lean" in out and check == "lean":
            l = out["lean"]
            print(
                f"  lean: base centroid {l['base']} m, top centroid {l['top']} m, downwind "
                f"{l['downwind']}: top leans {l['lean']:.0f} m downwind, base radius "
                f"{l['base_radius']:.0f} m: {'ok' if l['ok'] else 'NOT MET'}"
            )
    sys.exit(0 if ok else 1)


if __name__ == "__main__":
    main()
