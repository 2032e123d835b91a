#!/usr/bin/env python3
"""Writes the seed corpora of the fuzz targets into fuzz/corpus/<target>/seed_*.

Seeds are small valid (and a few nearly valid) inputs of every format each target decodes, built from
examples/scenes/ and from the file layouts the tests write (tests/core/particle_io_test.cpp, mesh_io_test.cpp).
Draco seeds need `draco_encoder` (Debian package `draco`), pieced-frame seeds the build's fuzz/fuzz_frame_seeds
(SURFACER_BUILD_DIR, default build/). Files not named seed_* (crash inputs saved as
regressions) are left alone. Run from anywhere: python3 fuzz/make_seeds.py
"""
import gzip
import json
import math
import os
import pathlib
import shutil
import struct
import subprocess
import tempfile

ROOT = pathlib.Path(__file__).resolve().parent.parent
CORPUS = ROOT / "fuzz" / "corpus"


def reset(target):
    d = CORPUS / target
    d.mkdir(parents=True, exist_ok=True)
    for old in d.glob("seed_*"):
        old.unlink()
    return d


def write(d, name, data):
    if isinstance(data, str):
        data = data.encode()
    (d / ("seed_" + name)).write_bytes(data)


# --- scene_json ----------------------------------------------------------------------------------------------------

