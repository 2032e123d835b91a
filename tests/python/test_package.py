"""The package as users install and type-check it: `pip install` offline into a fresh virtual environment, the type
stubs against the keywords the functions really take, and the progress callable."""

import ast
import os
import pathlib
import subprocess
import sys
import typing

import numpy as np
import pytest

import surfacer
from conftest import SCENES, SOURCE_DIR, sphere_scene

JOB_METHODS = ["isosurface", "particles", "optimize", "active_coat", "active_morph", "active_advect"]
STUB = pathlib.Path(surfacer.__file__).with_name("__init__.pyi")


def accepted_keywords(client, method):
    """The keywords a job method takes, from the TypeError an unknown keyword raises (it lists them)."""
    inputs = [sphere_scene()] * (2 if method == "active_morph" else 1)
    with pytest.raises(TypeError) as caught:
        getattr(client, method)(*inputs, no_such_keyword=1)
    message = str(caught.value)
    assert "no_such_keyword" in message
    listed = message[message.index("(it takes ") + len("(it takes "):message.rindex(")")]
    return set(listed.split(", "))


def stub_methods():
    """{method: {keyword: annotation text}} of Client's job methods in the generated stubs."""
    tree = ast.parse(STUB.read_text())
    client = next(n for n in tree.body if isinstance(n, ast.ClassDef) and n.name == "Client")
    out = {}
    for node in client.body:
        if isinstance(node, ast.FunctionDef) and node.name in JOB_METHODS:
            assert node.args.kwarg is None, node.name + " still has **options in the stubs"
            out[node.name] = {a.arg: ast.unparse(a.annotation) for a in node.args.kwonlyargs}
    return out


def test_stubs_list_exactly_the_keywords_each_job_method_takes(local_client):
    stubs = stub_methods()
    assert sorted(stubs) == sorted(JOB_METHODS)
    namespace = {"os": os, "np": np, **{name: getattr(typing, name) for name in typing.__all__}}
    for method in JOB_METHODS:
        keywords = stubs[method]
        assert set(keywords) - {"progress"} == accepted_keywords(local_client, method), method
        for name, annotation in keywords.items():
            eval(annotation, namespace)  # a valid annotation: every name it uses exists
            assert annotation.startswith("Optional["), (method, name, annotation)
    assert "Literal['cubes', 'tiles']" in stubs["isosurface"]["method"]
    assert stubs["particles"]["r_inner"] == "Optional[float]"
    assert stubs["optimize"]["max_iterations"] == "Optional[int]"
    assert stubs["particles"]["vertex_only_band"] == "Optional[bool]"
    assert (STUB.parent / "py.typed").exists()


def test_progress_callable_sees_every_frame_in_order(local_client):
    scenes = [sphere_scene(0.5 + 0.1 * k) for k in range(3)]
    events = []
    frames = list(local_client.isosurface(scenes, cells=24, progress=lambda f, s, x: events.append((f, s, x))))
    assert len(frames) == 3
    assert events[-1] == (2, "done", 1.0)  # the end, heard once, even when the job outran its stream
    assert sum(1 for e in events if e[1] == "done") == 1
    for frame, stage, fraction in events:
        assert 0 <= frame < 3 and isinstance(stage, str) and stage and 0.0 <= fraction <= 1.0
    fractions = [x for _, _, x in events]
    assert fractions == sorted(fractions), "progress went backwards"


def test_progress_exception_ends_the_iteration_and_a_non_callable_is_refused(local_client):
    def fail(frame, stage, fraction):
        raise RuntimeError("stop here")

    with pytest.raises(RuntimeError, match="stop here"):
        for _ in local_client.isosurface([sphere_scene(0.5 + 0.1 * k) for k in range(4)], cells=24, progress=fail):
            pass
    with pytest.raises(TypeError, match="progress"):
        local_client.isosurface(sphere_scene(), cells=16, progress=3)


@pytest.mark.skipif(not os.environ.get("SURFACER_BUILD_DIR"), reason="SURFACER_BUILD_DIR is not set (CTest sets it)")
def test_pip_installs_offline_into_a_fresh_venv_and_runs_a_job(tmp_path):
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--system-site-packages", str(venv)], check=True)
    python = venv / "bin" / "python"
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    install = subprocess.run([str(python), "-m", "pip", "install", "--no-index", "--no-build-isolation", "-q",
                              str(SOURCE_DIR)], env=env, capture_output=True, text=True, timeout=600)
    assert install.returncode == 0, install.stdout + install.stderr
    script = (
        "import surfacer, os\n"
        "assert os.path.realpath(surfacer.__file__).startswith(os.path.realpath(%r)), surfacer.__file__\n"
        "stages = []\n"
        "frames = list(surfacer.Client().isosurface(%r, cells=20, progress=lambda f, s, x: stages.append(s)))\n"
        "assert len(frames) == 1 and len(frames[0].triangles) > 0 and stages[-1] == 'done'\n"
        "print(len(frames[0].triangles))\n" % (str(venv), str(SCENES / "torus.json")))
    run = subprocess.run([str(python), "-c", script], cwd=tmp_path, env=env, capture_output=True, text=True,
                         timeout=120)
    assert run.returncode == 0, run.stdout + run.stderr
    assert int(run.stdout.strip()) > 100
    site = next(venv.glob("lib/python3*/site-packages/surfacer"))
    assert (site / "__init__.pyi").exists() and (site / "py.typed").exists()
