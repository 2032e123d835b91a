// surfacer._surfacer: the C++ client library (client/) as a Python extension. Jobs are built by prepare_job() from the
// job's proto fields set through the CLI's own option table (client/job_fields.h), inputs uploaded by upload_inputs(),
// frames received by JobWatcher (CRC checks, reconnect and resume) and decoded by decode_frame(): the Python package
// adds only the mapping of keyword arguments onto that table and the conversion of arrays and dicts. The public API
// (classes, docstrings) is python/surfacer/__init__.py.
#include <google/protobuf/descriptor.h>
#include <google/protobuf/reflection.h>
#include <google/protobuf/timestamp.pb.h>
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <atomic>
#include <cctype>
#include <condition_variable>
#include <cstdlib>
#include <deque>
#include <filesystem>
#include <functional>
#include <iostream>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "client/commands.h"
#include "client/connection.h"
#include "client/frame_writer.h"
#include "client/health.h"
#include "client/job_fields.h"
#include "client/job_spec.h"
#include "client/progress.h"
#include "client/security.h"
#include "client/server_list.h"
#include "client/summary.h"
#include "client/upload.h"
#include "client/vdb_writer.h"
#include "client/watch.h"
#include "core/mesh/frame_codec.h"
#include "core/mesh/mesh_io.h"
#include "core/particles/particle_io.h"
#include "core/util/errors.h"
#include "core/util/format.h"
#include "core/util/parallel.h"
#include "wire/output.h"

namespace py = pybind11;