def scenes():
    d = reset("scene_json")
    for f in sorted((ROOT / "examples" / "scenes").glob("*.json")):
        write(d, f.name, f.read_bytes())
    s = {
        "every_primitive.json": """{"name": "all", "root": {"union": {"children": [
  {"sphere": {"center": {"x": 1}, "radius": 0.5}},
  {"box": {"center": {"y": 1}, "half_size": {"x": 0.2, "y": 0.3, "z": 0.4}}},
  {"rounded_box": {"half_size": {"x": 0.5, "y": 0.5, "z": 0.5}, "radius": 0.1}},
  {"cylinder": {"a": {"z": -1}, "b": {"z": 1}, "radius": 0.25}},
  {"cone": {"a": {"x": -1}, "b": {"x": 1}, "radius_a": 0.5, "radius_b": 0.1}},
  {"torus": {"center": {"z": 2}, "axis": {"x": 1}, "major_radius": 1, "minor_radius": 0.2}},
  {"capsule": {"a": {"y": -1}, "b": {"y": 1}, "radius": 0.3}}]}}}""",
        "plane_gyroid.json": """{"root": {"intersection": {"blend": "BLEND_RFUNCTION", "children": [
  {"plane": {"normal": {"x": 1, "y": 1}, "offset": 0.5}},
  {"gyroid": {"period": 2, "thickness": 0.3}},
  {"sphere": {"radius": 2}}]}}}""",
        "difference_smooth.json": """{"root": {"difference": {"blend": "BLEND_SMOOTH", "radius": 0.2, "children": [
  {"box": {"half_size": {"x": 1, "y": 1, "z": 1}}}, {"sphere": {"radius": 1.2}}]}}}""",
        "transform_matrix.json": """{"root": {"transform": {"matrix": [2, 0, 0, 1, 0, 1, 0, 0, 0, 0, 0.5, -1],
  "child": {"sphere": {"radius": 1}}}}}""",
        "transform_trs.json": """{"root": {"transform": {"translate": {"x": 1, "y": 2}, "rotate_axis": {"z": 1},
  "rotate_degrees": 30, "scale": 1.5, "child": {"box": {"half_size": {"x": 1, "y": 0.5, "z": 0.25}}}}}}""",
        "blobs_blinn.json": """{"root": {"blobs": {"kernel": "KERNEL_BLINN", "iso": 0.3, "blobbiness": 2,
  "points": [{"center": {"x": -0.5}, "radius": 1, "strength": 1}, {"center": {"x": 0.5}, "radius": 0.8}],
  "segments": [{"a": {"y": -1}, "b": {"y": 1}, "radius": 0.6, "strength": 0.5}]}}}""",
        "blobs_wyvill.json": """{"root": {"blobs": {"points": [{"radius": 1}],
  "segments": [{"a": {"z": -1}, "b": {"z": 1}, "radius": 0.7}]}}}""",
        "grid_inline.json": """{"root": {"grid": {"origin": {"x": -1, "y": -1, "z": -1}, "spacing": {"x": 1, "y": 1, "z": 1},
  "nx": 3, "ny": 3, "nz": 2, "values": [1, 1, 1, 1, -0.5, 1, 1, 1, 1, 1, 1, 1, 1, -0.25, 1, 1, 1, 1]}}}""",
        "grid_potential.json": """{"root": {"grid": {"spacing": {"x": 0.5, "y": 0.5, "z": 0.5}, "nx": 2, "ny": 2, "nz": 2,
  "potential": true, "iso": 0.5, "values": [0, 1, 0, 0, 0, 0, 0, 0.9]}}}""",
        "grid_upload.json": """{"root": {"union": {"children": [
  {"grid": {"spacing": {"x": 0.5, "y": 0.5, "z": 0.5}, "nx": 3, "ny": 3, "nz": 3, "upload_id": "u-grid"}},
  {"grid": {"spacing": {"x": 1, "y": 1, "z": 1}, "nx": 2, "ny": 2, "nz": 2, "upload_id": "u-odd"}}]}}}""",
        "grid_huge_dims.json": """{"root": {"grid": {"spacing": {"x": 1, "y": 1, "z": 1},
  "nx": 1000000000, "ny": 1000000000, "nz": 2, "values": [1, 2]}}}""",
        "unknown_upload.json": """{"root": {"grid": {"spacing": {"x": 1, "y": 1, "z": 1}, "nx": 2, "ny": 2, "nz": 2,
  "upload_id": "u-0123456789abcdef"}}}""",
        "bad_radius.json": """{"root": {"sphere": {"radius": -1}}}""",
        "empty_node.json": """{"root": {"union": {"children": [{}, {"sphere": {"radius": 1}}]}}}""",
        "nan.json": """{"root": {"sphere": {"center": {"x": "NaN"}, "radius": "Infinity"}}}""",
    }
    # Nesting near and beyond the JSON parser's depth limit.
    for depth in (10, 40):
        text = '{"sphere": {"radius": 1}}'
        for i in range(depth):
            if i % 2:
                text = '{"transform": {"translate": {"x": 0.1}, "child": %s}}' % text
            else:
                text = '{"union": {"children": [%s, {"box": {"half_size": {"x": 1, "y": 1, "z": 1}}}]}}' % text
        s["nested_%d.json" % depth] = '{"root": %s}' % text
    s["blobs_many.json"] = json.dumps({"root": {"blobs": {"points": [
        {"center": {"x": 0.3 * i, "y": 0.1 * (i % 7), "z": 0.05 * (i % 3)}, "radius": 0.4 + 0.01 * (i % 5)}
        for i in range(70)]}}})
    for name, text in s.items():
        write(d, name, text)
    # The same scenes as binary v1.Scene (a 0 byte first), through protoc's text format encoder.
    protoc = shutil.which("protoc")
    if protoc is None:
        print("make_seeds: protoc not found; no binary scene seeds")
        return
    texts = {f.name: f.read_text() for f in sorted((ROOT / "examples" / "scenes").glob("*.json"))}
    texts.update(s)
    for name, text in texts.items():
        try:
            textproto = to_textproto(json.loads(text))
        except ValueError:
            continue  # NaN strings and the like: JSON only
        result = subprocess.run([protoc, "--encode=surfacer.v1.Scene", "-I", str(ROOT / "proto"),
                                 "surfacer/v1/scene.proto"], input=textproto.encode(), capture_output=True)
        if result.returncode == 0:
            write(d, "binary_" + name.replace(".json", ""), b"\x00" + result.stdout)


