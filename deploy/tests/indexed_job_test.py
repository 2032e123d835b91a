#!/usr/bin/python3
"""Runs deploy/indexed-job-entry.sh as two pods of an Indexed Job would, with the real `surfacer` CLI, and checks
that the union of their output is the whole frame sequence under global frame numbers, each file holding the
surface of its own input frame.

Usage: indexed_job_test.py ENTRY_SCRIPT SURFACER_CLI

The sequence is five particle frames numbered 10..14 (a ball of particles on a lattice, moved along x by
SHIFT * frame number), split across JOB_COMPLETIONS=2 pods: pod 0 takes 10..12, pod 1 takes 13..14. A frame's mesh
centroid tells which input it came from, so a frame written under the wrong number fails the test.
"""
import os
import struct
import subprocess
import sys
import tempfile
from pathlib import Path

SHIFT = 0.5  # x offset per frame number; frames are far apart compared with the ball radius
RADIUS = 0.3
SPACING = 0.1
FIRST, TOTAL = 10, 5


def write_frames(directory: Path) -> int:
    count = 0
    for k in range(FIRST, FIRST + TOTAL):
        lines = []
        steps = range(-3, 4)
        for i in steps:
            for j in steps:
                for m in steps:
                    x, y, z = i * SPACING, j * SPACING, m * SPACING
                    if x * x + y * y + z * z <= RADIUS * RADIUS + 1e-9:
                        lines.append(f"{x + SHIFT * k:.5f} {y:.5f} {z:.5f}\n")
        (directory / f"drop_{k:04d}.xyz").write_text("".join(lines))
        count = len(lines)
    return count


def ply_centroid(path: Path) -> tuple[float, float, float, int]:
    """Mean vertex position and vertex count of a binary little-endian (or ASCII) PLY file."""
    data = path.read_bytes()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    header = data[:end].decode("ascii").splitlines()
    fmt = next(line.split()[1] for line in header if line.startswith("format "))
    sizes = {"float": "f", "float32": "f", "double": "d", "float64": "d", "int": "i", "int32": "i",
             "uint": "I", "uint32": "I", "uchar": "B", "uint8": "B", "char": "b", "short": "h", "ushort": "H"}
    vertices, props, in_vertex = 0, [], False
    for line in header:
        words = line.split()
        if words[:2] == ["element", "vertex"]:
            vertices, in_vertex = int(words[2]), True
        elif words and words[0] == "element":
            in_vertex = False
        elif in_vertex and words[0] == "property":
            props.append((words[-1], sizes[words[1]]))
    names = [name for name, _ in props]
    xi, yi, zi = names.index("x"), names.index("y"), names.index("z")
    sx = sy = sz = 0.0
    if fmt == "ascii":
        rows = data[end:].decode("ascii").splitlines()[:vertices]
        for row in rows:
            values = [float(v) for v in row.split()]
            sx, sy, sz = sx + values[xi], sy + values[yi], sz + values[zi]
    else:
        assert fmt == "binary_little_endian", f"{path}: unexpected PLY format {fmt}"
        record = struct.Struct("<" + "".join(code for _, code in props))
        for values in record.iter_unpack(data[end:end + record.size * vertices]):
            sx, sy, sz = sx + values[xi], sy + values[yi], sz + values[zi]
    assert vertices > 0, f"{path}: no vertices"
    return sx / vertices, sy / vertices, sz / vertices, vertices


def run_pod(entry: str, env: dict, index: int) -> subprocess.CompletedProcess:
    pod_env = dict(env, JOB_COMPLETION_INDEX=str(index))
    return subprocess.run([entry], env=pod_env, capture_output=True, text=True, timeout=120)


