"""Particle attributes end to end: dict frames and files made by the real VTK (python3-vtk9) and meshio carry velocity
and density through interpolate=/--interpolate onto the mesh, and our .vtu/.vtk/.ply outputs read back in VTK and
meshio with the arrays under the same names (and .drc through our Draco reader); every encoding carries them, and
.glb/.gltf hold them as _NAME attributes (VTK's glTF reader reads the plain ones).
CTest sets PYTHONPATH and SURFACER_CLI_BINARY (tests/CMakeLists.txt)."""

import os
import subprocess

import meshio
import numpy as np
import pytest
from vtkmodules.util.numpy_support import numpy_to_vtk, vtk_to_numpy
from vtkmodules.vtkCommonCore import vtkPoints
from vtkmodules.vtkCommonDataModel import vtkUnstructuredGrid, VTK_VERTEX
from vtkmodules.vtkIOLegacy import vtkUnstructuredGridReader
from vtkmodules.vtkIOXML import vtkXMLUnstructuredGridReader, vtkXMLUnstructuredGridWriter

import surfacer

from conftest import lattice_ball

GRADIENT = np.array([0.5, -1.0, 2.0])


def fields(points):
    """A constant density and a linear velocity (each component linear in the position)."""
    density = np.full(len(points), 998.25, dtype=np.float32)
    velocity = np.stack([points @ GRADIENT, 2.0 * points[:, 0], np.full(len(points), -0.5)], axis=1)
    return density, velocity.astype(np.float32)


def check_frame_attributes(vertices, density, velocity, r_outer):
    assert density.shape == (len(vertices),)
    assert velocity.shape == (len(vertices), 3)
    np.testing.assert_array_equal(density, np.float32(998.25))  # a constant comes back exactly
    np.testing.assert_array_equal(velocity[:, 2], np.float32(-0.5))
    # A linear field within r_outer x |grad| (plus float32 slack).
    assert np.max(np.abs(velocity[:, 0] - vertices @ GRADIENT)) <= r_outer * np.linalg.norm(GRADIENT) + 1e-4
    assert np.max(np.abs(velocity[:, 1] - 2.0 * vertices[:, 0])) <= r_outer * 2.0 + 1e-4


def test_dict_frames_interpolate_onto_frame_attributes(local_client, tmp_path):
    ball = lattice_ball()
    density, velocity = fields(ball)
    (frame,) = local_client.particles([{"positions": ball, "density": density, "velocity": velocity}], r_inner=0.04,
                                      interpolate=["density", "velocity"])
    assert sorted(frame.attributes) == ["density", "velocity"]
    check_frame_attributes(frame.vertices, frame.attributes["density"], frame.attributes["velocity"], 0.08)
    frame.write(tmp_path / "mesh.ply")
    back = surfacer.read_mesh(tmp_path / "mesh.ply")
    np.testing.assert_array_equal(back.attributes["velocity"], frame.attributes["velocity"])
    np.testing.assert_array_equal(back.attributes["density"], frame.attributes["density"])


@pytest.mark.parametrize("encoding", ["draco", "meshopt", "raw"])
def test_every_encoding_carries_the_attributes_and_glb_keeps_them(local_client, encoding, tmp_path):
    ball = lattice_ball()
    density, velocity = fields(ball)
    (frame,) = local_client.particles([{"positions": ball, "density": density, "velocity": velocity}], r_inner=0.04,
                                      interpolate=["density", "velocity"], encoding=encoding)
    assert list(frame.attributes) == ["density", "velocity"]
    check_frame_attributes(frame.vertices, frame.attributes["density"], frame.attributes["velocity"], 0.08)
    # .glb (Draco pieces of the frame's mesh, re-quantized on its own box) and plain .gltf (float32 positions):
    # _DENSITY and _VELOCITY, read back under their names; in the .gltf each vertex's values bit for bit.
    for suffix in (".glb", ".gltf"):
        frame.write(tmp_path / ("mesh" + suffix))
        back = surfacer.read_mesh(tmp_path / ("mesh" + suffix))
        assert list(back.attributes) == ["density", "velocity"], suffix
        check_frame_attributes(back.vertices, back.attributes["density"], back.attributes["velocity"], 0.08)
        if suffix == ".gltf":
            at = {tuple(p): i for i, p in enumerate(frame.vertices.astype(np.float32))}
            order = [at[tuple(p)] for p in back.vertices.astype(np.float32)]
            np.testing.assert_array_equal(back.attributes["velocity"], frame.attributes["velocity"][order])