def to_textproto(value, indent=""):
    """protobuf JSON (original field names) -> text format."""
    out = []
    for key, v in value.items():
        items = v if isinstance(v, list) else [v]
        for item in items:
            if isinstance(item, dict):
                out.append("%s%s {\n%s%s}\n" % (indent, key, to_textproto(item, indent + "  "), indent))
            elif isinstance(item, bool):
                out.append("%s%s: %s\n" % (indent, key, "true" if item else "false"))
            elif isinstance(item, (int, float)):
                out.append("%s%s: %r\n" % (indent, key, item))
            elif isinstance(item, str) and item.isupper():
                out.append("%s%s: %s\n" % (indent, key, item))  # enum value
            elif isinstance(item, str) and key in ("name", "upload_id"):
                out.append("%s%s: %s\n" % (indent, key, json.dumps(item)))
            else:
                raise ValueError(item)
    return "".join(out)


# --- particles -----------------------------------------------------------------------------------------------------

def sample(n=6, radii=False):
    pts = [(0.5 * i - 1.0, 0.25 * i * i - 0.5, 100.0 + 0.125 * i) for i in range(n)]
    rs = [0.05 + 0.01 * i for i in range(n)] if radii else []
    return pts, rs


def put(fmt, big, *v):
    return struct.pack((">" if big else "<") + fmt, *v)


def xyz(pts, rs, sep):
    s = "# particles\n\n"
    for i, p in enumerate(pts):
        s += sep.join(repr(c) for c in p)
        if rs:
            s += sep + repr(rs[i])
        s += "  # comment\r\n" if i % 3 == 0 else "\n"
    return s.encode()


def ply(pts, rs, fmt):
    big = fmt == "binary_big_endian"
    s = ("ply\nformat %s 1.0\ncomment seed\nelement face 2\nproperty list uchar int vertex_indices\n" % fmt)
    s += "element vertex %d\nproperty double x\nproperty float y\nproperty uchar red\nproperty double z\n" % len(pts)
    s += "property list uchar short tags\n"
    if rs:
        s += "property float radius\n"
    s += "end_header\n"
    if fmt == "ascii":
        s += "3 0 1 2\n4 0 1 2 3\n"
        for i, p in enumerate(pts):
            s += "%r %r 200 %r 2 7 8" % p + (" %r" % rs[i] if rs else "") + "\n"
        return s.encode()
    b = s.encode()
    for face in range(2):
        b += put("B", big, 3 + face) + b"".join(put("i", big, k) for k in range(3 + face))
    for i, p in enumerate(pts):
        b += put("d", big, p[0]) + put("f", big, p[1]) + put("B", big, 200) + put("d", big, p[2])
        b += put("B", big, 1) + put("h", big, 5)
        if rs:
            b += put("f", big, rs[i])
    return b


def vtk(pts, rs, binary, dataset, vtk51=False):
    n = len(pts)
    b = ("# vtk DataFile Version %s\nparticles\n%s\nDATASET %s\n"
         % ("5.1" if vtk51 else "3.0", "BINARY" if binary else "ASCII", dataset)).encode()
    b += b"FIELD FieldData 1\nTIME 1 1 double\n"
    b += put("d", True, 0.5) + b"\n" if binary else b"0.5\n"
    b += ("POINTS %d %s\n" % (n, "float" if binary else "double")).encode()
    for p in pts:
        b += b"".join(put("f", True, c) for c in p) if binary else (" ".join(repr(c) for c in p) + "\n").encode()
    if binary:
        b += b"\n"
    cells = "VERTICES" if dataset == "POLYDATA" else "CELLS"
    if vtk51:
        b += ("%s %d %d\nOFFSETS vtktypeint64\n" % (cells, n + 1, n)).encode()
        b += b"".join(put("q", True, i) if binary else b"%d\n" % i for i in range(n + 1))
        b += (b"\n" if binary else b"") + b"CONNECTIVITY vtktypeint64\n"
        b += b"".join(put("q", True, i) if binary else b"%d\n" % i for i in range(n))
    else:
        b += ("%s %d %d\n" % (cells, n, 2 * n)).encode()
        b += b"".join(put("ii", True, 1, i) if binary else b"1 %d\n" % i for i in range(n))
    if binary:
        b += b"\n"
    if dataset == "UNSTRUCTURED_GRID":
        b += b"CELL_TYPES %d\n" % n + b"".join(put("i", True, 1) if binary else b"1\n" for _ in range(n))
        if binary:
            b += b"\n"
    b += b"POINT_DATA %d\nVECTORS velocity float\n" % n
    b += b"".join(put("f", True, 1.5) if binary else b"1.5\n" for _ in range(3 * n))
    if binary:
        b += b"\n"
    if rs:
        b += b"SCALARS radius double 1\nLOOKUP_TABLE default\n"
        b += b"".join(put("d", True, r) if binary else (repr(r) + "\n").encode() for r in rs)
        if binary:
            b += b"\n"
    return b + b"METADATA\nINFORMATION 0\n\n"


