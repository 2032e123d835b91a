"""Open sequences from Python: any iterable of frames, a generator included, is surfaced while it is still producing
(each frame joins the running job as it is yielded), against a real surfacer-server on a loopback port and the
in-process one. A generator that waits for the first mesh would wait forever if the whole sequence were uploaded
before the job started: it gives up after WAIT seconds, so that behaviour fails the test instead of hanging it."""

import threading

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
