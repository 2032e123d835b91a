// Every numeric field of one spec per job type and mode, set in turn to values at and past the edges (0, -1, tiny,
// huge, infinite, NaN; for integers 0, -1 and the extremes), submitted to a real server on a loopback port. What the
// server accepts must not fail later for a reason submit could have seen: an accepted job ends SUCCEEDED, CANCELLED
// (stopped here after a while), or FAILED with RESOURCE_EXHAUSTED (a limit only the result shows, such as
// --max-triangles). What it refuses is refused with INVALID_ARGUMENT or RESOURCE_EXHAUSTED naming the field.
#include <google/protobuf/descriptor.h>
#include <google/protobuf/util/json_util.h>
#include <gtest/gtest.h>

#include <chrono>
#include <cmath>
#include <functional>
#include <limits>
#include <thread>

#include "core/util/format.h"
#include "tests/server/test_client.h"

namespace surfacer::testing {
namespace {

using namespace std::chrono_literals;
using google::protobuf::FieldDescriptor;
using google::protobuf::Message;

v1::JobSpec spec_from_json(const std::string& json) {
  v1::JobSpec spec;
  const auto status = google::protobuf::util::JsonStringToMessage(json, &spec);
  EXPECT_TRUE(status.ok()) << status.ToString() << "\n" << json;
  return spec;
}

// A small fast job of each type and mode, with every kind of scene node.
std::vector<v1::JobSpec> base_specs() {
  const std::string particles =
      R"({"positions": [0,0,0, 0.1,0,0, 0,0.1,0, 0,0,0.1, 0.1,0.1,0, 0.1,0,0.1, 0,0.1,0.1, 0.1,0.1,0.1]})";
  return {
      spec_from_json(R"({"name": "every node", "output": {"quantizationBits": 12, "dracoSpeed": 8},
        "isosurface": {"cells": 12, "scenes": [{"root": {"union": {"blend": "BLEND_SMOOTH", "radius": 0.1, "children": [
          {"sphere": {"center": {"x": 0.1}, "radius": 0.5}},
          {"box": {"center": {"y": 0.2}, "halfSize": {"x": 0.3, "y": 0.3, "z": 0.3}}},
          {"roundedBox": {"halfSize": {"x": 0.3, "y": 0.3, "z": 0.3}, "radius": 0.1}},
          {"cylinder": {"a": {"z": -0.5}, "b": {"z": 0.5}, "radius": 0.2}},
          {"cone": {"a": {"z": -0.5}, "b": {"z": 0.5}, "radiusA": 0.3, "radiusB": 0.1}},
          {"torus": {"axis": {"z": 1}, "majorRadius": 0.4, "minorRadius": 0.1}},
          {"capsule": {"a": {"x": -0.5}, "b": {"x": 0.5}, "radius": 0.1}},
          {"intersection": {"children": [{"gyroid": {"period": 0.5, "thickness": 0.05}},
                                         {"sphere": {"radius": 0.4}}]}},
          {"difference": {"blend": "BLEND_RFUNCTION", "children": [{"sphere": {"radius": 0.4}},
                                                                   {"plane": {"normal": {"z": 1}, "offset": 0.1}}]}},
          {"blobs": {"kernel": "KERNEL_BLINN", "iso": 0.5, "blobbiness": 1.0,
                     "points": [{"center": {"x": 0.2}, "radius": 0.3, "strength": 1}],
                     "segments": [{"a": {"y": -0.2}, "b": {"y": 0.2}, "radius": 0.2, "strength": 1}]}},
          {"blobs": {"kernel": "KERNEL_WYVILL", "iso": 0.5, "points": [{"radius": 0.3}]}},
          {"transform": {"translate": {"x": 0.1}, "rotateAxis": {"z": 1}, "rotateDegrees": 30, "scale": 0.9,
                         "child": {"sphere": {"radius": 0.3}}}},
          {"transform": {"matrix": [1,0,0,0.1, 0,1,0,0, 0,0,1,0], "child": {"sphere": {"radius": 0.3}}}},
          {"grid": {"origin": {"x": -0.5, "y": -0.5, "z": -0.5}, "spacing": {"x": 1, "y": 1, "z": 1},
                    "nx": 2, "ny": 2, "nz": 2, "iso": 0, "values": [1,1,1,1,1,1,1,-1]}}]}}}]}})"),
      spec_from_json(R"({"isosurface": {"cellSize": 0.1, "bounds": {"min": {"x": -1, "y": -1, "z": -1},
        "max": {"x": 1, "y": 1, "z": 1}}, "scenes": [{"root": {"sphere": {"radius": 0.5}}}]}})"),
      spec_from_json(R"({"particles": {"rInner": 0.06, "rOuter": 0.12, "spacingFactor": 0.8, "laplacianSweeps": 2,
        "bilaplacianSweeps": 2, "polishSweeps": 1, "relaxation": 0.5, "erosion": 0.1, "minParticlesPerComponent": 1,
        "container": {"box": {"min": {"x": -1, "y": -1, "z": -1}, "max": {"x": 1, "y": 1, "z": 1}},
                      "solid": {"root": {"sphere": {"radius": 2}}}},
        "frames": [)" +
                     particles + R"(]}})"),
      spec_from_json(R"({"particles": {"deriveRInner": true, "frames": [{"positions": [0,0,0, 0.1,0,0, 0,0.1,0],
        "radii": [0.06, 0.06, 0.06]}]}})"),
      spec_from_json(R"({"optimize": {"scene": {"root": {"sphere": {"radius": 0.5}}},
        "polygonize": {"cells": 8, "bounds": {"min": {"x": -1, "y": -1, "z": -1}, "max": {"x": 1, "y": 1, "z": 1}}},
        "cD": 1, "cN": 1, "cT": 1, "stepBound": 0.5, "tFlowIterations": 2, "maxIterations": 3, "tolerance": 1e-4,
        "subdivisionThreshold": 0.5, "triangleBudget": 5000, "snapshotEvery": 1}})"),
      spec_from_json(R"({"optimize": {"scene": {"root": {"sphere": {"radius": 0.5}}},
        "polygonize": {"cellSize": 0.2}, "maxIterations": 2}})"),
      spec_from_json(R"({"active": {"gridSpacing": 0.1, "alpha": 1, "beta": 0.1, "gamma": 0.1, "delta": 0.1,
        "cfl": 0.5, "coat": {"kernelRadius": 0.3, "iso": 0.5, "frames": [)" +
                     particles + "," + particles + R"(]}}})"),
      spec_from_json(R"({"active": {"gridSpacing": 0.1, "coat": {"kernelRadius": 0.3, "substepsPerFrame": 2,
        "frames": [)" +
                     particles + R"(]}}})"),
      spec_from_json(R"({"active": {"gridSpacing": 0.1, "bounds": {"min": {"x": -1, "y": -1, "z": -1},
        "max": {"x": 1, "y": 1, "z": 1}}, "morph": {"from": {"root": {"sphere": {"radius": 0.4}}},
        "to": {"root": {"box": {"halfSize": {"x": 0.3, "y": 0.3, "z": 0.3}}}},
        "tolerance": 0.01, "maxFrames": 2, "frameTime": 0.05}}})"),
      spec_from_json(R"({"active": {"gridSpacing": 0.05, "advect": {"shape": {"root": {"sphere": {
        "center": {"x": 0.35, "y": 0.35, "z": 0.35}, "radius": 0.15}}}, "enright": {"period": 3},
        "frameInterval": 0.02, "frames": 2}}})"),
  };
}