def b64(data):
    import base64
    return base64.b64encode(data).decode()


def vtu_payload(raw, header, big, zlib_blocks):
    """A binary array's header and data: a byte count, or VTK's zlib layout (blocks, block size, partial last block
    size or 0, each block's compressed size; then the zlib blocks)."""
    word = "Q" if header == "UInt64" else "I"
    if not zlib_blocks:
        return put(word, big, len(raw)), raw
    import zlib
    bs = zlib_blocks
    blocks = [zlib.compress(raw[i:i + bs]) for i in range(0, len(raw), bs)]
    h = put(word, big, len(blocks)) + put(word, big, bs) + put(word, big, len(raw) % bs)
    return h + b"".join(put(word, big, len(b)) for b in blocks), b"".join(blocks)


def vtu_array(values, name, comps, fmt, header, big, float64, zlib_blocks=0, appended=None):
    t = "Float64" if float64 else "Float32"
    s = '<DataArray type="%s" %sNumberOfComponents="%d" format="%s"' % (
        t, 'Name="%s" ' % name if name else "", comps, fmt)
    if fmt == "ascii":
        return s + ">\n" + " ".join(repr(v) for v in values) + " \n</DataArray>\n"
    data = b"".join(put("d" if float64 else "f", big, v) for v in values)
    h, d = vtu_payload(data, header, big, zlib_blocks)
    if fmt == "appended":
        s += ' offset="%d"/>\n' % len(appended)
        appended += h + d
        return s
    return s + ">\n" + b64(h) + b64(d) + "\n</DataArray>\n"


def vtu(pts, rs, fmt="ascii", header="UInt32", big=False, float64=False, pieces=1, kind="UnstructuredGrid",
        zlib_blocks=0):
    s = ('<?xml version="1.0"?>\n<!-- seed -->\n<VTKFile type="%s" version="1.0" byte_order="%s" '
         'header_type="%s"%s>\n<%s>\n' % (kind, "BigEndian" if big else "LittleEndian", header,
                                         ' compressor="vtkZLibDataCompressor"' if zlib_blocks else "", kind))
    n = len(pts)
    appended = bytearray()
    args = (fmt, header, big, float64, zlib_blocks, appended)
    for piece in range(pieces):
        a, e = n * piece // pieces, n * (piece + 1) // pieces
        s += '<Piece NumberOfPoints="%d" NumberOfCells="0">\n<PointData Scalars="radius">\n' % (e - a)
        s += vtu_array([2.0] * (e - a), "density", 1, *args)
        if rs:
            s += vtu_array(rs[a:e], "radius", 1, *args)
        s += "</PointData>\n<Points>\n"
        s += vtu_array([c for p in pts[a:e] for c in p], "Points", 3, *args)
        s += ('</Points>\n<Cells>\n<DataArray type="Int64" Name="connectivity" format="ascii"></DataArray>\n'
              '</Cells>\n</Piece>\n')
    b = (s + "</%s>\n" % kind).encode()
    if fmt == "appended":
        b += b'<AppendedData encoding="raw">\n   _' + bytes(appended) + b"\n</AppendedData>\n"
    return b + b"</VTKFile>\n"


