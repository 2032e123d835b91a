#!/usr/bin/python3
"""Runs deploy/slurm/surfacer-array.sbatch on a real single-host Slurm cluster (scripts/local-slurm.sh: munged,
slurmctld and slurmd on this machine, started and stopped here) and checks that the union of the array's output is
one local `surfacer run particles` over the whole sequence, byte for byte, under global frame numbers; then reruns
one task (a retry after a killed attempt) and checks that nothing changed.

Usage: slurm_array_test.py DEPLOY_DIR LOCAL_SLURM_SCRIPT SURFACER_CLI
Exit status: 0 passed, 1 failed, 77 skipped (not root, or the Slurm daemons could not be started on this machine:
scripts/setup.sh installs slurm-wlm and munge; the reason and the daemons' logs are printed).

The sequence is the Indexed Job test's: five particle frames numbered 10..14, here split by FRAMES_PER_TASK=2 into an
array of three tasks (10-11, 12-13, 14). Frames are the default .glb files (Draco pieces, encoded on every core of a task): each task quantizes them on the box
given by --quantization-bounds (the whole sequence's particles padded by more than r_outer), so every task's frames
are the whole run's bit for bit. (Without it each task's grid would be its own range's box, one quantization step off.)
"""
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

sys.dont_write_bytecode = True  # no __pycache__ in the source tree
sys.path.insert(0, str(Path(__file__).resolve().parent))
from indexed_job_test import FIRST, TOTAL, write_frames  # noqa: E402  (the same sequence as the Indexed Job test)

PER_TASK = 2
R_INNER = "0.06"
SKIP = 77


def sequence_box(inputs: Path, pad: float) -> str:
    """The box of every particle of the sequence, padded by `pad`, as --quantization-bounds takes it."""
    points = [tuple(float(v) for v in line.split()) for p in sorted(inputs.glob("drop_*.xyz"))
              for line in p.read_text().splitlines() if line.strip()]
    lo = [min(p[a] for p in points) - pad for a in range(3)]
    hi = [max(p[a] for p in points) + pad for a in range(3)]
    return ",".join(f"{v:.6f}" for v in lo + hi)


def frames_in(directory: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in directory.iterdir() if p.is_file() and p.name.startswith("frame_")}


