// Runs a parsed invocation against a server: run, submit, watch, status, list, cancel, health. The unary calls
// behind them are public for the Python package, which drives the same functions.
#pragma once

#include <atomic>
#include <iosfwd>
#include <string>
#include <vector>

#include "client/connection.h"
#include "client/exit_codes.h"
#include "client/options.h"
#include "surfacer/v1/surfacer.pb.h"

namespace surfacer::client {

class ProgressDisplay;
struct PreparedJob;

// Connects (remote or in-process), runs the command and returns its exit code. Results go to `out` (job ids,
// status, lists), progress, warnings and the summary to `err`; `tty` selects the in-place progress bar.
// Throws CliError for every failure (its code is the exit code).
ExitCode run_invocation(const Invocation& invocation, std::ostream& out, std::ostream& err, bool tty);

// SubmitJob: returns the job id (and the job as queued in `job` when not null). A rejection throws
// CliError(kJobFailed) with the server's status code and message (kUnreachable when the server cannot be reached).
std::string submit_job(Connection& connection, const v1::JobSpec& spec, v1::Job* job = nullptr);
// Reads and uploads the inputs of `prepared` and submits its job, returning its id once every input is uploaded and
// part of the job. A particle sequence to a server that takes open sequences (streams_as_open_sequence) is read once
// whole first (a bad file fails before any job is queued, and the quantization box is the whole sequence's, so the
// frames are those of the job submitted whole), then queued open as soon as its first frame is uploaded, each later
// frame joining it once uploaded and the last one ending the sequence: the server surfaces the first frames while
// the others upload (docs/ALGORITHMS.md §5, "Open sequences"). Any other job, and any job for an older server: every
// input uploaded, then the job submitted. One progress line per upload. Throws as upload_inputs() and submit_job();
// once the job is queued, a frame that cannot be read or uploaded fails the job and throws its error with the job
// named (the frames before it are kept), a job that finished first (cancelled elsewhere) throws CliError(kJobFailed
// or kCancelled) naming its state, and `stop` (Ctrl-C) cancels the job: CliError(kCancelled).
std::string submit_with_inputs(Connection& connection, PreparedJob& prepared, ProgressDisplay& progress,
                               const std::atomic<bool>* stop = nullptr);
// GetJob. Throws rpc_error("status of job ID", status), e.g. NOT_FOUND.
v1::Job get_job(Connection& connection, const std::string& job_id);
// ListJobs, every page, of jobs in `states` (lower-case names, "running"; empty: all). CliError(kUsage) for an
// unknown state name, rpc_error("listing jobs", status) when the server refuses.
std::vector<v1::Job> list_jobs(Connection& connection, const std::vector<std::string>& states);
// CancelJob: the job as the server answered (terminal, or still running with the cancel requested).
v1::Job request_cancel(Connection& connection, const std::string& job_id);

}  // namespace surfacer::client