namespace surfacer::client {
namespace {

// ---- errors ------------------------------------------------------------------------------------------------------

// The gRPC code name a client-side failure stands for, when the error is not a server's answer.
std::string code_of(const CliError& e) {
  if (e.status_code()) return status_code_name(static_cast<grpc::StatusCode>(*e.status_code()));
  switch (e.code()) {
    case ExitCode::kUsage:
      return "INVALID_ARGUMENT";
    case ExitCode::kUnreachable:
      return "UNAVAILABLE";
    case ExitCode::kCancelled:
      return "CANCELLED";
    case ExitCode::kIntegrity:
      return "DATA_LOSS";
    case ExitCode::kJobFailed:
      return "UNKNOWN";
    default:
      return "INTERNAL";
  }
}

// Raises the surfacer.Error subclass of the CLI's exit code (python/surfacer/_errors.py) with `.code` (gRPC code name)
// and `.exit_code` (what the CLI would exit with).
void raise_error(ExitCode exit_code, const std::string& code, const std::string& message) {
  const char* name = "Error";
  switch (exit_code) {
    case ExitCode::kUsage:
      name = "UsageError";
      break;
    case ExitCode::kUnreachable:
      name = "Unreachable";
      break;
    case ExitCode::kJobFailed:
      name = "JobFailed";
      break;
    case ExitCode::kCancelled:
      name = "Cancelled";
      break;
    case ExitCode::kIntegrity:
      name = "IntegrityError";
      break;
    default:
      break;
  }
  py::object cls = py::module_::import("surfacer._errors").attr(name);
  py::object error = cls(message, code, to_int(exit_code));
  PyErr_SetObject(cls.ptr(), error.ptr());
}

// ---- protobuf messages as Python values -------------------------------------------------------------------------

py::object to_python(const google::protobuf::Message& message);

py::object field_value(const google::protobuf::Message& message, const google::protobuf::FieldDescriptor* field,
                       int index) {
  using FD = google::protobuf::FieldDescriptor;
  const google::protobuf::Reflection* r = message.GetReflection();
  const bool repeated = field->is_repeated();
  switch (field->cpp_type()) {
    case FD::CPPTYPE_INT32:
      return py::int_(repeated ? r->GetRepeatedInt32(message, field, index) : r->GetInt32(message, field));
    case FD::CPPTYPE_INT64:
      return py::int_(repeated ? r->GetRepeatedInt64(message, field, index) : r->GetInt64(message, field));
    case FD::CPPTYPE_UINT32:
      return py::int_(repeated ? r->GetRepeatedUInt32(message, field, index) : r->GetUInt32(message, field));
    case FD::CPPTYPE_UINT64:
      return py::int_(repeated ? r->GetRepeatedUInt64(message, field, index) : r->GetUInt64(message, field));
    case FD::CPPTYPE_DOUBLE:
      return py::float_(repeated ? r->GetRepeatedDouble(message, field, index) : r->GetDouble(message, field));
    case FD::CPPTYPE_FLOAT:
      return py::float_(repeated ? r->GetRepeatedFloat(message, field, index) : r->GetFloat(message, field));
    case FD::CPPTYPE_BOOL:
      return py::bool_(repeated ? r->GetRepeatedBool(message, field, index) : r->GetBool(message, field));
    case FD::CPPTYPE_ENUM:
      return py::str((repeated ? r->GetRepeatedEnum(message, field, index) : r->GetEnum(message, field))->name());
    case FD::CPPTYPE_STRING:
      if (field->type() == FD::TYPE_BYTES) {
        return py::bytes(repeated ? r->GetRepeatedString(message, field, index) : r->GetString(message, field));
      }
      return py::str(repeated ? r->GetRepeatedString(message, field, index) : r->GetString(message, field));
    case FD::CPPTYPE_MESSAGE:
      return to_python(repeated ? r->GetRepeatedMessage(message, field, index) : r->GetMessage(message, field));
  }
  return py::none();
}

// A message as a dict keyed by the proto's field names: scalars always (their defaults included), messages and oneof
// members when set, repeated fields as lists, maps as dicts, enums by name, Timestamps as seconds since the epoch.
py::object to_python(const google::protobuf::Message& message) {
  if (const auto* ts = dynamic_cast<const google::protobuf::Timestamp*>(&message)) {
    return py::float_(static_cast<double>(ts->seconds()) + ts->nanos() * 1e-9);
  }
  const google::protobuf::Descriptor* d = message.GetDescriptor();
  const google::protobuf::Reflection* r = message.GetReflection();
  py::dict out;
  for (int i = 0; i < d->field_count(); ++i) {
    const google::protobuf::FieldDescriptor* field = d->field(i);
    if (field->is_map()) {
      py::dict map;
      for (int k = 0; k < r->FieldSize(message, field); ++k) {
        const google::protobuf::Message& entry = r->GetRepeatedMessage(message, field, k);
        const google::protobuf::Descriptor* e = entry.GetDescriptor();
        map[field_value(entry, e->field(0), -1)] = field_value(entry, e->field(1), -1);
      }
      out[py::str(field->name())] = map;
    } else if (field->is_repeated()) {
      py::list list;
      for (int k = 0; k < r->FieldSize(message, field); ++k) list.append(field_value(message, field, k));
      out[py::str(field->name())] = list;
    } else if (field->has_presence() && !r->HasField(message, field)) {
      if (field->containing_oneof() == nullptr) out[py::str(field->name())] = py::none();
    } else {
      out[py::str(field->name())] = field_value(message, field, -1);
    }
  }
  return out;
}

// ---- keyword arguments onto the job's proto fields ------------------------------------------------------------------

using Setter = std::function<void(py::handle value, const std::string& keyword)>;
// A keyword: how it sets the job, and its value's annotation in the package's type stubs (python/gen_stubs.py).
struct Keyword {
  Setter set;
  std::string type;
};
using Setters = std::map<std::string, Keyword>;

std::string text_of(py::handle value) { return py::str(value).cast<std::string>(); }

bool is_path_like(py::handle value) { return py::isinstance<py::str>(value) || py::hasattr(value, "__fspath__"); }
std::string path_of(py::handle value) { return py::module_::import("os").attr("fspath")(value).cast<std::string>(); }

// A keyword's value as the text the option table parses (client/job_fields.h): bools "true"/"false", numbers in full
// precision, sequences of numbers "1,2,3", strings (enum names, "d,n" flow lists) as they are; a list of strings is
// joined ("flows": ["d", "n"]).
std::string table_text(py::handle value, const std::string& keyword, bool words) {
  if (py::isinstance<py::bool_>(value)) return value.cast<bool>() ? "true" : "false";
  if (py::isinstance<py::str>(value)) {
    if (!words) throw py::type_error(keyword + "=" + text_of(py::repr(value)) + " has the wrong type (a number)");
    return value.cast<std::string>();
  }
  if (py::isinstance<py::int_>(value)) return text_of(value);
  if (py::isinstance<py::float_>(value)) return format_number(value.cast<double>());
  if (py::isinstance<py::bytes>(value) || py::isinstance<py::dict>(value)) {
    throw py::type_error(keyword + "=" + text_of(py::repr(value)) + " has the wrong type");
  }
  if (py::isinstance<py::sequence>(value) || py::isinstance<py::array>(value)) {
    std::string text;
    for (py::handle item : value) text += (text.empty() ? "" : ",") + table_text(item, keyword, words);
    return text;
  }
  // numpy scalars: whole numbers by __index__, the others by __float__ (at full precision).
  if (py::hasattr(value, "__index__")) return text_of(py::int_(py::reinterpret_borrow<py::object>(value)));
  if (py::hasattr(value, "__float__")) {
    return format_number(py::float_(py::reinterpret_borrow<py::object>(value)).cast<double>());
  }
  throw py::type_error(keyword + "=" + text_of(py::repr(value)) + " has the wrong type");
}

// Every field of `table` under its keyword and its aliases' (client/job_fields.h), setting it in job.spec.
void add_table(Setters& s, JobOptions& job, JobTable table) {
  for (const JobField& field : job_fields(table)) {
    const bool words = takes_words(table, field);
    const Setter set = [&job, table, &field, words](py::handle value, const std::string& name) {
      set_job_field(job.spec, table, field, table_text(value, name, words), name, job.names);
    };
    const std::string type = python_type(table, field);
    s[keyword(spelling(field))] = {set, type};
    for (const std::string& alias : field.aliases) s[keyword(alias)] = {set, type};
  }
}

// Applies `kwargs` through `setters`; an unknown keyword is a TypeError naming it, None leaves the default.
void apply(const py::dict& kwargs, const Setters& setters, const std::string& function) {
  for (auto [key, value] : kwargs) {
    const std::string name = key.cast<std::string>();
    const auto it = setters.find(name);
    if (it == setters.end()) {
      std::string known;
      for (const auto& [k, unused] : setters) known += (known.empty() ? "" : ", ") + k;
      throw py::type_error(function + "() got an unexpected keyword argument '" + name + "' (it takes " + known + ")");
    }
    if (value.is_none()) continue;
    try {
      it->second.set(value, name);
    } catch (const py::cast_error&) {
      throw py::type_error(function + "(): " + name + "=" + text_of(py::repr(value)) + " has the wrong type");
    }
  }
}

// Inputs of one call: scenes and particle frames given as dicts and arrays are kept here, under keys that stand for
// them in the options ("scene[0]", "frame[2]").
struct Inputs {
  InMemoryInputs memory;
  int first_frame = 0;  // the sequence's index of the first particle frame given (frames appended to an open job)

  // A scene: a path, or a dict in protobuf's JSON mapping of surfacer.v1.Scene.
  std::filesystem::path scene(py::handle value, const std::string& what) {
    if (is_path_like(value)) return path_of(value);
    if (!py::isinstance<py::dict>(value)) {
      throw py::type_error(what + " must be a scene dict or a path to a scene JSON file, not " +
                           text_of(py::repr(value)));
    }
    const std::string key = what;
    memory.scenes[key] = py::module_::import("json").attr("dumps")(value).cast<std::string>();
    return key;
  }

