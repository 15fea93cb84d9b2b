#!/usr/bin/python3
"""Cloud-field statistics of a nimbus run or a MicroHH run, by one definition (docs/data/bomex/README.md).

Usage:
  /usr/bin/python3 tools/cloud_stats.py SOURCE [SOURCE...] [--window T0,T1] [--json OUT.json]
      [--plot OUT.png] [--labels A,B,...] [--criteria] [--meta META.json] [--columns M]
      [--particles] [thresholds...]

A SOURCE is one of
  - a nimbus run directory (manifest.json, stats.jsonl, vdb/*.vdb: the `density` grid is cloud
    water times export.density_scale; the up axis and scene scale come from the manifest);
  - a MicroHH run directory (CASE.ini, grid.0000000, 3-D dumps ql.NNNNNNN, CASE.default.0000000.nc
    for the reference air density; ql_path.xy.000.NNNNNNN cross-sections, when present, are
    checked against the liquid water path computed here);
  - a JSON file this tool wrote with --json (the statistics are refitted from what it holds).
A nimbus run is measured on its export voxels, or with --columns M on columns M metres wide:
the voxels' cloud water averaged over each block, level by level, as an LES cell holds its mean.
With --particles it is measured from its particles instead (the checkpoints in the window, on
cells of the particle spacing, or columns of --columns M): each particle's water goes into the
cell holding it, times its volume over the cell's, so no kernel widens the clouds.

Averaged over the snapshots with T0 <= time <= T1 (s; default hours 3-6, 10800,21600):
  cloudy cell        ql > --ql-threshold (kg/kg, default 1e-5)
  cloud fraction     per level, the share of the level's cells that are cloudy
  cloud base / top   lowest / highest height where the mean cloud-fraction profile reaches
                     --cf-threshold (default 1e-3 = 0.1 %), linear between levels
  cover              share of columns holding at least one cloudy cell (projected cover)
  LWP                domain-mean column integral of rho*ql (g/m^2), all columns
  LWC in cloud       mean of rho*ql over the cloudy cells (g/m^3), volume-weighted
  clouds             4-connected regions of cloudy columns, periodic in both horizontal axes;
                     area A and perimeter P = (cloudy/clear column edges) x spacing
  size distribution  n(L) = clouds per unit area per unit size, L = sqrt(A), in bins of A between
                     powers of two (in columns); slope = least-squares slope of log n vs log L over
                     the contiguous bins from A >= --min-cloud-area (m^2, default 40000: 2 x 2
                     columns of the intercomparison's 100 m grid) up to --max-cloud-size (m, default none)
                     holding >= --min-bin-count clouds each (DeWitt & Garrett 2024, ACP 24, 8457:
                     fewer than 24 bias the fit); the same physical range at every resolution
  fractal dimension  D in P ~ sqrt(A)^D (Lovejoy 1982), least squares of log P on log sqrt(A) over
                     every cloud with A >= --min-cloud-area; squares give 1, long thin lines 2
  cover trend        least-squares slope of the cover over the window x window length / mean cover
Air density: for MicroHH its anelastic reference profile (rhoref, in its statistics file; its own
ql_path uses it). nimbus's paper thermodynamics has no pressure, so for nimbus the hydrostatic
profile of the BOMEX initial state (surface 1015 hPa, theta_l and q_t of Siebesma et al. 2003:
bomex_air_density); it matches MicroHH's rhoref of the BOMEX case to 1e-5.

With several sources it prints them side by side (and plots them together); --criteria adds
issue 39's pass/fail of the first source against the second (exit 1 when one fails); --json
writes the first source's record. Needs numpy; pyopenvdb for nimbus runs (Debian python3-openvdb,
only under /usr/bin/python3); netCDF4 for MicroHH runs (python3-netcdf4); matplotlib for --plot
(python3-matplotlib). Bad input exits 2 with a one-line reason.
"""
import argparse
import configparser
import glob
import importlib
import json
import math
import os
import re
import sys

import numpy as np

SCHEMA = "nimbus.cloud_stats/1"
G, RD, CP, P00 = 9.81, 287.04, 1005.0, 1.0e5


def fail(msg, code=2):
    """One line on stderr; exit 2 for bad input, 3 for a missing module or an I/O failure."""
    print(f"cloud_stats: {msg}", file=sys.stderr)
    sys.exit(code)


def need(module, package):
    try:
        return importlib.import_module(module)
    except ImportError:
        fail(f"needs the Python module {module} (Debian {package}, under /usr/bin/python3)", 3)


# --- air density -----------------------------------------------------------------------------


