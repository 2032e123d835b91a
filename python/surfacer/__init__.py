"""Surfacer from Python: implicit scenes and particle simulations to triangle meshes, numpy in and out.

    import surfacer
    c = surfacer.Client()                      # an in-process server; Client("host:50051", token=...) for a remote one
    for f in c.isosurface([scene], cells=128):  # scene: a dict in protobuf's JSON mapping of surfacer.v1.Scene, or a path
        f.index, f.vertices, f.triangles, f.normals, f.stats

This is the `surfacer` CLI's own client library (C++, in the extension module `surfacer._surfacer`): inputs are
uploaded in CRC-checked chunks, frames are verified, a broken stream is reopened from the first missing frame, and
frames are decoded (Draco, meshopt, PLY) in C++. Keyword options are those of `surfacer run <type>` with dashes as
underscores (``--r-inner`` is ``r_inner=``); an option left out (or None) takes the engine's default, and an
unknown keyword is a TypeError. The package's type stubs (``__init__.pyi``) list every keyword of every job method
with its type. Every job method also takes ``progress=``, a callable ``progress(frame, stage, fraction)`` called
with each progress event of the job (frame index, stage name such as "polygonize", fraction of the whole job in
0..1) while its frames are iterated, from the iterating thread, and once more as ``progress(last frame, "done", 1.0)``
when the job succeeded (a fast job may send no other event); an exception it raises ends the iteration.
"""

import os
import threading
from dataclasses import dataclass, field
from typing import Any, Callable, Dict, Iterator, List, Optional

import numpy as np

from . import _surfacer
from ._errors import Cancelled, Error, IntegrityError, JobFailed, Unreachable, UsageError

__all__ = ["Client", "Job", "Frame", "Mesh", "read_mesh", "Error", "UsageError", "Unreachable", "JobFailed",
           "Cancelled", "IntegrityError"]


@dataclass(frozen=True)
class Frame:
    """One finished frame of a job.

    vertices: (N,3) float64; triangles: (M,3) int32 indices into vertices, counter-clockwise seen from outside;
    normals: (N,3) float64 unit normals when the job asked for them (``normals=True``), else None; stats: the
    server's FrameStats as a dict (vertices, triangles, check (closed, edge_manifold, ...), timings, metrics,
    iteration); attributes: the particle attributes carried onto the vertices (``interpolate=[...]``), by name, each
    a float32 array of (N,) for a scalar or (N,k) for a vector."""

    index: int
    vertices: np.ndarray
    triangles: np.ndarray
    normals: Optional[np.ndarray]
    stats: Dict[str, Any]
    attributes: Dict[str, np.ndarray] = field(default_factory=dict)

    def write(self, path, vdb_voxel_size: Optional[float] = None) -> None:
        """Writes the mesh with the CLI's own writers, the format by the extension: .ply (binary; attributes as vertex
        properties), .obj, .drc, .glb (glTF with Draco pieces, encoded on every core), .gltf (plain glTF, for readers
        without Draco), .vtk or .vtu (VTK unstructured grids for ParaView, positions in double precision, normals
        and attributes as point arrays) or .vdb (an OpenVDB narrow-band level set named "surface", voxels of edge
        vdb_voxel_size, by default the mean edge length)."""
        _surfacer.write_mesh(os.fspath(path), self.vertices, self.triangles, self.normals, self.attributes,
                             vdb_voxel_size or 0.0)


@dataclass(frozen=True)
class Mesh:
    """A triangle mesh read from a file (``read_mesh``): vertices (N,3) float64; triangles (M,3) int32, counter-clockwise
    seen from outside; normals (N,3) float64 when the file has them, else None; attributes: other per-vertex
    properties of a .ply (``Frame.attributes``)."""

    vertices: np.ndarray
    triangles: np.ndarray
    normals: Optional[np.ndarray]
    attributes: Dict[str, np.ndarray] = field(default_factory=dict)

    def write(self, path, vdb_voxel_size: Optional[float] = None) -> None:
        """Writes the mesh as ``Frame.write`` does."""
        _surfacer.write_mesh(os.fspath(path), self.vertices, self.triangles, self.normals, self.attributes,
                             vdb_voxel_size or 0.0)


