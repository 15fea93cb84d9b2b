"""Render a nimbus VDB sequence (or one .vdb) headless in Blender with Cycles on the CPU.

Usage (Blender 3.4, Debian 12):
  blender -b --factory-startup --python-exit-code 1 -P tools/render_blender.py -- \
      RUN_DIR_OR_VDB OUT.png [--frame N] [--grid density] [--res W H] [--samples N] \
      [--up auto|y|z] [--motion-blur] [--density-scale physical|X] [--min-coverage F] \
      [--framing auto|domain|volume] [--volume-bounces N] [--sky-png PATH] \
      [--summary-json PATH]

RUN_DIR is a nimbus run directory: its manifest.json names the frames and their files (size and
SHA-256 are checked). The whole `<shot>.<digits>.vdb` sequence is imported as one Volume object
(Blender's own sequence detection) and the scene is set to the requested frame (default: the last
frame in the manifest), so the .blend-equivalent scene is what an artist gets from File > Import.

The cloud is rendered with its physical extinction (the density grid's `nimbus_extinction_per_unit`,
docs/RENDERING.md "Physical optics"), forward scattering (Henyey-Greenstein g = 0.8), enough
volume bounces for the shaded side to converge, under Cycles' Nishita sky with the sun of that
sky as a sun lamp, through the Filmic view transform.

Exit status 1 (through --python-exit-code 1) when the manifest or the file cannot be read, the
density grid is missing or empty, or the image shows (almost) nothing but sky.
Exactly one line starting with 'NIMBUS_BLENDER ' is printed: a JSON summary (ok, error, timings,
grids, density scale, coverage, the optical depth through the core along the view and the sun,
the luminance percentiles of the cloud pixels).
"""
import argparse
import hashlib
import json
import math
import os
import re
import sys
import time

import bpy
from mathutils import Vector

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import nimbus_look  # noqa: E402  (tools/, next to this script)