  // A dict frame {"positions": (N,3) or (N,4) array, "radii": (N,) optional, NAME: (N,) or (N,k) array, ...}: every
  // other key an attribute of k = 1..4 components (interpolate= names the ones carried onto the mesh).
  ParticleFrame dict_frame(const py::dict& item, const std::string& key) {
    if (!item.contains("positions")) throw py::type_error(key + " is a dict without \"positions\"");
    ParticleFrame frame = array_frame(item["positions"], key + "[\"positions\"]");
    const std::size_t n = frame.positions.size();
    for (auto [k, value] : item) {
      const std::string name = py::str(k).cast<std::string>();
      if (name == "positions") continue;
      const auto array = py::array_t<double, py::array::c_style | py::array::forcecast>::ensure(value);
      const bool ok = array && (array.ndim() == 1 || array.ndim() == 2) &&
                      static_cast<std::size_t>(array.shape(0)) == n &&
                      (array.ndim() == 1 || (array.shape(1) >= 1 && array.shape(1) <= Attribute::kMaxComponents));
      if (!ok) {
        throw py::type_error(key + "[\"" + name + "\"] must be an (N,) or (N,k) array, k in 1.." +
                             std::to_string(Attribute::kMaxComponents) + ", with N = " + std::to_string(n) +
                             " (one row per particle)");
      }
      const int components = array.ndim() == 1 ? 1 : static_cast<int>(array.shape(1));
      const double* data = array.data();
      if (name == "radii" && components == 1) {
        frame.radii.assign(data, data + n);
        continue;
      }
      Attribute attribute{name, components, {}};
      attribute.values.assign(data, data + n * static_cast<std::size_t>(components));
      frame.attributes.push_back(std::move(attribute));
    }
    return frame;
  }

  static ParticleFrame array_frame(py::handle item, const std::string& key) {
    const auto array = py::array_t<double, py::array::c_style | py::array::forcecast>::ensure(item);
    if (!array || array.ndim() != 2 || (array.shape(1) != 3 && array.shape(1) != 4)) {
      const std::string got =
          array ? "an array of shape " + text_of(array.attr("shape")) : text_of(py::repr(py::type::of(item)));
      throw py::type_error(key + " must be an (N,3) array of positions, an (N,4) array of positions and radii, " +
                           "a dict {\"positions\": P, NAME: values, ...} or a particle file or pattern, not " + got);
    }
    ParticleFrame frame;
    const auto a = array.unchecked<2>();
    frame.positions.reserve(static_cast<std::size_t>(a.shape(0)));
    for (py::ssize_t k = 0; k < a.shape(0); ++k) frame.positions.emplace_back(a(k, 0), a(k, 1), a(k, 2));
    if (a.shape(1) == 4) {
      for (py::ssize_t k = 0; k < a.shape(0); ++k) frame.radii.push_back(a(k, 3));
    }
    return frame;
  }