std::vector<double> edge_doubles() {
  const double inf = std::numeric_limits<double>::infinity();
  return {0.0, -1.0, 1e-300, 1e9, 1e308, -1e308, inf, -inf, std::numeric_limits<double>::quiet_NaN()};
}
std::vector<std::int64_t> edge_ints() { return {0, -1, 1 << 30, std::numeric_limits<std::int32_t>::min()}; }

struct Variant {
  v1::JobSpec spec;
  std::string field;  // its path, "spec.isosurface.scenes[0].root.sphere.radius"
  std::string value;
};

// Every numeric field of `message` (set or not, but no member of a oneof that is not chosen, and no message that is
// not there), and element 0 of every repeated numeric field, set to each edge value in turn.
void mutate(Message& message, const std::string& path, const std::function<void()>& emit,
            std::vector<std::pair<std::string, std::string>>& where) {
  const auto* descriptor = message.GetDescriptor();
  const auto* reflection = message.GetReflection();
  for (int i = 0; i < descriptor->field_count(); ++i) {
    const FieldDescriptor* field = descriptor->field(i);
    if (field->containing_oneof() && !reflection->HasField(message, field)) continue;
    const std::string name = path + "." + field->name();
    if (field->type() == FieldDescriptor::TYPE_MESSAGE) {
      if (field->is_repeated()) {
        for (int k = 0; k < reflection->FieldSize(message, field); ++k) {
          mutate(*reflection->MutableRepeatedMessage(&message, field, k), name + "[" + std::to_string(k) + "]", emit,
                 where);
        }
      } else if (reflection->HasField(message, field)) {
        mutate(*reflection->MutableMessage(&message, field), name, emit, where);
      }
      continue;
    }
    const bool is_double =
        field->cpp_type() == FieldDescriptor::CPPTYPE_DOUBLE || field->cpp_type() == FieldDescriptor::CPPTYPE_FLOAT;
    const bool is_int =
        field->cpp_type() == FieldDescriptor::CPPTYPE_INT32 || field->cpp_type() == FieldDescriptor::CPPTYPE_INT64;
    if (!is_double && !is_int) continue;
    if (field->is_repeated() && reflection->FieldSize(message, field) == 0) continue;
    std::unique_ptr<Message> saved(message.New());
    saved->CopyFrom(message);
    const std::string item = field->is_repeated() ? name + "[0]" : name;
    auto set = [&](auto value, const std::string& text) {
      if (field->is_repeated()) {
        if (field->cpp_type() == FieldDescriptor::CPPTYPE_DOUBLE)
          reflection->SetRepeatedDouble(&message, field, 0, value);
        if (field->cpp_type() == FieldDescriptor::CPPTYPE_FLOAT)
          reflection->SetRepeatedFloat(&message, field, 0, static_cast<float>(value));
        if (field->cpp_type() == FieldDescriptor::CPPTYPE_INT32)
          reflection->SetRepeatedInt32(&message, field, 0, static_cast<std::int32_t>(value));
        if (field->cpp_type() == FieldDescriptor::CPPTYPE_INT64)
          reflection->SetRepeatedInt64(&message, field, 0, static_cast<std::int64_t>(value));
      } else {
        if (field->cpp_type() == FieldDescriptor::CPPTYPE_DOUBLE) reflection->SetDouble(&message, field, value);
        if (field->cpp_type() == FieldDescriptor::CPPTYPE_FLOAT)
          reflection->SetFloat(&message, field, static_cast<float>(value));
        if (field->cpp_type() == FieldDescriptor::CPPTYPE_INT32)
          reflection->SetInt32(&message, field, static_cast<std::int32_t>(value));
        if (field->cpp_type() == FieldDescriptor::CPPTYPE_INT64)
          reflection->SetInt64(&message, field, static_cast<std::int64_t>(value));
      }
      where.emplace_back(item, text);
      emit();
      where.pop_back();
      message.CopyFrom(*saved);
    };
    if (is_double) {
      for (double v : edge_doubles()) set(v, format_number(v));
    } else {
      for (std::int64_t v : edge_ints()) set(static_cast<double>(v), std::to_string(v));
    }
  }
}