def json_points(pts):
    return ("[" + ",\n ".join("[%r, %r, %r]" % p for p in pts) + "]\n").encode()


def bgeo(pts, rs):
    b = b"BgeoV"
    for v in (5, len(pts), 0, 0, 0, 3 if rs else 2, 0, 0, 0):
        b += put("i", True, v)

    def name(n):
        return put("H", True, len(n)) + n.encode()
    b += name("kind") + put("H", True, 1) + put("i", True, 4) + put("i", True, 2) + name("water") + name("foam")
    b += name("v") + put("H", True, 3) + put("i", True, 5) + put("fff", True, 0, 0, 0)
    if rs:
        b += name("pscale") + put("H", True, 1) + put("i", True, 0) + put("f", True, 1.0)
    for i, p in enumerate(pts):
        b += put("ffff", True, p[0], p[1], p[2], 1.0) + put("i", True, i % 2) + put("fff", True, 0.25, 0.25, 0.25)
        if rs:
            b += put("f", True, rs[i])
    return b + b"beginExtra"


def gz(data):
    return gzip.compress(data, mtime=0)


def particles():
    d = reset("particles")
    # selector byte: 0 xyz, 1 ply, 2 vtk, 3 vtu, 4 bin, 5 bgeo, 6/7 upload (xyz / xyzr), 8 ParticleFrame proto, 9 json
    for radii in (False, True):
        pts, rs = sample(radii=radii)
        r = "_r" if radii else ""
        write(d, "xyz_space%s" % r, b"\x00" + xyz(pts, rs, " "))
        write(d, "xyz_comma%s" % r, b"\x00" + xyz(pts, rs, ", "))
        for fmt in ("ascii", "binary_little_endian", "binary_big_endian"):
            write(d, "ply_%s%s" % (fmt, r), b"\x01" + ply(pts, rs, fmt))
        for binary in (False, True):
            for dataset in ("POLYDATA", "UNSTRUCTURED_GRID"):
                for vtk51 in (False, True):
                    tag = "%s_%s_%s%s" % ("bin" if binary else "ascii", dataset.lower(), "51" if vtk51 else "30", r)
                    write(d, "vtk_" + tag, b"\x02" + vtk(pts, rs, binary, dataset, vtk51))
        write(d, "vtu_ascii%s" % r, b"\x03" + vtu(pts, rs))
        write(d, "vtu_b64_u32%s" % r, b"\x03" + vtu(pts, rs, fmt="binary"))
        write(d, "vtu_b64_u64_be_f64%s" % r,
              b"\x03" + vtu(pts, rs, fmt="binary", header="UInt64", big=True, float64=True, pieces=2))
        write(d, "vtu_polydata%s" % r, b"\x03" + vtu(pts, rs, kind="PolyData"))
        write(d, "vtu_appended_raw%s" % r, b"\x03" + vtu(pts, rs, fmt="appended"))
        write(d, "vtu_appended_zlib%s" % r, b"\x03" + vtu(pts, rs, fmt="appended", zlib_blocks=32))
        write(d, "vtu_b64_zlib_u64_be%s" % r,
              b"\x03" + vtu(pts, rs, fmt="binary", header="UInt64", big=True, pieces=2, zlib_blocks=40))
        write(d, "bgeo%s" % r, b"\x05" + bgeo(pts, rs))
        write(d, "bgeo_gz%s" % r, b"\x05" + gz(bgeo(pts, rs)))
    pts, rs = sample()
    write(d, "xyz_header", b"\x00id,Z,y,x,pscale,vx\n1,3,2,1,0.5,9\n2,6,5,4,0.25,9\n")
    write(d, "xyz_gz", b"\x00" + gz(xyz(pts, [], " ")))
    write(d, "ply_gz", b"\x01" + gz(ply(pts, [], "ascii")))
    write(d, "vtu_appended_no_data", b"\x03" + vtu(pts, []).replace(b'format="ascii"', b'format="appended" offset="0"'))
    write(d, "json", b"\x09" + json_points(pts))
    write(d, "json_empty", b"\x09[]")
    write(d, "xyz_binary", b"\x00" + b"".join(put("fff", False, *p) for p in pts))
    write(d, "bin", b"\x04" + b"".join(put("fff", False, *p) for p in pts))
    write(d, "bin_gz", b"\x04" + gz(b"".join(put("fff", False, *p) for p in pts)))
    write(d, "upload_xyz", b"\x06" + b"".join(put("fff", False, *p) for p in pts))
    pts_r, rs_r = sample(radii=True)
    write(d, "upload_xyzr", b"\x07" + b"".join(put("ffff", False, *p, r) for p, r in zip(pts_r, rs_r)))
    write(d, "upload_bad_radius", b"\x07" + put("ffff", False, 1, 2, 3, -1))
    write(d, "upload_nan", b"\x06" + put("fff", False, 1, float("nan"), 3))

    # v1.ParticleFrame: 1 packed float positions, 2 packed float radii, 3 upload_id, 4 with_radius.
    def packed(field, values):
        data = b"".join(put("f", False, v) for v in values)
        return bytes([field << 3 | 2]) + varint(len(data)) + data
    flat = [c for p in pts_r for c in p]
    write(d, "proto_inline", b"\x08" + packed(1, flat))
    write(d, "proto_inline_radii", b"\x08" + packed(1, flat) + packed(2, rs_r))
    write(d, "proto_radii_mismatch", b"\x08" + packed(1, flat) + packed(2, rs_r[:2]))
    write(d, "proto_upload_unknown", b"\x08" + bytes([3 << 3 | 2, 4]) + b"u-00" + bytes([4 << 3, 1]))