def bomex_initial(z):
    """theta_l (K) and q_t (kg/kg) of the BOMEX initial state (Siebesma et al. 2003, table 1)."""
    zt = [0.0, 520.0, 1480.0, 2000.0, 3000.0]
    th = [298.7, 298.7, 302.4, 308.2, 311.85]
    qt = [17.0e-3, 16.3e-3, 10.7e-3, 4.2e-3, 3.0e-3]
    z = np.asarray(z, float)
    # above 3 km: the last segment continued
    ext = lambda v: np.where(z > zt[-1], v[-1] + (z - zt[-1]) * (v[-1] - v[-2]) / (zt[-1] - zt[-2]),
                             np.interp(z, zt, v))
    return ext(th), np.maximum(ext(qt), 0.0)


def bomex_pressure(z, p_surface=101500.0):
    """Hydrostatic pressure (Pa) at heights z (m) of the BOMEX initial state:
    dp/dz = -g p / (R_d T_v), T = theta_l (p/p00)^(R_d/c_p), T_v = T (1 + 0.608 q_t)."""
    z = np.asarray(z, float)
    top = max(float(z.max()) if z.size else 0.0, 0.0) + 10.0
    zs = np.arange(0.0, top + 1.0, 1.0)
    th, qt = bomex_initial(zs)
    lnp = np.empty_like(zs)
    lnp[0] = math.log(p_surface)

    def rhs(lp, i):
        t = th[i] * (math.exp(lp) / P00) ** (RD / CP)
        return -G / (RD * t * (1.0 + 0.608 * qt[i]))

    for i in range(len(zs) - 1):  # Heun's method on a 1 m step
        k1 = rhs(lnp[i], i)
        k2 = rhs(lnp[i] + k1, i + 1)
        lnp[i + 1] = lnp[i] + 0.5 * (k1 + k2)
    return np.interp(z, zs, np.exp(lnp))


def bomex_air_density(z, p_surface=101500.0):
    """Hydrostatic air density (kg/m^3) at heights z (m) of the BOMEX initial state, p / (R_d T_v)
    with the pressure of bomex_pressure."""
    z = np.asarray(z, float)
    p = bomex_pressure(z, p_surface)
    th, qt = bomex_initial(z)
    tv = th * (p / P00) ** (RD / CP) * (1.0 + 0.608 * qt)
    return p / (RD * tv)


# --- per-snapshot accumulation -----------------------------------------------------------------


def label_periodic(mask):
    """4-connected labels of a 2-D mask, periodic in both axes: -1 clear, else 0..n-1."""
    nx, ny = mask.shape
    big = nx * ny
    lab = np.where(mask, np.arange(big).reshape(nx, ny), big)
    while True:  # each cloudy cell takes the smallest label among itself and its neighbours
        new = lab.copy()
        for ax in (0, 1):
            for s in (1, -1):
                new = np.minimum(new, np.where(mask, np.roll(lab, s, axis=ax), big))
        if np.array_equal(new, lab):
            break
        lab = new
    out = -np.ones(mask.shape, int)
    roots = np.unique(lab[mask])
    out[mask] = np.searchsorted(roots, lab[mask])
    return out, len(roots)


def clouds_of(mask):
    """(area, perimeter) in columns and column edges of each cloud of a top-view mask."""
    lab, n = label_periodic(mask)
    if n == 0:
        return np.zeros(0, int), np.zeros(0, int)
    m = mask.astype(int)
    clear_nb = 4 - (np.roll(m, 1, 0) + np.roll(m, -1, 0) + np.roll(m, 1, 1) + np.roll(m, -1, 1))
    area = np.bincount(lab[mask], minlength=n)
    perim = np.bincount(lab[mask], weights=clear_nb[mask], minlength=n).astype(int)
    return area, perim


