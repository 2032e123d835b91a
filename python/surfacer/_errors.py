"""Exceptions of the surfacer package. The extension module raises them (one per exit code of the `surfacer` CLI)."""


class Error(Exception):
    """A failure reported by Surfacer.

    ``code`` is the gRPC status code name ("INVALID_ARGUMENT", "NOT_FOUND", "UNAVAILABLE", ...): the server's own
    for its answers and for a job that failed, the nearest one for a failure on this side (a bad input file is
    INVALID_ARGUMENT, a frame that fails its CRC-32 is DATA_LOSS). ``exit_code`` is what the CLI exits with for the
    same failure. ``str(error)`` is the message, which for a server's answer names the field at fault
    (``spec.isosurface.cells (-1) must be > 0``).
    """

    def __init__(self, message, code="UNKNOWN", exit_code=1):
        super().__init__(message)
        self.message = message
        self.code = code
        self.exit_code = exit_code


class UsageError(Error, ValueError):
    """A bad argument caught before anything is submitted: an unreadable or malformed scene or particle file, a bad
    bounds box, a closed client (CLI exit code 2)."""


class Unreachable(Error):
    """No server answered within the timeout, or the connection was lost for good (exit code 3)."""


class JobFailed(Error):
    """The server refused the request (e.g. INVALID_ARGUMENT naming the field, NOT_FOUND for an unknown job id,
    RESOURCE_EXHAUSTED naming the limit), or the job failed (exit code 4)."""


class Cancelled(Error):
    """The job was cancelled, or watching it was stopped (exit code 5)."""


class IntegrityError(Error):
    """A frame failed its CRC-32, size or chunk-count checks, or did not decode (exit code 6)."""
