#!/usr/bin/python3
"""Writes one point set with VTK's own XML writers in every data mode, and with meshio, for the reader test.

Usage: vtk_writer_files.py OUT_DIR [N]. Writes OUT_DIR/positions.f32 (the N x 3 float32 positions, little-endian)
and one .vtu/.vtp per writer setting, named after it (ug_appended_b64_zlib_u32.vtu, pd_binary_lz4_u64.vtp, ...).
Needs python3-vtk9 and python3-meshio (Debian), run with /usr/bin/python3.
"""
import os
import sys

import numpy as np
import vtk
from vtk.util.numpy_support import numpy_to_vtk


def point_set(n):
    rng = np.random.default_rng(28)
    return rng.random((n, 3), dtype=np.float32)


def grid_and_poly(positions):
    points = vtk.vtkPoints()
    points.SetData(numpy_to_vtk(positions, deep=True))
    grid = vtk.vtkUnstructuredGrid()
    grid.SetPoints(points)
    cells = vtk.vtkCellArray()
    for i in range(len(positions)):
        cells.InsertNextCell(1)
        cells.InsertCellPoint(i)
    grid.SetCells(vtk.VTK_VERTEX, cells)
    poly = vtk.vtkPolyData()
    poly.SetPoints(points)
    poly.SetVerts(cells)
    radius = numpy_to_vtk(np.full(len(positions), 0.01, dtype=np.float32), deep=True)
    radius.SetName("radius")
    grid.GetPointData().AddArray(radius)
    poly.GetPointData().AddArray(radius)
    return grid, poly


def main():
    out = sys.argv[1]
    n = int(sys.argv[2]) if len(sys.argv) > 2 else 115000
    os.makedirs(out, exist_ok=True)
    positions = point_set(n)
    positions.astype("<f4").tofile(os.path.join(out, "positions.f32"))
    grid, poly = grid_and_poly(positions)
    compressors = {"none": None, "zlib": vtk.vtkZLibDataCompressor, "lz4": vtk.vtkLZ4DataCompressor,
                   "lzma": vtk.vtkLZMADataCompressor}
    modes = [("appended_b64", "Appended", True), ("appended_raw", "Appended", False), ("binary", "Binary", True),
             ("ascii", "Ascii", True)]
    for prefix, data, writer_class, ext in (("ug", grid, vtk.vtkXMLUnstructuredGridWriter, "vtu"),
                                            ("pd", poly, vtk.vtkXMLPolyDataWriter, "vtp")):
        for mode, data_mode, encode in modes:
            for cname, compressor in compressors.items():
                if mode == "ascii" and cname != "none":
                    continue  # ASCII arrays are never compressed
                for header in ("u32", "u64"):
                    w = writer_class()
                    w.SetInputData(data)
                    getattr(w, "SetDataModeTo" + data_mode)()
                    w.SetEncodeAppendedData(encode)
                    if compressor is None:
                        w.SetCompressorTypeToNone()
                    else:
                        w.SetCompressor(compressor())
                    getattr(w, "SetHeaderTypeTo" + ("UInt32" if header == "u32" else "UInt64"))()
                    w.SetFileName(os.path.join(out, f"{prefix}_{mode}_{cname}_{header}.{ext}"))
                    if w.Write() != 1:
                        sys.exit(f"vtk writer failed on {w.GetFileName()}")
    import meshio
    meshio.write(os.path.join(out, "meshio_default.vtu"),
                 meshio.Mesh(positions, [("vertex", np.arange(n).reshape(-1, 1))]))
    meshio.write(os.path.join(out, "meshio_binary_nocompress.vtu"),
                 meshio.Mesh(positions, [("vertex", np.arange(n).reshape(-1, 1))]), compression=None)
    meshio.write(os.path.join(out, "meshio_ascii.vtu"),
                 meshio.Mesh(positions, [("vertex", np.arange(n).reshape(-1, 1))]), binary=False)


if __name__ == "__main__":
    main()
