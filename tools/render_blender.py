"""Render a nimbus VDB sequence (or one .vdb) headless in Blender with Cycles on the CPU.

Usage (Blender 3.4, Debian 12):
  blender -b --factory-startup --python-exit-code 1 -P tools/render_blender.py -- \
      RUN_DIR_OR_VDB OUT.png [--frame N] [--grid density] [--res W H] [--samples N] \
      [--up auto|y|z] [--motion-blur] [--density-scale auto|X] [--min-coverage F] \
      [--framing auto|domain|volume]

RUN_DIR is a nimbus run directory: its manifest.json names the frames and their files (size and
SHA-256 are checked). The whole `<shot>.<digits>.vdb` sequence is imported as one Volume object
(Blender's own sequence detection) and the scene is set to the requested frame (default: the last
frame in the manifest), so the .blend-equivalent scene is what an artist gets from File > Import.

Exit status 1 (through --python-exit-code 1) when the manifest or the file cannot be read, the
density grid is missing or empty, or the image shows (almost) nothing but background.
Exactly one line starting with 'NIMBUS_BLENDER ' is printed: a JSON summary (ok, error, timings,
grids, density scale, coverage).
"""
import argparse
import hashlib
import json
import math
import os
import re
import struct
import sys
import time
import zlib

import bpy
from mathutils import Vector

T0 = time.time()
TAG = "NIMBUS_BLENDER "
# Optical depth aimed for along a chord through the core of the cloud: a few units gives a cloud
# with a lit side, a shadowed side and soft edges, whatever density units the grid is in.
CORE_OPTICAL_DEPTH = 4.0
# Linear world colour (a pale sky blue) and the sun; both are fixed so the image is comparable.
SKY_RGB = (0.16, 0.28, 0.55)


class RenderFailure(Exception):
    pass


def parse_args():
    argv = sys.argv[sys.argv.index("--") + 1 :] if "--" in sys.argv else []
    p = argparse.ArgumentParser(prog="render_blender.py")
    p.add_argument("input", help="nimbus run directory (with manifest.json) or a .vdb file")
    p.add_argument("output", help="PNG to write")
    p.add_argument("--frame", type=int, default=None, help="frame to render (default: last one)")
    p.add_argument("--grid", default="density", help="grid used as density (default: density)")
    p.add_argument("--res", type=int, nargs=2, default=[320, 240], metavar=("W", "H"))
    p.add_argument("--samples", type=int, default=16)
    p.add_argument(
        "--up",
        choices=["auto", "y", "z"],
        default="auto",
        help="up axis of the VDB; auto (default): the run's export.up_axis from its manifest "
        "(or the file's nimbus_up_axis metadata through pyopenvdb), else y",
    )
    p.add_argument(
        "--motion-blur",
        action="store_true",
        help="Cycles motion blur from the velocity grid (shutter 0.5 frame); the velocity unit "
        "is taken from the run's export.velocity_time",
    )
    p.add_argument(
        "--density-scale",
        default="auto",
        help="Cycles extinction per unit of grid value per scene unit; 'auto' aims at an optical "
        "depth of %g through the core from the grid's max and bbox" % CORE_OPTICAL_DEPTH,
    )
    p.add_argument(
        "--framing",
        choices=["auto", "domain", "volume"],
        default="auto",
        help="box the camera frames and --density-scale auto measures: the run's simulation "
        "domain from its manifest (domain; the same for every frame, and what nimbus's preview "
        "frames), or the volume's bounding box (volume); auto (default): domain for a run "
        "directory, volume for a lone .vdb",
    )
    p.add_argument(
        "--min-coverage",
        type=float,
        default=0.01,
        help="fail when fewer than this fraction of pixels differ from the background",
    )
    a = p.parse_args(argv)
    if a.res[0] < 8 or a.res[1] < 8 or a.samples < 1:
        p.error("--res needs at least 8x8 and --samples at least 1")
    return a


