#!/usr/bin/env python3
"""nimbus's PBF against SPlisHSPlasH's PBF on the same CPU, one after the other, in one command.

    tools/bench_pbf_vs_splishsplash.py [--particles 100000,300000] [--warmups 1,30] [--steps 20]
        [--threads 2] [--rounds 1] [--write-docs]

Builds the same scene for both solvers (a block of liquid at rest in a closed box, gravity,
spacing 0.05 m, kernel support 2 spacings = ~33 neighbours, 4 PBF iterations, fixed dt 2 ms,
XSPH 0.01, no s_corr/vorticity/viscosity) and times each one after the other in this process
tree: nimbus (`nimbus bench pbf --scene block`, lavapipe with LP_NUM_THREADS threads) and
SPlisHSPlasH 2.19 (PyPI `pysplishsplash`, OMP_NUM_THREADS threads), at every particle count and
warm-up (1: from rest; 30: 30 steps into the fall, disordered). With --rounds N each size and
warm-up runs N pairs, the two solvers' order swapped every round (a noisy machine's slow minute
then falls on both); the table gives median times and the median and range of the N pairs'
speed-ups. Prints a markdown table with both ms per step, ms per million particle-steps and the
ratio; `--write-docs` puts it into docs/PERFORMANCE.md ("Side by side with SPlisHSPlasH") with
the command, date and machine.

SPlisHSPlasH is installed into a venv if missing: $NIMBUS_SPL_VENV or /opt/nimbus/splvenv
(`python3 -m venv` + `pip install pysplishsplash==2.19.0`; Debian needs python3-venv). The
wheel's bundled libGLdispatch crashes at import next to Debian's libGLX, so SPlisHSPlasH runs
with LD_PRELOAD=/lib/x86_64-linux-gnu/libGLdispatch.so.0 where that exists (Debian libgl1).
The first run at a size builds the wall's volume map (seconds; cached under --work).

What is timed: nimbus's "PBF step" (predict, grid build, 4 x (lambda, delta), one more density
pass, velocity update and XSPH: GPU timestamps) against SPlisHSPlasH's wall time per step
(neighbour search, 4 iterations, velocity update, densities, XSPH), over the same `--steps`
steps after the same warm-up. docs/PERFORMANCE.md lists the differences that remain.
"""
import argparse
import datetime
import json
import math
import os
import platform
import re
import statistics
import subprocess
import sys
import tempfile
import time

SPL_VERSION = "2.19.0"
PRELOAD = "/lib/x86_64-linux-gnu/libGLdispatch.so.0"
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
BEGIN = "<!-- bench_pbf_vs_splishsplash: begin -->"
END = "<!-- bench_pbf_vs_splishsplash: end -->"


def rnd(x):
    """Rust's f64::round (half away from zero) for x >= 0, so both sides size the scene alike."""
    return int(math.floor(x + 0.5))


def block_dims(particles):
    """src/bench/pbf.rs `block_dims`: n x round(0.8 n) x n."""
    n = max(rnd((particles / 0.8) ** (1.0 / 3.0)), 2)
    return [n, max(rnd(0.8 * n), 2), n]


def block_box(dims):
    """src/bench/pbf.rs `block_box`, in spacings."""
    return [rnd(dims[a] * f) + 2 for a, f in enumerate((1.6, 1.5, 1.2))]


def ensure_venv(venv):
    py = os.path.join(venv, "bin", "python")
    probe = [py, "-c", "import importlib.metadata as m; print(m.version('pysplishsplash'))"]
    ok = os.path.exists(py) and subprocess.run(probe, capture_output=True, text=True).stdout.strip() == SPL_VERSION
    if not ok:
        print(f"installing pysplishsplash {SPL_VERSION} into {venv}", file=sys.stderr)
        subprocess.run([sys.executable, "-m", "venv", venv], check=True)
        subprocess.run([py, "-m", "pip", "install", "-q", "--disable-pip-version-check",
                        f"pysplishsplash=={SPL_VERSION}"], check=True)
    return py