class Accumulator:
    """Sums over the snapshots of one source on one grid (levels z, thicknesses dz, density rho)."""

    def __init__(self, z, dz, rho, dx, dy, ql_threshold):
        self.z, self.dz, self.rho = np.asarray(z, float), np.asarray(dz, float), np.asarray(rho, float)
        self.dx, self.dy, self.thr = float(dx), float(dy), float(ql_threshold)
        nz = len(self.z)
        self.cf_sum = np.zeros(nz)
        self.qlc_sum = np.zeros(nz)  # sum of ql over cloudy cells, per level
        self.nc_sum = np.zeros(nz)  # number of cloudy cells, per level
        self.lwc_num = self.lwc_den = 0.0
        self.times, self.cover, self.lwp = [], [], []
        self.clouds = {}
        self.columns = None
        self.n = 0

    def add(self, t, ql):
        """ql: (nx, ny, nz) cloud water (kg/kg), height last."""
        nx, ny, nz = ql.shape
        assert nz == len(self.z), (nz, len(self.z))
        self.columns = (nx, ny)
        cloudy = ql > self.thr
        per_level = cloudy.sum(axis=(0, 1))
        self.cf_sum += per_level / (nx * ny)
        qlc = np.where(cloudy, ql, 0.0).sum(axis=(0, 1))
        self.qlc_sum += qlc
        self.nc_sum += per_level
        self.lwc_num += float((qlc * self.rho * self.dz).sum())
        self.lwc_den += float((per_level * self.dz).sum())
        mask = cloudy.any(axis=2)
        self.times.append(float(t))
        self.cover.append(float(mask.mean()))
        self.lwp.append(float((ql.astype(float) * (self.rho * self.dz)).sum(axis=2).mean() * 1000.0))
        for a, p in zip(*clouds_of(mask)):
            self.clouds[(int(a), int(p))] = self.clouds.get((int(a), int(p)), 0) + 1
        self.n += 1

    def record(self, source, window, meta):
        if self.n == 0:
            fail(f"{source['path']}: no snapshot between {window[0]:g} and {window[1]:g} s")
        nx, ny = self.columns
        with np.errstate(invalid="ignore", divide="ignore"):
            qlc = np.where(self.nc_sum > 0, self.qlc_sum / self.nc_sum, 0.0)
        return {
            "schema": SCHEMA,
            "source": source,
            "meta": meta,
            "definitions": {"ql_threshold": self.thr, "window": list(window)},
            "grid": {"dx": self.dx, "dy": self.dy, "columns": [nx, ny],
                     "domain_area": self.dx * self.dy * nx * ny},
            "snapshots": self.n,
            "profiles": {"z": rnd(self.z), "dz": rnd(self.dz), "rho": rnd(self.rho),
                         "cloud_fraction": rnd(self.cf_sum / self.n),
                         "ql_in_cloud": rnd(qlc)},
            "lwc_in_cloud": self.lwc_num / self.lwc_den * 1000.0 if self.lwc_den else None,
            "series": {"time": self.times, "cover": rnd(self.cover), "lwp": rnd(self.lwp)},
            "clouds": sorted([a, p, c] for (a, p), c in self.clouds.items()),
        }


def rnd(v, sig=6):
    return [float(f"{x:.{sig}g}") for x in np.asarray(v, float)]


# --- sources -------------------------------------------------------------------------------------


def in_window(t, window):
    return window[0] - 1e-6 <= t <= window[1] + 1e-6


