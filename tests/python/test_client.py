"""The surfacer package end to end: jobs against the in-process server and a real loopback server, numpy in and out,
errors as exceptions with the gRPC code, cancel, and the job-management calls."""

import json
import os
import subprocess
import struct
import threading
import time

import numpy as np
import pytest

import surfacer
from conftest import SCENES, assert_closed, lattice_ball, sphere_scene


def test_isosurface_in_process_dict_and_path(local_client):
    frames = sorted(local_client.isosurface([sphere_scene(0.8), SCENES / "torus.json"], cells=24, normals=True),
                    key=lambda f: f.index)
    assert [f.index for f in frames] == [0, 1]
    for f in frames:
        assert_closed(f)
        assert f.normals is not None and f.normals.shape == f.vertices.shape
        assert np.allclose(np.linalg.norm(f.normals, axis=1), 1.0, atol=1e-2)
        assert f.stats["triangles"] == len(f.triangles)
        assert f.stats["check"]["closed"] is True
    # Within the scenes' bounds (plus a cell of padding): a ball of 0.8, a torus of radii 1 and 0.35.
    assert np.abs(frames[0].vertices).max() < 0.8 * 1.2
    radius = np.linalg.norm(frames[0].vertices, axis=1)
    assert abs(radius.mean() - 0.8) < 0.05
    assert np.abs(frames[1].vertices[:, 2]).max() < 0.35 * 1.2
    assert np.linalg.norm(frames[1].vertices[:, :2], axis=1).max() < 1.35 * 1.1


def test_isosurface_remote(remote_client):
    assert not remote_client.local
    job = remote_client.isosurface(sphere_scene(1.0), cells=20, method="cubes")
    frames = list(job)
    assert len(frames) == 1
    assert_closed(frames[0])
    assert job.state["state"] == "JOB_STATE_SUCCEEDED"
    assert any(j["id"] == job.id for j in remote_client.list())


def test_particles_from_numpy(local_client):
    ball = lattice_ball()
    frames = sorted(local_client.particles([ball, ball + [0.0, 0.0, 0.02]], r_inner=0.04), key=lambda f: f.index)
    assert [f.index for f in frames] == [0, 1]  # frames come as they finish, in any order
    for f, shift in zip(frames, (0.0, 0.02)):
        assert_closed(f)
        # Every vertex lies within r_outer (default 2 x r_inner) of the particles, so within the ball + 0.08.
        centre = np.array([0.0, 0.0, shift])
        assert np.linalg.norm(f.vertices - centre, axis=1).max() < 0.3 + 0.08 + 1e-6


def test_particles_polish_and_sliver_options(local_client):
    ball = lattice_ball()
    (faithful,) = local_client.particles([ball], r_inner=0.04)
    (thesis,) = local_client.particles([ball], r_inner=0.04, unconstrained_polish=True, min_angle=0)
    assert faithful.stats["metrics"]["faithful_fraction_final"] == 1.0
    assert thesis.stats["metrics"]["faithful_fraction_final"] < 1.0
    (band,) = local_client.particles([ball], r_inner=0.04, vertex_only_band=True)
    assert faithful.stats["metrics"]["cusp_vertices"] > 0
    assert band.stats["metrics"]["cusp_vertices"] == 0
    with pytest.raises(surfacer.UsageError) as error:  # core's range, checked before anything is submitted
        local_client.particles([ball], r_inner=0.04, min_angle=45)
    assert error.value.code == "INVALID_ARGUMENT" and "min_angle_degrees" in str(error.value)


def test_particles_remote_with_radii(remote_client):
    ball = lattice_ball()
    with_radii = np.hstack([ball, np.full((len(ball), 1), 0.04)]).astype(np.float32)
    (frame,) = remote_client.particles([with_radii], r_inner=0.04)
    assert_closed(frame)


def test_bad_option_names_the_field(local_client):
    with pytest.raises(surfacer.Error) as error:
        list(local_client.isosurface(sphere_scene(), cells=-1))
    assert error.value.code == "INVALID_ARGUMENT"
    assert "cells" in str(error.value)
    # Checked on this side with the server's own checks, before anything is submitted.
    assert isinstance(error.value, surfacer.UsageError)


def test_bad_scene_is_a_usage_error(local_client):
    with pytest.raises(surfacer.UsageError) as error:
        local_client.isosurface({"root": {"sphere": {"radius": 1, "colour": 3}}})
    assert error.value.code == "INVALID_ARGUMENT" and "colour" in str(error.value)