def varint(v):
    out = b""
    while True:
        b = v & 0x7F
        v >>= 7
        if v:
            out += bytes([b | 0x80])
        else:
            return out + bytes([b])


# --- mesh ----------------------------------------------------------------------------------------------------------

def octahedron():
    v = [(1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1)]
    f = [(0, 2, 4), (2, 1, 4), (1, 3, 4), (3, 0, 4), (2, 0, 5), (1, 2, 5), (3, 1, 5), (0, 3, 5)]
    return v, f


def mesh_ply(v, f, fmt, double=False, normals=False, quads=False):
    big = fmt == "binary_big_endian"
    t = "double" if double else "float"
    s = "ply\nformat %s 1.0\ncomment seed\nelement vertex %d\n" % (fmt, len(v))
    s += "".join("property %s %s\n" % (t, c) for c in "xyz")
    if normals:
        s += "property float nx\nproperty float ny\nproperty float nz\n"
    faces = [f[0] + (f[1][1],)] + f[2:] if quads else f
    s += "element face %d\nproperty list uchar int vertex_indices\nend_header\n" % len(faces)
    if fmt == "ascii":
        for p in v:
            s += " ".join(str(float(c)) for c in p)
            if normals:
                s += " " + " ".join(str(float(c)) for c in p)
            s += "\n"
        for face in faces:
            s += "%d %s\n" % (len(face), " ".join(str(i) for i in face))
        return s.encode()
    b = s.encode()
    for p in v:
        b += b"".join(put("d" if double else "f", big, c) for c in p)
        if normals:
            b += b"".join(put("f", big, c) for c in p)
    for face in faces:
        b += put("B", big, len(face)) + b"".join(put("i", big, i) for i in face)
    return b


def mesh_obj(v, f, normals=False, negative=False):
    s = "# seed\no octahedron\n" + "".join("v %g %g %g\n" % p for p in v)
    if normals:
        s += "".join("vn %g %g %g\n" % p for p in v)
    s += "vt 0 0\ng group\ns 1\n"
    for face in f:
        if negative:
            s += "f " + " ".join(str(i - len(v)) for i in face) + "\n"
        elif normals:
            s += "f " + " ".join("%d//%d" % (i + 1, i + 1) for i in face) + "\n"
        else:
            s += "f " + " ".join("%d/1" % (i + 1) for i in face) + "\n"
    s += "f 1 3 2 4\n"  # a quad, fan-triangulated
    return s.encode()