def sha256_file(path):
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def resolve_input(a, report):
    """Returns (vdb file of the frame to render, frame number or None)."""
    src = os.path.abspath(a.input)
    if os.path.isfile(src):
        if a.frame is not None:
            # a single file names its own frame; rendering another one would mislead
            m = re.match(r"^.*?(\d+)\.vdb$", os.path.basename(src), re.I)
            if not m or int(m.group(1)) != a.frame:
                raise RenderFailure(f"--frame {a.frame} does not match file {src}")
        m = re.match(r"^.*?(\d+)\.vdb$", os.path.basename(src), re.I)
        return src, (int(m.group(1)) if m else None)
    if not os.path.isdir(src):
        raise RenderFailure(f"input not found: {src}")
    mpath = os.path.join(src, "manifest.json")
    try:
        with open(mpath) as f:
            man = json.load(f)
        frames = man["frames"]
        shot = man["shot"]
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise RenderFailure(f"{mpath}: not a readable nimbus manifest: {e}")
    report["shot"] = shot
    report["export"] = man.get("export")
    report["fps"] = man.get("fps")
    report["voxel_size"] = man.get("voxel_size")
    try:
        size = [float(v) for v in man["config"]["domain"]["size"]]
        report["domain_size"] = size if len(size) == 3 else None
    except (KeyError, TypeError, ValueError):
        report["domain_size"] = None
    report["grid_origin"] = man.get("grid_origin")
    with_vdb = [
        fr for fr in frames if any(str(x.get("path", "")).endswith(".vdb") for x in fr.get("files", []))
    ]
    if not with_vdb:
        raise RenderFailure(f"{mpath}: no frame with a .vdb file")
    if a.frame is None:
        rec = max(with_vdb, key=lambda fr: fr["frame"])
    else:
        rec = next((fr for fr in with_vdb if fr["frame"] == a.frame), None)
        if rec is None:
            have = sorted(fr["frame"] for fr in with_vdb)
            raise RenderFailure(f"frame {a.frame} not in manifest (frames {have[0]}..{have[-1]})")
    frec = next(x for x in rec["files"] if str(x["path"]).endswith(".vdb"))
    path = os.path.join(src, frec["path"])
    if not os.path.isfile(path):
        raise RenderFailure(f"manifest names {frec['path']} but it is missing")
    size = os.path.getsize(path)
    if "bytes" in frec and size != frec["bytes"]:
        raise RenderFailure(f"{path}: {size} bytes, manifest says {frec['bytes']}")
    if "sha256" in frec and sha256_file(path) != frec["sha256"]:
        raise RenderFailure(f"{path}: SHA-256 differs from the manifest")
    return path, int(rec["frame"])


def sequence_files(path):
    """Every sibling `<prefix><digits>.vdb` of `path`, sorted by frame (Blender groups only the
    files it is given into a sequence; it does not scan the directory)."""
    d, name = os.path.split(path)
    m = re.match(r"^(.*?)(\d+)(\.vdb)$", name, re.I)
    if not m:
        return [name]
    pat = re.compile("^" + re.escape(m.group(1)) + r"(\d+)" + re.escape(m.group(3)) + "$", re.I)
    found = [(int(pm.group(1)), f) for f in os.listdir(d) for pm in [pat.match(f)] if pm]
    return [f for _, f in sorted(found)]