def test_all_and_a_missing_attribute(local_client):
    ball = lattice_ball()
    density, _ = fields(ball)
    (frame,) = local_client.particles([{"positions": ball, "density": density}], r_inner=0.04, interpolate="all")
    assert list(frame.attributes) == ["density"]
    with pytest.raises(surfacer.UsageError, match=r'no attribute "foam".*density \(1\)'):
        local_client.particles([{"positions": ball, "density": density}], r_inner=0.04, interpolate=["foam"])


def cli():
    binary = os.environ.get("SURFACER_CLI_BINARY")
    if not binary:
        pytest.skip("SURFACER_CLI_BINARY is not set (CTest sets it)")
    return binary


def write_vtk_input(path, points, density, velocity):
    """A .vtu as VTK writes it by default (appended, base64, zlib) with point data."""
    vtk_points = vtkPoints()
    vtk_points.SetData(numpy_to_vtk(points.astype(np.float32), deep=True))
    grid = vtkUnstructuredGrid()
    grid.SetPoints(vtk_points)
    grid.Allocate(len(points))
    for i in range(len(points)):
        grid.InsertNextCell(VTK_VERTEX, 1, [i])
    for name, values in (("density", density), ("velocity", velocity)):
        array = numpy_to_vtk(values, deep=True)
        array.SetName(name)
        grid.GetPointData().AddArray(array)
    writer = vtkXMLUnstructuredGridWriter()
    writer.SetFileName(str(path))
    writer.SetInputData(grid)
    assert writer.Write() == 1


def vtk_point_arrays(path):
    reader = vtkXMLUnstructuredGridReader() if path.suffix == ".vtu" else vtkUnstructuredGridReader()
    reader.SetFileName(str(path))
    reader.Update()
    grid = reader.GetOutput()
    data = grid.GetPointData()
    points = vtk_to_numpy(grid.GetPoints().GetData()).astype(np.float64)
    return points, {data.GetArrayName(i): vtk_to_numpy(data.GetArray(i)) for i in range(data.GetNumberOfArrays())}