def run_nimbus(a, particles, warmup):
    env = dict(os.environ, LP_NUM_THREADS=str(a.threads))
    env.setdefault("XDG_RUNTIME_DIR", "/tmp/nimbus-xdg")
    os.makedirs(env["XDG_RUNTIME_DIR"], mode=0o700, exist_ok=True)
    cmd = [a.nimbus, "bench", "pbf", "--scene", "block", "--particles", str(particles),
           "--steps", str(a.steps), "--warmup", str(warmup), "--spacing", str(a.spacing),
           "--kernel-ratio", "2", "--iterations", str(a.iterations), "--dt", str(a.dt)]
    r = subprocess.run(cmd, env=env, capture_output=True, text=True)
    if r.returncode != 0:
        sys.exit(f"nimbus failed ({r.returncode}): {r.stderr.strip()[-2000:]}")
    return json.loads(r.stdout)


def run_spl(a, py, particles, warmup):
    env = dict(os.environ, OMP_NUM_THREADS=str(a.threads))
    if os.path.exists(PRELOAD):
        env["LD_PRELOAD"] = PRELOAD
    cmd = [py, os.path.abspath(__file__), "--spl-child", "--particles", str(particles),
           "--steps", str(a.steps), "--warmup", str(warmup), "--spacing", str(a.spacing),
           "--iterations", str(a.iterations), "--dt", str(a.dt), "--work", a.work,
           "--spl-boundary", a.spl_boundary, "--spl-kernel", a.spl_kernel]
    r = subprocess.run(cmd, env=env, capture_output=True, text=True)
    line = [l for l in r.stdout.splitlines() if l.startswith("{")]
    if r.returncode != 0 or not line:
        sys.exit(f"SPlisHSPlasH failed ({r.returncode}): {(r.stdout + r.stderr).strip()[-2000:]}")
    return json.loads(line[-1])


def spl_child(a):
    """Runs in the venv's python: SPlisHSPlasH's PBF on the block scene, timed per step."""
    import pysplishsplash as sph

    d = a.spacing
    n = block_dims(a.particles)
    box = [b * d for b in block_box(n)]
    # nimbus's box spans [0, box]; SPlisHSPlasH's unit box is centred in x and z, floor at y = 0
    start = [-box[0] / 2 + d, d, -(n[2] + 1) * d / 2]
    # a fluid block of extent e holds round(e / d) - 1 particles per axis, the first d from start
    end = [start[k] + (n[k] + 1) * d for k in range(3)]
    unit_box = os.path.join(os.path.dirname(sys.executable), "data", "models", "UnitBox.obj")
    wall = {"geometryFile": unit_box, "translation": [0, box[1] / 2, 0], "scale": box,
            "isDynamic": False, "isWall": True}
    if a.spl_boundary == "volume-map":
        method = 2  # Bender et al. 2019
        wall.update({"mapInvert": True, "mapThickness": 0.0,
                     "mapResolution": [max(10, rnd(b / (2 * d))) for b in box]})
    else:
        method = 0  # Akinci et al. 2012: sampled wall particles
    cfg = {"particleRadius": d / 2, "simulationMethod": 2, "gravitation": [0, -9.81, 0],
           "timeStepSize": a.dt, "cflMethod": 0, "numberOfStepsPerRenderUpdate": 1,
           "boundaryHandlingMethod": method, "enableVTKExport": False,
           "enablePartioExport": False, "enableRigidBodyExport": False,
           "PBF": {"minIterations": a.iterations, "maxIterations": a.iterations, "maxError": 0.0}}
    if a.spl_kernel == "matched":
        cfg.update({"kernel": 2, "gradKernel": 3})  # poly6 and spiky, as nimbus
    scene = {"Configuration": cfg,
             "Materials": [{"id": "Fluid", "density0": 1000, "viscosityMethod": 0,
                            "vorticityMethod": 0, "XSPH": {"xsph": 0.01, "xsphBoundary": 0.0}}],
             "RigidBodies": [wall],
             "FluidBlocks": [{"denseMode": 0, "start": start, "end": end}]}
    os.makedirs(a.work, exist_ok=True)
    path = os.path.join(a.work, f"scene_{a.particles}_{a.spl_boundary}_{a.spl_kernel}.json")
    with open(path, "w") as f:
        json.dump(scene, f)
    total = a.warmup + a.steps
    base = sph.Exec.SimulatorBase()
    base.init(["bench_pbf_vs_splishsplash", "--no-gui", "--no-initial-pause",
               "--stopAt", str((total - 0.5) * a.dt), "--output-dir", os.path.join(a.work, "out"),
               path], "bench_pbf_vs_splishsplash")
    # SPlisHSPlasH does not own its GUI object: keep it referenced while the run lasts
    gui = sph.GUI.Simulator_GUI_imgui(base)
    base.setGui(gui)
    stamps = []
    base.setTimeStepCB(lambda: stamps.append(time.perf_counter()))
    base.initSimulation()
    sim = sph.Simulation.getCurrent()
    count = sim.getFluidModel(0).numActiveParticles()
    base.runSimulation()
    base.cleanup()
    if len(stamps) != total:
        sys.exit(f"ran {len(stamps)} steps, expected {total}")
    ms = (stamps[-1] - stamps[a.warmup - 1]) * 1e3 / a.steps
    print(json.dumps({"particles": count, "ms_per_step": ms, "steps": a.steps,
                      "warmup": a.warmup, "box": box, "boundary": a.spl_boundary,
                      "kernel": a.spl_kernel}))


