"""Our mesh files read back by the real third-party readers a user opens them with: VTK 9 (ParaView's library),
meshio (the Blender sequence loaders' library) and pyopenvdb (OpenVDB's own), all from Debian (python3-vtk9,
python3-meshio, python3-openvdb, installed by scripts/setup.sh). Frames are written by the `surfacer` CLI (CTest sets SURFACER_CLI_BINARY)."""

import os
import subprocess

import meshio
import numpy as np
import pytest
from vtkmodules.util.numpy_support import vtk_to_numpy
from vtkmodules.vtkIOLegacy import vtkUnstructuredGridReader
from vtkmodules.vtkIOXML import vtkXMLUnstructuredGridReader

import surfacer

from conftest import SCENES


def cli():
    binary = os.environ.get("SURFACER_CLI_BINARY")
    if not binary:
        pytest.skip("SURFACER_CLI_BINARY is not set (CTest sets it)")
    return binary


def vtk_read(path):
    reader = vtkXMLUnstructuredGridReader() if path.suffix == ".vtu" else vtkUnstructuredGridReader()
    reader.SetFileName(str(path))
    reader.Update()
    return reader.GetOutput()


@pytest.mark.parametrize("scene,encoding", [("torus", "draco"), ("csg_block", "raw"), ("gyroid_in_sphere", "meshopt")])
def test_vtk_and_meshio_read_our_vtk_and_vtu_with_normals(scene, encoding, tmp_path):
    out = tmp_path / "out"
    subprocess.run([cli(), "run", "isosurface", "--scene", str(SCENES / (scene + ".json")), "--cells", "24",
                    "--normals", "--encoding", encoding, "-o", str(out), "--format", "ply,vtk,vtu"],
                   check=True, capture_output=True, timeout=120)
    reference = surfacer.read_mesh(out / "frame_0000.ply")
    assert reference.normals is not None and len(reference.triangles) > 100
    for suffix in (".vtk", ".vtu"):
        path = out / ("frame_0000" + suffix)
        grid = vtk_read(path)
        assert grid.GetNumberOfPoints() == len(reference.vertices), path
        assert grid.GetNumberOfCells() == len(reference.triangles), path
        points = vtk_to_numpy(grid.GetPoints().GetData()).astype(np.float64)
        np.testing.assert_allclose(points, reference.vertices, atol=1e-6, err_msg=str(path))
        normals = vtk_to_numpy(grid.GetPointData().GetArray("Normals"))
        np.testing.assert_allclose(normals, reference.normals, atol=1e-6, err_msg=str(path))

        mesh = meshio.read(str(path))
        np.testing.assert_allclose(mesh.points, reference.vertices, atol=1e-6, err_msg=str(path))
        assert mesh.cells[0].type == "triangle"
        np.testing.assert_array_equal(mesh.cells[0].data, reference.triangles)
        np.testing.assert_allclose(mesh.point_data["Normals"], reference.normals, atol=1e-6, err_msg=str(path))


@pytest.mark.parametrize("cells", [12, 32])
def test_frame_write_vtk_and_vtu_are_read_by_vtk_and_meshio_exactly(local_client, cells, tmp_path):
    frame = next(iter(local_client.isosurface(str(SCENES / "torus.json"), cells=cells, encoding="raw",
                                              normals=True)))
    attributes = {"height": frame.vertices[:, 2].astype(np.float32)}
    mesh = surfacer.Mesh(frame.vertices, frame.triangles, frame.normals, attributes)
    for suffix in (".vtk", ".vtu"):
        path = tmp_path / ("mesh" + suffix)
        mesh.write(path)
        grid = vtk_read(path)
        assert grid.GetNumberOfCells() == len(frame.triangles), path
        points = vtk_to_numpy(grid.GetPoints().GetData())
        assert points.dtype == np.float64, path  # double precision, as the frame's raw positions
        np.testing.assert_array_equal(points, frame.vertices, err_msg=str(path))
        read = meshio.read(str(path))
        np.testing.assert_array_equal(read.cells[0].data, frame.triangles)
        np.testing.assert_allclose(read.point_data["Normals"], frame.normals, atol=1e-6, err_msg=str(path))
        np.testing.assert_array_equal(read.point_data["height"].reshape(-1), attributes["height"])


@pytest.mark.parametrize("scene,encoding,normals,suffix", [
    ("torus", "draco", True, "gltf"), ("csg_block", "raw", False, "gltf"), ("gyroid_in_sphere", "meshopt", True, "gltf"),
    ("torus", "raw", True, "glb"), ("csg_block", "raw", False, "glb")])