def read_mesh(path) -> Mesh:
    """Reads a mesh file with the CLI's own readers, the format by the extension: .ply, .obj, .drc, .glb or .gltf
    (every triangle primitive of its scene; a .gltf's buffer embedded as a data URI; a .glb the CLI or
    ``Frame.write`` wrote reads back as the frame's mesh, its pieces welded), .vtk, .vtu or .vtp (VTK's files in
    every mode the particle readers take: the triangle, quad, polygon and triangle-strip cells, a "Normals" point
    array as normals, the other point arrays as attributes), or .vdb (the zero level set of the
    FloatGrid "surface", else of the first level-set grid, meshed by OpenVDB's volumeToMesh: closed and
    outward-facing, vertices on the voxels' edges, so within about a voxel of the surface written). A file that is
    not such a mesh raises surfacer.UsageError naming what is wrong."""
    return Mesh(*_surfacer.read_mesh(os.fspath(path)))


class Job:
    """The frames of one job, streamed lazily in the order they finish (``Frame.index`` says which; iterate it, or
    ``sorted(job, key=lambda f: f.index)``).

    ``id`` is the job id; ``state`` the job's terminal state (a dict, as ``Client.status``) once the iteration ended.
    Iteration raises surfacer.JobFailed when the job fails and surfacer.Cancelled when it is cancelled. A job that
    this object submitted (``Client.isosurface`` and the like) is cancelled by Ctrl-C while iterating, by
    ``close()``, and when the object is dropped before the job finished; a job followed with ``Client.watch`` is
    only no longer watched. The GIL is released while waiting for frames."""

    def __init__(self, stream):
        self._stream = stream

    @property
    def id(self) -> str:
        return self._stream.job_id

    @property
    def state(self) -> Optional[Dict[str, Any]]:
        return self._stream.job

    def __iter__(self) -> Iterator[Frame]:
        return self

    def __next__(self) -> Frame:
        return Frame(*self._stream.next())

    def cancel(self) -> Dict[str, Any]:
        """Asks the server to cancel the job; iterating then ends with surfacer.Cancelled."""
        return self._stream.cancel()

    def close(self) -> None:
        """Stops watching (cancelling the job if this object submitted it and it has not finished)."""
        self._stream.close()

    def __enter__(self) -> "Job":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __repr__(self) -> str:
        return "<surfacer.Job %s>" % self.id


def _streams(frames) -> bool:
    """Whether `frames` goes as an open sequence: an iterable that is not a list, tuple, array, dict or path."""
    if isinstance(frames, (list, tuple, np.ndarray, dict, str, bytes, os.PathLike)):
        return False
    try:
        iter(frames)
    except TypeError:
        return False
    return True


def _progress_callable(progress):
    if progress is not None and not callable(progress):
        raise TypeError("progress=%r is not callable: give a function progress(frame, stage, fraction)" % (progress,))
    return progress