T0 = time.time()
TAG = "NIMBUS_BLENDER "
# The sun: 40 degrees up, from the camera's right and a little behind it (a lit side and a
# shaded side, the camera outside the forward-scattering lobe). Nishita's sun_rotation puts the
# sun at azimuth 90 - rotation degrees from +x towards +y (checked in Blender 3.4.1).
SUN_ELEVATION_DEG = 40.0
SUN_ROTATION_DEG = 110.0
# The Nishita sky's own sun at that elevation (air, dust and ozone 1, sea level), as a sun lamp:
# its irradiance on a plane facing it, in Blender units, and its colour. Measured in Blender
# 3.4.1 from two equirectangular renders of the sky, with and without its sun disc, the
# difference summed over the disc's solid angle: (145.5, 118.2, 89.1). The sky without its disc
# then adds 9.0 on a level surface (luminance): a diffuse share of 10%, as under a clear sky.
SUN_STRENGTH = 145.5
SUN_COLOR = (1.0, 0.812, 0.613)
# Film exposure (stops) that puts a sunlit cloud face (about SUN_STRENGTH x 0.8 / pi) 5 stops
# over Filmic's middle grey, below its white.
EXPOSURE = -2.4
# Henyey-Greenstein anisotropy of cloud droplets (0.85 for visible light; 0.8 keeps a little more
# light on the shaded side, as a renderer's single lobe usually does).
PHASE_G = 0.8
# Volume bounces: where the shaded side of a thick cloud has converged (docs/RENDERING.md "Light
# transport": quickstart's last frame, the darkest 5% of its cloud pixels 1% brighter at 512
# than at 256, 9% between 128 and 256).
VOLUME_BOUNCES = 256


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
        default="physical",
        help="Cycles extinction per unit of grid value per scene unit; 'physical' (default): the "
        "density grid's own (nimbus_extinction_per_unit in the run's manifest or the file's "
        "metadata, docs/RENDERING.md 'Physical optics')",
    )
    p.add_argument(
        "--volume-bounces",
        type=int,
        default=VOLUME_BOUNCES,
        help="Cycles volume bounces (default %d: the shaded side of a thick cloud converged)"
        % VOLUME_BOUNCES,
    )
    p.add_argument(
        "--summary-json",
        default=None,
        help="also write the JSON summary to this file (tools/cloud_look.py --render-summary)",
    )
    p.add_argument(
        "--sky-png",
        default=None,
        help="also keep the sky-only render (the volume hidden) that the cloud pixels are found "
        "against, at this path",
    )
    p.add_argument(
        "--framing",
        choices=["auto", "domain", "volume"],
        default="auto",
        help="box the camera frames: the run's simulation "
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
    if a.res[0] < 8 or a.res[1] < 8 or a.samples < 1 or a.volume_bounces < 0:
        p.error("--res needs at least 8x8, --samples at least 1, --volume-bounces at least 0")
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
    a.run_config = man.get("config")
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


def physical_scale(path, a, report):
    """The density grid's extinction per unit per scene unit: the run's manifest
    (`export.optics.extinction_per_unit`), else the file's density metadata, else (files
    written before nimbus recorded it) export.optics' defaults with the run's density_scale and
    scale."""
    exp = report.get("export") if isinstance(report.get("export"), dict) else {}
    optics = exp.get("optics") if isinstance(exp.get("optics"), dict) else None
    if optics and optics.get("extinction_per_unit"):
        report["optics"] = optics
        return float(optics["extinction_per_unit"]), "manifest"
    try:
        import pyopenvdb

        meta = pyopenvdb.read(path, a.grid).metadata
        if "nimbus_extinction_per_unit" in meta:
            report["optics"] = {k: meta[k] for k in meta if k.startswith("nimbus_")}
            return float(meta["nimbus_extinction_per_unit"]), "metadata"
    except (ImportError, KeyError, RuntimeError, ValueError):
        pass
    cfg = getattr(a, "run_config", None) or {}
    ex = cfg.get("export", {}) if isinstance(cfg, dict) else {}
    k = nimbus_look.default_extinction_per_unit(
        float(ex.get("density_scale", 1000.0)), float(ex.get("scale", 1.0))
    )
    return k, "defaults (the files predate export.optics)"


def build_material(obj, scale, a):
    mat = bpy.data.materials.new("NimbusCloud")
    mat.use_nodes = True
    nt = mat.node_tree
    nt.nodes.clear()
    out = nt.nodes.new("ShaderNodeOutputMaterial")
    pv = nt.nodes.new("ShaderNodeVolumePrincipled")
    # water droplets: white (single-scattering albedo ~0.9999 in the visible), forward
    pv.inputs["Color"].default_value = (1.0, 1.0, 1.0, 1.0)
    pv.inputs["Density"].default_value = scale
    pv.inputs["Density Attribute"].default_value = a.grid
    pv.inputs["Anisotropy"].default_value = PHASE_G
    # nimbus temperatures are ~250-300 K: physically no visible glow, keep blackbody off
    pv.inputs["Blackbody Intensity"].default_value = 0.0
    nt.links.new(pv.outputs["Volume"], out.inputs["Volume"])
    obj.data.materials.clear()
    obj.data.materials.append(mat)


def camera_view(lo, hi, aspect, lens=35.0, sensor=36.0):
    """The camera that frames box [lo, hi] from the ground: from the front (-y) and a little to
    the right, at 2% of the box's height, looking at the box's centre, at the nearest distance
    where all eight corners fit the frame with a 10% margin (35 mm lens on a 36 mm sensor fitted
    to the wider side). Returns (position, unit forward, right, up, fov_x, fov_y); nimbus's
    preview mirrors it (preview::blender_camera)."""
    center = (lo + hi) / 2
    size = hi - lo
    fov_wide = 2 * math.atan(sensor / (2 * lens))
    fov_x = fov_wide if aspect >= 1 else 2 * math.atan(math.tan(fov_wide / 2) * aspect)
    fov_y = 2 * math.atan(math.tan(fov_x / 2) / aspect)
    tx, ty = math.tan(fov_x / 2) / 1.1, math.tan(fov_y / 2) / 1.1
    heading = Vector((0.25, -1.0, 0.0)).normalized()
    z = lo[2] + 0.02 * size[2]

    def basis(dist):
        pos = Vector((center[0], center[1], z)) + heading * dist
        fwd = (center - pos).normalized()
        right = fwd.cross(Vector((0.0, 0.0, 1.0))).normalized()
        return pos, fwd, right, right.cross(fwd)

    def fits(dist):
        pos, fwd, right, up = basis(dist)
        for i in range(8):
            c = Vector([hi[k] if (i >> k) & 1 else lo[k] for k in range(3)]) - pos
            depth = c.dot(fwd)
            if depth <= 0 or abs(c.dot(right)) > tx * depth or abs(c.dot(up)) > ty * depth:
                return False
        return True

    near, far = 1e-3 * max(size.length, 1e-6), max(size.length, 1e-6)
    while not fits(far):
        far *= 2
    for _ in range(60):
        mid = 0.5 * (near + far)
        if fits(mid):
            far = mid
        else:
            near = mid
    pos, fwd, right, up = basis(far)
    return pos, fwd, right, up, fov_x, fov_y


def sun_direction():
    """Unit vector towards the sun (Blender world, z up): Nishita's convention."""
    el, rot = math.radians(SUN_ELEVATION_DEG), math.radians(SUN_ROTATION_DEG)
    return Vector((math.cos(el) * math.sin(rot), math.cos(el) * math.cos(rot), math.sin(el)))


def build_scene(lo, hi, a):
    scene = bpy.context.scene
    size = hi - lo
    cam_data = bpy.data.cameras.new("Camera")
    cam_data.lens = 35.0
    cam_data.sensor_fit = "AUTO"
    cam = bpy.data.objects.new("Camera", cam_data)
    scene.collection.objects.link(cam)
    pos, fwd, _, _, _, _ = camera_view(lo, hi, a.res[0] / a.res[1], cam_data.lens, cam_data.sensor_width)
    cam.location = pos
    cam.rotation_euler = fwd.to_track_quat("-Z", "Y").to_euler()
    dist = (pos - (lo + hi) / 2).length
    radius = max(0.5 * size.length, 1e-6)
    cam_data.clip_start = max(dist - 2 * radius, dist * 1e-3)
    cam_data.clip_end = dist + 2 * radius
    scene.camera = cam

    sun_data = bpy.data.lights.new("Sun", type="SUN")
    sun_data.energy = SUN_STRENGTH
    sun_data.color = SUN_COLOR
    sun_data.angle = math.radians(0.545)  # the sun's disc
    sun = bpy.data.objects.new("Sun", sun_data)
    # a sun lamp shines along its local -z
    sun.rotation_euler = (-sun_direction()).to_track_quat("-Z", "Y").to_euler()
    scene.collection.objects.link(sun)

    world = bpy.data.worlds.new("Sky")
    world.use_nodes = True
    nt = world.node_tree
    sky = nt.nodes.new("ShaderNodeTexSky")
    sky.sky_type = "NISHITA"
    sky.sun_elevation = math.radians(SUN_ELEVATION_DEG)
    sky.sun_rotation = math.radians(SUN_ROTATION_DEG)
    sky.sun_disc = False  # the sun is the lamp above: sampled directly, no fireflies
    sky.altitude = 0.0
    bg = nt.nodes["Background"]
    bg.inputs["Strength"].default_value = 1.0
    nt.links.new(sky.outputs["Color"], bg.inputs["Color"])
    scene.world = world

    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = a.samples
    scene.cycles.use_adaptive_sampling = False
    scene.cycles.use_denoising = False
    scene.cycles.max_bounces = max(4, a.volume_bounces)
    scene.cycles.volume_bounces = a.volume_bounces
    scene.cycles.volume_step_rate = 1.0
    scene.cycles.seed = 0  # same inputs, same image
    scene.render.threads_mode = "AUTO"
    scene.render.resolution_x, scene.render.resolution_y = a.res
    scene.render.resolution_percentage = 100
    scene.render.film_transparent = False
    scene.view_settings.view_transform = "Filmic"
    scene.view_settings.look = "None"
    scene.view_settings.exposure = EXPOSURE
    scene.render.image_settings.file_format = "PNG"
    scene.render.image_settings.color_mode = "RGB"
    scene.render.image_settings.color_depth = "8"
    return dist, pos


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
    if a.density_scale == "physical":
        scale, source = physical_scale(path, a, report)
    else:
        try:
            scale, source = float(a.density_scale), "--density-scale"
        except ValueError:
            raise RenderFailure(f"--density-scale {a.density_scale!r}: expected 'physical' or a number")
    report["density_scale"] = scale
    report["density_scale_from"] = source
    report["setup_s"] = round(time.time() - t, 3)
    build_material(obj, scale, a)
    if a.motion_blur:
        setup_motion_blur(obj, report)
    dist, cam_pos = build_scene(lo, hi, a)
    report["camera_distance"] = round(dist, 6)
    report["camera_position"] = [round(v, 6) for v in cam_pos]
    report["sun_direction"] = [round(v, 6) for v in sun_direction()]

    out = os.path.abspath(a.output)
    os.makedirs(os.path.dirname(out), exist_ok=True)
    scene = bpy.context.scene
    scene.render.filepath = out
    t = time.time()
    bpy.ops.render.render(write_still=True)
    report["render_s"] = round(time.time() - t, 3)
    report["output"] = out
    if not os.path.isfile(out) or os.path.getsize(out) == 0:
        raise RenderFailure(f"render wrote no image to {out}")
    # The same render without the cloud: the sky each pixel would show (Nishita's sky is not
    # uniform, so no corner colour stands for it); direct views of the world are noise-free.
    sky_png = os.path.abspath(a.sky_png) if a.sky_png else out + ".sky.png"
    obj.hide_render = True
    scene.render.filepath = sky_png
    t = time.time()
    bpy.ops.render.render(write_still=True)
    report["sky_render_s"] = round(time.time() - t, 3)
    img = nimbus_look.read_png_rgb(out)
    sky = nimbus_look.read_png_rgb(sky_png)
    if a.sky_png:
        report["sky_png"] = sky_png
    else:
        os.remove(sky_png)
    mask = nimbus_look.cloud_mask(img, sky)
    cov = float(mask.mean())
    report["coverage"] = round(cov, 4)
    report["cloud_luminance"] = nimbus_look.luminance_percentiles(img, mask)
    report["optical_depth"] = core_optical_depth(path, a, report, scale, cam_pos)
    if cov < a.min_coverage:
        raise RenderFailure(f"image is (almost) all sky: coverage {cov:.4f} < {a.min_coverage}")


def core_optical_depth(path, a, report, scale, cam_pos):
    """Optical depth of the lines through the cloud's core (the density-weighted centroid of the
    grid) along the camera's view and along the sun, with the render's extinction."""
    try:
        grid, lo, voxel, origin, _ = nimbus_look.read_density(path, a.grid)
    except ImportError:
        return {"error": "pyopenvdb is not installed (Debian: python3-openvdb)"}
    c = nimbus_look.centroid(grid)
    if c is None:
        return {"error": "empty density grid"}
    # file coordinates -> Blender's world: a y-up file was rotated +90 degrees about x
    y_up = report.get("up") == "y"

    def to_world(v):
        return Vector((v[0], -v[2], v[1])) if y_up else Vector(v)

    def to_file(v):
        return [v[0], v[2], -v[1]] if y_up else [v[0], v[1], v[2]]

    core = to_world(origin + (lo + c) * voxel)
    view = (core - cam_pos).normalized()
    return {
        "view": nimbus_look.optical_depth(grid, voxel, scale, c, to_file(view)),
        "sun": nimbus_look.optical_depth(grid, voxel, scale, c, to_file(sun_direction())),
        "core": [round(v, 3) for v in core],
    }


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
    if a.summary_json:
        with open(a.summary_json, "w") as f:
            json.dump(report, f, indent=1, sort_keys=True)
    if err:
        # --python-exit-code 1 turns an uncaught exception into exit status 1
        raise SystemExit("render_blender.py: " + err)


main()
