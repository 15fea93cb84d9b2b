"""What a cloud looks like, measured: shared by tools/render_blender.py (inside Blender, whose
Debian build runs the system Python with numpy and pyopenvdb) and tools/cloud_look.py.

- `read_density(path, grid)`: a VDB grid as a dense numpy array with its index box and
  transform (pyopenvdb), and the physical optics nimbus wrote into its metadata;
- `optical_depth(...)`: the optical depth through the cloud's core (its density-weighted
  centroid) along a direction, both ways to the end of the grid, trilinear samples every
  quarter voxel;
- `lwc_figures`, `base_spread`: liquid water content (g/m^3) and the spread of the cloud base;
- `read_png_rgb`, `cloud_mask`, `luminance_percentiles`: an 8-bit PNG, the pixels where a render
  differs from its sky-only render, and the luminance of those pixels.
"""
import math
import struct
import zlib

import numpy as np

# Extinction of liquid water cloud: beta = 3 LWC / (2 rho_w r_e) (docs/RENDERING.md "Physical
# optics"); the defaults of export.optics, for files written before nimbus recorded them.
WATER_DENSITY = 1000.0
DEFAULT_EFFECTIVE_RADIUS_UM = 10.0
DEFAULT_AIR_DENSITY = 1.1
# A pixel is cloud when its 8-bit RGB differs from the sky-only render's by more than this,
# summed over the channels (render_blender.py's coverage test).
MASK_THRESHOLD = 24


def default_extinction_per_unit(density_scale=1000.0, scale=1.0):
    """export.optics' defaults: 1/scene unit per unit of the density grid."""
    lwc_per_unit = DEFAULT_AIR_DENSITY / density_scale
    return 1.5 * lwc_per_unit / (WATER_DENSITY * DEFAULT_EFFECTIVE_RADIUS_UM * 1e-6) * scale


def read_density(path, grid="density"):
    """(array indexed [i, j, k] over the active box, lo index, voxel size, origin of voxel
    (0,0,0), metadata dict) of a float grid."""
    import pyopenvdb

    g = pyopenvdb.read(path, grid)
    lo, hi = g.evalActiveVoxelBoundingBox()
    dims = tuple(max(0, int(h - l + 1)) for l, h in zip(lo, hi))
    a = np.zeros(dims, np.float32)
    if all(d > 0 for d in dims):
        g.copyToArray(a, ijk=lo)
    t = g.transform
    voxel = float(t.voxelSize()[0])
    origin = np.array(t.indexToWorld((0, 0, 0)), float)
    meta = dict(g.metadata)
    return a, np.array(lo, int), voxel, origin, meta


def sample(a, q):
    """Trilinear samples of array `a` at fractional indices q (N x 3); 0 outside."""
    b = np.floor(q).astype(np.int64)
    t = q - b
    out = np.zeros(len(q))
    for c in range(8):
        o = np.array([(c >> 2) & 1, (c >> 1) & 1, c & 1])
        i = b + o
        w = np.prod(np.where(o == 1, t, 1.0 - t), axis=1)
        ok = np.all((i >= 0) & (i < np.array(a.shape)), axis=1)
        v = np.zeros(len(q))
        v[ok] = a[i[ok, 0], i[ok, 1], i[ok, 2]]
        out += w * v
    return out


def centroid(a):
    """Density-weighted centroid of `a` (fractional indices)."""
    s = float(a.sum())
    if s <= 0:
        return None
    idx = np.indices(a.shape).reshape(3, -1)
    return (idx * a.reshape(-1)).sum(axis=1) / s


def optical_depth(a, voxel, extinction_per_unit, through, direction, step=0.25):
    """Optical depth of the whole line through index point `through` along unit `direction`
    (index space is scene units / voxel): extinction_per_unit x integral of the density."""
    d = np.asarray(direction, float)
    d = d / np.linalg.norm(d)
    n = int(math.ceil(np.linalg.norm(a.shape) / step)) + 2
    s = (np.arange(-n, n + 1) * step)[:, None]
    q = np.asarray(through, float)[None, :] + s * d[None, :]
    return float(extinction_per_unit * sample(a, q).sum() * step * voxel)