  // One input per item: (N,3) positions, (N,4) positions and radii, a dict frame (dict_frame), or a file or pattern
  // (fluid_{:04d}.bgeo). A single array, dict or path is one input.
  std::vector<std::string> particle_inputs(py::handle frames) {
    std::vector<py::handle> items;
    if (py::isinstance<py::array>(frames) || is_path_like(frames) || py::isinstance<py::dict>(frames)) {
      items.push_back(frames);
    } else {
      for (py::handle item : frames) items.push_back(item);
    }
    std::vector<std::string> inputs;
    for (std::size_t i = 0; i < items.size(); ++i) {
      const std::string key = "frame[" + std::to_string(first_frame + static_cast<int>(i)) + "]";
      if (is_path_like(items[i])) {
        inputs.push_back(path_of(items[i]));
        continue;
      }
      ParticleFrame frame = py::isinstance<py::dict>(items[i])
                                ? dict_frame(py::reinterpret_borrow<py::dict>(items[i]), key)
                                : array_frame(items[i], key);
      memory.particles[key] = std::move(frame);
      inputs.push_back(key);
    }
    return inputs;
  }
};

// name and the output table (encoding, normals, quantization_bits, ...): every job type's output options.
void add_common(Setters& s, JobOptions& job) {
  s["name"] = {[&job](py::handle v, const std::string&) { job.name = v.cast<std::string>(); }, "str"};
  add_table(s, job, JobTable::kOutput);  // encoding, normals, quantization_bits, quantization_bounds, decimate
}

void add_particle_range(Setters& s, ParticleInputOptions& input) {
  s["start"] = {[&input](py::handle v, const std::string&) { input.start = v.cast<int>(); }, "int"};
  s["end"] = {[&input](py::handle v, const std::string&) { input.end = v.cast<int>(); }, "int"};
}

constexpr const char* kPathType = "Union[str, os.PathLike[str]]";
constexpr const char* kSceneType = "Union[Dict[str, Any], str, os.PathLike[str]]";

// The keywords of a call of `kind` (every one but the positional inputs), setting `job`; scenes given as dicts are
// kept in `in`. Keywords are the job's proto fields (client/job_fields.h, as the CLI's flags) and a few of the
// client's own (inputs, frame range, output).
Setters job_setters(const std::string& kind, JobOptions& job, Inputs& in) {
  Setters s;
  add_common(s, job);
  if (kind == "isosurface") {
    table_message(job.spec, JobTable::kIsosurface);
    add_table(s, job, JobTable::kIsosurface);
  } else if (kind == "particles") {
    table_message(job.spec, JobTable::kParticles);
    add_table(s, job, JobTable::kParticles);
    add_particle_range(s, job.particles);
    const Setter container = [&job, &in](py::handle v, const std::string& name) {
      job.container_scene = in.scene(v, name);
    };
    s["container_solid"] = {container, kSceneType};
    s["container_scene"] = {container, kSceneType};
  } else if (kind == "optimize") {
    table_message(job.spec, JobTable::kOptimize);
    add_table(s, job, JobTable::kOptimize);
    s["start_mesh"] = {[&job](py::handle v, const std::string&) { job.start_mesh = path_of(v); }, kPathType};
  } else if (kind == "active_coat") {
    table_message(job.spec, JobTable::kCoat);
    add_table(s, job, JobTable::kActive);
    add_table(s, job, JobTable::kCoat);
    add_particle_range(s, job.particles);
  } else if (kind == "active_morph") {
    table_message(job.spec, JobTable::kMorph);
    add_table(s, job, JobTable::kActive);
    add_table(s, job, JobTable::kMorph);
  } else if (kind == "active_advect") {
    table_message(job.spec, JobTable::kAdvect);
    add_table(s, job, JobTable::kActive);
    add_table(s, job, JobTable::kAdvect);
    s["velocity_grid"] = {[&job](py::handle v, const std::string&) { job.velocity_grid = path_of(v); }, kPathType};
  } else {
    throw py::value_error("unknown job kind '" + kind +
                          "': isosurface, particles, optimize, active_coat, active_morph or active_advect");
  }
  return s;
}

// The keywords of `kind` as [(keyword, annotation)], sorted: what the type stubs list (python/gen_stubs.py).
std::vector<std::pair<std::string, std::string>> job_keywords(const std::string& kind) {
  JobOptions job;
  Inputs in;
  std::vector<std::pair<std::string, std::string>> out;
  for (const auto& [name, k] : job_setters(kind, job, in)) out.emplace_back(name, k.type);
  return out;
}

// The JobOptions of a call of `kind` with its positional `inputs` and keyword `kwargs`, dicts and arrays kept in
// `in`. Values are checked by prepare_job with the server's own checks.
JobOptions job_options(const std::string& kind, const py::tuple& inputs, const py::dict& kwargs, Inputs& in) {
  const auto need = [&](std::size_t count, const char* what) {
    if (inputs.size() != count) {
      throw py::type_error(kind + "() takes " + what + " (" + std::to_string(inputs.size()) + " given)");
    }
  };
  JobOptions job;
  job.keywords = true;
  const Setters s = job_setters(kind, job, in);
  if (kind == "isosurface") {
    need(1, "one positional argument: a scene or a list of scenes (dicts or paths)");
    apply(kwargs, s, kind);
    py::handle scenes = inputs[0];
    if (py::isinstance<py::dict>(scenes) || is_path_like(scenes)) {
      job.scenes.push_back(in.scene(scenes, "scene[0]"));
    } else {
      for (py::handle scene : scenes)
        job.scenes.push_back(in.scene(scene, "scene[" + std::to_string(job.scenes.size()) + "]"));
    }
  } else if (kind == "particles") {
    need(1, "one positional argument: a list of frames ((N,3) arrays or file paths/patterns)");
    apply(kwargs, s, kind);
    job.particles.inputs = in.particle_inputs(inputs[0]);
  } else if (kind == "optimize") {
    need(1, "one positional argument: the scene (a dict or a path)");
    apply(kwargs, s, kind);
    if (job.start_mesh && job.spec.optimize().has_polygonize()) {
      throw CliError(ExitCode::kUsage, "start_mesh and " + names_below(job.names, "spec.optimize.polygonize") +
                                           " both give the start mesh: give one");
    }
    job.scenes.push_back(in.scene(inputs[0], "scene"));
  } else if (kind == "active_coat") {
    need(1, "one positional argument: a list of particle frames ((N,3) arrays or file paths/patterns)");
    apply(kwargs, s, kind);
    job.particles.inputs = in.particle_inputs(inputs[0]);
  } else if (kind == "active_morph") {
    need(2, "two positional arguments: the scenes to morph from and to (dicts or paths)");
    apply(kwargs, s, kind);
    job.scenes.push_back(in.scene(inputs[0], "from"));
    job.scenes.push_back(in.scene(inputs[1], "to"));
  } else if (kind == "active_advect") {
    need(1, "one positional argument: the scene to advect (a dict or a path)");
    apply(kwargs, s, kind);
    if (!job.velocity_grid && !job.spec.active().advect().has_grid()) {
      job.spec.mutable_active()->mutable_advect()->mutable_enright();
    }
    job.scenes.push_back(in.scene(inputs[0], "scene"));
  }
  return job;
}

// ---- blocking calls ----------------------------------------------------------------------------------------------

// Runs `work` on a helper thread with the GIL released, checking for Python signals (Ctrl-C) every 100 ms. On one,
// `on_interrupt` runs (e.g. sets a stop flag the work watches), the work is waited for, and the KeyboardInterrupt is
// raised. The work's own exception is rethrown.
template <typename T>
T interruptible(std::function<T()> work, const std::function<void()>& on_interrupt) {
  std::mutex mutex;
  std::condition_variable cv;
  bool done = false;
  std::optional<T> result;
  std::exception_ptr error;
  std::thread thread([&] {
    try {
      result.emplace(work());
    } catch (...) {
      error = std::current_exception();
    }
    std::lock_guard lock(mutex);
    done = true;
    cv.notify_all();
  });
  while (true) {
    {
      py::gil_scoped_release release;
      std::unique_lock lock(mutex);
      cv.wait_for(lock, std::chrono::milliseconds(100), [&] { return done; });
    }
    bool finished = false;
    {
      std::lock_guard lock(mutex);
      finished = done;
    }
    if (finished) break;
    if (PyErr_CheckSignals() != 0) {
      py::error_already_set interrupt;
      {
        py::gil_scoped_release release;
        on_interrupt();
        thread.join();
      }
      throw interrupt;
    }
  }
  thread.join();
  if (error) std::rethrow_exception(error);
  return std::move(*result);
}

// ---- the client --------------------------------------------------------------------------------------------------

class Client {
 public:
  Client(std::optional<std::string> server, std::optional<std::string> token, std::optional<std::string> token_file,
         bool tls, std::optional<std::string> tls_ca, std::optional<std::string> tls_cert,
         std::optional<std::string> tls_key, std::optional<std::string> tls_server_name, bool allow_insecure,
         std::optional<double> timeout, std::optional<int> workers) {
    ConnectOptions options;
    options.server = server;
    if (timeout) options.timeout_seconds = *timeout;
    options.workers = workers;
    if (options.server) check_server_ports(*options.server);
    check_workers(options);
    SecurityFlags flags;
    flags.token = token;
    if (token_file) flags.token_file = *token_file;
    flags.tls = tls;
    if (tls_ca) flags.tls_ca = *tls_ca;
    if (tls_cert) flags.tls_cert = *tls_cert;
    if (tls_key) flags.tls_key = *tls_key;
    flags.tls_server_name = tls_server_name;
    flags.allow_insecure = allow_insecure;
    options.security = load_security(flags, std::getenv("SURFACER_TOKEN"), !options.local());
    py::gil_scoped_release release;
    connection_ = std::shared_ptr<Connection>(Connection::open(options));
  }