def meshes():
    d = reset("mesh")
    v, f = octahedron()
    # selector byte: 0 PLY, 1 OBJ, 2 Draco via parse_mesh, 3 decode_draco, 4 sniffed like the server
    write(d, "ply_ascii", b"\x00" + mesh_ply(v, f, "ascii"))
    write(d, "ply_ascii_quads_normals", b"\x00" + mesh_ply(v, f, "ascii", normals=True, quads=True))
    write(d, "ply_le_float", b"\x00" + mesh_ply(v, f, "binary_little_endian"))
    write(d, "ply_be_double_normals", b"\x00" + mesh_ply(v, f, "binary_big_endian", double=True, normals=True))
    write(d, "obj", b"\x01" + mesh_obj(v, f))
    write(d, "obj_normals", b"\x01" + mesh_obj(v, f, normals=True))
    write(d, "obj_negative", b"\x01" + mesh_obj(v, f, negative=True))
    write(d, "sniff_ply", b"\x04" + mesh_ply(v, f, "binary_little_endian", double=True))
    write(d, "sniff_obj", b"\x04" + mesh_obj(v, f))
    encoder = shutil.which("draco_encoder")
    if encoder is None:
        print("make_seeds: draco_encoder not found (Debian package draco); no Draco seeds")
        return
    with tempfile.TemporaryDirectory() as tmp:
        src = pathlib.Path(tmp) / "octahedron.ply"
        src.write_bytes(mesh_ply(v, f, "ascii", normals=True))
        for name, args in (("drc_default", []), ("drc_sequential", ["-cl", "0"]), ("drc_edgebreaker", ["-cl", "7"]),
                           ("drc_qp8", ["-qp", "8", "-qn", "6"])):
            out = pathlib.Path(tmp) / (name + ".drc")
            subprocess.run([encoder, "-i", str(src), "-o", str(out)] + args, check=True, stdout=subprocess.DEVNULL)
            data = out.read_bytes()
            write(d, name, b"\x02" + data)
            write(d, name + "_direct", b"\x03" + data)
        write(d, "sniff_drc", b"\x04" + data)
    # Pieced frames (selectors 5 and 6): only our own encoder writes them.
    seeds = pathlib.Path(os.environ.get("SURFACER_BUILD_DIR", ROOT / "build")) / "fuzz" / "fuzz_frame_seeds"
    if not seeds.exists():
        print("make_seeds: %s not built (cmake --build build); no pieced-frame seeds" % seeds)
        return
    subprocess.run([str(seeds), str(d)], check=True, stdout=subprocess.DEVNULL)


# --- frame_assembler / upload_assembler -----------------------------------------------------------------------------
# Operation streams as fuzz/fuzz_frame_assembler.cpp and fuzz_upload_assembler.cpp read them (little-endian).

def frame_ops():
    d = reset("frame_assembler")

    def well_formed(index, encoding, payload, chunks, corruption, victim=0):
        # op 2: index byte, encoding byte, u16 length, payload, [empty: flag] chunks byte, corruption, victim
        b = bytes([2, index, encoding]) + put("H", False, len(payload)) + payload
        b += bytes([0]) if not payload else bytes([chunks - 1])
        return b + bytes([corruption, victim])
    payload = bytes(range(256)) * 3
    write(d, "one_frame", well_formed(0, 1, payload, 3, 0))
    write(d, "two_frames_ply", well_formed(0, 2, payload[:100], 1, 0) + well_formed(1, 2, payload[:10], 2, 1))
    write(d, "empty_frame", well_formed(2, 0, b"", 0, 0))
    write(d, "bad_chunk_crc", well_formed(0, 1, payload, 4, 3, 2) + bytes([3]) + well_formed(0, 1, payload, 2, 0))
    write(d, "bad_frame_crc", well_formed(1, 1, payload, 2, 4))
    write(d, "missing_chunk", well_formed(1, 1, payload, 3, 5, 1) + bytes([3]) + well_formed(1, 1, payload, 3, 0))
    write(d, "swapped_chunks", well_formed(0, 1, payload, 3, 7))
    write(d, "bad_encoding", well_formed(0, 3, payload[:50], 1, 0))
    # op 0: raw header (index, encoding, [flag] u16 total, [flag] num_chunks byte, crc); op 1: raw chunk
    header = bytes([0, 0, 1, 0]) + put("H", False, 5) + bytes([0, 1]) + put("I", False, 0x3610A686)
    chunk = bytes([1, 0, 0, 0, 1, 5]) + b"hello" + bytes([1])
    write(d, "raw_header_chunk", header + chunk)
    huge = bytes([0, 1, 1, 1]) + put("Q", False, 1 << 50) + bytes([1]) + put("I", False, 0x7FFFFFFF) + put("I", False, 0)
    write(d, "raw_huge_header", huge)
    write(d, "oversized_chunk", header + bytes([4, 0, 0]))


