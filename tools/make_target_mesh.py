#!/usr/bin/env python3
"""Writes samples/target_towers.obj, the target of pipelines/target_shape.yaml: a side profile
of three towers of different heights (a stepped skyline: low, tall, middle), extruded along z.
The mesh spans the unit box [0, 1]^3 (the shot's control.target.scale gives it metres) and is
closed: every edge is shared by exactly two faces (checked here and by nimbus at validation).

    /usr/bin/python3 tools/make_target_mesh.py            # writes samples/target_towers.obj
    /usr/bin/python3 tools/make_target_mesh.py OUT.obj
"""
import sys
from collections import Counter

# the profile in the x-y plane, counter-clockwise: three towers 1/3 wide, 0.5, 1.0 and 0.7 high
PROFILE = [(0, 0), (1, 0), (1, 0.7), (2 / 3, 0.7), (2 / 3, 1.0), (1 / 3, 1.0), (1 / 3, 0.5), (0, 0.5)]


def ear_clip(poly):
    """Triangles (index triples, counter-clockwise) of a simple counter-clockwise polygon."""
    def cross(o, a, b):
        return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])

    def inside(p, a, b, c):
        return cross(a, b, p) >= 0 and cross(b, c, p) >= 0 and cross(c, a, p) >= 0

    idx = list(range(len(poly)))
    tris = []
    while len(idx) > 3:
        for k in range(len(idx)):
            i, j, l = idx[k - 1], idx[k], idx[(k + 1) % len(idx)]
            a, b, c = poly[i], poly[j], poly[l]
            if cross(a, b, c) <= 0:
                continue  # reflex or straight corner
            if any(inside(poly[m], a, b, c) for m in idx if m not in (i, j, l)):
                continue
            tris.append((i, j, l))
            idx.pop(k)
            break
        else:
            raise SystemExit("the profile is not a simple counter-clockwise polygon")
    tris.append(tuple(idx))
    return tris


def main():
    out = sys.argv[1] if len(sys.argv) > 1 else "samples/target_towers.obj"
    n = len(PROFILE)
    verts = [(x, y, 0.0) for x, y in PROFILE] + [(x, y, 1.0) for x, y in PROFILE]
    faces = []
    for a, b, c in ear_clip(PROFILE):
        faces.append((a, c, b))  # back cap (z = 0), facing -z
        faces.append((n + a, n + b, n + c))  # front cap (z = 1), facing +z
    for k in range(n):
        m = (k + 1) % n
        faces.append((k, m, n + m, n + k))  # the side walls, facing out
    edges = Counter()
    for f in faces:
        for k in range(len(f)):
            a, b = f[k], f[(k + 1) % len(f)]
            edges[(min(a, b), max(a, b))] += 1
    if any(c != 2 for c in edges.values()):
        raise SystemExit("internal error: the mesh is not closed")
    with open(out, "w") as fh:
        fh.write("# three towers: tools/make_target_mesh.py (public domain)\n")
        for v in verts:
            fh.write("v %.6f %.6f %.6f\n" % v)
        for f in faces:
            fh.write("f " + " ".join(str(i + 1) for i in f) + "\n")
    print(f"{out}: {len(verts)} vertices, {len(faces)} faces")


if __name__ == "__main__":
    main()
