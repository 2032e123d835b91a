// The check of DecimateOptions (core/mesh/decimate.h), apart from the Decimater so that what validates a job's options
// (wire/output.cpp) does not link OpenMesh.
#include <cmath>
#include <string>

#include "core/mesh/decimate.h"
#include "core/util/errors.h"
#include "core/util/format.h"

namespace surfacer {

void validate(const DecimateOptions& options) {
  if (!std::isfinite(options.tolerance) || options.tolerance < 0.0) {
    throw InvalidInput("tolerance", "tolerance (" + format_number(options.tolerance) +
                                        ") must be a finite length >= 0 in scene units (0: no decimation)");
  }
  if (!(options.min_angle_degrees >= 0.0 && options.min_angle_degrees <= 30.0)) {
    throw InvalidInput("min_angle_degrees",
                       "min_angle_degrees (" + format_number(options.min_angle_degrees) + ") must be in [0, 30]");
  }
  if (options.threads < 0) {
    throw InvalidInput("threads", "threads (" + std::to_string(options.threads) + ") must be >= 0 (0: hardware threads)");
  }
}

}  // namespace surfacer
