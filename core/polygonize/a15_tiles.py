#!/usr/bin/env python3
"""Generates core/polygonize/a15_table.h: the periodic Delaunay tetrahedralization of the A15 point set (Williams 2008, ch. 4;
docs/ALGORITHMS.md section 2), the tile table of Marching Tiles (core/polygonize/marching_tiles.cpp).

    python3 core/polygonize/a15_tiles.py > core/polygonize/a15_table.h

Standard library only. Everything is exact: point coordinates are integers (cell edge 4), so the orientation and
in-sphere predicates are integer determinants.

Method
  1. Points: the 8 A15 sites of a cell, translated over a 5x5x5 block of cells (cells -2..2).
  2. Candidates: every 4-subset containing a point of the central cell with all 6 pairwise squared distances <= 13
     (the A15 nearest-neighbour shells are 4, 5 and 6, the next 12 and 13; 13 includes them, so the emptiness test has
     non-Delaunay candidates to reject), non-coplanar.
  3. Delaunay test: a candidate is kept when no point of the block lies strictly inside its circumsphere. A point ON
     the circumsphere (co-spherical degeneracy) is reported and makes the script fail, because then the
     tetrahedralization would not be unique; A15 has none (checked).
  4. Periodic classes: a kept tetrahedron is identified with its translates by multiples of 4; one representative per
     class. The script checks: 46 classes, volumes summing to 64 (= one cell, so the tetrahedra tile space without
     gaps or overlaps), 54 edge classes, every face shared by exactly 2 tetrahedra, dihedral angles in
     [53.1, 78.5] degrees, at least 5 tetrahedra around every edge.
  5. Home cells: each tetrahedron is assigned to the cell that is the per-axis minimum of its vertices' cells, so all
     its vertices lie in cells home + {0,1}^3 (offsets 0 or 1 per axis; checked). Any assignment of the 46 classes to
     cells tiles space (docs/ALGORITHMS.md section 2); this one lets the marcher read a cell and its +x/+y/+z
     neighbours only. Edges likewise get the per-axis minimum of their two endpoints' cells as home cell.
  6. Orientation: every tetrahedron's vertices are ordered so that det(v1 - v0, v2 - v0, v3 - v0) > 0.
"""

import itertools
import math
import sys

CELL = 4
POINTS = [(0, 0, 0), (2, 2, 2), (1, 0, 2), (3, 0, 2), (2, 1, 0), (2, 3, 0), (0, 2, 1), (0, 2, 3)]
POINT_NAMES = ["bcc corner", "bcc centre", "chain x", "chain x", "chain y", "chain y", "chain z", "chain z"]
MAX_EDGE2 = 13
BLOCK = range(-2, 3)


def sub(a, b):
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


def dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def cross(a, b):
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def det3(a, b, c):
    return dot(a, cross(b, c))


def orient(a, b, c, d):
    """6 x signed volume of (a, b, c, d)."""
    return det3(sub(b, a), sub(c, a), sub(d, a))


def det4(m):
    total = 0
    for col in range(4):
        minor = [[m[r][c] for c in range(4) if c != col] for r in range(1, 4)]
        sign = -1 if col % 2 else 1
        total += sign * m[0][col] * det3(*minor)
    return total


def insphere(a, b, c, d, e):
    """> 0 when e is strictly inside the circumsphere of the positively oriented (a, b, c, d), 0 on it."""
    rows = []
    for p in (a, b, c, d):
        q = sub(p, e)
        rows.append([q[0], q[1], q[2], dot(q, q)])
    return -det4(rows)  # sign convention checked in self_test()