def main() -> int:
    if len(sys.argv) != 3:
        print(__doc__, file=sys.stderr)
        return 2
    entry, cli = os.path.abspath(sys.argv[1]), os.path.abspath(sys.argv[2])
    failures = []

    def expect(condition: bool, message: str) -> None:
        if not condition:
            failures.append(message)
            print(f"FAIL: {message}")

    with tempfile.TemporaryDirectory(prefix="surfacer-indexed-job-") as tmp:
        tmp = Path(tmp)
        inputs, out = tmp / "input", tmp / "out"
        inputs.mkdir()
        particles = write_frames(inputs)
        base = {
            "PATH": os.environ.get("PATH", "/usr/bin:/bin"),
            "HOME": str(tmp),
            "SURFACER": cli,
            "SURFACER_WORKERS": "2",
            "INPUT_PATTERN": str(inputs / "drop_{:04d}.xyz"),
            "FRAME_FIRST": str(FIRST),
            "FRAMES_TOTAL": str(TOTAL),
            "JOB_COMPLETIONS": "2",
            "R_INNER": "0.06",
            "OUT_DIR": str(out),
            "SURFACER_ARGS": "--format ply",
        }
        os.chdir(tmp)  # the in-process server may keep its state in the working directory

        # Pod 1 first: completion order across pods is arbitrary.
        for index in (1, 0):
            result = run_pod(entry, base, index)
            expect(result.returncode == 0, f"pod {index} exited {result.returncode}:\n{result.stderr}")
        expected = {f"frame_{k:04d}.ply" for k in range(FIRST, FIRST + TOTAL)}
        written = {p.name for p in out.iterdir() if p.is_file()}
        expect(written == expected, f"frames written {sorted(written)}, expected {sorted(expected)}")
        leftovers = [p.name for p in out.iterdir() if p.is_dir() and p.name != "stats"]
        expect(not leftovers, f"part directories left behind: {leftovers}")

        for k in range(FIRST, FIRST + TOTAL):
            path = out / f"frame_{k:04d}.ply"
            if not path.exists():
                continue
            cx, cy, cz, vertices = ply_centroid(path)
            # The surface of a ball of particles is centred on the ball; frames differ by SHIFT along x.
            expect(abs(cx - SHIFT * k) < 0.05 and abs(cy) < 0.05 and abs(cz) < 0.05,
                   f"{path.name}: centroid ({cx:.3f}, {cy:.3f}, {cz:.3f}) is not the centre of input frame {k} "
                   f"({SHIFT * k:.3f}, 0, 0): the frame carries the wrong number")
            print(f"{path.name}: {vertices} vertices, centroid x {cx:.3f} (frame {k}: {SHIFT * k:.3f})")

        for index, frames in ((0, [10, 11, 12]), (1, [13, 14])):
            stats = out / "stats" / f"part-{index}.csv"
            if not stats.exists():
                expect(False, f"{stats} missing")
                continue
            rows = stats.read_text().splitlines()
            numbers = [int(row.split(",")[0]) for row in rows[1:] if row]
            expect(rows[0].startswith("frame,"), f"{stats}: header {rows[0]!r} lost")
            expect(sorted(numbers) == frames, f"{stats}: frame column {numbers}, expected {frames}")
            particles_col = rows[0].split(",").index("particles")
            counts = {int(row.split(",")[particles_col]) for row in rows[1:] if row}
            expect(counts == {particles}, f"{stats}: particle counts {counts}, expected {{{particles}}}")

        # A retried pod (a stale part directory from a killed attempt) publishes the same frames again.
        stale = out / ".part-1"
        stale.mkdir()
        (stale / "frame_0007.ply").write_text("junk from a killed attempt")
        before = (out / "frame_0013.ply").read_bytes() if (out / "frame_0013.ply").exists() else b""
        result = run_pod(entry, base, 1)
        expect(result.returncode == 0, f"retried pod 1 exited {result.returncode}:\n{result.stderr}")
        expect(not stale.exists(), "retried pod 1 left its part directory behind")
        expect({p.name for p in out.iterdir() if p.is_file()} == expected, "retried pod 1 changed the frame set")
        expect(before and (out / "frame_0013.ply").read_bytes() == before, "retried pod 1 changed frame_0013")

        # An index past the end of the sequence has nothing to do: 5 frames over 4 pods is 2 per pod, pod 3 idle.
        result = run_pod(entry, dict(base, JOB_COMPLETIONS="4", OUT_DIR=str(tmp / "idle")), 3)
        expect(result.returncode == 0 and not (tmp / "idle").exists(),
               f"idle pod 3 of 4: exit {result.returncode}, created output: {(tmp / 'idle').exists()}")

        # Bad environments exit 2 naming the variable, before running anything.
        bad_cases = [
            ({"JOB_COMPLETION_INDEX": "2"}, "JOB_COMPLETION_INDEX (2) must be < JOB_COMPLETIONS (2)"),
            ({"JOB_COMPLETION_INDEX": "x"}, "JOB_COMPLETION_INDEX (x) must be a non-negative integer"),
            ({"R_INNER": ""}, "R_INNER is not set"),
            ({"FRAMES_PER_POD": "2"}, "FRAMES_PER_POD (2) x JOB_COMPLETIONS (2) < FRAMES_TOTAL (5)"),
            ({"JOB_COMPLETIONS": ""}, "set JOB_COMPLETIONS"),
        ]
        for change, message in bad_cases:
            env = dict(base, JOB_COMPLETION_INDEX="0", OUT_DIR=str(tmp / "bad"))
            env.update(change)
            result = subprocess.run([entry], env=env, capture_output=True, text=True, timeout=30)
            expect(result.returncode == 2 and message in result.stderr,
                   f"{change}: exit {result.returncode}, stderr {result.stderr.strip()!r}, expected 2 and {message!r}")
            expect(not (tmp / "bad").exists(), f"{change}: output directory created despite the bad environment")

        # A CLI failure (an input frame missing) is passed through and publishes nothing.
        (inputs / "drop_0014.xyz").unlink()
        result = run_pod(entry, dict(base, OUT_DIR=str(tmp / "broken")), 1)
        expect(result.returncode != 0 and "drop_0014" in result.stderr,
               f"a missing input frame: exit {result.returncode}, stderr does not name drop_0014.xyz:\n"
               f"{result.stderr}")
        published = sorted(p.name for p in (tmp / "broken").glob("frame_*"))
        expect(not published, f"a failed pod published {published}")

    if failures:
        print(f"{len(failures)} failure(s)")
        return 1
    print("indexed job: 2 pods wrote frames 10..14 under global numbers; retry, idle pod and bad input checked")
    return 0


if __name__ == "__main__":
    sys.exit(main())
