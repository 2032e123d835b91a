#!/usr/bin/python3
"""The CLI's .glb files (the default file of Draco frames, and meshopt frames with --format glb) as third-party glTF
code reads them: the Khronos glTF validator finds no error and no warning, and glTF-Transform, decoding the Draco
primitives with Google's draco3dgltf and the meshopt views with meshoptimizer's decoder (read_glb.mjs), finds the
surface of the .ply the same job writes: the same triangles, corner for corner on the job's quantization grid through
the node's scale and translation (KHR_mesh_quantization), with the same normals and interpolated particle attributes
at every vertex. Usage: third_party_glb_test.py SURFACER_CLI SCRATCH_DIR. Exits 77 (skipped) when node or npm is
missing or the pinned packages (package-lock.json) cannot be installed from the npm registry."""
import json
import math
import os
import shutil
import subprocess
import sys

import meshio
import numpy as np

cli, scratch = sys.argv[1], sys.argv[2]
here = os.path.dirname(os.path.abspath(__file__))
source = os.path.dirname(os.path.dirname(here))
if not shutil.which("node") or not shutil.which("npm"):
    print("skipped: node or npm is not installed (the glTF readers are npm packages)")
    sys.exit(77)
shutil.rmtree(scratch, ignore_errors=True)
node_dir = os.path.join(scratch, "node")
os.makedirs(node_dir)
for name in ("package.json", "package-lock.json", "read_glb.mjs"):
    shutil.copy(os.path.join(here, name), node_dir)
installed = subprocess.run(["npm", "ci", "--no-audit", "--no-fund"], cwd=node_dir, capture_output=True, text=True,
                           timeout=300)
if installed.returncode != 0:
    print(f"skipped: npm ci could not install the glTF readers:\n{installed.stderr[-2000:]}")
    sys.exit(77)

failures = []


def expect(ok, what):
    if not ok:
        failures.append(what)
        print(f"FAILED: {what}")
    return ok


def run(out, args):
    r = subprocess.run([cli, "--local", *args, "-o", out], capture_output=True, text=True, timeout=300)
    if r.returncode != 0:
        raise SystemExit(f"{' '.join(args)}: exit {r.returncode}\n{r.stderr}")


def oriented(triple):
    """A triangle's three corners (hashable), rotated to start at the smallest: orientation kept, start forgotten."""
    k = min(range(3), key=lambda i: triple[i])
    return triple[k:] + triple[:k]