def self_test():
    a, b, c, d = (0, 0, 0), (1, 0, 0), (0, 1, 0), (0, 0, 1)
    assert orient(a, b, c, d) > 0
    assert insphere(a, b, c, d, (0, 0, 0)) == 0  # a vertex lies on the sphere
    assert insphere(a, b, c, d, (1, 1, 1)) == 0  # (1,1,1) is on the circumsphere of the corner tetrahedron
    # centre (1/2, 1/2, 1/2): a point near it is inside, a far point is outside (scaled to stay integral).
    a2, b2, c2, d2 = [tuple(2 * x for x in p) for p in (a, b, c, d)]
    assert insphere(a2, b2, c2, d2, (1, 1, 1)) > 0
    assert insphere(a2, b2, c2, d2, (5, 5, 5)) < 0


class Site:
    __slots__ = ("coord", "point", "cell")

    def __init__(self, point, cell):
        self.point = point
        self.cell = cell
        self.coord = tuple(POINTS[point][i] + CELL * cell[i] for i in range(3))


def floordiv_cell(c):
    return tuple(x // CELL for x in c)


def canonical_tet(sites):
    """Periodic class key: the sorted (point, cell offset from the per-axis minimum cell) tuples."""
    home = tuple(min(s.cell[i] for s in sites) for i in range(3))
    return home, tuple(sorted((s.point, tuple(s.cell[i] - home[i] for i in range(3))) for s in sites))


def canonical_edge(s, t):
    home = tuple(min(s.cell[i], t.cell[i]) for i in range(3))
    ends = sorted([(s.point, tuple(s.cell[i] - home[i] for i in range(3))),
                   (t.point, tuple(t.cell[i] - home[i] for i in range(3)))])
    return home, tuple(ends)


def dihedral_angles(p):
    """The 6 interior dihedral angles (degrees) of the tetrahedron with vertex coordinates p[0..3]."""
    out = []
    for i, j in itertools.combinations(range(4), 2):
        k, l = [m for m in range(4) if m not in (i, j)]
        e = sub(p[j], p[i])
        # Normals of the faces (i, j, k) and (i, j, l) projected perpendicular to the edge.
        def perp(q):
            v = sub(q, p[i])
            ee = dot(e, e)
            t = dot(v, e) / ee
            return (v[0] - t * e[0], v[1] - t * e[1], v[2] - t * e[2])
        u, w = perp(p[k]), perp(p[l])
        cosang = dot(u, w) / math.sqrt(dot(u, u) * dot(w, w))
        out.append(math.degrees(math.acos(max(-1.0, min(1.0, cosang)))))
    return out


def main():
    self_test()
    sites = [Site(pt, (x, y, z)) for x in BLOCK for y in BLOCK for z in BLOCK for pt in range(8)]
    central = [s for s in sites if s.cell == (0, 0, 0)]

    def near(s, t):
        d = sub(s.coord, t.coord)
        return dot(d, d) <= MAX_EDGE2

    neighbours = {id(s): [t for t in sites if t is not s and near(s, t)] for s in central}

    classes = {}
    candidates = 0
    degenerate = []
    for s in central:
        nb = neighbours[id(s)]
        for trio in itertools.combinations(nb, 3):
            if not (near(trio[0], trio[1]) and near(trio[0], trio[2]) and near(trio[1], trio[2])):
                continue
            tet = [s, *trio]
            vol6 = orient(*(t.coord for t in tet))
            if vol6 == 0:
                continue
            if vol6 < 0:
                tet[2], tet[3] = tet[3], tet[2]
            home, key = canonical_tet(tet)
            if key in classes:
                continue
            candidates += 1
            coords = [t.coord for t in tet]
            members = set(id(t) for t in tet)
            empty = True
            on_sphere = []
            for e in sites:
                if id(e) in members:
                    continue
                side = insphere(*coords, e.coord)
                if side > 0:
                    empty = False
                    break
                if side == 0:
                    on_sphere.append((e.point, e.cell))
            if empty:
                if on_sphere:
                    degenerate.append((key, on_sphere))
                classes[key] = tet
    if degenerate:
        sys.exit("co-spherical degeneracy: %r" % degenerate[:5])

    tets = []
    for key in sorted(classes):
        # Re-express with home cell (0,0,0): vertices as (point, offset), positively oriented.
        verts = [(pt, off) for pt, off in key]
        coords = [tuple(POINTS[pt][i] + CELL * off[i] for i in range(3)) for pt, off in verts]
        if orient(*coords) < 0:
            verts[2], verts[3] = verts[3], verts[2]
            coords[2], coords[3] = coords[3], coords[2]
        assert orient(*coords) > 0
        for _, off in verts:
            assert all(o in (0, 1) for o in off), "vertex cell offset outside {0,1}"
        tets.append((verts, coords))

    # --- Checks ---------------------------------------------------------------------------------------------------
    assert len(tets) == 46, len(tets)
    total6 = sum(orient(*c) for _, c in tets)
    assert total6 == 6 * CELL ** 3, total6  # volumes sum to one cell

    def site_of(pt, off, home=(0, 0, 0)):
        return Site(pt, tuple(home[i] + off[i] for i in range(3)))

    # Edges: periodic classes with home cell; ring sizes.
    edge_index = {}
    edges = []
    for verts, _ in tets:
        for a, b in itertools.combinations(verts, 2):
            _, key = canonical_edge(site_of(*a), site_of(*b))
            if key not in edge_index:
                edge_index[key] = len(edges)
                edges.append(key)
    assert len(edges) == 54, len(edges)
    ring = [0] * len(edges)
    tet_edges = []
    for verts, _ in tets:
        row = []
        for i, j in ((0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)):
            home, key = canonical_edge(site_of(*verts[i]), site_of(*verts[j]))
            e = edge_index[key]
            ring[e] += 1
            # Is the tet's vertex i the edge's first endpoint?
            first = (verts[i][0], tuple(verts[i][1][k] - home[k] for k in range(3))) == key[0]
            row.append((i, j, e, home, first))
        tet_edges.append(row)
    assert min(ring) >= 5, ring
    # Faces: periodic classes, each shared by exactly 2 tetrahedra.
    faces = {}
    for verts, _ in tets:
        for tri in itertools.combinations(verts, 3):
            ss = [site_of(*v) for v in tri]
            home = tuple(min(s.cell[i] for s in ss) for i in range(3))
            key = tuple(sorted((s.point, tuple(s.cell[i] - home[i] for i in range(3))) for s in ss))
            faces[key] = faces.get(key, 0) + 1
    assert all(n == 2 for n in faces.values()), faces
    assert len(faces) == 2 * 46, len(faces)
    angles = [a for _, c in tets for a in dihedral_angles(c)]
    assert 53.0 < min(angles) and max(angles) < 78.6, (min(angles), max(angles))
    # Mean edge length (sample spacing in lattice units).
    lengths = []
    for (p0, o0), (p1, o1) in edges:
        a = tuple(POINTS[p0][i] + CELL * o0[i] for i in range(3))
        b = tuple(POINTS[p1][i] + CELL * o1[i] for i in range(3))
        lengths.append(math.sqrt(dot(sub(a, b), sub(a, b))))
    mean = sum(lengths) / len(lengths)
    shells = sorted(set(round(l * l) for l in lengths))

    # --- Output ---------------------------------------------------------------------------------------------------
    w = sys.stdout.write
    w("// GENERATED by core/polygonize/a15_tiles.py (python3 core/polygonize/a15_tiles.py > core/polygonize/a15_table.h); do not edit.\n")
    w("// The A15 tiling (docs/ALGORITHMS.md section 2; Williams 2008, ch. 4): periodic Delaunay tetrahedralization of the\n")
    w("// 8 A15 sites per cell of edge 4 (integer lattice units). Checked by the script and by tests/core/a15_table_test.cpp:\n")
    w("// %d tetrahedra, %d edges, 8 vertices per cell; volumes sum to 64; every face shared by 2 tetrahedra;\n" % (len(tets), len(edges)))
    w("// dihedral angles %.2f..%.2f degrees; %d..%d tetrahedra around an edge; squared edge lengths %s;\n"
      % (min(angles), max(angles), min(ring), max(ring), "/".join(map(str, shells))))
    w("// mean edge length %.15f; %d candidate tetrahedra tested, no co-spherical degeneracy.\n" % (mean, candidates))
    w("//\n")
    w("// Cells: cell c holds the sites 4c + kPoints[p]. A tetrahedron's home cell is the per-axis minimum of its vertices'\n")
    w("// cells, so every vertex is (point, offset) with offset in {0,1}^3 from the home cell. Vertices are ordered so that\n")
    w("// det(v1 - v0, v2 - v0, v3 - v0) > 0. An edge's home cell is the per-axis minimum of its endpoints' cells.\n")
    w("#pragma once\n\n#include <array>\n#include <cstdint>\n\nnamespace surfacer::a15 {\n\n")
    w("inline constexpr int kCellEdge = %d;\ninline constexpr int kPointCount = 8;\n" % CELL)
    w("inline constexpr int kTetCount = %d;\ninline constexpr int kEdgeCount = %d;\n" % (len(tets), len(edges)))
    w("// Mean Delaunay edge length in lattice units: world = lattice * (spacing / kMeanEdge).\n")
    w("inline constexpr double kMeanEdge = %.17g;\n\n" % mean)
    w("// Site p of a cell, lattice units.\n")
    w("inline constexpr std::array<std::array<int, 3>, kPointCount> kPoints = {{\n")
    for p, name in zip(POINTS, POINT_NAMES):
        w("    {%d, %d, %d},  // %s\n" % (p + (name,)))
    w("}};\n\n")
    w("// A lattice site relative to a home cell.\nstruct Site {\n  std::uint8_t point;\n  std::array<std::uint8_t, 3> offset;  // 0 or 1 per axis\n};\n\n")
    w("// Tetrahedra relative to their home cell, positively oriented.\n")
    w("inline constexpr std::array<std::array<Site, 4>, kTetCount> kTets = {{\n")
    for verts, coords in tets:
        w("    {{" + ", ".join("{%d, {%d, %d, %d}}" % (pt, *off) for pt, off in verts) + "}},\n")
    w("}};\n\n")
    w("// Edges relative to their home cell: endpoints a and b (a has the smaller (point, offset)).\n")
    w("struct Edge {\n  Site a;\n  Site b;\n};\n")
    w("inline constexpr std::array<Edge, kEdgeCount> kEdges = {{\n")
    for (p0, o0), (p1, o1) in edges:
        w("    {{%d, {%d, %d, %d}}, {%d, {%d, %d, %d}}},\n" % (p0, *o0, p1, *o1))
    w("}};\n\n")
    w("// The 6 edges of each tetrahedron, in the order (0,1) (0,2) (0,3) (1,2) (1,3) (2,3) of its vertices: edge class,\n")
    w("// the edge's home cell relative to the tetrahedron's (0 or 1 per axis), and whether the tetrahedron's first vertex\n")
    w("// of the pair is the edge's endpoint a.\n")
    w("struct TetEdge {\n  std::uint8_t edge;\n  std::array<std::uint8_t, 3> home;\n  bool a_first;\n};\n")
    w("inline constexpr std::array<std::array<TetEdge, 6>, kTetCount> kTetEdges = {{\n")
    for row in tet_edges:
        items = ["{%d, {%d, %d, %d}, %s}" % (e, *h, "true" if f else "false") for _, _, e, h, f in row]
        w("    {{" + ", ".join(items[:3]) + ",\n      " + ", ".join(items[3:]) + "}},\n")
    w("}};\n\n}  // namespace surfacer::a15\n")
    sys.stderr.write("tets %d edges %d faces %d angles %.3f..%.3f ring %d..%d mean edge %.6f candidates %d\n"
                     % (len(tets), len(edges), len(faces), min(angles), max(angles), min(ring), max(ring), mean,
                        candidates))


if __name__ == "__main__":
    main()
