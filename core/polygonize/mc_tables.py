#!/usr/bin/env python3
"""Generates core/polygonize/mc_tables.h: the 256-case Marching Cubes triangle table used by core/polygonize/marching_cubes.cpp.

    python3 core/polygonize/mc_tables.py > core/polygonize/mc_tables.h

Conventions (they differ from Lorensen/Bourke's numbering; the topology is the classic one):
  corner c = (c & 1, (c >> 1) & 1, (c >> 2) & 1) as (x, y, z); bit c of the case index is set when corner c is
  inside (value < 0; a value equal to 0 counts as outside).
  edges: x-edges 0..3 = 0 + y + 2z, y-edges 4..7 = 4 + x + 2z, z-edges 8..11 = 8 + x + 2y.

How the table is built (so that it is consistent by construction rather than by transcription):
  1. Every cube face gets contour segments between its crossed edges. A face with four crossed edges is ambiguous;
     it is always resolved the same way, from the face's own corner signs only: the segments cut off the two
     OUTSIDE corners (the inside corners stay connected across the face). Neighbouring cubes therefore produce the
     same segments on their shared face, so the mesh has no cracks.
  2. Each segment is directed so that the surface normal (toward the outside corners) n, the face's outward normal
     n_F and the segment direction t satisfy t = n x n_F; then the segments chain into closed loops, counter-
     clockwise seen from outside the surface.
  3. Each loop is triangulated as a disk, keeping its orientation. Among all triangulations we pick one with no
     diagonal joining two vertices of the same cube face when possible (such a diagonal could coincide with the
     neighbour's and give an edge with four triangles), then the one with the largest smallest angle (vertices at
     edge midpoints), then the lexicographically first.
  The script checks: at most 5 triangles per case, every crossed edge in exactly one loop, and no two cubes sharing
  a face can both use the same diagonal on it (so the output is edge-manifold and vertex-manifold).
"""
import itertools
import math
import sys

CORNERS = [((c >> 0) & 1, (c >> 1) & 1, (c >> 2) & 1) for c in range(8)]


def corner_index(x, y, z):
    return x | (y << 1) | (z << 2)


EDGES = []  # (corner a, corner b)
for y, z in [(0, 0), (1, 0), (0, 1), (1, 1)]:
    EDGES.append((corner_index(0, y, z), corner_index(1, y, z)))
for x, z in [(0, 0), (1, 0), (0, 1), (1, 1)]:
    EDGES.append((corner_index(x, 0, z), corner_index(x, 1, z)))
for x, y in [(0, 0), (1, 0), (0, 1), (1, 1)]:
    EDGES.append((corner_index(x, y, 0), corner_index(x, y, 1)))


def sub(a, b):
    return tuple(p - q for p, q in zip(a, b))


def add(a, b):
    return tuple(p + q for p, q in zip(a, b))


def scale(a, s):
    return tuple(p * s for p in a)


def dot(a, b):
    return sum(p * q for p, q in zip(a, b))


def cross(a, b):
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def midpoint(e):
    a, b = EDGES[e]
    return scale(add(CORNERS[a], CORNERS[b]), 0.5)


# Faces: (axis, side) with outward normal; corners and edges lying in the face.
FACES = []
for axis in range(3):
    for side in range(2):
        normal = tuple((2 * side - 1) if k == axis else 0 for k in range(3))
        corners = [c for c in range(8) if CORNERS[c][axis] == side]
        edges = [e for e in range(12) if CORNERS[EDGES[e][0]][axis] == side and CORNERS[EDGES[e][1]][axis] == side]
        FACES.append((axis, side, normal, corners, edges))

EDGE_FACES = {e: [f for f in range(6) if e in FACES[f][4]] for e in range(12)}


def inside(case, c):
    return (case >> c) & 1 == 1


def face_segments(case, f):
    """Directed segments (edge_from, edge_to) on face f."""
    _, _, normal, corners, edges = FACES[f]
    crossed = [e for e in edges if inside(case, EDGES[e][0]) != inside(case, EDGES[e][1])]
    if not crossed:
        return []
    if len(crossed) == 2:
        pairs = [tuple(crossed)]
    else:
        assert len(crossed) == 4
        pairs = []
        for c in corners:
            if not inside(case, c):
                incident = [e for e in edges if c in EDGES[e]]
                pairs.append(tuple(incident))
        assert len(pairs) == 2
    out = []
    for e1, e2 in pairs:
        p, q = midpoint(e1), midpoint(e2)
        m = scale(add(p, q), 0.5)
        shared = set(EDGES[e1]) & set(EDGES[e2])
        if shared:
            c = shared.pop()
            n = sub(CORNERS[c], m) if not inside(case, c) else sub(m, CORNERS[c])
        else:
            outs = [CORNERS[c] for c in corners if not inside(case, c)]
            ins = [CORNERS[c] for c in corners if inside(case, c)]
            n = sub(scale(tuple(map(sum, zip(*outs))), 1.0 / len(outs)), scale(tuple(map(sum, zip(*ins))), 1.0 / len(ins)))
        t = cross(n, normal)
        d = dot(sub(q, p), t)
        assert abs(d) > 1e-9
        out.append((e1, e2) if d > 0 else (e2, e1))
    return out


def loops_of(case):
    nxt = {}
    for f in range(6):
        for a, b in face_segments(case, f):
            assert a not in nxt
            nxt[a] = b
    loops = []
    seen = set()
    for start in sorted(nxt):
        if start in seen:
            continue
        loop = [start]
        seen.add(start)
        e = nxt[start]
        while e != start:
            assert e not in seen
            loop.append(e)
            seen.add(e)
            e = nxt[e]
        loops.append(loop)
    crossed = {e for e in range(12) if inside(case, EDGES[e][0]) != inside(case, EDGES[e][1])}
    assert seen == crossed and set(nxt.values()) == crossed
    return loops


