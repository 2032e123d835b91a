// A job's state as the CLI prints it, in text and in JSON (client/json_output.h): "QUEUED" ... "CANCELLED".
#pragma once

#include <string>

#include "surfacer/v1/surfacer.pb.h"

namespace surfacer::client {

// "RUNNING" for JOB_STATE_RUNNING; "STATE_<n>" for a number this client does not know.
inline std::string state_name(v1::JobState state) {
  std::string name = v1::JobState_Name(state);
  const std::string prefix = "JOB_STATE_";
  if (name.rfind(prefix, 0) == 0) name = name.substr(prefix.size());
  return name.empty() ? "STATE_" + std::to_string(static_cast<int>(state)) : name;
}

}  // namespace surfacer::client