def test_server_kind_options_refused_with_the_other_kind():
    """workers sizes only the in-process server, allow_insecure concerns only tokens sent to a remote one."""
    with pytest.raises(surfacer.UsageError, match="workers"):
        surfacer.Client(server="localhost:1", workers=2)
    with pytest.raises(surfacer.UsageError, match="--allow-insecure"):
        surfacer.Client(allow_insecure=True)


def test_unknown_keyword_is_a_type_error(local_client):
    with pytest.raises(TypeError, match="'cels'"):
        local_client.isosurface(sphere_scene(), cels=32)
    with pytest.raises(TypeError, match="'r_iner'"):
        local_client.particles([lattice_ball()], r_iner=0.04)


def test_unknown_job_is_not_found(remote_client):
    with pytest.raises(surfacer.JobFailed) as error:
        remote_client.status("j-does-not-exist")
    assert error.value.code == "NOT_FOUND"


def test_cancel(local_client):
    # Many fine frames, so the job is still running when it is cancelled.
    job_id = local_client.submit("isosurface", [sphere_scene()] * 50, cells=200)
    job = local_client.watch(job_id)
    answer = local_client.cancel(job_id)
    assert answer["id"] == job_id
    started = time.monotonic()
    with pytest.raises(surfacer.Cancelled) as error:
        for _ in job:
            pass
    assert error.value.code == "CANCELLED"
    assert time.monotonic() - started < 10
    assert local_client.status(job_id)["state"] == "JOB_STATE_CANCELLED"


def test_keyboard_interrupt_cancels_the_job(local_client):
    job = local_client.isosurface([sphere_scene()] * 50, cells=200)
    # A KeyboardInterrupt as Ctrl-C raises it: in the main thread, while next() waits with the GIL released.
    timer = threading.Timer(0.3, lambda: __import__("_thread").interrupt_main())
    timer.start()
    with pytest.raises(KeyboardInterrupt):
        for _ in job:
            pass
    timer.join()
    deadline = time.monotonic() + 10
    while local_client.status(job.id)["state"] != "JOB_STATE_CANCELLED":
        assert time.monotonic() < deadline, local_client.status(job.id)
        time.sleep(0.05)


def test_submit_watch_status_list_health(remote_client):
    assert remote_client.health() == "SERVING"
    job_id = remote_client.submit("isosurface", [sphere_scene(0.5)], cells=16)
    frames = list(remote_client.watch(job_id))
    assert len(frames) == 1 and frames[0].index == 0
    status = remote_client.status(job_id)
    assert status["state"] == "JOB_STATE_SUCCEEDED" and status["kind"] == "isosurface"
    assert status["frames_done"] == 1
    assert job_id in [j["id"] for j in remote_client.list(["succeeded"])]
    assert job_id not in [j["id"] for j in remote_client.list(["running"])]
    # Watching again from a later frame gets nothing more.
    assert list(remote_client.watch(job_id, from_frame=1)) == []


def test_optimize_and_morph(local_client):
    snapshots = list(local_client.optimize(SCENES / "csg_block.json", start_cells=16, iterations=4,
                                           snapshot_every=2))
    assert len(snapshots) >= 2
    assert_closed(snapshots[-1])
    assert snapshots[-1].stats["iteration"] >= 2
    morph = list(local_client.active_morph(sphere_scene(0.5), sphere_scene(0.5, (0.2, 0.0, 0.0)),
                                           grid_spacing=0.1, max_frames=3))
    assert 1 <= len(morph) <= 3
    assert_closed(morph[-1])


def test_frame_write(local_client, tmp_path):
    (frame,) = local_client.isosurface(sphere_scene(), cells=12)
    frame.write(tmp_path / "ball.ply")
    frame.write(tmp_path / "ball.obj")
    assert (tmp_path / "ball.ply").read_bytes().startswith(b"ply\n")
    assert sum(1 for line in open(tmp_path / "ball.obj") if line.startswith("f ")) == len(frame.triangles)
    # glTF: header, JSON chunk, and index accessors for every triangle (the C++ end-to-end test decodes the pieces).
    frame.write(tmp_path / "ball.glb")
    data = (tmp_path / "ball.glb").read_bytes()
    magic, version, length, json_length, json_type = struct.unpack_from("<4sIIII", data)
    assert (magic, version, length, json_type) == (b"glTF", 2, len(data), 0x4E4F534A)
    gltf = json.loads(data[20:20 + json_length])
    assert gltf["extensionsRequired"] == ["KHR_draco_mesh_compression", "KHR_mesh_quantization"]
    primitives = gltf["meshes"][0]["primitives"]
    assert sum(gltf["accessors"][p["indices"]]["count"] for p in primitives) == 3 * len(frame.triangles)


