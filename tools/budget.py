#!/usr/bin/env python3
"""The heat and water budgets of a nimbus run, from its stats.jsonl.

    tools/budget.py RUN_DIR [--from FRAME] [--json]

Heat: the rise of `static_energy_mean` (the mass-weighted mean of T + Gamma_d y - Q w, K) from
the end of frame FROM (default: the first written) to the last, against what was put in over
the frames after FROM: `heat_input_mean` (ground heating and sources, estimated from each
frame's end state) plus `forcing_heat_mean` (physics.forcing, exact). Water: the rise of
`total_water` (kg) against `water_input` plus `forcing_water`. A ratio kept / put in of 1 is a
closed budget (docs/PHYSICS.md "Heat budget").
"""
import argparse
import json
import sys
from pathlib import Path


def load(run_dir):
    path = Path(run_dir) / "stats.jsonl"
    try:
        lines = path.read_text().splitlines()
    except OSError as e:
        sys.exit(f"error: {path}: {e.strerror}")
    stats = []
    for n, line in enumerate(lines, 1):
        try:
            stats.append(json.loads(line))
        except json.JSONDecodeError as e:
            sys.exit(f"error: {path}:{n}: {e}")
    return sorted(stats, key=lambda s: s["frame"])


def budget(stats, start):
    frames = [s for s in stats if s["frame"] >= start]
    if len(frames) < 2:
        sys.exit(f"error: fewer than two frames from frame {start}")
    first, rest = frames[0], frames[1:]
    d = lambda s, k: s["diagnostics"].get(k, 0.0)
    heat_in = sum(d(s, "heat_input_mean") + d(s, "forcing_heat_mean") for s in rest)
    water_in = sum(d(s, "water_input") + d(s, "forcing_water") for s in rest)
    heat_kept = d(rest[-1], "static_energy_mean") - d(first, "static_energy_mean")
    water_kept = d(rest[-1], "total_water") - d(first, "total_water")
    ratio = lambda kept, put: kept / put if put != 0 else None
    return {
        "from_frame": first["frame"],
        "to_frame": rest[-1]["frame"],
        "heat_in_K": heat_in,
        "heat_kept_K": heat_kept,
        "heat_ratio": ratio(heat_kept, heat_in),
        "water_in_kg": water_in,
        "water_kept_kg": water_kept,
        "water_ratio": ratio(water_kept, water_in),
    }


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("run_dir")
    ap.add_argument("--from", dest="start", type=int, default=None,
                    help="the frame whose end the budget starts from (default: the first)")
    ap.add_argument("--json", action="store_true")
    a = ap.parse_args()
    stats = load(a.run_dir)
    if not stats:
        sys.exit("error: stats.jsonl is empty")
    b = budget(stats, stats[0]["frame"] if a.start is None else a.start)
    if a.json:
        print(json.dumps(b, indent=1))
        return
    fmt = lambda r: "n/a (nothing put in)" if r is None else f"{r:.4f}"
    print(f"frames {b['from_frame']}..{b['to_frame']}")
    print(f"heat:  {b['heat_in_K']:.6f} K put in, {b['heat_kept_K']:.6f} K kept, "
          f"kept / put in {fmt(b['heat_ratio'])}")
    print(f"water: {b['water_in_kg']:.6e} kg put in, {b['water_kept_kg']:.6e} kg kept, "
          f"kept / put in {fmt(b['water_ratio'])}")


if __name__ == "__main__":
    main()
