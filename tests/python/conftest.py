"""Fixtures of the Python package's tests: an in-process client, a real surfacer-server on a loopback port, analytic
inputs, and mesh checks (closed: every edge shared by exactly two triangles). CTest sets PYTHONPATH to build/python
and SURFACER_SERVER_BINARY to the built server (tests/CMakeLists.txt)."""

import os
import pathlib
import subprocess
import tempfile
import time

import numpy as np
import pytest

import surfacer

SOURCE_DIR = pathlib.Path(__file__).resolve().parents[2]
SCENES = SOURCE_DIR / "examples" / "scenes"


def sphere_scene(radius=1.0, center=(0.0, 0.0, 0.0)):
    """A sphere as a scene dict (protobuf's JSON mapping of surfacer.v1.Scene)."""
    x, y, z = center
    return {"name": "ball", "root": {"sphere": {"center": {"x": x, "y": y, "z": z}, "radius": radius}}}


def lattice_ball(radius=0.3, spacing=0.05):
    """Particles on a cubic lattice inside a ball: an (N,3) float64 array."""
    axis = np.arange(-radius, radius + 1e-9, spacing)
    points = np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), axis=-1).reshape(-1, 3)
    return points[np.linalg.norm(points, axis=1) <= radius]


def assert_closed(frame):
    """Every edge is shared by exactly two triangles, indices are in range, no triangle repeats a vertex."""
    t = frame.triangles
    assert frame.vertices.dtype == np.float64 and frame.vertices.shape[1] == 3
    assert t.dtype == np.int32 and t.shape[1] == 3 and len(t) > 0
    assert t.min() >= 0 and t.max() < len(frame.vertices)
    assert np.all((t[:, 0] != t[:, 1]) & (t[:, 1] != t[:, 2]) & (t[:, 0] != t[:, 2]))
    edges = np.sort(np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]]), axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    assert np.all(counts == 2), "edges not shared by exactly two triangles: %d" % np.count_nonzero(counts != 2)


@pytest.fixture(scope="session")
def local_client():
    with surfacer.Client(workers=2) as client:
        yield client


@pytest.fixture(scope="session")
def server_address():
    """A surfacer-server of this build on 127.0.0.1, port 0 + --port-file."""
    binary = os.environ.get("SURFACER_SERVER_BINARY")
    if not binary:
        pytest.skip("SURFACER_SERVER_BINARY is not set (CTest sets it)")
    with tempfile.TemporaryDirectory() as tmp:
        port_file = pathlib.Path(tmp) / "port"
        log = open(pathlib.Path(tmp) / "server.log", "wb")
        process = subprocess.Popen([binary, "--listen", "127.0.0.1:0", "--port-file", str(port_file),
                                    "--workers", "2", "--memory-only"], stdout=log, stderr=subprocess.STDOUT)
        try:
            deadline = time.monotonic() + 30
            while not (port_file.exists() and port_file.read_text().strip()):
                assert process.poll() is None, "surfacer-server exited: " + (pathlib.Path(tmp) / "server.log").read_text()
                assert time.monotonic() < deadline, "surfacer-server did not write its port within 30 s"
                time.sleep(0.05)
            yield "127.0.0.1:" + port_file.read_text().strip()
        finally:
            process.terminate()
            try:
                process.wait(timeout=30)
            except subprocess.TimeoutExpired:
                process.kill()
            log.close()


@pytest.fixture(scope="session")
def remote_client(server_address):
    with surfacer.Client(server_address) as client:
        yield client