std::vector<Variant> variants_of(const v1::JobSpec& base) {
  std::vector<Variant> out;
  v1::JobSpec spec = base;
  std::vector<std::pair<std::string, std::string>> where;
  mutate(
      spec, "spec",
      [&] {
        out.push_back({spec, where.back().first, where.back().second});
      },
      where);
  return out;
}

// The message that holds `field`: "spec.isosurface.scenes[0].root.sphere" for ".sphere.radius" and for
// ".sphere.center.x", "spec.particles.frames[0]" for ".frames[0].positions[0]". A refusal must name it (or `field`).
std::string owner_of(std::string path) {
  auto drop_last = [&] { path = path.substr(0, path.rfind('.')); };
  const std::string last = path.substr(path.rfind('.') + 1);
  if (last == "x" || last == "y" || last == "z") drop_last();
  const std::string next = path.substr(path.rfind('.') + 1);
  if (next == "min" || next == "max") drop_last();
  drop_last();
  return path;
}

// Whether `message` names `field` or a message enclosing it below the job ("spec.active.advect.shape" for
// "spec.active.advect.shape.root.sphere.radius"): a size limit made of a whole scene or frame names that.
bool names_enclosing(const std::string& message, const std::string& field) {
  for (std::size_t end = field.size(); end != std::string::npos; end = field.find_last_of(".[", end - 1)) {
    const std::string prefix = field.substr(0, end);
    if (std::count(prefix.begin(), prefix.end(), '.') < 3) break;  // "spec.<job>.<mode or list>" is too wide
    for (std::size_t at = message.find(prefix); at != std::string::npos; at = message.find(prefix, at + 1)) {
      const std::size_t after = at + prefix.size();
      if (after == message.size() ||
          !(std::isalnum(static_cast<unsigned char>(message[after])) || message[after] == '_')) {
        return true;
      }
    }
    if (end == 0) break;
  }
  return false;
}