def machine():
    cpu = ""
    try:
        with open("/proc/cpuinfo") as f:
            cpu = next((l.split(":", 1)[1].strip() for l in f if l.startswith("model name")), "")
    except OSError:
        pass
    return f"{cpu}, {os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f} at the start"


def write_docs(text):
    path = os.path.join(ROOT, "docs", "PERFORMANCE.md")
    with open(path) as f:
        doc = f.read()
    block = f"{BEGIN}\n{text}{END}"
    if BEGIN in doc and END in doc:
        doc = doc[: doc.index(BEGIN)] + block + doc[doc.index(END) + len(END):]
    else:
        sys.exit(f"{path}: markers {BEGIN} / {END} not found")
    with open(path, "w") as f:
        f.write(doc)
    print(f"wrote the table into {path}", file=sys.stderr)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--particles", default="100000,300000", help="comma-separated targets")
    ap.add_argument("--warmups", default="1,30", help="steps before timing (1: from rest)")
    ap.add_argument("--steps", type=int, default=20, help="timed steps")
    ap.add_argument("--threads", type=int, default=2, help="CPU threads for both solvers")
    ap.add_argument("--spacing", type=float, default=0.05)
    ap.add_argument("--iterations", type=int, default=4)
    ap.add_argument("--rounds", type=int, default=1,
                    help="pairs of runs per size and warm-up, the order swapped every round")
    ap.add_argument("--dt", type=float, default=0.002)
    ap.add_argument("--nimbus", default=os.path.join(ROOT, "target", "release", "nimbus"))
    ap.add_argument("--venv", default=os.environ.get("NIMBUS_SPL_VENV", "/opt/nimbus/splvenv"))
    ap.add_argument("--work", default=os.path.join(tempfile.gettempdir(), "nimbus-splbench"))
    ap.add_argument("--spl-boundary", choices=["volume-map", "particles"], default="volume-map")
    ap.add_argument("--spl-kernel", choices=["matched", "default"], default="matched",
                    help="matched: poly6 + spiky like nimbus; default: its precomputed cubic spline")
    ap.add_argument("--write-docs", action="store_true")
    ap.add_argument("--spl-child", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--warmup", type=int, default=1, help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.spl_child:
        a.particles = int(a.particles)
        return spl_child(a)
    if not os.path.exists(a.nimbus):
        sys.exit(f"{a.nimbus} not found: run `cargo build --release` first")
    py = ensure_venv(a.venv)
    started = datetime.datetime.now().strftime("%Y-%m-%d %H:%M")
    host = machine()
    rows = []
    adapter = ""
    for particles in [int(p) for p in a.particles.split(",")]:
        for warmup in [max(1, int(w)) for w in a.warmups.split(",")]:
            pairs = []
            for k in range(max(1, a.rounds)):
                if k % 2 == 0:
                    nb = run_nimbus(a, particles, warmup)
                    sp = run_spl(a, py, particles, warmup)
                else:
                    sp = run_spl(a, py, particles, warmup)
                    nb = run_nimbus(a, particles, warmup)
                if nb["particles"] != sp["particles"]:
                    sys.exit(f"particle counts differ: nimbus {nb['particles']}, SPlisHSPlasH {sp['particles']}")
                adapter = nb["adapter"]
                pairs.append((nb, sp))
                print(json.dumps({"particles": nb["particles"], "warmup": warmup, "round": k + 1,
                                  "nimbus_ms": nb["pbf_step_ms"], "spl_ms": sp["ms_per_step"],
                                  "speedup": sp["ms_per_step"] / nb["pbf_step_ms"]}), file=sys.stderr)
            med = statistics.median
            ratios = sorted(sp["ms_per_step"] / nb["pbf_step_ms"] for nb, sp in pairs)
            phases = {k: med(nb["phase_ms"].get(k, 0.0) for nb, _ in pairs)
                      for k in pairs[0][0]["phase_ms"]}
            row = {"particles": pairs[0][0]["particles"], "warmup": warmup,
                   "nimbus_ms": med(nb["pbf_step_ms"] for nb, _ in pairs),
                   "nimbus_substep_ms": med(nb["ms_per_substep_wall"] for nb, _ in pairs),
                   "spl_ms": med(sp["ms_per_step"] for _, sp in pairs), "phase_ms": phases,
                   "speedup": med(ratios), "speedup_range": [ratios[0], ratios[-1]]}
            rows.append(row)
            print(json.dumps(row), file=sys.stderr)
    cmd = "tools/bench_pbf_vs_splishsplash.py " + " ".join(
        x for x in sys.argv[1:] if x != "--write-docs")
    rounds = ""
    ratio_range = ""
    if a.rounds > 1:
        rounds = (f"; {a.rounds} rounds, the order swapped every round: times are medians, the "
                  "speed-up is the median of the rounds' speed-ups, with their range")
        ratio_range = " | range"
    lines = [
        f"`{cmd.strip()}` ({started}; {host}; nimbus on {adapter}, SPlisHSPlasH {SPL_VERSION} "
        f"PBF, {a.spl_boundary} walls, {a.spl_kernel} kernels; {a.threads} threads each; "
        f"{a.steps} steps timed{rounds}):\n\n",
        "| particles | state | nimbus PBF step ms | (grid / pbf / velocity) | SPlisHSPlasH ms/step "
        f"| nimbus ms per M particle-steps | SPlisHSPlasH | nimbus speed-up{ratio_range} |\n",
        f"|---|---|---|---|---|---|---|---|{'---|' if a.rounds > 1 else ''}\n",
    ]
    def ms(x):
        # whole ms as the CPU figures always were; 3 digits below 100 (a GPU's ms)
        return f"{x:.0f}" if x >= 100 else f"{x:.3g}"

    for r in rows:
        state = "from rest" if r["warmup"] <= 1 else f"after {r['warmup']} steps"
        p = r["phase_ms"]
        split = " / ".join(ms(p.get(k, 0)) for k in ("grid", "pbf", "velocity"))
        m = r["particles"] / 1e6
        lines.append(f"| {r['particles']:,} | {state} | {ms(r['nimbus_ms'])} | {split} | "
                     f"{ms(r['spl_ms'])} | {ms(r['nimbus_ms'] / m)} | {ms(r['spl_ms'] / m)} | "
                     f"**{r['speedup']:.2f}x** |" + (
                         f" {r['speedup_range'][0]:.2f}-{r['speedup_range'][1]:.2f}x |"
                         if a.rounds > 1 else "") + "\n")
    text = "".join(lines)
    print(text)
    if a.write_docs:
        write_docs(text)


if __name__ == "__main__":
    main()