  // Drops this handle's share of the connection (the in-process server stops once no Job uses it either).
  void close() {
    std::shared_ptr<Connection> connection;
    connection.swap(connection_);
    py::gil_scoped_release release;
    connection.reset();
  }

  Connection& connection() {
    if (!connection_) throw CliError(ExitCode::kUsage, "the client is closed");
    return *connection_;
  }
  const std::shared_ptr<Connection>& shared() {
    connection();
    return connection_;
  }
  bool local() { return connection().local(); }
  std::string describe() { return connection().describe(); }

  // Prepares the job, uploads its inputs and submits it as the CLI's submit does (submit_with_inputs: a particle
  // sequence joins its job frame by frame on a server that takes open sequences), returning once every input is in
  // the job; Ctrl-C before the job is queued abandons the uploads (no job), after it cancels the job.
  std::string submit(const std::string& kind, const py::tuple& inputs, const py::dict& kwargs) {
    return submit_job_of(kind, inputs, kwargs, /*open=*/false);
  }

  // submit() and submit_open(): the spec as prepared, or opened for frames that join it.
  std::string submit_job_of(const std::string& kind, const py::tuple& inputs, const py::dict& kwargs, bool open) {
    auto in = std::make_shared<Inputs>();
    const JobOptions options = job_options(kind, inputs, kwargs, *in);
    auto prepared = std::make_shared<PreparedJob>(prepare_job(options, in->memory));
    fit_encoding_to_memory(prepared->spec);
    Connection& connection = this->connection();
    auto stop = std::make_shared<std::atomic<bool>>(false);
    return interruptible<std::string>(
        [&connection, in, prepared, stop, open]() {
          std::ostringstream quiet;
          ProgressDisplay progress(quiet, false);
          if (!open) return submit_with_inputs(connection, *prepared, progress, stop.get());
          upload_inputs(connection, prepared->spec, prepared->uploads, progress, stop.get());
          if (*stop) throw CliError(ExitCode::kCancelled, "interrupted before the job was submitted");
          const std::string id = submit_job(connection, open_sequence_spec(prepared->spec));
          if (*stop) cancel_job(connection, id);
          return id;
        },
        [stop] { *stop = true; });
  }

  // --- Open sequences (client/upload.h): a job submitted with its first frame, the others appended as they come.

  // Whether the server takes open sequences (ServerInfo.open_sequences).
  bool open_sequences() {
    py::gil_scoped_release release;
    const auto& info = connection().server_info();
    return info && info->open_sequences();
  }

  // As submit(), with the job open (ParticlesJob.open): `inputs` holds its first frame.
  std::string submit_open(const std::string& kind, const py::tuple& inputs, const py::dict& kwargs) {
    return submit_job_of(kind, inputs, kwargs, /*open=*/true);
  }

  // Prepares `inputs` (one frame, frame `index` of the sequence, as errors name it) with the job's keywords, as
  // submit() would, uploads it and appends it to the open job `job_id` (called from the thread that drains the
  // caller's iterable; the GIL is released while uploading).
  void append(const std::string& job_id, const std::string& kind, const py::tuple& inputs, const py::dict& kwargs,
              int index) {
    Inputs in;
    in.first_frame = index;
    const JobOptions options = job_options(kind, inputs, kwargs, in);
    PreparedJob prepared = prepare_job(options, in.memory);
    Connection& connection = this->connection();
    py::gil_scoped_release release;
    std::ostringstream quiet;
    ProgressDisplay progress(quiet, false);
    upload_inputs(connection, prepared.spec, prepared.uploads, progress);
    append_frames(connection, job_id, {prepared.spec.particles().frames(0)}, false);
  }

  // Ends the open job's sequence, or with `abort_reason` fails the job with it.
  void end(const std::string& job_id, const std::string& abort_reason) {
    Connection& connection = this->connection();
    py::gil_scoped_release release;
    append_frames(connection, job_id, {}, abort_reason.empty(), abort_reason);
  }

  py::object status(const std::string& id) {
    v1::Job job;
    {
      py::gil_scoped_release release;
      job = get_job(connection(), id);
    }
    return to_python(job);
  }

  py::list list(const std::vector<std::string>& states) {
    std::vector<v1::Job> jobs;
    {
      py::gil_scoped_release release;
      jobs = list_jobs(connection(), states);
    }
    py::list out;
    for (const v1::Job& job : jobs) out.append(to_python(job));
    return out;
  }

  py::object cancel(const std::string& id) {
    v1::Job job;
    {
      py::gil_scoped_release release;
      job = request_cancel(connection(), id);
    }
    return to_python(job);
  }

  std::string health(const std::string& service) {
    HealthStatus status;
    {
      py::gil_scoped_release release;
      status = check_health(connection().channel_ptr(), service, connection().unary_deadline());
    }
    return health_status_name(status);
  }

  py::object server_info() {
    std::optional<v1::ServerInfo> info;
    {
      py::gil_scoped_release release;
      info = connection().server_info();
    }
    return info ? to_python(*info) : py::none();
  }

