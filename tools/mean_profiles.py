#!/usr/bin/env python3
"""Horizontal-mean theta_l, q_t, cloud water and wind profiles of a nimbus run or a MicroHH run.

    /usr/bin/python3 tools/mean_profiles.py SOURCE [SOURCE...] [--window T0,T1] [--dz M]
        [--labels A,B] [--json OUT] [--meta META.json] [--plot PNG] [--nimbus-frame-u U]
        [--dynamics] [--convective FLUX]

A SOURCE is one of:
- a nimbus run directory (thermodynamics: atmospheric): its checkpoints (checkpoints/*.nck)
  whose simulated time lies in the window. Each particle gives theta_l = (T - Q w)
  (p0 / p(y))^(R_d / c_p), with p(y) the run's reference pressure (sim::thermo::Pressure), and
  q_t = v + w; layers of --dz metres (default 100) average them with equal weight per particle
  (particles of one level share one mass); u, v are the mean horizontal velocities east (x)
  and north (-z: y is up, and `physics.wind.coriolis` > 0 turns the air to its right);
- a MicroHH run directory: its statistics file (<case>.default.0000000.nc, groups `thermo` and
  `default`), the snapshots in the window;
- a JSON file this tool wrote (--json): the profiles it holds.

With --dynamics it also prints the vertical velocity variance w'^2 and the vertical fluxes
w'q_t' and w'theta_l' of each source: for nimbus the particles' departures from their layer's
mean, per snapshot, averaged over the snapshots (the resolved flux); for MicroHH its statistics
file's w_2, qt_flux and thl_flux (resolved plus subgrid), moved from its half levels to the full
levels by linear interpolation. A JSON file written before these keys existed has none.
--plot draws theta_l, q_t, q_l and the wind, and w'^2 on a log axis for the sources that have
it.

With --convective FLUX (the surface buoyancy flux w'theta_v' in K m/s) it also scales each
nimbus source as a convective boundary layer (Deardorff 1970): z_i is the lowest height where
d theta_v/dz between two layers reaches half the mean gradient of the column's upper third (the
free atmosphere above the capping inversion), w* = (g / theta_v FLUX z_i)^(1/3) with theta_v
the mean below z_i, and w'^2 / w*^2 of each layer is printed against the fit of Lenschow et
al. (1980, J. Atmos. Sci. 37, 1313) to aircraft measurements of convective boundary layers,
1.8 (z/z_i)^(2/3) (1 - 0.8 z/z_i)^2 (at most 0.46, at z/z_i = 0.33). Needs --dynamics's w'^2;
--json writes the scaling as the record's "convective".

Window default 10800-21600 s (hours 3-6 of BOMEX). Prints the profiles side by side at the
heights of the first source, with the BOMEX initial state. --json writes the first source's
profiles (schema nimbus.mean_profiles/1) with the provenance of --meta.
Needs numpy; netCDF4 for MicroHH; matplotlib for --plot (tools/setup.sh installs them).
"""
import argparse
import glob
import json
import math
import os
import struct
import sys

P00 = 100000.0
CP_OVER_RD = 3.4978  # c_p / R_d as sim::thermo::CP_OVER_RD
Q = 2500.0  # L / c_p (K per kg/kg), as nimbus's latent_heat default
VIRTUAL_FACTOR = 0.608  # R_v / R_d - 1, as sim::thermo::VIRTUAL_FACTOR


def fail(msg, code=2):
    print(f"error: {msg}", file=sys.stderr)
    sys.exit(code)


try:
    import numpy as np
except ImportError:
    fail("numpy is missing: run tools/setup.sh (Debian python3-numpy) and use /usr/bin/python3")


# The BOMEX initial theta_l and q_t: one definition, cloud_stats.py's (this file's directory
# is on sys.path when it runs as a script).
from cloud_stats import bomex_initial  # noqa: E402


def read_checkpoint(path):
    """(frame, sim time, pos, thermo, vel) of a nimbus checkpoint (src/io/checkpoint/format.rs)."""
    frame, time, sec = read_checkpoint_sections(path)
    try:
        arr = lambda k: section_array(sec, k).astype(float)
        return frame, time, arr("pos"), arr("thermo"), arr("vel")
    except (KeyError, ValueError) as e:
        fail(f"{path}: not a readable nimbus checkpoint ({e})", 3)


