"""Open sequences from Python: any iterable of frames, a generator included, is surfaced while it is still producing
(each frame joins the running job as it is yielded), against a real surfacer-server on a loopback port and the
in-process one. A generator that waits for the first mesh would wait forever if the whole sequence were uploaded
before the job started: it gives up after WAIT seconds, so that behaviour fails the test instead of hanging it."""

import threading
import time

import numpy as np
import pytest

import surfacer
from conftest import assert_closed, lattice_ball

WAIT = 30.0  # seconds a generator waits for the first mesh before it raises


def waiting_generator(first_mesh, produced, frames=4):
    """Yields frame 0, then waits until `first_mesh` is set before it yields frames 1.. (a simulation that steps only
    when its consumer has looked at the last result)."""
    ball = lattice_ball(0.3, 0.05)
    yield ball
    produced.append(0)
    if not first_mesh.wait(WAIT):
        raise TimeoutError("no mesh came back within %g s while the generator was still producing" % WAIT)
    for k in range(1, frames):
        yield ball + [0.01 * k, 0.0, 0.0]
        produced.append(k)


@pytest.mark.parametrize("which", ["remote_client", "local_client"])
def test_a_generator_is_surfaced_while_it_produces(which, request):
    client = request.getfixturevalue(which)
    first_mesh = threading.Event()
    produced = []
    received = []  # (frame index, frames the generator had produced when it arrived)
    with client.particles(waiting_generator(first_mesh, produced), r_inner=0.05) as job:
        for frame in job:
            received.append((frame.index, len(produced)))
            assert_closed(frame)
            first_mesh.set()
    assert job.state["state"] == "JOB_STATE_SUCCEEDED"
    assert sorted(index for index, _ in received) == [0, 1, 2, 3]
    # The first mesh came back while the generator had yielded only its first frame (and was waiting for that mesh).
    assert received[0][0] == 0 and received[0][1] <= 1
    assert produced == [0, 1, 2, 3]


def test_a_failing_generator_fails_the_job_with_its_error(remote_client):
    def frames():
        yield lattice_ball(0.3, 0.05)
        raise RuntimeError("the simulation diverged")

    with pytest.raises(surfacer.JobFailed, match="the simulation diverged"):
        list(remote_client.particles(frames(), r_inner=0.05))


def test_an_iterator_that_is_not_a_list_streams_and_a_list_does_not(remote_client):
    balls = [lattice_ball(0.3, 0.05) + [0.01 * k, 0.0, 0.0] for k in range(3)]
    streamed = sorted(remote_client.particles(iter(balls), r_inner=0.05), key=lambda f: f.index)
    whole = sorted(remote_client.particles(balls, r_inner=0.05), key=lambda f: f.index)
    assert [f.index for f in streamed] == [f.index for f in whole] == [0, 1, 2]
    for a, b in zip(streamed, whole):
        assert_closed(a)
        # The same surface; only the quantization grid differs (an open sequence's box is grown).
        assert abs(len(a.triangles) - len(b.triangles)) <= 0.02 * len(b.triangles)


def test_submit_of_a_generator_starts_the_job_at_its_first_frame(remote_client, server_address):
    """Client.submit with a generator returns the id once every frame is in the job, the job having surfaced frame 0
    while the generator was still producing; the frames are those of the same frames submitted as a list."""
    name = "submit-generator"
    bounds = (-0.5, -0.5, -0.5, 0.6, 0.5, 0.5)  # the same quantization grid for both submissions
    balls = [lattice_ball(0.3, 0.05) + [0.03 * k, 0.0, 0.0] for k in range(4)]
    seen = []
    with surfacer.Client(server_address) as other:
        def frames():
            yield balls[0]
            deadline = time.monotonic() + WAIT
            while time.monotonic() < deadline and not any(
                    j["name"] == name and j["frames_done"] >= 1 for j in other.list(["running"])):
                time.sleep(0.02)
            seen.append(any(j["name"] == name and j["frames_done"] >= 1 for j in other.list()))
            yield from balls[1:]

        job_id = remote_client.submit("particles", frames(), r_inner=0.05, name=name, quantization_bounds=bounds)
    assert seen == [True], "frame 0 was not done while the generator was still producing"
    assert remote_client.status(job_id)["frames_total"] == 4
    streamed = sorted(remote_client.watch(job_id), key=lambda f: f.index)
    whole_id = remote_client.submit("particles", balls, r_inner=0.05, quantization_bounds=bounds)
    whole = sorted(remote_client.watch(whole_id), key=lambda f: f.index)
    assert [f.index for f in streamed] == [f.index for f in whole] == [0, 1, 2, 3]
    for a, b in zip(streamed, whole):
        assert np.array_equal(a.vertices, b.vertices) and np.array_equal(a.triangles, b.triangles)


def test_submit_of_a_generator_with_a_nan_frame_fails_the_job_naming_it(remote_client):
    """A frame that is refused in the middle (a NaN coordinate) fails the job naming that frame and what is wrong;
    submit raises JobFailed naming the job, whose frames before it are kept."""
    name = "submit-nan-frame"

    def frames():
        for k in range(3):
            yield lattice_ball(0.3, 0.05) + [0.02 * k, 0.0, 0.0]
        bad = lattice_ball(0.3, 0.05)
        bad[7, 1] = np.nan
        yield bad
        yield lattice_ball(0.3, 0.05)

    with pytest.raises(surfacer.JobFailed) as failure:
        remote_client.submit("particles", frames(), r_inner=0.05, name=name)
    message = str(failure.value)
    assert "frame 3" in message and "not finite" in message, message
    job_id = next(j["id"] for j in remote_client.list() if j["name"] == name)
    assert job_id in message
    kept = []
    with pytest.raises(surfacer.JobFailed, match="frame 3"):
        for frame in remote_client.watch(job_id):
            kept.append(frame.index)
    assert sorted(kept) == [0, 1, 2]
    state = remote_client.status(job_id)
    assert state["state"] == "JOB_STATE_FAILED"
    assert "frame 3" in state["error"]["message"] and "not finite" in state["error"]["message"], state