@pytest.mark.parametrize("writer", ["vtk", "meshio"])
def test_cli_interpolates_from_third_party_files_and_they_read_ours(writer, tmp_path):
    ball = lattice_ball()
    density, velocity = fields(ball)
    source = tmp_path / "fluid.vtu"
    if writer == "vtk":
        write_vtk_input(source, ball, density, velocity)
    else:
        meshio.write(str(source), meshio.Mesh(ball, [("vertex", np.arange(len(ball)).reshape(-1, 1))],
                                              point_data={"density": density, "velocity": velocity}))
    out = tmp_path / "out"
    subprocess.run([cli(), "run", "particles", "--input", str(source), "--r-inner", "0.04", "--interpolate",
                    "velocity,density", "-o", str(out), "--format", "ply,vtk,vtu,drc,glb,gltf"],
                   check=True, capture_output=True, timeout=120)
    reference = surfacer.read_mesh(out / "frame_0000.ply")
    check_frame_attributes(reference.vertices, reference.attributes["density"], reference.attributes["velocity"],
                           0.08)
    draco = surfacer.read_mesh(out / "frame_0000.drc")  # Draco generic attributes named in its metadata
    assert len(draco.vertices) == len(reference.vertices)
    np.testing.assert_array_equal(draco.attributes["density"], np.float32(998.25))
    assert draco.attributes["velocity"].shape == reference.attributes["velocity"].shape
    for suffix in (".glb", ".gltf"):  # _VELOCITY and _DENSITY, named back by the mesh's extras
        back = surfacer.read_mesh(out / ("frame_0000" + suffix))
        assert sorted(back.attributes) == ["density", "velocity"], suffix
        np.testing.assert_array_equal(back.attributes["density"], np.float32(998.25))
        assert back.attributes["velocity"].shape == (len(back.vertices), 3)
        np.testing.assert_array_equal(back.attributes["velocity"][:, 2], np.float32(-0.5))
    for suffix in (".vtk", ".vtu"):
        path = out / ("frame_0000" + suffix)
        points, arrays = vtk_point_arrays(path)
        np.testing.assert_allclose(points, reference.vertices, atol=1e-6, err_msg=str(path))
        for name in ("density", "velocity"):
            np.testing.assert_array_equal(arrays[name], reference.attributes[name], err_msg=str(path))
        mesh = meshio.read(str(path))
        for name in ("density", "velocity"):
            np.testing.assert_array_equal(np.asarray(mesh.point_data[name]).reshape(reference.attributes[name].shape),
                                          reference.attributes[name], err_msg=str(path))


def test_vtk_gltf_reader_reads_the_attributes_of_plain_gltf(tmp_path):
    """VTK's own glTF reader (no Draco or meshopt in VTK 9.1) takes the raw frames' plain .glb and .gltf: the
    attributes are point arrays _DENSITY and _VELOCITY holding the frame's values, vertex for vertex."""
    from vtkmodules.vtkIOGeometry import vtkGLTFReader
    ball = lattice_ball()
    density, velocity = fields(ball)
    source = tmp_path / "fluid.vtu"
    write_vtk_input(source, ball, density, velocity)
    out = tmp_path / "out"
    subprocess.run([cli(), "run", "particles", "--input", str(source), "--r-inner", "0.04", "--interpolate",
                    "velocity,density", "--encoding", "raw", "-o", str(out), "--format", "ply,glb,gltf"],
                   check=True, capture_output=True, timeout=120)
    reference = surfacer.read_mesh(out / "frame_0000.ply")
    for suffix in (".glb", ".gltf"):
        reader = vtkGLTFReader()
        reader.SetFileName(str(out / ("frame_0000" + suffix)))
        reader.Update()
        blocks = reader.GetOutput().NewIterator()
        blocks.InitTraversal()
        mesh = blocks.GetCurrentDataObject()
        data = mesh.GetPointData()
        arrays = {data.GetArrayName(i): vtk_to_numpy(data.GetArray(i)) for i in range(data.GetNumberOfArrays())}
        assert sorted(arrays) == ["_DENSITY", "_VELOCITY"], suffix
        points = vtk_to_numpy(mesh.GetPoints().GetData()).astype(np.float64)
        np.testing.assert_allclose(points, reference.vertices, atol=1e-6, err_msg=suffix)
        np.testing.assert_array_equal(arrays["_DENSITY"], reference.attributes["density"], err_msg=suffix)
        np.testing.assert_array_equal(arrays["_VELOCITY"], reference.attributes["velocity"], err_msg=suffix)


def test_cli_names_the_file_and_its_attributes_when_one_is_missing(tmp_path):
    ball = lattice_ball()
    density, velocity = fields(ball)
    source = tmp_path / "fluid.vtu"
    write_vtk_input(source, ball, density, velocity)
    run = subprocess.run([cli(), "run", "particles", "--input", str(source), "--r-inner", "0.04", "--interpolate",
                          "foam", "-o", str(tmp_path / "out"), "--format", "ply"],
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 2, run.stderr
    assert "fluid.vtu" in run.stderr and 'no attribute "foam"' in run.stderr
    assert "density (1), velocity (3)" in run.stderr