def main() -> int:
    if len(sys.argv) != 4:
        print(__doc__, file=sys.stderr)
        return 2
    deploy, local_slurm, cli = (os.path.abspath(a) for a in sys.argv[1:])
    sbatch_script = os.path.join(deploy, "slurm", "surfacer-array.sbatch")
    if os.geteuid() != 0:
        print("SKIP: the single-host Slurm cluster needs root (slurmd starts jobs as their users)")
        return SKIP
    missing = [tool for tool in ("munged", "slurmctld", "slurmd", "sbatch") if not shutil.which(
        tool, path=os.environ.get("PATH", "") + ":/usr/sbin")]
    if missing:
        print(f"SKIP: {', '.join(missing)} not installed (scripts/setup.sh installs slurm-wlm and munge)")
        return SKIP
    failures = []

    def expect(condition: bool, message: str) -> None:
        if not condition:
            failures.append(message)
            print(f"FAIL: {message}")

    with tempfile.TemporaryDirectory(prefix="surfacer-slurm-") as tmp:
        tmp = Path(tmp)
        tmp.chmod(0o755)  # munged wants every directory above its socket searchable by all
        cluster, inputs, out, ref = tmp / "cluster", tmp / "input", tmp / "out", tmp / "ref"
        inputs.mkdir()
        write_frames(inputs)
        format_args = ["--quantization-bounds", sequence_box(inputs, 4 * float(R_INNER))]
        started = subprocess.run([local_slurm, "start", str(cluster)], capture_output=True, text=True, timeout=90)
        if started.returncode != 0:
            subprocess.run([local_slurm, "stop", str(cluster)], timeout=60)
            print(f"SKIP: the Slurm daemons did not start on this machine (exit {started.returncode}):\n"
                  f"{started.stdout}{started.stderr}")
            return SKIP
        try:
            env = {
                "PATH": os.environ.get("PATH", "/usr/bin:/bin") + ":/usr/sbin",
                "HOME": str(tmp),
                "SLURM_CONF": str(cluster / "slurm.conf"),
                "SURFACER": cli,
                "INPUT_PATTERN": str(inputs / "drop_{:04d}.xyz"),
                "FRAME_FIRST": str(FIRST),
                "FRAMES_TOTAL": str(TOTAL),
                "FRAMES_PER_TASK": str(PER_TASK),
                "R_INNER": R_INNER,
                "OUT_DIR": str(out),
                "SURFACER_ARGS": " ".join(format_args),
            }
            # The cluster's node may be small: one core and a little memory per task, so the three tasks run at once
            # on two cores or queue on one. --wait returns when every task has ended, with the highest exit status.
            small = ["--wait", "--cpus-per-task=1", "--mem=400M", "--time=5", f"--output={tmp}/task-%A_%a.out"]
            submit = subprocess.run([sbatch_script, *small], env=env, cwd=tmp, capture_output=True, text=True,
                                    timeout=120)
            logs = "".join(f"--- {p.name}\n{p.read_text()}" for p in sorted(tmp.glob("task-*.out")))
            expect(submit.returncode == 0,
                   f"the array exited {submit.returncode}:\n{submit.stdout}{submit.stderr}{logs}")
            tasks = sorted(tmp.glob("task-*.out"))
            expect(len(tasks) == 3, f"{len(tasks)} task logs, expected 3 (array 0-2 for {TOTAL} frames, "
                                    f"{PER_TASK} per task)")

            local = subprocess.run([cli, "--local", "--workers", "2", "run", "particles", "--input",
                                    env["INPUT_PATTERN"], "--start", str(FIRST), "--end", str(FIRST + TOTAL - 1),
                                    "--r-inner", R_INNER, "-o", str(ref), *format_args],
                                   cwd=tmp, capture_output=True, text=True, timeout=120)
            expect(local.returncode == 0, f"the local run exited {local.returncode}:\n{local.stderr}")
            expected = frames_in(ref) if ref.exists() else {}
            expect(sorted(expected) == [f"frame_{k:04d}.glb" for k in range(FIRST, FIRST + TOTAL)],
                   f"the local run wrote {sorted(expected)}")
            written = frames_in(out) if out.exists() else {}
            expect(sorted(written) == sorted(expected),
                   f"the array wrote {sorted(written)}, the local run {sorted(expected)}")
            for name, data in sorted(expected.items()):
                if name in written:
                    expect(written[name] == data, f"{name}: the array's bytes differ from the local run's")
            hidden = [p.name for p in out.iterdir() if p.name.startswith(".")] if out.exists() else []
            expect(not hidden, f"part directories left behind: {hidden}")
            stats = sorted(p.name for p in (out / "stats").glob("*.csv")) if out.exists() else []
            expect(stats == ["part-0.csv", "part-1.csv", "part-2.csv"], f"stats files {stats}")

            # A retry of task 1 after a killed attempt (a stale part directory with a junk frame): resubmitted alone,
            # it redoes frames 12-13 and publishes the same bytes; the other tasks' frames are untouched.
            stale = out / ".part-1"
            stale.mkdir(parents=True, exist_ok=True)
            (stale / "frame_0012.glb").write_text("half a frame from a killed attempt")
            before = {name: (out / name).stat().st_mtime_ns for name in written}
            retry = subprocess.run(["sbatch", "--array=1", *small, sbatch_script],
                                   env=dict(env, SURFACER_ENTRY=os.path.join(deploy, "indexed-job-entry.sh")),
                                   cwd=tmp, capture_output=True, text=True, timeout=120)
            expect(retry.returncode == 0, f"the retried task exited {retry.returncode}:\n{retry.stdout}{retry.stderr}")
            again = frames_in(out)
            expect(again == written, "the retried task changed the frames: "
                   f"{sorted(k for k in set(again) | set(written) if again.get(k) != written.get(k))}")
            rewritten = sorted(n for n in again if (out / n).stat().st_mtime_ns != before.get(n))
            expect(rewritten == ["frame_0012.glb", "frame_0013.glb"],
                   f"the retried task 1 rewrote {rewritten}, expected its own frames 12-13")
            expect(not stale.exists(), "the retried task left its part directory behind")
        finally:
            stopped = subprocess.run([local_slurm, "stop", str(cluster)], capture_output=True, text=True, timeout=60)
            expect(stopped.returncode == 0, f"stopping the daemons: exit {stopped.returncode} {stopped.stderr}")

    if failures:
        print(f"{len(failures)} failure(s)")
        return 1
    print(f"slurm array: 3 tasks on a single-host Slurm wrote frames {FIRST}..{FIRST + TOTAL - 1}, byte-identical to "
          "one local run; a retried task changed nothing")
    return 0


if __name__ == "__main__":
    sys.exit(main())