def upload_ops():
    d = reset("upload_assembler")

    def limit(v):  # kind 2: u32 % 16 MiB
        return bytes([2]) + put("I", False, v)

    def well_formed(payload, chunks, announce, crc, corruption, victim=0):
        b = bytes([3]) + put("H", False, len(payload)) + payload
        return b + bytes([chunks - 1, int(announce), int(crc), corruption, victim])
    payload = bytes(range(256)) * 4
    write(d, "one_upload", limit(1 << 20) + well_formed(payload, 3, True, True, 0) + bytes([2]))
    write(d, "no_crc_no_total", limit(1 << 20) + well_formed(payload, 2, False, False, 0) + bytes([2]))
    write(d, "over_limit", limit(100) + well_formed(payload, 2, True, True, 0))
    write(d, "short_total", limit(1 << 20) + well_formed(payload, 2, True, True, 3))
    write(d, "bad_crc", limit(1 << 20) + well_formed(payload, 4, False, True, 4, 1))
    write(d, "extra_byte", limit(1 << 20) + well_formed(payload, 2, True, True, 5, 1))
    # op 0: raw chunk [flag name] [flag total [flag u64]] data(u8 len) crc-kind; then finish twice, take
    raw = bytes([0, 1, 0]) + b"name.bin" + bytes([1, 1]) + put("Q", False, 1 << 40) + bytes([3]) + b"abc" + bytes([1])
    write(d, "huge_total", limit(1 << 20) + raw + bytes([1, 1, 2]))
    raw2 = bytes([0, 0, 0, 4]) + b"data" + bytes([2]) + put("I", False, 1234)
    write(d, "raw_bad_crc", bytes([1]) + put("H", False, 4096) + raw2 + bytes([0, 0, 0, 2]) + b"ok" + bytes([0, 1, 2]))


# --- http_request_head ---------------------------------------------------------------------------------------------

def http_heads():
    """What the metrics endpoint reads from a connection: scrapes and probes, and a few malformed heads."""
    d = reset("http_request_head")
    write(d, "get_metrics", "GET /metrics HTTP/1.1\r\nHost: localhost:9090\r\nUser-Agent: Prometheus/2.45\r\n"
                            "Accept: text/plain;version=0.0.4\r\n\r\n")
    write(d, "head_healthz_lf", "HEAD /healthz?probe=1 HTTP/1.0\n\n")
    write(d, "http2", "GET /metrics HTTP/2.0\r\n\r\n")
    write(d, "bad_header", "GET /metrics HTTP/1.1\r\nno colon\r\n\r\n")
    write(d, "post_body", "POST /metrics HTTP/1.1\r\nContent-Length: 3\r\n\r\nabc")
    write(d, "partial", "GET /met")


if __name__ == "__main__":
    scenes()
    particles()
    meshes()
    frame_ops()
    upload_ops()
    http_heads()
    for t in sorted(CORPUS.iterdir()):
        files = list(t.iterdir())
        print("%-18s %3d files, %6d bytes" % (t.name, len(files), sum(f.stat().st_size for f in files)))