def test_read_mesh_gives_back_what_frame_write_wrote(local_client, tmp_path):
    (frame,) = local_client.isosurface(sphere_scene(), cells=24, normals=True)
    for name in ("ball.ply", "ball.glb", "ball.drc", "ball.obj"):
        frame.write(tmp_path / name)
        mesh = surfacer.read_mesh(tmp_path / name)
        assert mesh.triangles.shape == frame.triangles.shape, name
        assert mesh.triangles.dtype == np.int32 and mesh.vertices.dtype == np.float64
        # The same surface: every vertex within a quantization step of the frame's bounds, and (but for Draco's one
        # mesh, which may split or merge points) as many vertices, the .glb's pieces welded back.
        assert np.allclose(mesh.vertices.min(axis=0), frame.vertices.min(axis=0), atol=1e-3), name
        assert np.allclose(mesh.vertices.max(axis=0), frame.vertices.max(axis=0), atol=1e-3), name
        if name != "ball.drc":
            assert len(mesh.vertices) == len(frame.vertices), name
        if name in ("ball.ply", "ball.glb"):  # unit normals, as the frame's (Draco quantizes them a little)
            assert mesh.normals is not None and mesh.normals.shape == mesh.vertices.shape, name
            assert np.allclose(np.linalg.norm(mesh.normals, axis=1), 1.0, atol=1e-3), name
    again = tmp_path / "again.ply"
    surfacer.read_mesh(tmp_path / "ball.glb").write(again)
    assert len(surfacer.read_mesh(again).triangles) == len(frame.triangles)
    (tmp_path / "broken.glb").write_bytes(b"glTF\x02\x00\x00\x00")
    with pytest.raises(surfacer.UsageError, match="broken.glb"):
        surfacer.read_mesh(tmp_path / "broken.glb")


def _triangles_by_position(frame):
    """The mesh whatever order its vertices and triangles come in: its distinct positions in lexicographic order, and
    every triangle as indices into them, starting at its smallest (orientation kept), the triangles sorted."""
    positions, ids = np.unique(frame.vertices, axis=0, return_inverse=True)
    tris = ids.reshape(-1)[frame.triangles]
    first = np.argmin(tris, axis=1)
    rolled = np.concatenate([np.roll(tris[first == k], -k, axis=1) for k in range(3)])
    return positions, rolled[np.lexsort(rolled.T[::-1])]


def test_draco_frames_come_in_pieces_with_the_mesh_of_one_draco_mesh(local_client, tmp_path):
    """The package keeps frames in memory and writes no .drc from the stream, so it asks for Draco frames in pieces
    (as the CLI does when it writes no .drc), encoded on every core of the server and decoded on every core here: the
    same vertices and triangles as the one Draco mesh the CLI writes to a .drc, in another order."""
    binary = os.environ.get("SURFACER_CLI_BINARY")
    if not binary:
        pytest.skip("SURFACER_CLI_BINARY is not set (CTest sets it)")
    scene = SCENES / "gyroid_in_sphere.json"
    for method in ("cubes", "tiles"):
        (pieced,) = list(local_client.isosurface([scene], cells=96, method=method))
        (asked,) = list(local_client.isosurface([scene], cells=96, method=method, encoding="draco_pieces"))
        assert len(pieced.triangles) > 2**18  # several pieces at the default size of at most 2^18 triangles
        assert np.array_equal(pieced.vertices, asked.vertices) and np.array_equal(pieced.triangles, asked.triangles)
        drc = tmp_path / f"{method}.drc"
        subprocess.run([binary, "--local", "run", "isosurface", "--scene", str(scene), "--cells", "96", "--method",
                        method, "-o", str(drc)], check=True, capture_output=True)
        one = surfacer.read_mesh(drc)
        assert len(pieced.vertices) == len(one.vertices)
        assert not np.array_equal(pieced.vertices, one.vertices)  # Draco's one mesh numbers its vertices otherwise
        positions_p, triangles_p = _triangles_by_position(pieced)
        positions_o, triangles_o = _triangles_by_position(one)
        assert np.array_equal(positions_p, positions_o) and np.array_equal(triangles_p, triangles_o)