 private:
  std::shared_ptr<Connection> connection_;
};

// A decoded frame, waiting to be handed to Python.
struct DecodedFrame {
  int index = 0;
  Mesh mesh;
  v1::FrameStats stats;
};

// (vertices (N,3) float64, triangles (M,3) int32, normals (N,3) float64 or None) of a mesh.
// Mesh::attributes as {name: float32 array}, (N,) for a scalar, (N,k) for k components.
py::dict attribute_arrays(const Mesh& mesh) {
  py::dict out;
  for (const Attribute& a : mesh.attributes) {
    const auto n = static_cast<py::ssize_t>(a.count());
    py::array_t<float> array =
        a.components == 1 ? py::array_t<float>({n}) : py::array_t<float>({n, static_cast<py::ssize_t>(a.components)});
    std::copy(a.values.begin(), a.values.end(), array.mutable_data());
    out[py::str(a.name)] = array;
  }
  return out;
}

// (vertices, triangles, normals or None, attributes): a mesh as numpy arrays.
py::tuple mesh_arrays(const Mesh& mesh) {
  auto rows = [](const auto& items, auto element) {
    using T = decltype(element);
    py::array_t<T> array({static_cast<py::ssize_t>(items.size()), py::ssize_t{3}});
    auto a = array.template mutable_unchecked<2>();
    for (py::ssize_t i = 0; i < a.shape(0); ++i) {
      for (int k = 0; k < 3; ++k) a(i, k) = static_cast<T>(items[static_cast<std::size_t>(i)][k]);
    }
    return array;
  };
  py::object normals = py::none();
  if (!mesh.normals.empty()) normals = rows(mesh.normals, double{});
  return py::make_tuple(rows(mesh.vertices, double{}), rows(mesh.triangles, std::int32_t{}), normals,
                        attribute_arrays(mesh));
}

// The frames of one job, received by a JobWatcher on a helper thread (started by the first next()) and decoded
// there; at most kQueued frames wait for Python, so a slow consumer slows the stream instead of filling memory.
class FrameStream {
 public:
  static constexpr std::size_t kQueued = 4;

  // Progress events kept for the callable between two calls of next(); beyond this many the oldest are dropped.
  static constexpr std::size_t kProgressQueued = 256;

  // `progress` (None or a callable(frame, stage, fraction)) is called on the iterating thread, from next(), with
  // every Progress event received since the previous call (it runs only while the frames are iterated), and once
  // more with stage "done" and fraction 1 when the job succeeded.
  FrameStream(std::shared_ptr<Connection> connection, std::string job_id, int from_frame, bool owns_job,
              py::object progress)
      : connection_(std::move(connection)),
        job_id_(std::move(job_id)),
        from_frame_(from_frame),
        owns_job_(owns_job),
        progress_callable_(std::move(progress)) {}

  ~FrameStream() {
    py::gil_scoped_release release;
    close_locked_out();
  }

  const std::string& job_id() const { return job_id_; }
  py::object job() const {
    std::lock_guard lock(mutex_);
    return finished_ ? to_python(result_.job) : py::none();
  }

  // The next frame as (index, vertices, triangles, normals or None, stats); StopIteration once the job succeeded and
  // every frame was returned; the job's failure or cancellation as surfacer errors. Ctrl-C cancels a job this stream
  // submitted, stops watching and raises KeyboardInterrupt.
  py::tuple next() {
    start();
    while (true) {
      std::optional<DecodedFrame> frame;
      bool finished = false;
      {
        py::gil_scoped_release release;
        std::unique_lock lock(mutex_);
        cv_.wait_for(lock, std::chrono::milliseconds(100), [&] { return !queue_.empty() || finished_; });
        if (!queue_.empty()) {
          frame = std::move(queue_.front());
          queue_.pop_front();
          cv_.notify_all();
        } else {
          finished = finished_;
        }
      }
      report_progress();
      if (frame) return frame_tuple(*frame);
      if (finished) finish();
      if (PyErr_CheckSignals() != 0) {
        py::error_already_set interrupt;
        {
          py::gil_scoped_release release;
          close_locked_out();  // cancels the job if this stream submitted it
        }
        throw interrupt;
      }
    }
  }

  // Stops watching; a job this stream submitted and that has not finished is cancelled.
  void close() {
    py::gil_scoped_release release;
    close_locked_out();
  }

  // Asks the server to cancel the job (the stream then ends with surfacer.Cancelled).
  py::object cancel() {
    v1::Job job;
    {
      py::gil_scoped_release release;
      job = request_cancel(*connection_, job_id_);
    }
    return to_python(job);
  }

 private:
  void start() {
    std::lock_guard lock(mutex_);
    if (started_ || closed_) {
      if (closed_ && !finished_) throw CliError(ExitCode::kCancelled, "stopped watching job " + job_id_);
      return;
    }
    started_ = true;
    watcher_ = std::make_unique<JobWatcher>(
        *connection_, job_id_, from_frame_, [this](const ReceivedFrame& frame) { receive(frame); }, progress_,
        ReconnectPolicy{}, /*quiet=*/true);
    if (!progress_callable_.is_none()) {
      watcher_->set_progress_handler([this](const v1::Progress& progress) {
        std::lock_guard lock(mutex_);
        if (progress_queue_.size() == kProgressQueued) progress_queue_.pop_front();
        progress_queue_.push_back(progress);
      });
    }
    thread_ = std::thread([this] { run(); });
  }

  void run() {
    WatchResult result;
    std::exception_ptr error;
    try {
      result = watcher_->run();
    } catch (...) {
      error = std::current_exception();
    }
    std::lock_guard lock(mutex_);
    result_ = std::move(result);
    error_ = error;
    finished_ = true;
    cv_.notify_all();
  }