def import_volume(path, frame, a, report):
    scene = bpy.context.scene
    files = sequence_files(path)
    report["sequence_files"] = len(files)
    res = bpy.ops.object.volume_import(
        filepath=path,
        directory=os.path.dirname(path) + os.sep,
        files=[{"name": f} for f in files],
        use_sequence_detection=True,
        align="WORLD",
        location=(0, 0, 0),
    )
    if "FINISHED" not in res or not bpy.context.selected_objects:
        raise RenderFailure(f"volume import of {path} returned {sorted(res)}")
    obj = bpy.context.selected_objects[0]
    vol = obj.data
    if vol.is_sequence:
        # Blender maps scene frame F to file number F - frame_start + 1 + frame_offset; make that
        # the identity so scene frames are nimbus frames (frame 0 included).
        first = int(re.match(r"^.*?(\d+)\.vdb$", files[0], re.I).group(1))
        vol.frame_start = first
        vol.frame_offset = first - 1
        vol.sequence_mode = "CLIP"
    if frame is not None:
        scene.frame_start = min(scene.frame_start, frame)
        scene.frame_end = max(scene.frame_end, frame)
        scene.frame_set(frame)
    up = resolve_up(path, a, report)
    report["up"] = up
    if up == "y":
        # a y-up file in z-up Blender: +90 degrees about x maps +y onto +z
        obj.rotation_euler = (math.radians(90.0), 0.0, 0.0)
    bpy.context.view_layer.update()
    grids = vol.grids
    loaded = grids.load()
    report["volume"] = {
        "is_sequence": bool(vol.is_sequence),
        "frame_duration": vol.frame_duration,
        "frame_filepath": grids.frame_filepath,
        "loaded": bool(loaded),
    }
    if not loaded or grids.error_message:
        raise RenderFailure(f"{path}: Blender could not load the grids: {grids.error_message!r}")
    if os.path.abspath(bpy.path.abspath(grids.frame_filepath)) != os.path.abspath(path):
        raise RenderFailure(f"Blender loaded {grids.frame_filepath} for frame {frame}, expected {path}")
    names = [g.name for g in grids]
    report["grids"] = names
    if a.grid not in names:
        raise RenderFailure(f"density grid {a.grid!r} not in {path} (grids: {names})")
    return obj


def resolve_up(path, a, report):
    if a.up != "auto":
        return a.up
    exp = report.get("export")
    if isinstance(exp, dict) and exp.get("up_axis") in ("y", "z"):
        return exp["up_axis"]
    try:
        import pyopenvdb

        up = pyopenvdb.readMetadata(path).get("nimbus_up_axis")
    except (ImportError, KeyError, RuntimeError):
        up = None
    # nimbus wrote y-up files before export.up_axis existed
    return up if up in ("y", "z") else "y"


def setup_motion_blur(obj, report):
    """Cycles volume motion blur from the velocity grid Blender detected on import."""
    scene = bpy.context.scene
    vol = obj.data
    exp = report.get("export") if isinstance(report.get("export"), dict) else {}
    # a manifest without "export" predates export.velocity_time: m/s of simulated time
    basis = exp.get("velocity_time", "simulated")
    fps = float(report.get("fps") or exp.get("fps") or 24.0)
    scene.render.fps = max(1, int(round(fps)))
    scene.render.fps_base = scene.render.fps / fps
    if basis == "per_frame":
        vol.velocity_unit = "FRAME"
        vol.velocity_scale = 1.0
    elif basis == "playback":
        vol.velocity_unit = "SECOND"
        vol.velocity_scale = 1.0
    else:
        # per second of simulated time: a playback second is frame_seconds x fps of them
        vol.velocity_unit = "SECOND"
        vol.velocity_scale = float(exp.get("frame_seconds", 1.0)) * fps
    scene.render.use_motion_blur = True
    scene.render.motion_blur_shutter = 0.5
    names = [g.name for g in vol.grids]
    if vol.velocity_grid not in names:
        raise RenderFailure(f"motion blur: no velocity grid {vol.velocity_grid!r} in {names}")
    report["motion_blur"] = {
        "velocity_grid": vol.velocity_grid,
        "velocity_unit": vol.velocity_unit,
        "velocity_scale": vol.velocity_scale,
        "basis": basis,
        "shutter": scene.render.motion_blur_shutter,
        "fps": fps,
    }


def world_bbox(obj):
    dg = bpy.context.evaluated_depsgraph_get()
    oe = obj.evaluated_get(dg)
    corners = [oe.matrix_world @ Vector(c) for c in oe.bound_box]
    lo = Vector([min(c[i] for c in corners) for i in range(3)])
    hi = Vector([max(c[i] for c in corners) for i in range(3)])
    return lo, hi


def domain_bbox(report):
    """The run's domain [0, size] (metres, y up) in Blender's world: the export's scale, and
    (x, y, z) -> (x, -z, y) whether the files are y-up (rotated on import) or z-up."""
    exp = report.get("export") if isinstance(report.get("export"), dict) else {}
    s = float(exp.get("scale") or 1.0)
    sx, sy, sz = report["domain_size"]
    return Vector((0.0, -sz / s, 0.0)), Vector((sx / s, 0.0, sy / s))


