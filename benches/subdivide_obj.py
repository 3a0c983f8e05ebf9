#!/usr/bin/env python3
"""Writes a 4x finer copy of an OBJ mesh (each triangle split at its edge midpoints into four),
for load and whole-process timings at the size of the full Stanford dragon (871k triangles,
33 MB), which ../shared/data does not hold: dragon_res2.obj (202k) gives 810k triangles.

    python3 benches/subdivide_obj.py ../shared/data/dragon_res2.obj target/dragon_x4.obj
"""
import sys

src, dst = sys.argv[1], sys.argv[2]
verts, tris = [], []
for line in open(src):
    p = line.split()
    if not p:
        continue
    if p[0] == "v":
        verts.append(tuple(float(x) for x in p[1:4]))
    elif p[0] == "f":
        idx = [int(x.split("/")[0]) for x in p[1:]]
        idx = [i - 1 if i > 0 else len(verts) + i for i in idx]
        for k in range(2, len(idx)):
            tris.append((idx[0], idx[k - 1], idx[k]))
mid = {}


def midpoint(a, b):
    key = (min(a, b), max(a, b))
    if key not in mid:
        va, vb = verts[a], verts[b]
        verts.append(tuple((x + y) / 2 for x, y in zip(va, vb)))
        mid[key] = len(verts) - 1
    return mid[key]


out = []
for a, b, c in tris:
    ab, bc, ca = midpoint(a, b), midpoint(b, c), midpoint(c, a)
    out += [(a, ab, ca), (ab, b, bc), (ca, bc, c), (ab, bc, ca)]
with open(dst, "w") as f:
    f.write("".join(f"v {x!r} {y!r} {z!r}\n" for x, y, z in verts))
    f.write("".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in out))
print(f"{dst}: {len(verts)} vertices, {len(out)} triangles")