def triangulations(poly):
    """All triangulations of the polygon given as a vertex list (orientation kept)."""
    if len(poly) < 3:
        yield []
        return
    if len(poly) == 3:
        yield [tuple(poly)]
        return
    a, b = poly[0], poly[-1]
    for k in range(1, len(poly) - 1):
        apex = poly[k]
        for left in triangulations(poly[: k + 1]):
            for right in triangulations(poly[k:]):
                yield left + [(a, apex, b)] + right


def same_face(e1, e2):
    return bool(set(EDGE_FACES[e1]) & set(EDGE_FACES[e2]))


def angle_min(tris):
    best = 180.0
    for tri in tris:
        pts = [midpoint(e) for e in tri]
        for i in range(3):
            u = sub(pts[(i + 1) % 3], pts[i])
            v = sub(pts[(i + 2) % 3], pts[i])
            cosang = dot(u, v) / math.sqrt(dot(u, u) * dot(v, v))
            best = min(best, math.degrees(math.acos(max(-1.0, min(1.0, cosang)))))
    return best


def diagonals(loop, tris):
    boundary = {frozenset((loop[i], loop[(i + 1) % len(loop)])) for i in range(len(loop))}
    diag = set()
    for tri in tris:
        for i in range(3):
            e = frozenset((tri[i], tri[(i + 1) % 3]))
            if e not in boundary:
                diag.add(e)
    return diag


def rotate_canonical(tri):
    # Rotation keeps orientation; start at the smallest edge id for a stable table.
    i = tri.index(min(tri))
    return tri[i:] + tri[:i]


def build():
    table = []
    face_diagonals = []  # per case: set of (face, frozenset(edge pair)) diagonals lying in a face
    for case in range(256):
        tris = []
        fdiag = set()
        for loop in loops_of(case):
            best = None
            for cand in triangulations(loop):
                diag = diagonals(loop, cand)
                bad = sum(1 for d in diag if same_face(*tuple(d)))
                key = (bad, -round(angle_min(cand), 9), [rotate_canonical(t) for t in cand])
                if best is None or key < best[0]:
                    best = (key, cand, diag)
            tris += [rotate_canonical(t) for t in best[1]]
            for d in best[2]:
                e1, e2 = tuple(d)
                for f in set(EDGE_FACES[e1]) & set(EDGE_FACES[e2]):
                    fdiag.add((f, d))
        assert len(tris) <= 5, (case, tris)
        table.append(tris)
        face_diagonals.append(fdiag)
    return table, face_diagonals


def check_face_diagonals(face_diagonals):
    """No two face-adjacent cubes may put a diagonal on the same pair of shared-face vertices."""
    # Cube A's face (axis, 1) touches cube B's face (axis, 0); corner (.., 1, ..) of A is corner (.., 0, ..) of B.
    problems = 0
    for axis in range(3):
        fa, fb = 2 * axis + 1, 2 * axis
        bit = 1 << axis
        edge_map = {}
        for e in FACES[fa][4]:
            a, b = EDGES[e]
            a2, b2 = a & ~bit, b & ~bit
            edge_map[e] = next(x for x in range(12) if set(EDGES[x]) == {a2, b2})
        for ca in range(256):
            da = [d for f, d in face_diagonals[ca] if f == fa]
            if not da:
                continue
            mapped = {frozenset(edge_map[e] for e in d) for d in da}
            for cb in range(256):
                if any(inside(ca, c) != inside(cb, c & ~bit) for c in FACES[fa][3]):
                    continue
                db = {d for f, d in face_diagonals[cb] if f == fb}
                if mapped & db:
                    problems += 1
    assert problems == 0, problems


def main():
    table, face_diagonals = build()
    check_face_diagonals(face_diagonals)
    used_face_diagonals = sum(1 for d in face_diagonals if d)
    out = sys.stdout
    out.write("// Generated by core/polygonize/mc_tables.py; do not edit. See that script for conventions and checks.\n")
    out.write("#pragma once\n\n#include <cstdint>\n\n// clang-format off\nnamespace surfacer::mc {\n\n")
    out.write("// Cube corner c = (c & 1, (c >> 1) & 1, (c >> 2) & 1); case bit c set when corner c is inside.\n")
    out.write("// Edges: x-edges 0..3 = y + 2z, y-edges 4..7 = 4 + x + 2z, z-edges 8..11 = 8 + x + 2y.\n")
    out.write("inline constexpr std::uint8_t kEdgeCorners[12][2] = {\n")
    out.write("    " + ", ".join("{%d, %d}" % e for e in EDGES) + "};\n\n")
    out.write("// Number of triangles per case (0..5).\n")
    out.write("inline constexpr std::uint8_t kTriangleCount[256] = {\n")
    counts = [len(t) for t in table]
    for row in range(0, 256, 32):
        out.write("    " + ", ".join(str(c) for c in counts[row : row + 32]) + ",\n")
    out.write("};\n\n")
    out.write("// Triangles per case as edge ids, counter-clockwise seen from outside; -1 pads.\n")
    out.write("inline constexpr std::int8_t kTriangles[256][15] = {\n")
    for case, tris in enumerate(table):
        flat = [e for t in tris for e in t]
        flat += [-1] * (15 - len(flat))
        out.write("    {" + ", ".join(str(e) for e in flat) + "},\n")
    out.write("};\n\n}  // namespace surfacer::mc\n// clang-format on\n")
    sys.stderr.write("cases with a same-face diagonal: %d; max triangles: %d\n" % (used_face_diagonals, max(counts)))


if __name__ == "__main__":
    main()