  // On the watcher's thread: decode, then wait for room in the queue.
  void receive(const ReceivedFrame& frame) {
    const std::optional<FrameCodec> codec = wire::frame_codec(frame.encoding);
    if (!codec) throw CliError(ExitCode::kIntegrity, "frame " + std::to_string(frame.index) + ": unknown encoding");
    DecodedFrame decoded;
    decoded.index = frame.index;
    decoded.stats = frame.stats;
    try {
      decoded.mesh = decode_frame(frame.bytes, *codec, decode_threads_);
    } catch (const Error& e) {
      throw CliError(ExitCode::kIntegrity, "frame " + std::to_string(frame.index) + ": " +
                                               std::string(frame_codec_name(*codec)) +
                                               " bytes passed the CRC-32 check but do not decode: " + e.what());
    }
    std::unique_lock lock(mutex_);
    cv_.wait(lock, [&] { return queue_.size() < kQueued || closed_; });
    if (closed_) throw CliError(ExitCode::kCancelled, "stopped watching job " + job_id_);
    queue_.push_back(std::move(decoded));
    cv_.notify_all();
  }

  // Raises the end of the stream: StopIteration after success, else the error or the job's terminal state.
  [[noreturn]] void finish() {
    std::exception_ptr error;
    v1::Job job;
    {
      std::lock_guard lock(mutex_);
      error = error_;
      job = result_.job;
    }
    if (error) std::rethrow_exception(error);
    const std::string reason = job_error_text(job);
    switch (job.state()) {
      case v1::JOB_STATE_SUCCEEDED:
        // A job may finish before its stream sent any progress: the callable always hears the end, once.
        if (!progress_callable_.is_none() && !progress_done_) {
          progress_done_ = true;
          progress_callable_(std::max(0, job.frames_total() - 1), "done", 1.0);
        }
        throw py::stop_iteration();
      case v1::JOB_STATE_CANCELLED:
        throw CliError(ExitCode::kCancelled,
                       "job " + job.id() + " was cancelled" + (reason.empty() ? "" : ": " + reason),
                       static_cast<int>(grpc::StatusCode::CANCELLED));
      default:
        throw CliError(ExitCode::kJobFailed, "job " + job.id() + " failed" + (reason.empty() ? "" : ": " + reason),
                       job.error().code() != 0 ? std::optional<int>(job.error().code()) : std::nullopt);
    }
  }

  // Without the GIL: ends the watcher and joins it; cancels an owned job that did not finish.
  void close_locked_out() {
    bool cancel = false;
    {
      std::lock_guard lock(mutex_);
      if (closed_) return;
      closed_ = true;
      cancel = owns_job_ && !finished_;
      cv_.notify_all();
    }
    if (cancel) cancel_job(*connection_, job_id_);
    if (watcher_) watcher_->stop();
    if (thread_.joinable()) thread_.join();
  }

  // With the GIL: calls the progress callable with the events received so far (its exception propagates).
  void report_progress() {
    if (progress_callable_.is_none()) return;
    std::deque<v1::Progress> events;
    {
      std::lock_guard lock(mutex_);
      events.swap(progress_queue_);
    }
    for (const v1::Progress& p : events) progress_callable_(p.frame_index(), p.stage(), p.fraction());
  }

  static py::tuple frame_tuple(const DecodedFrame& frame) {
    const py::tuple arrays = mesh_arrays(frame.mesh);
    return py::make_tuple(frame.index, arrays[0], arrays[1], arrays[2], to_python(frame.stats), arrays[3]);
  }

  std::shared_ptr<Connection> connection_;
  std::string job_id_;
  int from_frame_;
  bool owns_job_;
  int decode_threads_ = resolve_threads(0);     // pieced frames decode on every core
  ProgressDisplay progress_{std::cerr, false};  // quiet: only reconnect lines
  std::unique_ptr<JobWatcher> watcher_;
  std::thread thread_;