def lwc_figures(a, lwc_per_unit, floor_g_m3=0.01):
    """Mean and max liquid water content (g/m^3) of the voxels holding at least `floor_g_m3`."""
    lwc = a.astype(np.float64) * lwc_per_unit * 1000.0
    cloud = lwc >= floor_g_m3
    if not cloud.any():
        return {"mean": 0.0, "max": 0.0, "voxels": 0, "floor": floor_g_m3}
    return {
        "mean": float(lwc[cloud].mean()),
        "max": float(lwc.max()),
        "voxels": int(cloud.sum()),
        "floor": floor_g_m3,
    }


def base_spread(a, voxel, up_axis, lwc_per_unit, floor_g_m3=0.01, height0=0.0):
    """The cloud base over its footprint: per column (along the up axis) holding cloud, the
    lowest cloudy voxel; the 5th-95th percentile spread of those heights over the cloud's depth
    (highest cloudy voxel minus lowest), and both in scene units (`height0`: the height of
    index 0 of the array along the up axis)."""
    cloud = a.astype(np.float64) * lwc_per_unit * 1000.0 >= floor_g_m3
    if not cloud.any():
        return None
    ax = {"x": 0, "y": 1, "z": 2}[up_axis]
    c = np.moveaxis(cloud, ax, -1)
    has = c.any(axis=-1)
    n = c.shape[-1]
    lowest = np.argmax(c, axis=-1)[has]
    highest = (n - 1 - np.argmax(c[..., ::-1], axis=-1))[has]
    depth = (highest.max() - lowest.min() + 1) * voxel
    p5, p95 = np.percentile(lowest, [5, 95]) * voxel + height0
    return {
        "base_p5": float(p5),
        "base_p95": float(p95),
        "depth": float(depth),
        "spread_fraction": float((p95 - p5) / depth),
        "columns": int(has.sum()),
    }


def boundary_thickness(a, tau, reach, step=0.25):
    """10%-90% rise distances (voxels) along the density gradient from every surface voxel of
    `a` at level `tau` (at or above it, a face neighbour below): the grid sampled every quarter
    voxel from `reach` voxels outside to `reach` inside; 90% of the largest value on the inward
    half, the first point reaching it, and the last point at or below 10% before that. The same
    definition as `nimbus bench detail` (src/bench/surface.rs)."""
    inside = a >= tau
    pad = np.pad(inside, 1, constant_values=False)
    below = np.zeros_like(inside)
    for ax in range(3):
        for d in (-1, 1):
            below |= ~np.roll(pad, d, axis=ax)[1:-1, 1:-1, 1:-1]
    surf = np.argwhere(inside & below)
    if len(surf) == 0:
        return np.zeros(0)
    g = np.stack(np.gradient(np.pad(a.astype(np.float64), 1)), axis=-1)[1:-1, 1:-1, 1:-1]
    gs = g[surf[:, 0], surf[:, 1], surf[:, 2]]
    gn = np.linalg.norm(gs, axis=1)
    ok = gn > 0
    surf, u = surf[ok], gs[ok] / gn[ok, None]
    n = int(math.ceil(reach / step))
    s = np.arange(-n, n + 1) * step
    q = surf[:, None, :] + s[None, :, None] * u[:, None, :]
    prof = sample(a, q.reshape(-1, 3)).reshape(len(surf), len(s))
    top = prof[:, n:].max(axis=1)
    reach90 = prof >= 0.9 * top[:, None]
    has90 = reach90.any(axis=1)
    i90 = np.argmax(reach90, axis=1)
    low = prof <= 0.1 * top[:, None]
    idx = np.arange(len(s))[None, :]
    low &= idx <= i90[:, None]
    has10 = low.any(axis=1)
    i10 = len(s) - 1 - np.argmax(low[:, ::-1], axis=1)
    keep = has90 & has10
    return (i90[keep] - i10[keep]) * step