def test_vtk_reads_our_plain_gltf(scene, encoding, normals, suffix, tmp_path):
    """--format gltf, and --format glb of raw frames, are for readers without Draco (Debian's Blender, VTK): VTK's own
    glTF reader gets the frame."""
    from vtkmodules.vtkIOGeometry import vtkGLTFReader
    out = tmp_path / "out"
    subprocess.run([cli(), "run", "isosurface", "--scene", str(SCENES / (scene + ".json")), "--cells", "24",
                    "--encoding", encoding, "-o", str(out), "--format", "ply," + suffix] +
                   (["--normals"] if normals else []), check=True, capture_output=True, timeout=120)
    reference = surfacer.read_mesh(out / "frame_0000.ply")
    path = out / ("frame_0000." + suffix)
    assert b"extensionsUsed" not in path.read_bytes()[:4096]  # no compression extension a reader could lack
    reader = vtkGLTFReader()
    reader.SetFileName(str(path))
    reader.Update()
    blocks = reader.GetOutput()
    iterator = blocks.NewIterator()
    iterator.InitTraversal()
    meshes = []
    while not iterator.IsDoneWithTraversal():
        meshes.append(iterator.GetCurrentDataObject())
        iterator.GoToNextItem()
    assert len(meshes) == 1
    mesh = meshes[0]
    assert mesh.GetNumberOfPoints() == len(reference.vertices)
    assert mesh.GetNumberOfCells() == len(reference.triangles)
    points = vtk_to_numpy(mesh.GetPoints().GetData()).astype(np.float64)
    np.testing.assert_allclose(points, reference.vertices, atol=1e-6)
    polys = vtk_to_numpy(mesh.GetPolys().GetConnectivityArray()).reshape(-1, 3)
    np.testing.assert_array_equal(polys, reference.triangles)
    if normals:
        np.testing.assert_allclose(vtk_to_numpy(mesh.GetPointData().GetNormals()), reference.normals, atol=1e-6)
    else:
        assert mesh.GetPointData().GetNormals() is None
    # And our own reader (Python's read_mesh, the CLI's --start-mesh) takes it back.
    again = surfacer.read_mesh(path)
    assert len(again.triangles) == len(reference.triangles)