def grid_max_pyopenvdb(path, grid):
    import pyopenvdb  # Debian's blender runs the system python, where python3-openvdb lives

    _, hi = pyopenvdb.read(path, grid).evalMinMax()
    return float(hi)


def grid_max_mesh(obj, grid):
    """Max of the grid without pyopenvdb (e.g. Blender's own builds): bisect (on a log scale) the
    iso-value at which Blender's Volume to Mesh modifier stops producing vertices."""
    holder = bpy.data.objects.new("_max_probe", bpy.data.meshes.new("_max_probe"))
    bpy.context.scene.collection.objects.link(holder)
    mod = holder.modifiers.new("v2m", "VOLUME_TO_MESH")
    mod.object = obj
    mod.grid_name = grid
    mod.resolution_mode = "GRID"

    def has_voxels_above(t):
        mod.threshold = t
        dg = bpy.context.evaluated_depsgraph_get()
        return len(holder.evaluated_get(dg).data.vertices) > 0

    lo, hi = -30.0, 30.0  # log10 bounds of the search
    if not has_voxels_above(10.0**lo):
        bpy.data.objects.remove(holder)
        return 0.0
    for _ in range(24):  # 60 decades / 2^24: far finer than the factor of ~2 that matters
        mid = 0.5 * (lo + hi)
        if has_voxels_above(10.0**mid):
            lo = mid
        else:
            hi = mid
    bpy.data.objects.remove(holder)
    return 10.0**hi


def build_material(obj, scale, a):
    mat = bpy.data.materials.new("NimbusCloud")
    mat.use_nodes = True
    nt = mat.node_tree
    nt.nodes.clear()
    out = nt.nodes.new("ShaderNodeOutputMaterial")
    pv = nt.nodes.new("ShaderNodeVolumePrincipled")
    pv.inputs["Color"].default_value = (1.0, 1.0, 1.0, 1.0)
    pv.inputs["Density"].default_value = scale
    pv.inputs["Density Attribute"].default_value = a.grid
    pv.inputs["Anisotropy"].default_value = 0.3  # droplets scatter forward; milder with 2 bounces
    # nimbus temperatures are ~250-300 K: physically no visible glow, keep blackbody off
    pv.inputs["Blackbody Intensity"].default_value = 0.0
    nt.links.new(pv.outputs["Volume"], out.inputs["Volume"])
    obj.data.materials.clear()
    obj.data.materials.append(mat)