def section_array(sec, name, dtype="<f4", width=4):
    """A checkpoint section as rows of `width` values (pos, vel, thermo: 4 f32; info: 2 u32)."""
    return np.frombuffer(sec[name], dtype).reshape(-1, width)


def read_checkpoint_sections(path):
    """(frame, sim time, {section name: bytes}) of a nimbus checkpoint."""
    try:
        return checkpoint_sections(path, open(path, "rb").read())
    except (OSError, struct.error, KeyError, ValueError, UnicodeDecodeError) as e:
        fail(f"{path}: not a readable nimbus checkpoint ({e})", 3)


def checkpoint_sections(path, b):
    if b[:8] != b"NIMBUSCK":
        fail(f"{path}: not a nimbus checkpoint")
    h = struct.unpack_from("<I", b, 12)[0]
    o = 16 + 8
    for _ in range(2):  # tool version, config hash
        n = struct.unpack_from("<H", b, o)[0]
        o += 2 + n
    frame, _step, time = struct.unpack_from("<IQd", b, o)
    o = 16 + h + 4
    sec = {}
    while o < len(b) - 32:
        n = struct.unpack_from("<H", b, o)[0]
        name = b[o + 2:o + 2 + n].decode()
        o += 2 + n
        size = struct.unpack_from("<Q", b, o)[0]
        sec[name] = b[o + 8:o + 8 + size]
        o += 8 + size + 4
    return frame, time, sec