def read_png_rgb(path):
    """8-bit RGB, non-interlaced PNG -> uint8 array (h, w, 3). The filters are undone row by
    row (Sub and Up with numpy, Average and Paeth pixel by pixel)."""
    with open(path, "rb") as f:
        data = f.read()
    if data[:8] != b"\x89PNG\r\n\x1a\n":
        raise ValueError(f"{path}: not a PNG")
    pos, idat, w = 8, b"", None
    while pos < len(data):
        n, kind = struct.unpack(">I4s", data[pos : pos + 8])
        body = data[pos + 8 : pos + 8 + n]
        if kind == b"IHDR":
            w, h, depth, ctype, _, _, interlace = struct.unpack(">IIBBBBB", body)
            if depth != 8 or ctype != 2 or interlace != 0:
                raise ValueError(f"{path}: unexpected PNG format (depth {depth}, type {ctype})")
        elif kind == b"IDAT":
            idat += body
        pos += 12 + n
    raw = np.frombuffer(zlib.decompress(idat), np.uint8).reshape(h, 3 * w + 1)
    out = np.zeros((h, 3 * w), np.uint8)
    prev = np.zeros(3 * w, np.int64)
    for y in range(h):
        ft = raw[y, 0]
        line = raw[y, 1:].astype(np.int64)
        if ft == 0:
            cur = line
        elif ft == 1:
            cur = np.cumsum(line.reshape(w, 3), axis=0).reshape(-1) % 256
        elif ft == 2:
            cur = (line + prev) % 256
        else:
            cur = line.copy()
            for i in range(3 * w):
                left = cur[i - 3] if i >= 3 else 0
                up = prev[i]
                if ft == 3:
                    cur[i] = (cur[i] + ((left + up) >> 1)) & 255
                else:
                    ul = prev[i - 3] if i >= 3 else 0
                    pa, pb, pc = abs(up - ul), abs(left - ul), abs(left + up - 2 * ul)
                    pr = left if pa <= pb and pa <= pc else (up if pb <= pc else ul)
                    cur[i] = (cur[i] + pr) & 255
        out[y] = cur
        prev = cur
    return out.reshape(h, w, 3)


def cloud_mask(img, sky):
    """Pixels where a render differs from its sky-only render by more than MASK_THRESHOLD."""
    d = np.abs(img.astype(np.int32) - sky.astype(np.int32)).sum(axis=2)
    return d > MASK_THRESHOLD


def srgb_to_linear(v):
    s = v / 255.0
    return np.where(s <= 0.04045, s / 12.92, ((s + 0.055) / 1.055) ** 2.4)


def luminance(img):
    """Rec. 709 relative luminance of the displayed (sRGB-encoded) 8-bit image."""
    lin = srgb_to_linear(img.astype(np.float64))
    return 0.2126 * lin[..., 0] + 0.7152 * lin[..., 1] + 0.0722 * lin[..., 2]


def linear_to_srgb(v):
    v = np.asarray(v, np.float64)
    return np.where(v <= 0.0031308, 12.92 * v, 1.055 * np.power(np.maximum(v, 0.0), 1 / 2.4) - 0.055)


def luminance_percentiles(img, mask):
    """5th, 50th and 95th percentile of the cloud pixels' (linear) luminance and the 95th / 5th
    ratio; also the ratio of the two percentiles sRGB-encoded, as the display shows them
    (`ratio_95_5_srgb`: the figure of 1.3 that issue 37 quoted for the look before it)."""
    y = luminance(img)[mask]
    if y.size == 0:
        return None
    p5, p50, p95 = np.percentile(y, [5, 50, 95])
    e5, e95 = linear_to_srgb(p5), linear_to_srgb(p95)
    return {
        "p5": float(p5),
        "p50": float(p50),
        "p95": float(p95),
        "ratio_95_5": float(p95 / p5) if p5 > 0 else float("inf"),
        "ratio_95_5_srgb": float(e95 / e5) if e5 > 0 else float("inf"),
        "pixels": int(y.size),
    }
