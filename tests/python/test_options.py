"""One option model: the Python keywords, the CLI's flags and a raw JobSpec sent to the server are the proto's field
names, and a bad value gets the same message from core's check whichever way it came in. The Python package and the
CLI check before anything is submitted (UsageError / exit 2, naming the keyword or flag); a spec file sent as it is
(`surfacer run --spec`) is checked by the server (exit 4). CTest sets SURFACER_CLI_BINARY to the built CLI."""

import json
import os
import subprocess

import numpy as np
import pytest

import surfacer

from conftest import lattice_ball, sphere_scene

# (job kind, python keywords, CLI arguments, JobSpec JSON, the core message every route must carry)
CASES = [
    ("particles", {"r_inner": 0.1, "r_outer": 0.05}, ["--r-inner", "0.1", "--r-outer", "0.05"],
     {"particles": {"rInner": 0.1, "rOuter": 0.05}},
     "spec.particles.r_outer (0.05) must exceed r_inner (0.1)"),
    ("particles", {"r_inner": 0.1, "min_angle_degrees": 45}, ["--r-inner", "0.1", "--min-angle-degrees", "45"],
     {"particles": {"rInner": 0.1, "minAngleDegrees": 45}},
     "spec.particles.min_angle_degrees (45)"),
    ("particles", {"r_inner": 0.1, "spacing_factor": 0}, ["--r-inner", "0.1", "--spacing-factor", "0"],
     {"particles": {"rInner": 0.1, "spacingFactor": 0}},
     "spec.particles.spacing_factor (0) must be in [0.1, 10]"),
    ("particles", {"r_inner": 0.1, "sweeps": (5, -1, 5)}, ["--r-inner", "0.1", "--sweeps", "5,-1,5"],
     {"particles": {"rInner": 0.1, "laplacianSweeps": 5, "bilaplacianSweeps": -1, "polishSweeps": 5}},
     "spec.particles.bilaplacian_sweeps (-1) must be in 0..100000"),
    ("isosurface", {"cells": -4}, ["--cells", "-4"], {"isosurface": {"cells": -4}}, "spec.isosurface.cells (-4)"),
    ("optimize", {"c_d": 1.5}, ["--c-d", "1.5"], {"optimize": {"cD": 1.5}}, "spec.optimize.c_d (1.5)"),
    ("isosurface", {"decimate": -0.5}, ["--decimate", "-0.5"], {"isosurface": {}, "output": {"decimate": -0.5}},
     "spec.output.decimate (-0.5) must be a finite length >= 0"),
    ("isosurface", {"quantization_bounds": (1, 0, 0, 0, 1, 1)}, ["--quantization-bounds", "1,0,0,0,1,1"],
     {"isosurface": {}, "output": {"quantizationBounds": {"min": {"x": 1}, "max": {"y": 1, "z": 1}}}},
     "spec.output.quantization_bounds.min.x (1) must be < spec.output.quantization_bounds.max.x (0)"),
]


def cli_binary():
    binary = os.environ.get("SURFACER_CLI_BINARY")
    if not binary:
        pytest.skip("SURFACER_CLI_BINARY is not set (CTest sets it)")
    return binary


def inputs_for(kind, tmp_path):
    """The positional input of the Python call, the CLI's input flags, and the spec JSON's inputs, for `kind`."""
    scene = tmp_path / "ball.json"
    scene.write_text(json.dumps(sphere_scene(0.5)))
    if kind == "particles":
        points = tmp_path / "ball.xyz"
        points.write_text("\n".join("%g %g %g" % tuple(p) for p in lattice_ball()) + "\n")
        return [lattice_ball()], ["--input", str(points)], {}
    if kind == "isosurface":
        return [sphere_scene(0.5)], ["--scene", str(scene)], {"scenes": [sphere_scene(0.5)]}
    return sphere_scene(0.5), ["--scene", str(scene)], {"scene": sphere_scene(0.5)}