def check(name, args, attributes=()):
    glb_dir, ply_dir = os.path.join(scratch, name, "glb"), os.path.join(scratch, name, "ply")
    run(glb_dir, args)
    run(ply_dir, [*args, "--format", "ply"])
    glb = os.path.join(glb_dir, "frame_0000.glb")
    if not expect(os.path.isfile(glb), f"{name}: {' '.join(args)} wrote {os.listdir(glb_dir)}, not frame_0000.glb"):
        return
    r = subprocess.run(["node", os.path.join(node_dir, "read_glb.mjs"), glb], cwd=node_dir, capture_output=True,
                       text=True, timeout=300)
    if not expect(r.returncode == 0, f"{name}: read_glb.mjs exit {r.returncode}: {r.stderr[-2000:]}"):
        return
    read = json.loads(r.stdout)
    expect(read["errors"] == 0 and read["warnings"] == 0,
           f"{name}: the validator found {read['errors']} errors and {read['warnings']} warnings: {read['issues']}")
    ply = meshio.read(os.path.join(ply_dir, "frame_0000.ply"))
    nodes = [n for n in read["nodes"] if n["mesh"]]
    if not expect(len(nodes) == 1, f"{name}: {len(nodes)} nodes with a mesh"):
        return
    scale, translation = np.array(nodes[0]["scale"]), np.array(nodes[0]["translation"])
    points = ply.points.astype(np.float64)
    grid = np.rint((points - translation) / scale).astype(np.int64)
    residual = np.abs(points - (grid * scale + translation)).max() / scale.max()
    expect(residual < 1e-3, f"{name}: the .ply's vertices lie {residual:.3g} steps off the node's grid")
    wanted = {}  # grid point -> the .ply's values there (normals, attributes)
    for v, g in enumerate(map(tuple, grid)):
        wanted[g] = [ply.point_data[a][v] for a in attributes]
    ply_triangles = sorted(oriented(tuple(tuple(grid[c]) for c in t)) for t in ply.cells_dict["triangle"])
    # Where the .glb holds each of the .ply's columns: a component of NORMAL (octahedral in the Draco streams, so
    # within a few thousandths), or the application attribute _NAME, exactly.
    columns = [("NORMAL", "xyz".index(a[1]), 5e-3) if a in ("nx", "ny", "nz") else ("_" + a.upper(), None, 0.0)
               for a in attributes]
    glb_triangles = []
    mismatched_values = 0
    for p in read["primitives"]:
        expect(p["mode"] == 4, f"{name}: a primitive of mode {p['mode']}, not triangles")
        position = p["attributes"]["POSITION"]
        q = np.array(position["values"], dtype=np.int64).reshape(-1, 3)
        for semantic, _, _ in columns:
            if not expect(semantic in p["attributes"], f"{name}: a primitive without {semantic}"):
                return
            expect(p["attributes"][semantic]["count"] == position["count"], f"{name}: {semantic} count")
        for i, g in enumerate(map(tuple, q)):
            if g not in wanted:
                continue  # counted below, as triangles that differ
            for j, (semantic, component, tolerance) in enumerate(columns):
                values = p["attributes"][semantic]["values"]
                value = values[i] if component is None else values[3 * i + component]
                if not math.isclose(value, float(wanted[g][j]), rel_tol=0.0, abs_tol=tolerance):
                    mismatched_values += 1
        indices = p["indices"]
        glb_triangles += [oriented(tuple(tuple(q[indices[k + c]]) for c in range(3)))
                          for k in range(0, len(indices), 3)]
    glb_triangles.sort()
    expect(glb_triangles == ply_triangles,
           f"{name}: {len(glb_triangles)} triangles in the .glb against {len(ply_triangles)} in the .ply, "
           f"{sum(a != b for a, b in zip(glb_triangles, ply_triangles))} of them differ")
    expect(mismatched_values == 0, f"{name}: {mismatched_values} attribute values differ from the .ply's")
    print(f"{name}: {len(read['primitives'])} primitives, {len(glb_triangles)} triangles, validator "
          f"{read['errors']} errors {read['warnings']} warnings; {' '.join(args)}")


scenes = os.path.join(source, "examples", "scenes")
gyroid = ["run", "isosurface", "--scene", os.path.join(scenes, "gyroid_in_sphere.json")]
check("cubes", [*gyroid, "--method", "cubes", "--cells", "96"])  # 4 pieces
check("tiles", [*gyroid, "--cells", "48"])
check("meshopt", [*gyroid, "--method", "cubes", "--cells", "64", "--encoding", "meshopt", "--format", "glb"])

# A ball of particles with a density and a velocity per particle, carried onto the surface with its normals.
rng = np.random.default_rng(3)
d = 0.02
lattice = np.stack(np.meshgrid(*[np.arange(-6, 7)] * 3, indexing="ij"), -1).reshape(-1, 3) * d
ball = lattice[np.linalg.norm(lattice, axis=1) <= 0.12]
ball = ball + rng.uniform(-d / 10, d / 10, ball.shape)
particles = os.path.join(scratch, "ball.ply")
meshio.write_points_cells(particles, ball, [], point_data={"density": 1000 + 100 * ball[:, 2],
                                                           "vx": ball[:, 1], "vy": -ball[:, 0]}, binary=True)
check("particles", ["run", "particles", "--input", particles, "--r-inner", "0.012", "--interpolate", "all",
                    "--normals"], attributes=("nx", "ny", "nz", "density", "vx", "vy"))

print(f"{len(failures)} failures" if failures else "every .glb reads back as the .ply's surface")
sys.exit(1 if failures else 0)
