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


@pytest.mark.parametrize("scene,encoding,normals", [("torus", "draco", True), ("csg_block", "raw", False),
                                                    ("gyroid_in_sphere", "meshopt", True)])
def test_vtk_reads_our_plain_gltf(scene, encoding, normals, tmp_path):
    """--format gltf is for readers without Draco (Debian's Blender, VTK): VTK's own glTF reader gets the frame."""
    from vtkmodules.vtkIOGeometry import vtkGLTFReader
    out = tmp_path / "out"
    subprocess.run([cli(), "run", "isosurface", "--scene", str(SCENES / (scene + ".json")), "--cells", "24",
                    "--encoding", encoding, "-o", str(out), "--format", "ply,gltf"] + (["--normals"] if normals else []),
                   check=True, capture_output=True, timeout=120)
    reference = surfacer.read_mesh(out / "frame_0000.ply")
    reader = vtkGLTFReader()
    reader.SetFileName(str(out / "frame_0000.gltf"))
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
    again = surfacer.read_mesh(out / "frame_0000.gltf")
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