// Failures only the run can find: the data has no surface where the job looks for one.
bool found_by_running(const std::string& message) {
  for (const char* known : {"no triangles", "no surface", "lies outside the domain"}) {
    if (message.find(known) != std::string::npos) return true;
  }
  return false;
}

TEST(SubmitValues, NothingAcceptedFailsForAReasonSubmitCouldHaveSeen) {
  auto options = LoopbackServer::default_options();
  options.workers = 4;
  options.max_queued_jobs = 1000;
  options.limits.max_frames = 1000;
  options.limits.max_grid_cells = 1 << 22;
  options.limits.max_triangles = 2'000'000;
  LoopbackServer s(options);
  std::vector<std::string> problems;
  struct Accepted {
    std::string id;
    Variant variant;
  };
  std::vector<Accepted> batch;
  int accepted = 0, refused = 0;
  auto settle = [&] {
    const auto until = std::chrono::steady_clock::now() + 5s;
    for (auto& a : batch) {
      v1::Job job = get_job(*s.stub, a.id);
      while (job.state() != v1::JOB_STATE_SUCCEEDED && job.state() != v1::JOB_STATE_FAILED &&
             job.state() != v1::JOB_STATE_CANCELLED && std::chrono::steady_clock::now() < until) {
        std::this_thread::sleep_for(5ms);
        job = get_job(*s.stub, a.id);
      }
      if (job.state() == v1::JOB_STATE_FAILED &&
          job.error().code() != static_cast<int>(grpc::StatusCode::RESOURCE_EXHAUSTED) &&
          !found_by_running(job.error().message())) {
        problems.push_back(a.variant.field + " = " + a.variant.value + ": accepted, then FAILED with " +
                           std::to_string(job.error().code()) + ": " + job.error().message());
      }
    }
    s.server->cancel_jobs("enough");
    batch.clear();
  };
  for (const v1::JobSpec& base : base_specs()) {
    std::string id;
    ASSERT_TRUE(submit(*s.stub, base, &id).ok()) << base.DebugString();
    for (Variant& v : variants_of(base)) {
      const grpc::Status status = submit(*s.stub, v.spec, &id);
      if (status.ok()) {
        ++accepted;
        batch.push_back({id, std::move(v)});
        if (batch.size() >= 16) settle();
        continue;
      }
      ++refused;
      // Bad values name where they are; sizes over a limit (often made of several fields) name the flag that raises
      // it, or where they are, or the scene or frame they are in.
      const std::string& message = status.error_message();
      const bool named =
          status.error_code() == grpc::StatusCode::INVALID_ARGUMENT
              ? message.find(owner_of(v.field)) != std::string::npos
              : status.error_code() == grpc::StatusCode::RESOURCE_EXHAUSTED &&
                    (message.find("--max-") != std::string::npos ||
                     message.find(owner_of(v.field)) != std::string::npos || names_enclosing(message, v.field));
      if (!named) {
        problems.push_back(v.field + " = " + v.value + ": refused with " + std::to_string(status.error_code()) +
                           " without naming it: " + message);
      }
    }
  }
  settle();
  EXPECT_GT(accepted, 0);
  EXPECT_GT(refused, 0);
  std::string all;
  for (const auto& p : problems) all += p + "\n";
  EXPECT_TRUE(problems.empty()) << problems.size() << " problems (" << accepted << " accepted, " << refused
                                << " refused):\n"
                                << all;
}

// A ball three cells wide, carried through a whole Enright period in one frame, falls below the grid's resolution
// and vanishes: the job ends with an empty frame (it used to take the server down with it).
TEST(SubmitValues, AnAdvectedShapeThatVanishesEndsTheJobNotTheServer) {
  LoopbackServer s;
  std::string id;
  ASSERT_TRUE(submit(*s.stub, spec_from_json(R"({"active": {"gridSpacing": 0.05, "advect": {"shape": {"root":
      {"sphere": {"center": {"x": 0.35, "y": 0.35, "z": 0.35}, "radius": 0.15}}}, "enright": {"period": 3},
      "frameInterval": 3, "frames": 1}}})"),
                     &id)
                  .ok());
  const auto result = watch_job(*s.stub, id);
  EXPECT_EQ(result.final_job.state(), v1::JOB_STATE_SUCCEEDED) << result.final_job.error().message();
  ASSERT_EQ(result.frames.size(), 2u);
  EXPECT_EQ(result.frames.at(1).header.stats().triangles(), 0);
}

}  // namespace
}  // namespace surfacer::testing