def read_nimbus(run, window, dz):
    manifest = json.load(open(os.path.join(run, "manifest.json")))
    cfg = manifest["config"]
    ph = cfg["physics"]
    if ph.get("thermodynamics", "paper") != "atmospheric":
        fail(f"{run}: theta_l needs thermodynamics: atmospheric (the paper's has no pressure)")
    levels = ph["environment"].get("profile") or []
    if not levels:
        fail(f"{run}: needs physics.environment.profile (the surface temperature of the reference atmosphere)")
    t_s = levels[0]["temperature"] if levels[0]["height"] <= 0 else None
    if t_s is None:
        fail(f"{run}: the profile's first level must be at the ground")
    gamma = ph.get("adiabatic_lapse_rate", 0.0098)
    p_s = ph.get("surface_pressure") or P00
    q = ph.get("latent_heat", Q)
    height = cfg["domain"]["size"][1]
    top = t_s / gamma
    n = int(math.ceil(height / dz))
    acc = np.zeros((n, 6))
    count = np.zeros(n)
    # w'^2, w'q_t', w'theta_l' of each snapshot's layers, summed over the snapshots
    dyn = np.zeros((n, 3))
    times = []
    for path in sorted(glob.glob(os.path.join(run, "checkpoints", "*.nck"))):
        _frame, t, pos, th, vel = read_checkpoint(path)
        if not (window[0] - 1.0 <= t <= window[1] + 1.0):  # frame times drift by ~1e-4 s
            continue
        times.append(t)
        y = pos[:, 1]
        p = p_s * (1.0 - y / top) ** CP_OVER_RD
        exner = (P00 / p) ** (1.0 / CP_OVER_RD)
        theta_l = (th[:, 0] - q * th[:, 2]) * exner
        theta_v = th[:, 0] * exner * (1.0 + VIRTUAL_FACTOR * th[:, 1] - th[:, 2])
        k = np.clip((y // dz).astype(int), 0, n - 1)
        q_t = th[:, 1] + th[:, 2]
        for j, f in enumerate([theta_l, q_t, th[:, 2], vel[:, 0], -vel[:, 2], theta_v]):
            acc[:, j] += np.bincount(k, f, n)
        here = np.bincount(k, None, n)
        count += here
        layer_mean = lambda f: (np.bincount(k, f, n) / np.maximum(here, 1))[k]
        w = vel[:, 1] - layer_mean(vel[:, 1])
        for j, f in enumerate([w, q_t - layer_mean(q_t), theta_l - layer_mean(theta_l)]):
            dyn[:, j] += np.bincount(k, w * f, n) / np.maximum(here, 1)
    if not times:
        fail(f"{run}: no checkpoint in the window {window[0]:g}-{window[1]:g} s")
    m = acc / np.maximum(count, 1)[:, None]
    d = dyn / len(times)
    z = (np.arange(n) + 0.5) * dz
    return {"kind": "nimbus", "path": os.path.abspath(run), "snapshots": len(times),
            "times": times, "z": z.tolist(), "thl": m[:, 0].tolist(), "qt": m[:, 1].tolist(),
            "ql": m[:, 2].tolist(), "u": m[:, 3].tolist(), "v": m[:, 4].tolist(),
            "thv": m[:, 5].tolist(), "count": count.tolist(),
            "w2": d[:, 0].tolist(), "wqt": d[:, 1].tolist(), "wthl": d[:, 2].tolist(),
            "note": f"checkpoints; layers of {dz:g} m; u, v in the simulation's frame (x, -z)"}


def read_microhh(run, window):
    try:
        import netCDF4
    except ImportError:
        fail("netCDF4 is missing: apt-get install python3-netcdf4 and use /usr/bin/python3")
    files = sorted(glob.glob(os.path.join(run, "*.default.0000000.nc")))
    if not files:
        fail(f"{run}: no MicroHH statistics file (*.default.0000000.nc)")
    f = netCDF4.Dataset(files[0])
    t = np.asarray(f["time"][:], float)
    sel = (t >= window[0]) & (t <= window[1])
    if not sel.any():
        fail(f"{run}: no statistics in the window")
    mean = lambda g, v: np.asarray(f[g][v][sel, :], float).mean(axis=0).tolist()
    z = np.asarray(f["z"][:], float)
    zh = np.asarray(f["zh"][:], float)
    full = lambda g, v: np.interp(z, zh, np.asarray(f[g][v][sel, :], float).mean(axis=0)).tolist()
    utrans = 0.0
    ini = glob.glob(os.path.join(run, "*.ini"))
    if ini:
        for line in open(ini[0]):
            if line.strip().startswith("utrans="):
                utrans = float(line.split("=")[1])
    return {"kind": "microhh", "path": os.path.abspath(run), "snapshots": int(sel.sum()),
            "z": z.tolist(), "thl": mean("thermo", "thl"),
            "qt": mean("thermo", "qt"), "ql": mean("thermo", "ql"), "u": mean("default", "u"),
            "v": mean("default", "v"), "w2": full("default", "w_2"),
            "wqt": full("thermo", "qt_flux"), "wthl": full("thermo", "thl_flux"), "utrans": utrans,
            "note": "statistics file; u, v in the ground frame (MicroHH adds back its utrans)"}


def load(src, window, dz):
    if src.endswith(".json"):
        rec = json.load(open(src))
        if rec.get("schema") != "nimbus.mean_profiles/1":
            fail(f"{src}: not a mean_profiles record")
        return rec["profiles"]
    if os.path.exists(os.path.join(src, "manifest.json")):
        return read_nimbus(src, window, dz)
    if glob.glob(os.path.join(src, "*.default.0000000.nc")):
        return read_microhh(src, window)
    fail(f"{src}: neither a nimbus run, a MicroHH run nor a mean_profiles JSON")


def at(rec, key, z):
    return np.interp(z, rec["z"], rec[key])


def print_dynamics(recs, labels, z):
    """w'^2 (m^2/s^2), w'q_t' (g/kg m/s) and w'theta_l' (K m/s) side by side; "-" for a JSON
    source written without them."""
    cell = lambda r, key, zi, scale, f: f"{scale * at(r, key, zi):{f}}" if key in r else "-"
    wide = [max(14, len(l) + 6) for l in labels]
    print("\n  z (m)   " + "".join(f"{'w2 ' + l:>{n}}{'wqt ' + l:>{n}}{'wthl ' + l:>{n}}" for l, n in zip(labels, wide)))
    for zi in z:
        row = f"{zi:8.0f}  "
        for r, n in zip(recs, wide):
            row += f"{cell(r, 'w2', zi, 1.0, '.4f'):>{n}}{cell(r, 'wqt', zi, 1e3, '.5f'):>{n}}{cell(r, 'wthl', zi, 1.0, '.5f'):>{n}}"
        print(row)


def lenschow(x):
    """w'^2 / w*^2 at z / z_i: Lenschow, Wyngaard & Pennell (1980)'s fit to aircraft data."""
    return 1.8 * x ** (2.0 / 3.0) * (1.0 - 0.8 * x) ** 2 if 0.0 <= x <= 1.25 else 0.0


def convective_scaling(rec, flux, label):
    """z_i, w* and w'^2 / w*^2 of a nimbus source (--convective's definitions, above)."""
    if "thv" not in rec or "count" not in rec or "w2" not in rec:
        fail(f"{label}: --convective needs a nimbus run (its theta_v and w'^2)")
    held = np.asarray(rec["count"]) > 0  # a layer above the domain's top holds no particle
    z, thv, w2 = (np.asarray(rec[k], float)[held] for k in ("z", "thv", "w2"))
    grad = np.diff(thv) / np.diff(z)
    mid = 0.5 * (z[1:] + z[:-1])
    upper = z >= z[-1] - (z[-1] - z[0]) / 3.0
    free = (thv[upper][-1] - thv[upper][0]) / (z[upper][-1] - z[upper][0])
    if not (free > 0 and (grad >= 0.5 * free).any()):
        fail(f"{label}: --convective needs a stable free atmosphere above the boundary layer")
    j = int(np.argmax(grad >= 0.5 * free))
    zi = mid[0] if j == 0 else np.interp(0.5 * free, [grad[j - 1], grad[j]], [mid[j - 1], mid[j]])
    th0 = thv[z < zi].mean() if (z < zi).any() else thv[0]
    ws = (9.81 / th0 * flux * zi) ** (1.0 / 3.0)
    rows = [{"z": float(a), "z_zi": float(a / zi), "w2": float(b), "w2_ws2": float(b / ws ** 2),
             "lenschow": lenschow(a / zi)} for a, b in zip(z, w2)]
    return {"flux": flux, "zi": float(zi), "free_gradient": float(free), "theta_v": float(th0),
            "wstar": float(ws), "max_w2_ws2": float(w2.max() / ws ** 2),
            "at_z_zi": float(z[np.argmax(w2)] / zi), "layers": rows}


def print_convective(c, label):
    print(f"\n{label}: z_i {c['zi']:.0f} m (d theta_v/dz reaches half of the upper third's "
          f"{1e3 * c['free_gradient']:.2f} K/km), w* {c['wstar']:.3f} m/s from {c['flux']:g} K m/s")
    print("  z (m)   z/z_i   w'^2   w'^2/w*^2   Lenschow 1980")
    for r in c["layers"]:
        if r["z_zi"] <= 1.5:
            print(f"{r['z']:7.0f}  {r['z_zi']:6.2f}  {r['w2']:6.3f}  {r['w2_ws2']:9.3f}  {r['lenschow']:9.3f}")
    print(f"  most w'^2/w*^2: {c['max_w2_ws2']:.3f} at z/z_i {c['at_z_zi']:.2f} (Lenschow 1980: 0.46 at 0.33)")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("sources", nargs="+")
    ap.add_argument("--window", default="10800,21600")
    ap.add_argument("--dz", type=float, default=100.0)
    ap.add_argument("--labels")
    ap.add_argument("--json")
    ap.add_argument("--meta")
    ap.add_argument("--plot")
    ap.add_argument("--dynamics", action="store_true",
                    help="also print w'^2, w'q_t' and w'theta_l' of each source")
    ap.add_argument("--convective", type=float, metavar="FLUX",
                    help="scale each nimbus source as a convective boundary layer with this surface buoyancy flux (K m/s)")
    ap.add_argument("--nimbus-frame-u", type=float, default=0.0,
                    help="speed (m/s, along x) of the frame a nimbus run's wind is given in; added to its u in the plot (BOMEX: -8)")
    a = ap.parse_args(argv)
    try:
        window = [float(x) for x in a.window.split(",")]
        assert len(window) == 2 and window[0] <= window[1]
    except (ValueError, AssertionError):
        fail("--window wants T0,T1 with T0 <= T1")
    if not a.dz > 0:
        fail("--dz must be > 0")
    if a.convective is not None and not (a.convective > 0 and a.dynamics):
        fail("--convective wants a surface buoyancy flux > 0 (K m/s) and --dynamics")
    frame_u = a.nimbus_frame_u
    recs = [load(s, window, a.dz) for s in a.sources]
    labels = a.labels.split(",") if a.labels else [os.path.basename(s.rstrip("/")) for s in a.sources]
    if len(labels) != len(recs):
        fail("--labels needs one name per source")
    z = np.asarray(recs[0]["z"])
    th0, qt0 = bomex_initial(z)
    head = "  z (m)   " + "".join(f"{'thl ' + l:>16}{'qt ' + l:>14}{'ql ' + l:>13}" for l in labels)
    print(f"window {window[0]:g}-{window[1]:g} s; snapshots: " + ", ".join(f"{l} {r['snapshots']}" for l, r in zip(labels, recs)))
    print(head + f"{'thl BOMEX t=0':>16}{'qt t=0':>10}")
    for i, zi in enumerate(z):
        row = f"{zi:8.0f}  "
        for r in recs:
            row += f"{at(r, 'thl', zi):16.2f}{1e3 * at(r, 'qt', zi):14.2f}{1e3 * at(r, 'ql', zi):13.4f}"
        print(row + f"{th0[i]:16.2f}{1e3 * qt0[i]:10.2f}")
    if a.dynamics:
        print_dynamics(recs, labels, z)
    scaling = [convective_scaling(r, a.convective, l) for r, l in zip(recs, labels)] if a.convective else []
    for c, l in zip(scaling, labels):
        print_convective(c, l)
    if a.json:
        rec = {"schema": "nimbus.mean_profiles/1", "window": window, "profiles": recs[0]}
        if scaling:
            rec["convective"] = scaling[0]
        if a.meta:
            rec["meta"] = json.load(open(a.meta))
        with open(a.json, "w") as out:
            json.dump(rec, out, indent=1)
    if a.plot:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        # a fifth panel, w'^2 on a log axis, when a source has it (--dynamics's variance)
        dyn = any("w2" in r for r in recs)
        fig, ax = plt.subplots(1, 5 if dyn else 4, figsize=(17 if dyn else 14, 5), sharey=True)
        zz = np.linspace(0, max(r["z"][-1] for r in recs), 200)
        th, qt = bomex_initial(zz)
        for axis, v in [(ax[0], th), (ax[1], 1e3 * qt)]:
            axis.plot(v, zz, "k:", label="BOMEX t = 0")
        for r, l in zip(recs, labels):
            zr = np.asarray(r["z"])
            ax[0].plot(r["thl"], zr, label=l)
            ax[1].plot(1e3 * np.asarray(r["qt"]), zr, label=l)
            ax[2].plot(1e3 * np.asarray(r["ql"]), zr, label=l)
            line, = ax[3].plot(np.asarray(r["u"]) + (frame_u if r["kind"] == "nimbus" else 0.0), zr, label=l)
            ax[3].plot(np.asarray(r["v"]), zr, "--", color=line.get_color())
            if dyn and "w2" in r:
                ax[4].plot(np.maximum(np.asarray(r["w2"]), 1e-5), zr, label=l)
        if dyn:
            ax[4].set_xscale("log")
        names = ["theta_l (K)", "q_t (g/kg)", "mean q_l (g/kg)", "u, v dashed (m/s, ground frame)",
                 "w'^2 (m^2/s^2)"]
        for axis, name in zip(ax, names):
            axis.set_xlabel(name)
            axis.grid(alpha=0.3)
        ax[0].set_ylabel("height (m)")
        ax[0].legend(fontsize=8)
        fig.suptitle(f"mean profiles, {window[0] / 3600:g}-{window[1] / 3600:g} h")
        fig.tight_layout()
        fig.savefig(a.plot, dpi=90)


if __name__ == "__main__":
    main()
