#!/usr/bin/python3
"""Every file VTK's XML writers and meshio write for a 115,000-point set (tests/core/vtk_writer_files.py) reads back
with our reader to the float32 positions written. Usage: vtk_writer_files_test.py CHECK_BINARY SCRATCH_DIR.
Exits 77 (skipped) when python3-vtk9 or python3-meshio is missing."""
import os
import subprocess
import sys

try:
    import vtk  # noqa: F401
    import meshio  # noqa: F401
except ImportError as e:
    print(f"skipped: {e}")
    sys.exit(77)

check, scratch = sys.argv[1], sys.argv[2]
here = os.path.dirname(os.path.abspath(__file__))
subprocess.run([sys.executable, os.path.join(here, "vtk_writer_files.py"), scratch, "115000"], check=True)
failed = []
files = sorted(f for f in os.listdir(scratch) if f.endswith((".vtu", ".vtp")))
for f in files:
    r = subprocess.run([check, os.path.join(scratch, f), os.path.join(scratch, "positions.f32")],
                       capture_output=True, text=True)
    print(r.stdout.strip() or r.stderr.strip())
    if r.returncode != 0:
        failed.append(f)
print(f"{len(files) - len(failed)} of {len(files)} files read back exactly")
sys.exit(1 if failed or not files else 0)