  mutable std::mutex mutex_;
  std::condition_variable cv_;
  std::deque<DecodedFrame> queue_;
  std::deque<v1::Progress> progress_queue_;
  py::object progress_callable_;
  bool progress_done_ = false;  // the final ("done", 1.0) call was made
  bool started_ = false;
  bool closed_ = false;
  bool finished_ = false;
  WatchResult result_;
  std::exception_ptr error_;
};

// Whether `path` names an OpenVDB file (.vdb, any case): the client's reader and writer, not core's.
bool is_vdb(const std::string& path) { return lower_extension(path) == ".vdb"; }

// Reads a mesh file with core's reader (read_mesh: .ply, .obj, .drc, .glb or .gltf by the extension), VTK's surface
// cells (read_vtk_mesh: .vtk, .vtu, .vtp), or the zero level set of a .vdb's level set (read_vdb), as arrays.
py::tuple read_mesh_file(const std::string& path) {
  Mesh mesh;
  {
    py::gil_scoped_release release;
    try {
      const std::string extension = lower_extension(path);
      mesh = extension == ".vdb"                                                 ? read_vdb(path)
             : extension == ".vtk" || extension == ".vtu" || extension == ".vtp" ? read_vtk_mesh(path)
                                                                                 : surfacer::read_mesh(path);
    } catch (const Error& e) {
      throw CliError(ExitCode::kUsage, e.what());
    }
  }
  return mesh_arrays(mesh);
}

// Writes a mesh given as arrays with core's writer (write_mesh: .ply, .obj, .drc, .glb, .gltf, .vtk or .vtu by the
// extension), or
// the client's .vdb writer (voxel_size 0: the mesh's mean edge length).
void write_mesh_file(const std::string& path,
                     const py::array_t<double, py::array::c_style | py::array::forcecast>& vertices,
                     const py::array_t<std::int64_t, py::array::c_style | py::array::forcecast>& triangles,
                     const std::optional<py::array_t<double, py::array::c_style | py::array::forcecast>>& normals,
                     const std::optional<py::dict>& attributes, double voxel_size) {
  const auto rows = [](const auto& array, const char* what) {
    if (array.ndim() != 2 || array.shape(1) != 3) throw py::value_error(std::string(what) + " must be an (N,3) array");
    return array.shape(0);
  };
  Mesh mesh;
  const auto v = vertices.unchecked<2>();
  for (py::ssize_t i = 0, n = rows(vertices, "vertices"); i < n; ++i)
    mesh.vertices.emplace_back(v(i, 0), v(i, 1), v(i, 2));
  const auto t = triangles.unchecked<2>();
  for (py::ssize_t i = 0, n = rows(triangles, "triangles"); i < n; ++i) {
    Triangle triangle;
    for (int k = 0; k < 3; ++k) {
      if (t(i, k) < 0 || t(i, k) >= static_cast<std::int64_t>(mesh.vertices.size())) {
        throw py::value_error("triangle " + std::to_string(i) + " refers to vertex " + std::to_string(t(i, k)) +
                              ", not one of the " + std::to_string(mesh.vertices.size()));
      }
      triangle[k] = static_cast<std::uint32_t>(t(i, k));
    }
    mesh.triangles.push_back(triangle);
  }
  if (normals) {
    const auto a = normals->unchecked<2>();
    if (rows(*normals, "normals") != static_cast<py::ssize_t>(mesh.vertices.size())) {
      throw py::value_error("normals must have one row per vertex");
    }
    for (py::ssize_t i = 0; i < a.shape(0); ++i) mesh.normals.emplace_back(a(i, 0), a(i, 1), a(i, 2));
  }
  if (attributes) {
    for (auto [key, value] : *attributes) {
      const std::string name = py::str(key).cast<std::string>();
      const auto array = py::array_t<float, py::array::c_style | py::array::forcecast>::ensure(value);
      const bool ok = array &&
                      (array.ndim() == 1 ||
                       (array.ndim() == 2 && array.shape(1) >= 1 && array.shape(1) <= Attribute::kMaxComponents)) &&
                      static_cast<std::size_t>(array.shape(0)) == mesh.vertices.size();
      if (!ok) {
        throw py::value_error("attributes[\"" + name + "\"] must be an (N,) or (N,k) array, k in 1.." +
                              std::to_string(Attribute::kMaxComponents) + ", one row per vertex");
      }
      Attribute attribute{name, array.ndim() == 1 ? 1 : static_cast<int>(array.shape(1)), {}};
      attribute.values.assign(array.data(), array.data() + array.size());
      mesh.attributes.push_back(std::move(attribute));
    }
  }
  py::gil_scoped_release release;
  try {
    if (is_vdb(path)) {
      write_file_atomically(path, write_vdb(mesh, voxel_size));
    } else {
      surfacer::write_mesh(path, mesh);
    }
  } catch (const Error& e) {
    throw CliError(ExitCode::kUsage, e.what());
  }
}

}  // namespace
}  // namespace surfacer::client

PYBIND11_MODULE(_surfacer, m) {
  using namespace surfacer::client;
  m.doc() = "Surfacer's C++ client library; use the `surfacer` package, not this module.";

  py::register_exception_translator([](std::exception_ptr p) {
    try {
      if (p) std::rethrow_exception(p);
    } catch (const CliError& e) {
      raise_error(e.code(), code_of(e), e.what());
    }
  });

  py::class_<Client>(m, "Client")
      .def(py::init<std::optional<std::string>, std::optional<std::string>, std::optional<std::string>, bool,
                    std::optional<std::string>, std::optional<std::string>, std::optional<std::string>,
                    std::optional<std::string>, bool, std::optional<double>, std::optional<int>>(),
           py::arg("server"), py::arg("token"), py::arg("token_file"), py::arg("tls"), py::arg("tls_ca"),
           py::arg("tls_cert"), py::arg("tls_key"), py::arg("tls_server_name"), py::arg("allow_insecure"),
           py::arg("timeout"), py::arg("workers"))
      .def("close", &Client::close)
      .def_property_readonly("local", &Client::local)
      .def("describe", &Client::describe)
      .def("submit", &Client::submit, py::arg("kind"), py::arg("inputs"), py::arg("options"))
      .def("open_sequences", &Client::open_sequences)
      .def("submit_open", &Client::submit_open, py::arg("kind"), py::arg("inputs"), py::arg("options"))
      .def("append", &Client::append, py::arg("job_id"), py::arg("kind"), py::arg("inputs"), py::arg("options"),
           py::arg("index"))
      .def("end", &Client::end, py::arg("job_id"), py::arg("abort_reason") = "")
      .def(
          "stream",
          [](Client& client, const std::string& job_id, int from_frame, bool owns_job, py::object progress) {
            return std::make_unique<FrameStream>(client.shared(), job_id, from_frame, owns_job, std::move(progress));
          },
          py::arg("job_id"), py::arg("from_frame"), py::arg("owns_job"), py::arg("progress") = py::none())
      .def("status", &Client::status, py::arg("job_id"))
      .def("list", &Client::list, py::arg("states"))
      .def("cancel", &Client::cancel, py::arg("job_id"))
      .def("health", &Client::health, py::arg("service"))
      .def("server_info", &Client::server_info);

  m.def("read_mesh", &read_mesh_file, py::arg("path"));
  m.def("job_keywords", &job_keywords, py::arg("kind"),
        "The keyword options of a job kind as [(keyword, annotation)] (what the type stubs list).");
  m.def("write_mesh", &write_mesh_file, py::arg("path"), py::arg("vertices"), py::arg("triangles"),
        py::arg("normals") = py::none(), py::arg("attributes") = py::none(), py::arg("voxel_size") = 0.0);

  py::class_<FrameStream>(m, "FrameStream")
      .def_property_readonly("job_id", &FrameStream::job_id)
      .def_property_readonly("job", &FrameStream::job)
      .def("next", &FrameStream::next)
      .def("close", &FrameStream::close)
      .def("cancel", &FrameStream::cancel);
}