def build_scene(lo, hi, a):
    scene = bpy.context.scene
    center = (lo + hi) / 2
    size = hi - lo
    cam_data = bpy.data.cameras.new("Camera")
    cam_data.lens = 35.0
    cam_data.sensor_fit = "AUTO"
    cam = bpy.data.objects.new("Camera", cam_data)
    scene.collection.objects.link(cam)
    # from the side (-y in Blender, the front view), slightly raised, looking at the centre
    direction = Vector((0.25, -1.0, 0.18)).normalized()
    aspect = a.res[0] / a.res[1]
    fov_wide = 2 * math.atan(cam_data.sensor_width / (2 * cam_data.lens))
    fov_x = fov_wide if aspect >= 1 else 2 * math.atan(math.tan(fov_wide / 2) * aspect)
    fov_y = 2 * math.atan(math.tan(fov_x / 2) / aspect)
    # distance at which all 8 bbox corners fit the frame with a 10% margin (perspective: a
    # corner at lateral offset l and depth dist - p.d needs l <= tan(fov/2) * (dist - p.d))
    cam.rotation_euler = (-direction).to_track_quat("-Z", "Y").to_euler()
    rot = cam.rotation_euler.to_matrix()
    right, up = rot.col[0], rot.col[1]
    tx, ty = math.tan(fov_x / 2) / 1.1, math.tan(fov_y / 2) / 1.1
    dist = 1e-6
    for i in range(8):
        p = Vector([hi[k] if (i >> k) & 1 else lo[k] for k in range(3)]) - center
        dist = max(dist, abs(p.dot(right)) / tx + p.dot(direction), abs(p.dot(up)) / ty + p.dot(direction))
    radius = max(0.5 * size.length, 1e-6)
    cam.location = center + direction * dist
    cam_data.clip_start = max(dist - 2 * radius, dist * 1e-3)
    cam_data.clip_end = dist + 2 * radius
    scene.camera = cam

    sun_data = bpy.data.lights.new("Sun", type="SUN")
    sun_data.energy = 5.0
    sun_data.angle = math.radians(1.0)
    sun = bpy.data.objects.new("Sun", sun_data)
    # 40 degrees high, from the camera's right (+x) and a little behind it: a lit side, a
    # shadowed side, and the camera not looking into the forward-scattering lobe
    sun.rotation_euler = (math.radians(50.0), 0.0, math.radians(70.0))
    scene.collection.objects.link(sun)

    world = bpy.data.worlds.new("Sky")
    world.use_nodes = True
    bg = world.node_tree.nodes["Background"]
    bg.inputs["Color"].default_value = SKY_RGB + (1.0,)
    bg.inputs["Strength"].default_value = 1.0
    scene.world = world

    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = a.samples
    scene.cycles.use_adaptive_sampling = False
    scene.cycles.use_denoising = False
    scene.cycles.max_bounces = 4
    scene.cycles.volume_bounces = 2
    scene.cycles.volume_step_rate = 1.0
    scene.cycles.seed = 0  # same inputs, same image
    scene.render.threads_mode = "AUTO"
    scene.render.resolution_x, scene.render.resolution_y = a.res
    scene.render.resolution_percentage = 100
    scene.render.film_transparent = False
    scene.view_settings.view_transform = "Standard"
    scene.view_settings.look = "None"
    scene.render.image_settings.file_format = "PNG"
    scene.render.image_settings.color_mode = "RGB"
    scene.render.image_settings.color_depth = "8"
    return dist


def read_png_rgb(path):
    """8-bit RGB, non-interlaced PNG (what this script writes) -> (w, h, rows of bytes).
    Decoded here, not through bpy.data.images, so no colour management stands in between."""
    with open(path, "rb") as f:
        data = f.read()
    if data[:8] != b"\x89PNG\r\n\x1a\n":
        raise RenderFailure(f"{path}: not a PNG")
    pos, idat, w = 8, b"", None
    while pos < len(data):
        n, kind = struct.unpack(">I4s", data[pos : pos + 8])
        body = data[pos + 8 : pos + 8 + n]
        if kind == b"IHDR":
            w, h, depth, ctype, _, _, interlace = struct.unpack(">IIBBBBB", body)
            if depth != 8 or ctype != 2 or interlace != 0:
                raise RenderFailure(f"{path}: unexpected PNG format (depth {depth}, type {ctype})")
        elif kind == b"IDAT":
            idat += body
        pos += 12 + n
    raw = zlib.decompress(idat)
    stride, bpp = 3 * w, 3
    rows, prev = [], bytearray(stride)
    for y in range(h):
        ft = raw[y * (stride + 1)]
        line = bytearray(raw[y * (stride + 1) + 1 : (y + 1) * (stride + 1)])
        for i in range(stride):
            left = line[i - bpp] if i >= bpp else 0
            up = prev[i]
            ul = prev[i - bpp] if i >= bpp else 0
            if ft == 1:
                line[i] = (line[i] + left) & 255
            elif ft == 2:
                line[i] = (line[i] + up) & 255
            elif ft == 3:
                line[i] = (line[i] + ((left + up) >> 1)) & 255
            elif ft == 4:
                pa, pb, pc = abs(up - ul), abs(left - ul), abs(left + up - 2 * ul)
                pr = left if pa <= pb and pa <= pc else (up if pb <= pc else ul)
                line[i] = (line[i] + pr) & 255
        rows.append(bytes(line))
        prev = line
    return w, h, rows


