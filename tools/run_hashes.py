#!/usr/bin/env python3
"""sha256 of every file of a nimbus run directory, one "HASH PATH" line each, sorted by path.

  python3 tools/run_hashes.py RUN_DIR

stats.jsonl is hashed without its `phase_ms` (timings, the one part of a run directory that is
not deterministic); `.lock` is left out. Two runs of the same config and adapter into the same
path give the same lines (docs/ARCHITECTURE.md "Layers"); tools/byte_identical.sh compares
two builds this way.
"""
import hashlib
import json
import os
import sys


def main():
    if len(sys.argv) != 2 or not os.path.isdir(sys.argv[1]):
        sys.exit("usage: run_hashes.py RUN_DIR")
    root = sys.argv[1]
    out = []
    for d, _, files in os.walk(root):
        for f in files:
            if f == ".lock":
                continue
            p = os.path.join(d, f)
            with open(p, "rb") as fh:
                data = fh.read()
            if f == "stats.jsonl":
                lines = []
                for line in data.decode().splitlines():
                    rec = json.loads(line)
                    rec.pop("phase_ms", None)
                    lines.append(json.dumps(rec, sort_keys=True))
                data = "\n".join(lines).encode()
            out.append((os.path.relpath(p, root), hashlib.sha256(data).hexdigest()))
    for rel, h in sorted(out):
        print(h, rel)


if __name__ == "__main__":
    main()