def read_nimbus(path, window, ql_threshold, column=None):
    """column: analyse on columns of this width (m), block means of the voxels' cloud water, as
    an LES cell holds its cell's mean (a multiple of the voxel size dividing the domain)."""
    vdb = need("pyopenvdb", "python3-openvdb")

    man = json.load(open(os.path.join(path, "manifest.json")))
    cfg = man["config"]
    size = cfg["domain"]["size"]
    scale = float(man["export"]["scale"])  # metres per scene unit
    up = man["export"]["up_axis"]
    vs = float(man["voxel_size"]) * scale
    dscale = float(cfg["export"]["density_scale"])
    gname = cfg["export"]["grids"]["density"] or "density"
    nx, nlev, ny = (int(round(s / vs)) for s in size)
    times = {}
    stats = os.path.join(path, "stats.jsonl")
    if not os.path.exists(stats):
        fail(f"{path}: no stats.jsonl (it holds the simulated time of each frame)")
    for line in open(stats):
        rec = json.loads(line)
        times[rec["frame"]] = float(rec["sim_time"])
    z = (np.arange(nlev) + 0.5) * vs
    k = 1
    if column is not None:
        k = int(round(column / vs))
        if k < 1 or abs(k * vs - column) > 1e-6 * column or nx % k or ny % k:
            fail(f"--columns {column:g}: not a multiple of the voxel size {vs:g} m that divides "
                 f"the domain's {nx} x {ny} voxels")
    acc = Accumulator(z, np.full(nlev, vs), bomex_air_density(z), vs * k, vs * k, ql_threshold)
    frames = []
    for f in man["frames"]:
        t = times.get(f["frame"])
        vdbs = [x["path"] for x in f["files"] if x["path"].endswith(".vdb")]
        if t is not None and vdbs and in_window(t, window):
            frames.append((f["frame"], t, vdbs[0]))
    for frame, t, rel in sorted(frames):
        grid = vdb.read(os.path.join(path, rel), gname)
        field = np.zeros((nx, ny, nlev), np.float32)
        lo, hi = grid.evalActiveVoxelBoundingBox()
        if hi[0] >= lo[0]:
            a = np.zeros([h - l + 1 for l, h in zip(lo, hi)], np.float32)
            grid.copyToArray(a, ijk=lo)
            # world position (m) of each index's voxel centre, per file axis
            w0 = np.array(grid.transform.indexToWorld(lo)) * scale
            pos = [w0[i] + np.arange(a.shape[i]) * vs for i in range(3)]
            if up == "y":  # file (x, y, z) = nimbus (x, up, z)
                a, (px, pz, pl) = a.transpose(0, 2, 1), (pos[0], pos[2], pos[1])
            else:  # up z: file (x, y, z) = nimbus (x, -z, up)
                px, pz, pl = pos
            ix = np.floor(px / vs).astype(int) % nx
            iy = np.floor(pz / vs).astype(int) % ny
            il = np.floor(pl / vs).astype(int)
            if il.min() < 0 or il.max() >= nlev:
                fail(f"{rel}: density voxels outside the domain's height 0-{size[1]:g} m")
            field[np.ix_(ix, iy, il)] = a
        if k > 1:  # block means over k x k voxel columns, level by level
            field = field.reshape(nx // k, k, ny // k, k, nlev).mean(axis=(1, 3))
        acc.add(t, field / dscale)
    source = {"kind": "nimbus", "path": os.path.abspath(path), "shot": man["shot"],
              "spacing_m": vs, "column_m": vs * k, "domain_m": size, "frame_seconds": man["export"]["frame_seconds"],
              "air_density": "hydrostatic BOMEX initial state, 1015 hPa (tools/cloud_stats.py)"}
    return acc, source


def read_microhh(path, window, ql_threshold):
    netCDF4 = need("netCDF4", "python3-netcdf4")

    inis = [p for p in glob.glob(os.path.join(path, "*.ini"))]
    if len(inis) != 1:
        fail(f"{path}: expected one MicroHH .ini, found {len(inis)}")
    case = os.path.splitext(os.path.basename(inis[0]))[0]
    ini = configparser.ConfigParser(interpolation=None, strict=False, inline_comment_prefixes="#")
    ini.optionxform = str
    ini.read(inis[0])
    g = ini["grid"]
    itot, jtot, ktot = int(g["itot"]), int(g["jtot"]), int(g["ktot"])
    xsize, ysize, zsize = float(g["xsize"]), float(g["ysize"]), float(g["zsize"])
    gridfile = os.path.join(path, "grid.0000000")
    n_grid = 2 * itot + 2 * jtot + 2 * ktot
    prec = "f8" if os.path.getsize(gridfile) == 8 * n_grid else "f4"
    gr = np.fromfile(gridfile, "<" + prec)
    o = 2 * itot + 2 * jtot
    z, zh = gr[o:o + ktot], np.append(gr[o + ktot:o + 2 * ktot], zsize)
    dz = np.diff(zh)
    with netCDF4.Dataset(os.path.join(path, f"{case}.default.0000000.nc")) as nc:
        nc.set_auto_mask(False)
        # the anelastic reference density: what MicroHH itself integrates ql_path with
        rho = np.asarray(nc["default"]["rhoref"][:], float)
        zs = np.asarray(nc["z"][:], float)
    if not np.allclose(zs, z):
        fail(f"{path}: grid.0000000 and the statistics file disagree on z")
    acc = Accumulator(z, dz, rho, xsize / itot, ysize / jtot, ql_threshold)
    dumps = sorted((int(m.group(1)), p) for p in glob.glob(os.path.join(path, "ql.*"))
                   if (m := re.fullmatch(r"ql\.(\d{7})", os.path.basename(p))))
    lwp_check = []
    for t, p in dumps:
        if not in_window(t, window):
            continue
        # MicroHH writes x fastest, then y, then z
        ql = np.fromfile(p, "<" + prec).reshape(ktot, jtot, itot).transpose(2, 1, 0)
        acc.add(t, ql)
        cross = os.path.join(path, f"ql_path.xy.000.{t:07d}")
        if os.path.exists(cross):
            ref = np.fromfile(cross, "<" + prec).reshape(jtot, itot).T
            mine = (ql * (rho * dz)).sum(axis=2)
            lwp_check.append(float(abs(mine - ref).max() / max(ref.max(), 1e-12)))
    source = {"kind": "microhh", "path": os.path.abspath(path), "case": case,
              "grid": [itot, jtot, ktot], "size_m": [xsize, ysize, zsize],
              "air_density": "MicroHH anelastic reference density (statistics file, default/rhoref)",
              "ql_path_crosscheck_max_rel_diff": max(lwp_check) if lwp_check else None}
    return acc, source


def load(path, window, ql_threshold, meta, column=None, particles=False):
    try:
        return read_source(path, window, ql_threshold, meta, column, particles)
    except OSError as e:
        fail(f"{path}: {e}", 3)
    except (KeyError, ValueError, TypeError, IndexError) as e:
        fail(f"{path}: not a readable run or record ({type(e).__name__}: {e})")


def read_nimbus_particles(path, window, ql_threshold, column=None):
    """A nimbus run's particles (its checkpoints in the window) deposited on cells of the particle
    spacing (columns of `column` metres if given): each particle's water into the cell holding
    it, times its volume over the cell's, so the water is kept and a cell is cloudy when a
    particle in it is; the model's own state, without the export kernel's smoothing."""
    from mean_profiles import read_checkpoint_sections, section_array  # it imports this module

    man = json.load(open(os.path.join(path, "manifest.json")))
    cfg = man["config"]
    size = [float(v) for v in cfg["domain"]["size"]]
    sp = float(cfg["domain"]["spacing"])
    c = float(column) if column is not None else sp
    nx, ny, nlev = (int(round(size[0] / c)), int(round(size[2] / c)), int(round(size[1] / sp)))
    if min(nx, ny) < 1 or abs(nx * c - size[0]) > 1e-6 * size[0] or abs(ny * c - size[2]) > 1e-6 * size[2]:
        fail(f"--columns {c:g}: does not divide the domain's {size[0]:g} x {size[2]:g} m")
    z = (np.arange(nlev) + 0.5) * size[1] / nlev
    dz = size[1] / nlev
    acc = Accumulator(z, np.full(nlev, dz), bomex_air_density(z), c, c, ql_threshold)
    paths = sorted(glob.glob(os.path.join(path, "checkpoints", "*.nck")))
    for cp in paths:
        _frame, t, sec = read_checkpoint_sections(cp)
        if not window[0] - 1.0 <= t <= window[1] + 1.0:  # a checkpoint's time drifts by ~1e-5 s
            continue
        pos = section_array(sec, "pos").astype(float)
        ql = section_array(sec, "thermo")[:, 2].astype(float)
        level = section_array(sec, "info", "<u4", 2)[:, 1].astype(float)
        vol = sp ** 3 * np.exp2(-level) / (c * c * dz)
        i = np.floor(pos[:, 0] / c).astype(int) % nx
        j = np.floor(pos[:, 2] / c).astype(int) % ny
        k = np.clip(np.floor(pos[:, 1] / dz).astype(int), 0, nlev - 1)
        field = np.zeros(nx * ny * nlev)
        np.add.at(field, (i * ny + j) * nlev + k, ql * vol)
        acc.add(t, field.reshape(nx, ny, nlev))
    source = {"kind": "nimbus particles", "path": os.path.abspath(path), "shot": man["shot"],
              "spacing_m": sp, "column_m": c, "domain_m": size,
              "air_density": "hydrostatic BOMEX initial state, 1015 hPa (tools/cloud_stats.py)"}
    return acc, source


def read_source(path, window, ql_threshold, meta, column=None, particles=False):
    if os.path.isfile(path) and path.endswith(".json"):
        rec = json.load(open(path))
        if rec.get("schema") != SCHEMA:
            fail(f"{path}: not a {SCHEMA} file")
        if abs(rec["definitions"]["ql_threshold"] - ql_threshold) > 1e-15:
            fail(f"{path}: written with --ql-threshold {rec['definitions']['ql_threshold']:g}, "
                 f"not {ql_threshold:g}; recompute it from the run")
        if tuple(rec["definitions"]["window"]) != tuple(window):
            fail(f"{path}: written for the window {rec['definitions']['window'][0]:g},"
                 f"{rec['definitions']['window'][1]:g} s, not {window[0]:g},{window[1]:g}; "
                 "recompute it from the run")
        return rec
    if os.path.exists(os.path.join(path, "manifest.json")) and particles:
        acc, source = read_nimbus_particles(path, window, ql_threshold, column)
    elif os.path.exists(os.path.join(path, "manifest.json")):
        acc, source = read_nimbus(path, window, ql_threshold, column)
    elif os.path.exists(os.path.join(path, "grid.0000000")):
        acc, source = read_microhh(path, window, ql_threshold)
    else:
        fail(f"{path}: neither a nimbus run (manifest.json), a MicroHH run (grid.0000000) nor a "
             f"{SCHEMA} JSON file")
    return acc.record(source, window, meta)


# --- statistics from the record --------------------------------------------------------------


def crossing(z, f, thr, from_top):
    """Height where profile f first reaches thr, scanning up (base) or down (top)."""
    idx = np.nonzero(f >= thr)[0]
    if len(idx) == 0:
        return None
    k = idx[-1] if from_top else idx[0]
    j = k + 1 if from_top else k - 1
    if j < 0 or j >= len(z):
        return float(z[k])
    return float(z[j] + (thr - f[j]) / (f[k] - f[j]) * (z[k] - z[j]))


def min_columns(rec, min_area):
    """The fewest columns a cloud of at least min_area (m^2) has on this grid (at least 1)."""
    g = rec["grid"]
    return max(1, math.ceil(min_area / (g["dx"] * g["dy"]) - 1e-9))


def size_distribution(rec, min_area, max_size, min_count):
    cl = np.array(rec["clouds"], float).reshape(-1, 3)
    g = rec["grid"]
    px = g["dx"] * g["dy"]
    norm = rec["snapshots"] * g["domain_area"]
    if len(cl) == 0:
        return [], None
    top = int(math.ceil(math.log2(cl[:, 0].max() + 1))) + 1
    bins = []
    for i in range(top):  # areas 2^i .. 2^(i+1)-1 columns stand for [2^i - 1/2, 2^(i+1) - 1/2)
        a0, a1 = 2 ** i, 2 ** (i + 1)
        sel = (cl[:, 0] >= a0) & (cl[:, 0] < a1)
        count = int(cl[sel, 2].sum())
        l0, l1 = math.sqrt((a0 - 0.5) * px), math.sqrt((a1 - 0.5) * px)
        bins.append({"area_columns": [a0, a1 - 1], "L": math.sqrt(l0 * l1), "L_edges": [l0, l1],
                     "count": count, "n": count / (norm * (l1 - l0))})
    fit = [b for b in bins if b["area_columns"][0] >= min_columns(rec, min_area)
           and (max_size is None or b["L_edges"][1] <= max_size)]
    run = []
    for b in fit:  # contiguous bins from the smallest resolved size up
        if b["count"] < min_count:
            break
        run.append(b)
    if len(run) < 3:
        return bins, {"slope": None, "bins": len(run), "why": "fewer than 3 bins with enough clouds"}
    x = np.log10([b["L"] for b in run])
    y = np.log10([b["n"] for b in run])
    slope = float(np.polyfit(x, y, 1)[0])
    return bins, {"slope": slope, "bins": len(run), "clouds": sum(b["count"] for b in run),
                  "L_range": [run[0]["L_edges"][0], run[-1]["L_edges"][1]]}


def fractal_dimension(rec, min_area):
    min_cols = min_columns(rec, min_area)
    cl = np.array(rec["clouds"], float).reshape(-1, 3)
    g = rec["grid"]
    cl = cl[cl[:, 0] >= min_cols] if len(cl) else cl
    n = int(cl[:, 2].sum()) if len(cl) else 0
    if n < 10 or len(np.unique(cl[:, 0])) < 3:
        return {"D": None, "clouds": n, "why": "fewer than 10 clouds of 3 sizes"}
    d = math.sqrt(g["dx"] * g["dy"])
    x = np.log10(np.sqrt(cl[:, 0]) * d)
    y = np.log10(cl[:, 1] * d)
    w = cl[:, 2]
    xm, ym = np.average(x, weights=w), np.average(y, weights=w)
    D = float(np.sum(w * (x - xm) * (y - ym)) / np.sum(w * (x - xm) ** 2))
    return {"D": D, "clouds": n, "area_min_m2": min_cols * g["dx"] * g["dy"],
            "intercept": float(ym - D * xm)}


def summarize(rec, cf_threshold, min_area, max_size, min_count):
    p = rec["profiles"]
    z, cf = np.array(p["z"]), np.array(p["cloud_fraction"])
    t, cover = np.array(rec["series"]["time"]), np.array(rec["series"]["cover"])
    bins, sd = size_distribution(rec, min_area, max_size, min_count)
    trend = None
    if len(t) >= 2 and cover.mean() > 0 and t[-1] > t[0]:
        trend = float(np.polyfit(t, cover, 1)[0] * (t[-1] - t[0]) / cover.mean())
    k = int(np.argmax(cf))
    s = {
        "cloud_base": crossing(z, cf, cf_threshold, False),
        "cloud_top": crossing(z, cf, cf_threshold, True),
        "cf_max": float(cf[k]),
        "cf_max_height": float(z[k]),
        "cover": float(cover.mean()),
        "lwp": float(np.mean(rec["series"]["lwp"])),
        "lwc_in_cloud": rec["lwc_in_cloud"],
        "size_slope": sd["slope"] if sd else None,
        "size_fit": sd,
        "fractal": fractal_dimension(rec, min_area),
        "cover_trend": trend,
        "snapshots": rec["snapshots"],
        "clouds_per_snapshot": sum(c for _, _, c in rec["clouds"]) / rec["snapshots"],
    }
    s["fractal_dimension"] = s["fractal"]["D"]
    return s, bins


# --- output ----------------------------------------------------------------------------------

ROWS = [  # key, label, format
    ("cloud_base", "cloud base (m)", "{:.0f}"),
    ("cloud_top", "cloud top (m)", "{:.0f}"),
    ("cf_max", "max cloud fraction", "{:.4f}"),
    ("cf_max_height", "  at height (m)", "{:.0f}"),
    ("cover", "total cloud cover", "{:.4f}"),
    ("lwp", "LWP (g/m^2)", "{:.2f}"),
    ("lwc_in_cloud", "LWC in cloud (g/m^3)", "{:.3f}"),
    ("size_slope", "size distribution slope", "{:.2f}"),
    ("fractal_dimension", "area-perimeter dimension D", "{:.3f}"),
    ("fractal_clouds", "  clouds it rests on", "{:d}"),
    ("cover_trend", "cover trend / mean (window)", "{:+.3f}"),
    ("clouds_per_snapshot", "clouds per snapshot", "{:.1f}"),
    ("snapshots", "snapshots", "{:d}"),
]


def fmt(v, f):
    return "n/a" if v is None else f.format(v)


def criteria(cand, ref):
    """Issue 39's "Done when" for a nimbus BOMEX shot (first source) against MicroHH (second)."""
    def ratio_ok(a, b, f):
        return a is not None and b is not None and a > 0 and b > 0 and max(a / b, b / a) <= f

    def within(a, b, d):
        return a is not None and b is not None and abs(a - b) <= d

    D = cand["fractal_dimension"]
    return [
        ("cloud base within 100 m", within(cand["cloud_base"], ref["cloud_base"], 100)),
        ("cloud top within 250 m", within(cand["cloud_top"], ref["cloud_top"], 250)),
        ("cover within a factor 1.5", ratio_ok(cand["cover"], ref["cover"], 1.5)),
        ("max cloud fraction within a factor 1.5", ratio_ok(cand["cf_max"], ref["cf_max"], 1.5)),
        ("LWP within a factor 2", ratio_ok(cand["lwp"], ref["lwp"], 2.0)),
        ("|cover trend| <= 30% of mean", cand["cover_trend"] is not None
         and abs(cand["cover_trend"]) <= 0.3),
        ("fractal dimension in [1.2, 1.45]", D is not None and 1.2 <= D <= 1.45),
    ]


def table(summaries, labels):
    w = max(len(l) for _, l, _ in ROWS) + 2
    cw = max(14, *(len(l) + 2 for l in labels))
    lines = ["".ljust(w) + "".join(l.rjust(cw) for l in labels)]
    for key, label, f in ROWS:
        vals = [s["fractal"]["clouds"] if key == "fractal_clouds" else s[key] for s in summaries]
        lines.append(label.ljust(w) + "".join(fmt(v, f).rjust(cw) for v in vals))
    for s, l in zip(summaries, labels):
        sd = s["size_fit"]
        if sd and sd.get("slope") is not None:
            lines.append(f"{l}: size fit over L = {sd['L_range'][0]:.0f}-{sd['L_range'][1]:.0f} m, "
                         f"{sd['bins']} bins, {sd['clouds']} clouds")
        fr = s["fractal"]
        if fr["D"] is not None:
            lines.append(f"{l}: D from {fr['clouds']} clouds of area >= {fr['area_min_m2']:.0f} m^2")
    return "\n".join(lines)


def plot(records, summaries, bins_list, labels, out):
    matplotlib = need("matplotlib", "python3-matplotlib")
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(2, 3, figsize=(13, 8))
    span = max(r["series"]["time"][-1] for r in records)
    tunit = (3600.0, "h") if span > 7200 else (60.0, "min")
    for rec, s, bins, lab in zip(records, summaries, bins_list, labels):
        p = rec["profiles"]
        z = np.array(p["z"])
        (line,) = ax[0, 0].plot(p["cloud_fraction"], z, label=lab)
        c = line.get_color()
        for h in (s["cloud_base"], s["cloud_top"]):
            if h is not None:
                ax[0, 0].axhline(h, color=c, ls=":", lw=0.8)
        lwc = np.array(p["ql_in_cloud"]) * np.array(p["rho"]) * 1000.0
        if s["cloud_base"] is not None:  # only within the cloud layer: above it, a few cells
            lwc[(z < s["cloud_base"]) | (z > s["cloud_top"])] = np.nan
        ax[0, 1].plot(lwc, z, color=c, label=lab)
        th = np.array(rec["series"]["time"]) / tunit[0]
        ax[0, 2].plot(th, rec["series"]["cover"], color=c, label=lab)
        ax[1, 0].plot(th, rec["series"]["lwp"], color=c, label=lab)
        nb = [b for b in bins if b["count"] > 0]
        ax[1, 1].loglog([b["L"] for b in nb], [b["n"] for b in nb], "o", color=c, label=lab)
        sd = s["size_fit"]
        if sd and sd.get("slope") is not None:
            run = [b for b in nb if sd["L_range"][0] <= b["L"] <= sd["L_range"][1]]
            x = np.array([b["L"] for b in run])
            y0 = np.exp(np.mean(np.log([b["n"] for b in run]) - sd["slope"] * np.log(x)))
            ax[1, 1].loglog(x, y0 * x ** sd["slope"], "-", color=c, label=f"slope {sd['slope']:.2f}")
        cl = np.array(rec["clouds"], float).reshape(-1, 3)
        g = rec["grid"]
        if len(cl):
            d = math.sqrt(g["dx"] * g["dy"])
            ax[1, 2].loglog(np.sqrt(cl[:, 0]) * d, cl[:, 1] * d, ".", color=c, ms=3, alpha=0.4)
        fr = s["fractal"]
        if fr["D"] is not None:
            x = np.sqrt(np.array([fr["area_min_m2"], cl[:, 0].max() * g["dx"] * g["dy"]]))
            ax[1, 2].loglog(x, 10 ** fr["intercept"] * x ** fr["D"], "-", color=c,
                            label=f"{lab}: D = {fr['D']:.2f} ({fr['clouds']} clouds)")
    ax[0, 0].set(xlabel="cloud fraction", ylabel="height (m)", title="cloud fraction")
    ax[0, 1].set(xlabel="LWC in cloud (g/m^3)", ylabel="height (m)", title="liquid water in cloud")
    ax[0, 2].set(xlabel=f"time ({tunit[1]})", ylabel="projected cover", title="cover")
    ax[1, 0].set(xlabel=f"time ({tunit[1]})", ylabel="LWP (g/m^2)", title="liquid water path")
    ax[1, 1].set(xlabel="L = sqrt(A) (m)", ylabel="n(L) (m^-3)", title="cloud size distribution")
    ax[1, 2].set(xlabel="sqrt(A) (m)", ylabel="perimeter (m)", title="area-perimeter")
    for a in ax.flat:
        a.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out, dpi=90)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("sources", nargs="+", metavar="SOURCE")
    ap.add_argument("--window", default="10800,21600", help="T0,T1 in seconds (default 10800,21600)")
    ap.add_argument("--ql-threshold", type=float, default=1e-5)
    ap.add_argument("--cf-threshold", type=float, default=1e-3)
    ap.add_argument("--min-cloud-area", type=float, default=40000.0,
                    help="m^2: smaller clouds stay out of the size fit and D (default 40000)")
    ap.add_argument("--max-cloud-size", type=float,
                    help="m: largest L = sqrt(A) of the size fit (default: no limit)")
    ap.add_argument("--min-bin-count", type=int, default=24)
    ap.add_argument("--columns", type=float, metavar="M",
                    help="m: analyse nimbus runs on columns this wide, block means of their "
                         "voxels (as an LES grid's cells; default: the voxels)")
    ap.add_argument("--particles", action="store_true",
                    help="measure nimbus runs from their particles (the checkpoints in the "
                         "window) on cells of the particle spacing, not from the exported voxels")
    ap.add_argument("--labels", help="comma-separated names of the sources")
    ap.add_argument("--json", help="write the first source's record and statistics here")
    ap.add_argument("--meta", help="JSON file of provenance to store in --json's record")
    ap.add_argument("--plot", help="PNG of profiles, series, size distribution, area-perimeter")
    ap.add_argument("--criteria", action="store_true",
                    help="issue 39's pass/fail of the first source against the second")
    a = ap.parse_args(argv)
    try:
        window = tuple(float(x) for x in a.window.split(","))
        assert len(window) == 2 and window[0] <= window[1]
    except (ValueError, AssertionError):
        fail(f"--window {a.window}: expected T0,T1 in seconds with T0 <= T1")
    labels = a.labels.split(",") if a.labels else [os.path.basename(os.path.normpath(s))
                                                   for s in a.sources]
    if len(labels) != len(a.sources):
        fail("--labels needs one name per source")
    meta = json.load(open(a.meta)) if a.meta else None
    for s in a.sources:
        if not os.path.exists(s):
            fail(f"{s}: no such file or directory")
    records = [load(s, window, a.ql_threshold, meta, a.columns, a.particles) for s in a.sources]
    out = [summarize(r, a.cf_threshold, a.min_cloud_area, a.max_cloud_size, a.min_bin_count)
           for r in records]
    summaries, bins_list = [o[0] for o in out], [o[1] for o in out]
    print(f"window {window[0]:g}-{window[1]:g} s; cloudy: ql > {a.ql_threshold:g} kg/kg; "
          f"base/top: cloud fraction >= {a.cf_threshold:g}")
    print(table(summaries, labels))
    for r, l in zip(records, labels):
        c = r["source"].get("ql_path_crosscheck_max_rel_diff")
        if c is not None:
            print(f"{l}: LWP columns against MicroHH's ql_path cross-sections: max rel. diff {c:.1e}")
    if a.json:
        rec = dict(records[0])
        rec["definitions"] = dict(rec["definitions"], cf_threshold=a.cf_threshold,
                                  min_cloud_area=a.min_cloud_area,
                                  max_cloud_size=a.max_cloud_size,
                                  min_bin_count=a.min_bin_count)
        rec["summary"] = summaries[0]
        rec["size_bins"] = bins_list[0]
        with open(a.json, "w") as f:
            json.dump(rec, f, separators=(",", ":"))
            f.write("\n")
    if a.plot:
        plot(records, summaries, bins_list, labels, a.plot)
    if a.criteria:
        if len(records) != 2:
            fail("--criteria compares two sources")
        res = criteria(*summaries)
        for name, ok in res:
            print(f"{'PASS' if ok else 'FAIL'}  {name}")
        if not all(ok for _, ok in res):
            sys.exit(1)


if __name__ == "__main__":
    main()