class Client:
    """A connection to a Surfacer server.

    ``Client()`` starts an in-process server (no network; it lives as long as the client and its jobs; ``workers``
    sizes it). ``Client("host:50051")`` connects to a surfacer-server, waiting up to ``timeout`` seconds; ``tls``
    (system roots) or ``tls_ca`` (a CA file) turn TLS on, ``tls_cert``/``tls_key`` present a client certificate,
    ``tls_server_name`` checks the certificate against that name; ``token`` or ``token_file`` (or $SURFACER_TOKEN)
    send a bearer token, refused in plain text to a host that is not loopback unless ``allow_insecure``. ``workers``
    with a server, and the TLS, token and ``allow_insecure`` options without one, raise UsageError. These are
    the CLI's --server, --tls, --tls-ca, ... with the same checks and defaults."""

    def __init__(self, server: Optional[str] = None, *, token: Optional[str] = None,
                 token_file: Optional[str] = None, tls: bool = False, tls_ca: Optional[str] = None,
                 tls_cert: Optional[str] = None, tls_key: Optional[str] = None,
                 tls_server_name: Optional[str] = None, allow_insecure: bool = False,
                 timeout: Optional[float] = None, workers: Optional[int] = None):
        self._client = _surfacer.Client(server, token, token_file, tls, tls_ca, tls_cert, tls_key, tls_server_name,
                                        allow_insecure, timeout, workers)

    # -- jobs that stream their frames back ------------------------------------------------------------------------

    def isosurface(self, scenes, **options) -> Job:
        """Polygonizes f = 0 of each scene (a dict in protobuf's JSON mapping of surfacer.v1.Scene, or a path to a
        scene JSON file; one scene or a list), one frame per scene. Options: cells, cell_size, bounds (x0, y0, z0,
        x1, y1, z1), method ("tiles" or "cubes"), and every job's name, encoding ("draco", "meshopt", "raw"),
        normals, quantization_bits, decimate (a length in scene units: error-bounded level of detail, 0 off)."""
        return self._run("isosurface", (scenes,), options)

    def particles(self, frames, **options) -> Job:
        """Surfaces particle frames (Williams 2008), one mesh per frame. Each frame is an (N,3) array of positions,
        an (N,4) array of positions and radii, or a particle file or pattern (``fluid_{:04d}.bgeo``, with start=
        and end=). Options (surfacer.v1.ParticlesJob's fields): r_inner or derive_r_inner=True, r_outer,
        spacing_factor, laplacian_sweeps, bilaplacian_sweeps, polish_sweeps (or sweeps=(L, B, P)), relaxation,
        erosion, unconstrained_polish, vertex_only_band, min_angle_degrees (alias min_angle), container_box,
        container_solid (dict or path; alias container_scene), min_particles_per_component (alias min_particles),
        start, end, and every job's. Values are checked with the server's own checks before anything is
        submitted (UsageError naming the keyword).

        ``frames`` may also be any other iterable, a generator included: the job is then an open sequence, submitted
        with the first frame it yields and taking each later one as it comes (uploaded from a thread of its own), so
        that frames are surfaced and iterated while the iterable is still producing. Its quantization box is then the
        first frame's grown by its own extent on every side unless ``quantization_bounds`` is given (a frame outside
        fails the job, naming it); an exception the iterable raises fails the job with its text. A list (or tuple)
        goes as the CLI's sequences do: every frame read once first (its quantization box the whole sequence's), the
        job started with the first frame and the others joining it as they are uploaded, iteration starting once
        all are in. A server without open sequences gets any sequence whole before the job starts."""
        if _streams(frames):
            return self._run_open("particles", frames, options)
        return self._run("particles", (frames,), options)

    def optimize(self, scene, **options) -> Job:
        """Optimizes a mesh toward the scene's surface (Ohtake-Belyaev-Pasko 2002): snapshot frames, the last one the
        result. Options (surfacer.v1.OptimizeJob's fields): start_mesh (a .ply/.obj/.drc/.glb/.gltf path) or
        polygonize_cells, polygonize_cell_size, polygonize_method, polygonize_bounds (aliases start_cells,
        start_method, start_bounds); max_iterations (alias iterations), tolerance, snapshot_every, flows ("d,n,t" or a
        list), c_d, c_n, c_t, step_bound, modified_flows, t_flow_iterations, subdivision_threshold (alias
        subdivide), triangle_budget, and every job's."""
        return self._run("optimize", (scene,), options)

    def active_coat(self, frames, **options) -> Job:
        """A skin coating a particle sequence (Desbrun-Cani 1998). Options: kernel_radius and grid_spacing
        (required), iso, substeps_per_frame (alias substeps), start, end, bounds, alpha, beta, gamma, delta, cfl,
        polygonizer, and every job's."""
        return self._run("active_coat", (frames,), options)

    def active_morph(self, a, b, **options) -> Job:
        """Morphs scene a into scene b (Desbrun-Cani 1998). Options: grid_spacing (required), tolerance, max_frames,
        frame_time, bounds, alpha, beta, gamma, delta, cfl, polygonizer, and every job's."""
        return self._run("active_morph", (a, b), options)

    def active_advect(self, scene, **options) -> Job:
        """Advects a scene by the Enright test field, or by a sampled one: velocity_grid (a raw float32 file) with
        velocity_origin, velocity_spacing and velocity_dims. Options: grid_spacing, frame_interval, frames
        (required), enright_period (alias period), error_compensation, bounds, beta, gamma, delta, cfl, polygonizer,
        and every job's."""
        return self._run("active_advect", (scene,), options)

    def _run_open(self, kind, frames, options) -> Job:
        it = iter(frames)
        try:
            first = next(it)
        except StopIteration:
            return self._run(kind, ([],), options)
        if not self._client.open_sequences():
            return self._run(kind, ([first, *it],), options)
        progress = _progress_callable(options.pop("progress", None))
        job_id = self._client.submit_open(kind, ([first],), options)
        job = Job(self._client.stream(job_id, 0, True, progress))

        def feed():
            try:
                self._feed(job_id, kind, it, options)
            except BaseException:
                pass  # the job failed with the error (or had finished already): its iteration says why

        threading.Thread(target=feed, name="surfacer-open-sequence", daemon=True).start()
        return job

    def _feed(self, job_id, kind, it, options) -> None:
        """Appends each frame `it` yields (frames 1, 2, ...) to the open job `job_id`, then ends its sequence. An
        exception on the way (the iterable's, a frame refused, Ctrl-C) fails the job with "frame K: TYPE: text"
        and is raised again; an Error as JobFailed naming the job and frame K (the frames before it are kept)."""
        index = 1
        try:
            for frame in it:
                self._client.append(job_id, kind, ([frame],), options, index)
                index += 1
            self._client.end(job_id)
        except BaseException as e:
            reason = "frame %d: %s: %s" % (index, type(e).__name__, e)
            try:
                self._client.end(job_id, reason)
            except Exception:
                pass  # the job has finished already (cancelled, failed)
            if not isinstance(e, Exception):
                raise
            raise JobFailed("job %s failed at %s (the frames before it are kept: Client.watch(%r))"
                            % (job_id, reason, job_id), getattr(e, "code", "ABORTED"), 4) from e

    def _run(self, kind, inputs, options) -> Job:
        progress = _progress_callable(options.pop("progress", None))
        job_id = self._client.submit(kind, inputs, options)
        return Job(self._client.stream(job_id, 0, True, progress))

    # -- jobs by id ------------------------------------------------------------------------------------------------

    def submit(self, kind: str, *inputs, **options) -> str:
        """Submits a job without watching it and returns its id once every input is uploaded and part of the job.
        kind: "isosurface", "particles", "optimize", "active_coat", "active_morph" or "active_advect"; inputs and
        options as for the method of that name. A particle sequence starts as soon as its first frame is uploaded,
        the others joining it as they are uploaded (a generator's as it yields them; see ``particles``), so its
        first frames may be done when this returns. A frame that fails once the job started (a generator that
        raises, a frame refused) fails the job and raises JobFailed naming the job and the frame; the frames before
        it are kept (``watch``)."""
        if kind == "particles" and len(inputs) == 1 and _streams(inputs[0]):
            it = iter(inputs[0])
            try:
                first = next(it)
            except StopIteration:
                return self._client.submit(kind, ([],), options)
            if not self._client.open_sequences():
                return self._client.submit(kind, ([first, *it],), options)
            job_id = self._client.submit_open(kind, ([first],), options)
            self._feed(job_id, kind, it, options)
            return job_id
        return self._client.submit(kind, inputs, options)

    def watch(self, job_id: str, from_frame: int = 0,
              progress: Optional[Callable[[int, str, float], Any]] = None) -> Job:
        """The frames of a job from frame ``from_frame`` on (also those already finished); ``progress`` as for the
        job methods."""
        return Job(self._client.stream(job_id, from_frame, False, _progress_callable(progress)))

    def status(self, job_id: str) -> Dict[str, Any]:
        """The job as a dict: id, name, kind, state ("JOB_STATE_RUNNING", ...), frames_total, frames_done,
        progress, error (code, message), created/started/finished (seconds since the epoch)."""
        return self._client.status(job_id)

    def list(self, states: Optional[List[str]] = None) -> List[Dict[str, Any]]:
        """Every job the server keeps (for this token), optionally only those in ``states`` ("queued",
        "running", "succeeded", "failed", "cancelled")."""
        return self._client.list(list(states or []))

    def cancel(self, job_id: str) -> Dict[str, Any]:
        """Asks the server to cancel a job; returns the job as the server answered."""
        return self._client.cancel(job_id)

    def health(self, service: str = "") -> str:
        """The grpc.health.v1 status: "SERVING", "NOT_SERVING", ..."""
        return self._client.health(service)

    def server_info(self) -> Optional[Dict[str, Any]]:
        """The server's version and limits (GetServerInfo)."""
        return self._client.server_info()

    @property
    def local(self) -> bool:
        """True for an in-process server."""
        return self._client.local

    def close(self) -> None:
        """Lets go of the connection (an in-process server stops once no Job uses it either)."""
        self._client.close()

    def __enter__(self) -> "Client":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __repr__(self) -> str:
        return "<surfacer.Client %s>" % self._client.describe()