@pytest.mark.parametrize("kind,keywords,flags,spec,message", CASES)
def test_same_message_from_python_cli_and_a_raw_spec(kind, keywords, flags, spec, message, tmp_path,
                                                     server_address, remote_client):
    positional, input_flags, spec_inputs = inputs_for(kind, tmp_path)

    # Python: refused before anything is submitted, naming the keyword.
    with pytest.raises(surfacer.UsageError) as error:
        list(getattr(remote_client, kind)(positional, **keywords))
    assert error.value.code == "INVALID_ARGUMENT"
    assert message in str(error.value), str(error.value)

    # The CLI: exit 2 before submitting, naming the flag.
    cli = subprocess.run([cli_binary(), "--server", server_address, "run", kind] + input_flags + flags +
                         ["-o", str(tmp_path / "cli")], capture_output=True, text=True, timeout=120)
    assert cli.returncode == 2, cli.stderr
    assert message in cli.stderr, cli.stderr

    # A raw JobSpec, as any gRPC client sends it: the server's INVALID_ARGUMENT (exit 4), the same message.
    job = dict(spec)
    job[kind] = dict(job[kind], **spec_inputs)
    if kind == "particles":  # a spec file cannot name local files: the frame goes inline
        job[kind]["frames"] = [{"positions": [float(v) for v in lattice_ball().ravel()]}]
    path = tmp_path / "job.json"
    path.write_text(json.dumps(job))
    raw = subprocess.run([cli_binary(), "--server", server_address, "run", "--spec", str(path), "-o",
                          str(tmp_path / "raw")], capture_output=True, text=True, timeout=120)
    assert raw.returncode == 4, raw.stderr
    assert message in raw.stderr, raw.stderr


def test_keywords_are_proto_names_and_old_spellings_still_work(local_client):
    ball = lattice_ball()
    (proto,) = local_client.particles([ball], r_inner=0.04, min_angle_degrees=0, min_particles_per_component=1)
    (alias,) = local_client.particles([ball], r_inner=0.04, min_angle=0, min_particles=1)
    assert proto.stats["metrics"] == alias.stats["metrics"]
    assert len(proto.triangles) == len(alias.triangles)
    with pytest.raises(TypeError) as error:
        local_client.particles([ball], r_inner=0.04, min_angel=3)
    assert "min_angel" in str(error.value) and "min_angle_degrees" in str(error.value)


@pytest.mark.parametrize("cells", [np.int64(12), np.int32(12), np.uint16(12), 12])
def test_numpy_values_are_accepted_where_numbers_are(local_client, cells):
    """Pipelines pass numpy scalars and arrays (a bounds array, a cell count from arithmetic); they mean their value."""
    bounds = np.array([-1.5, -1.5, -1.5, 1.5, 1.5, 1.5])
    (plain,) = local_client.isosurface([sphere_scene()], cells=12, bounds=[-1.5, -1.5, -1.5, 1.5, 1.5, 1.5])
    (numpy_frame,) = local_client.isosurface([sphere_scene()], cells=cells, bounds=bounds)
    assert np.array_equal(plain.vertices, numpy_frame.vertices)
    assert np.array_equal(plain.triangles, numpy_frame.triangles)


@pytest.mark.parametrize("keyword,value", [("cells", "16"), ("cells", b"16"), ("bounds", "-1,-1,-1,1,1,1"),
                                           ("max_triangles", "1000")])
def test_a_string_for_a_number_is_a_type_error_naming_the_keyword(local_client, keyword, value):
    with pytest.raises(TypeError) as error:
        local_client.isosurface([sphere_scene()], **{keyword: value})
    assert keyword in str(error.value)


def test_decimate_is_an_output_keyword_of_every_job(local_client):
    (plain,) = local_client.isosurface(sphere_scene(0.5), cells=32)
    (decimated,) = local_client.isosurface(sphere_scene(0.5), cells=32, decimate=0.002)
    assert len(decimated.triangles) * 2 < len(plain.triangles)
    assert decimated.stats["metrics"]["triangles_before_decimate"] == len(plain.triangles)
    assert "triangles_before_decimate" not in plain.stats["metrics"]
