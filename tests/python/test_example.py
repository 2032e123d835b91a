"""examples/python/surface_particles.py runs and writes a closed PLY mesh."""

import os
import subprocess
import sys

from conftest import SOURCE_DIR


def test_surface_particles_example(tmp_path):
    output = tmp_path / "blob.ply"
    result = subprocess.run([sys.executable, str(SOURCE_DIR / "examples" / "python" / "surface_particles.py"),
                             str(output)], capture_output=True, text=True, timeout=60, env=dict(os.environ))
    assert result.returncode == 0, result.stderr
    assert "closed: True" in result.stdout
    data = output.read_bytes()
    assert data.startswith(b"ply\n") and b"element face" in data