@pytest.mark.parametrize("voxel", [None, 0.05, 0.11])
def test_pyopenvdb_reads_our_vdb_as_the_level_set_of_the_frame(voxel, tmp_path):
    """--format vdb: OpenVDB's own reader gets a level set named "surface" whose values are the signed distance to
    the frame's sphere (negative inside) within the narrow band, at the voxel size asked for (else the mean edge)."""
    import pyopenvdb
    out = tmp_path / "out"
    center, radius = np.array([0.2, -0.1, 0.05]), 0.8
    scene = tmp_path / "ball.json"
    scene.write_text('{"root": {"sphere": {"center": {"x": 0.2, "y": -0.1, "z": 0.05}, "radius": 0.8}}}')
    subprocess.run([cli(), "run", "isosurface", "--scene", str(scene), "--cells", "40", "-o", str(out),
                    "--format", "ply,vdb"] + (["--vdb-voxel-size", str(voxel)] if voxel else []),
                   check=True, capture_output=True, timeout=120)
    mesh = surfacer.read_mesh(out / "frame_0000.ply")
    edges = np.concatenate([mesh.vertices[mesh.triangles[:, k]] - mesh.vertices[mesh.triangles[:, (k + 1) % 3]]
                            for k in range(3)])
    expected_voxel = voxel or float(np.mean(np.linalg.norm(edges, axis=1)))
    grid = pyopenvdb.read(str(out / "frame_0000.vdb"), "surface")
    assert grid.gridClass == pyopenvdb.GridClass.LEVEL_SET
    np.testing.assert_allclose(grid.transform.voxelSize(), [expected_voxel] * 3, rtol=1e-6)
    band = grid.background
    np.testing.assert_allclose(band, 3 * expected_voxel, rtol=1e-5)
    accessor = grid.getConstAccessor()
    rng = np.random.default_rng(3)
    directions = rng.normal(size=(200, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    for offset in (-2.0, -0.5, 0.0, 0.5, 2.0):  # in voxels from the surface, inside the band
        for d in directions:
            point = center + d * (radius + offset * expected_voxel)
            ijk = grid.transform.worldToIndexCellCentered(tuple(point))
            centre = np.array(grid.transform.indexToWorld(ijk))
            distance = np.linalg.norm(centre - center) - radius
            assert abs(accessor.getValue(ijk) - distance) < 0.5 * expected_voxel + 0.01 * radius, (point, offset)
    assert accessor.getValue(grid.transform.worldToIndexCellCentered(tuple(center))) == -band
    assert accessor.getValue(grid.transform.worldToIndexCellCentered((5.0, 5.0, 5.0))) == band
    # Python writes the same file.
    frame_path = tmp_path / "again.vdb"
    mesh.write(frame_path, vdb_voxel_size=voxel)
    again = pyopenvdb.read(str(frame_path), "surface")
    assert again.activeVoxelCount() == grid.activeVoxelCount()


def test_a_vdb_voxel_too_small_for_the_surface_is_refused_before_any_voxel(tmp_path):
    result = subprocess.run([cli(), "run", "isosurface", "--scene", str(SCENES / "sphere.json"), "--cells", "16",
                             "-o", str(tmp_path / "out"), "--format", "vdb", "--vdb-voxel-size", "1e-5"],
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 2, result.stderr
    assert "--vdb-voxel-size 1e-05: the surface's band would hold about" in result.stderr
    assert "use a voxel size of at least" in result.stderr


def test_pvd_gives_paraview_the_input_frame_numbers_as_times(tmp_path):
    """The .pvd is a VTK XML Collection (ParaView's reader; Debian's VTK 9.1 has no Python binding of it, so the XML
    is read here and each data set it names is read by VTK's own reader)."""
    import json
    import xml.etree.ElementTree as ElementTree
    for i in (100, 101, 102):  # times are the input numbers, not the frame indices 0, 1, 2
        (tmp_path / ("drop_%d.xyz" % i)).write_text("0 0 0\n0.1 0 0\n0 0.1 0\n0.1 0.1 %g\n" % (0.01 * i))
    out = tmp_path / "seq"
    subprocess.run([cli(), "run", "particles", "--input", str(tmp_path / "drop_{}.xyz"), "--r-inner", "0.05",
                    "-o", str(out / "surface_{:04d}.vtu")], check=True, capture_output=True, timeout=120)
    root = ElementTree.parse(out / "surface.pvd").getroot()
    assert root.tag == "VTKFile" and root.get("type") == "Collection"
    datasets = root.find("Collection").findall("DataSet")
    assert [(float(d.get("timestep")), d.get("file")) for d in datasets] == [
        (100.0, "surface_0100.vtu"), (101.0, "surface_0101.vtu"), (102.0, "surface_0102.vtu")]
    for d in datasets:
        assert vtk_read(out / d.get("file")).GetNumberOfCells() > 0
    # The legacy files' series (ParaView's file-series JSON): the same times.
    subprocess.run([cli(), "run", "particles", "--input", str(tmp_path / "drop_{}.xyz"), "--r-inner", "0.05",
                    "-o", str(tmp_path / "legacy"), "--format", "vtk"], check=True, capture_output=True, timeout=120)
    series = json.loads((tmp_path / "legacy" / "frames.vtk.series").read_text())
    assert [(f["name"], f["time"]) for f in series["files"]] == [
        ("frame_0100.vtk", 100), ("frame_0101.vtk", 101), ("frame_0102.vtk", 102)]
    assert all((tmp_path / "legacy" / f["name"]).exists() for f in series["files"])


def signed_volume(mesh):
    v = mesh.vertices[mesh.triangles]
    return float(np.einsum("ij,ij->i", v[:, 0], np.cross(v[:, 1], v[:, 2])).sum() / 6.0)


@pytest.mark.parametrize("voxel", [0.02, 0.05, 0.1])
def test_read_mesh_takes_a_vdb_written_by_pyopenvdb_back_as_its_zero_level_set(voxel, tmp_path):
    """A level set another program wrote (OpenVDB's own createLevelSetSphere): read_mesh gives its zero level set,
    closed, outward-facing, every vertex within a voxel of the sphere."""
    import pyopenvdb
    from conftest import assert_closed
    center, radius = np.array([0.3, -0.2, 0.1]), 0.7
    grid = pyopenvdb.createLevelSetSphere(radius=radius, center=tuple(center), voxelSize=voxel)
    grid.name = "ball"
    path = tmp_path / "ball.vdb"
    pyopenvdb.write(str(path), grids=[grid])
    mesh = surfacer.read_mesh(path)
    assert_closed(mesh)
    distance = np.abs(np.linalg.norm(mesh.vertices - center, axis=1) - radius)
    assert distance.max() <= voxel, distance.max()
    np.testing.assert_allclose(signed_volume(mesh), 4 / 3 * np.pi * radius ** 3, rtol=3 * voxel / radius)


@pytest.mark.parametrize("cells,voxel", [(24, None), (48, 0.03)])
def test_frame_write_vdb_reads_back_as_the_frame(local_client, cells, voxel, tmp_path):
    frame = next(iter(local_client.isosurface(str(SCENES / "torus.json"), cells=cells, encoding="raw")))
    path = tmp_path / "torus.vdb"
    frame.write(path, vdb_voxel_size=voxel)
    mesh = surfacer.read_mesh(path)
    from conftest import assert_closed
    assert_closed(mesh)
    edges = np.linalg.norm(frame.vertices[frame.triangles[:, 0]] - frame.vertices[frame.triangles[:, 1]], axis=1)
    h = voxel or float(edges.mean())
    # Distance to the torus (major 1, minor 0.35 about z): every vertex within a voxel of the surface.
    ring = np.hypot(np.hypot(mesh.vertices[:, 0], mesh.vertices[:, 1]) - 1.0, mesh.vertices[:, 2])
    assert np.abs(ring - 0.35).max() <= h + 0.02
    np.testing.assert_allclose(signed_volume(mesh), frame.stats["check"]["volume"], rtol=0.08)
    with pytest.raises(surfacer.UsageError, match="OpenVDB"):
        (tmp_path / "not.vdb").write_bytes(b"not a vdb file")
        surfacer.read_mesh(tmp_path / "not.vdb")


def vtk_sphere(strips=False, resolution=(24, 16)):
    """A closed triangulated sphere (VTK's own source) with point normals; optionally as triangle strips."""
    from vtkmodules.vtkFiltersCore import vtkStripper
    from vtkmodules.vtkFiltersSources import vtkSphereSource
    source = vtkSphereSource()
    source.SetThetaResolution(resolution[0])
    source.SetPhiResolution(resolution[1])
    source.SetRadius(0.7)
    source.SetCenter(0.2, -0.1, 0.3)
    source.Update()
    if not strips:
        return source.GetOutput()
    stripper = vtkStripper()
    stripper.SetInputData(source.GetOutput())
    stripper.Update()
    return stripper.GetOutput()


def write_vtk_file(data, path, mode):
    """Writes `data` (vtkPolyData) with VTK's own writers: legacy (.vtk, ascii or binary, file version 4.2 or 5.1) or
    XML (.vtp PolyData / .vtu UnstructuredGrid; ascii, binary, appended raw or base64, with a compressor)."""
    from vtkmodules.vtkFiltersCore import vtkAppendFilter
    from vtkmodules.vtkIOLegacy import vtkPolyDataWriter, vtkUnstructuredGridWriter
    from vtkmodules.vtkIOXML import vtkXMLPolyDataWriter, vtkXMLUnstructuredGridWriter
    if path.suffix in (".vtu",) or (path.suffix == ".vtk" and "grid" in mode):
        append = vtkAppendFilter()
        append.SetInputData(data)
        append.Update()
        data = append.GetOutput()
    if path.suffix == ".vtk":
        writer = vtkUnstructuredGridWriter() if "grid" in mode else vtkPolyDataWriter()
        writer.SetFileTypeToBinary() if "binary" in mode else writer.SetFileTypeToASCII()
        if "4.2" in mode:
            writer.SetFileVersion(42)
    else:
        writer = vtkXMLUnstructuredGridWriter() if path.suffix == ".vtu" else vtkXMLPolyDataWriter()
        if "ascii" in mode:
            writer.SetDataModeToAscii()
        elif "binary" in mode:
            writer.SetDataModeToBinary()
        else:
            writer.SetDataModeToAppended()
            writer.SetEncodeAppendedData("base64" in mode)
        compressors = {"zlib": writer.SetCompressorTypeToZLib, "lz4": writer.SetCompressorTypeToLZ4,
                       "lzma": writer.SetCompressorTypeToLZMA}
        compressor = next((c for c in compressors if c in mode), None)
        compressors[compressor]() if compressor else writer.SetCompressorTypeToNone()
    writer.SetInputData(data)
    writer.SetFileName(str(path))
    assert writer.Write() == 1


@pytest.mark.parametrize("suffix,mode", [
    (".vtk", "ascii"), (".vtk", "binary"), (".vtk", "ascii 4.2"), (".vtk", "binary 4.2"), (".vtk", "binary grid"),
    (".vtk", "ascii grid 4.2"), (".vtp", "ascii"), (".vtp", "binary zlib"), (".vtp", "appended raw"),
    (".vtp", "appended base64 zlib"), (".vtp", "appended raw lz4"), (".vtu", "appended base64 lzma"),
    (".vtu", "binary"), (".vtu", "ascii")])
def test_read_mesh_takes_the_surfaces_vtk_writes_in_every_mode(suffix, mode, tmp_path):
    # 65 k triangles: compressed arrays span many of VTK's 32 KiB blocks.
    sphere = vtk_sphere(resolution=(256, 128))
    path = tmp_path / ("sphere" + suffix)
    write_vtk_file(sphere, path, mode)
    mesh = surfacer.read_mesh(path)
    points = vtk_to_numpy(sphere.GetPoints().GetData()).astype(np.float64)
    triangles = vtk_to_numpy(sphere.GetPolys().GetConnectivityArray()).reshape(-1, 3)
    if "ascii" in mode:  # VTK writes ASCII values with 6 to 9 significant digits
        np.testing.assert_allclose(mesh.vertices, points, atol=1e-6)
    else:
        np.testing.assert_array_equal(mesh.vertices, points)
    np.testing.assert_array_equal(mesh.triangles, triangles)
    np.testing.assert_allclose(mesh.normals, vtk_to_numpy(sphere.GetPointData().GetNormals()), atol=1e-6)
    from conftest import assert_closed
    assert_closed(mesh)


def test_read_mesh_splits_strips_and_quads_and_reads_meshio_files(tmp_path):
    from conftest import assert_closed
    from vtkmodules.vtkFiltersSources import vtkPlaneSource
    plain = vtk_sphere()
    stripped = vtk_sphere(strips=True)
    assert stripped.GetNumberOfStrips() > 0
    for suffix in (".vtp", ".vtk"):
        write_vtk_file(stripped, tmp_path / ("strips" + suffix), "binary")
        mesh = surfacer.read_mesh(tmp_path / ("strips" + suffix))
        assert_closed(mesh)  # every strip triangle keeps the surface's side: closed and one orientation
        assert len(mesh.triangles) == plain.GetNumberOfPolys()
        np.testing.assert_allclose(signed_volume(mesh), signed_volume(surfacer.Mesh(
            vtk_to_numpy(plain.GetPoints().GetData()).astype(np.float64),
            vtk_to_numpy(plain.GetPolys().GetConnectivityArray()).reshape(-1, 3), None)), rtol=1e-9)
    plane = vtkPlaneSource()
    plane.SetResolution(5, 4)
    plane.Update()
    write_vtk_file(plane.GetOutput(), tmp_path / "quads.vtp", "appended raw")
    quads = surfacer.read_mesh(tmp_path / "quads.vtp")
    assert len(quads.triangles) == 2 * 5 * 4
    area = 0.5 * np.linalg.norm(np.cross(quads.vertices[quads.triangles[:, 1]] - quads.vertices[quads.triangles[:, 0]],
                                         quads.vertices[quads.triangles[:, 2]] - quads.vertices[quads.triangles[:, 0]]),
                                axis=1)
    np.testing.assert_allclose(area.sum(), 1.0, rtol=1e-6)  # the unit plane, every quad covered once
    triangles = vtk_to_numpy(plain.GetPolys().GetConnectivityArray()).reshape(-1, 3)
    points = vtk_to_numpy(plain.GetPoints().GetData()).astype(np.float64)
    meshio.write(str(tmp_path / "meshio.vtu"), meshio.Mesh(points, [("triangle", triangles)],
                                                           point_data={"height": points[:, 2]}))
    read = surfacer.read_mesh(tmp_path / "meshio.vtu")
    np.testing.assert_array_equal(read.triangles, triangles)
    np.testing.assert_array_equal(read.vertices, points)
    np.testing.assert_allclose(read.attributes["height"], points[:, 2].astype(np.float32))
    # A file without surface cells (particles) is not a mesh: the message says so.
    meshio.write(str(tmp_path / "points.vtu"), meshio.Mesh(points, [("vertex", np.arange(len(points))[:, None])]))
    with pytest.raises(surfacer.UsageError, match="no triangle"):
        surfacer.read_mesh(tmp_path / "points.vtu")