def coverage(path):
    """Fraction of pixels that differ from the background, taken as the median colour of the
    four corners (the framing leaves a margin there; a direct view of the world is noise-free)."""
    w, h, rows = read_png_rgb(path)
    corners = [rows[y][3 * x : 3 * x + 3] for y in (0, h - 1) for x in (0, w - 1)]
    bgc = [sorted(c[k] for c in corners)[1] for k in range(3)]
    differ, lum = 0, 0
    for r in rows:
        for i in range(0, 3 * w, 3):
            if abs(r[i] - bgc[0]) + abs(r[i + 1] - bgc[1]) + abs(r[i + 2] - bgc[2]) > 24:
                differ += 1
            lum += r[i] + r[i + 1] + r[i + 2]
    return differ / float(w * h), bgc, lum / (3.0 * 255 * w * h)


def run(a, report):
    path, frame = resolve_input(a, report)
    report["vdb"] = path
    report["frame"] = frame
    bpy.ops.wm.read_factory_settings(use_empty=True)
    t = time.time()
    obj = import_volume(path, frame, a, report)
    lo, hi = world_bbox(obj)
    size = hi - lo
    report["world_bbox"] = [[round(v, 6) for v in lo], [round(v, 6) for v in hi]]
    if not all(math.isfinite(v) for v in size) or min(size) <= 0:
        raise RenderFailure("empty volume: the grids have no active voxels")
    framing = a.framing
    if framing == "auto":
        framing = "domain" if report.get("domain_size") else "volume"
    if framing == "domain":
        if not report.get("domain_size"):
            raise RenderFailure("--framing domain needs a run directory whose manifest has the config")
        lo, hi = domain_bbox(report)
        size = hi - lo
    report["framing"] = framing
    report["frame_bbox"] = [[round(v, 6) for v in lo], [round(v, 6) for v in hi]]
    if a.density_scale == "auto":
        try:
            gmax = grid_max_pyopenvdb(path, a.grid)
            report["grid_max_from"] = "pyopenvdb"
        except ImportError:
            gmax = grid_max_mesh(obj, a.grid)
            report["grid_max_from"] = "volume_to_mesh"
        report["grid_max"] = gmax
        if not (gmax > 0 and math.isfinite(gmax)):
            raise RenderFailure(f"grid {a.grid!r} has max {gmax}: nothing to render")
        # a chord through the core is ~ half the median bbox side (the bbox holds the thin
        # edges too), and the grid along it ~ half its max
        chord = 0.5 * sorted(size)[1]
        scale = CORE_OPTICAL_DEPTH / (0.5 * gmax * chord)
    else:
        scale = float(a.density_scale)
    report["density_scale"] = scale
    report["setup_s"] = round(time.time() - t, 3)
    build_material(obj, scale, a)
    if a.motion_blur:
        setup_motion_blur(obj, report)
    report["camera_distance"] = round(build_scene(lo, hi, a), 6)

    out = os.path.abspath(a.output)
    os.makedirs(os.path.dirname(out), exist_ok=True)
    bpy.context.scene.render.filepath = out
    t = time.time()
    bpy.ops.render.render(write_still=True)
    report["render_s"] = round(time.time() - t, 3)
    report["output"] = out
    if not os.path.isfile(out) or os.path.getsize(out) == 0:
        raise RenderFailure(f"render wrote no image to {out}")
    cov, bgc, mean = coverage(out)
    report["coverage"] = round(cov, 4)
    report["background_rgb8"] = bgc
    report["mean_luminance"] = round(mean, 4)
    if cov < a.min_coverage:
        raise RenderFailure(f"image is (almost) all background: coverage {cov:.4f} < {a.min_coverage}")


def main():
    a = parse_args()
    report = {"ok": True, "blender": bpy.app.version_string, "input": os.path.abspath(a.input)}
    err = None
    try:
        run(a, report)
    except RenderFailure as e:
        err = str(e)
    except RuntimeError as e:  # bpy operators raise RuntimeError on a failed import or render
        err = f"blender: {e}".strip()
    if err:
        report["ok"] = False
        report["error"] = err
    report["total_s"] = round(time.time() - T0, 3)
    print(TAG + json.dumps(report, sort_keys=True), flush=True)
    if err:
        # --python-exit-code 1 turns an uncaught exception into exit status 1
        raise SystemExit("render_blender.py: " + err)


main()
