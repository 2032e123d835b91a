#include "client/particle_files.h"

#include <algorithm>
#include <bit>
#include <charconv>
#include <cmath>
#include <limits>
#include <map>
#include <optional>
#include <set>

#include "client/exit_codes.h"
#include "core/particles/particle_io.h"
#include "core/util/errors.h"

namespace surfacer::client {
namespace {

namespace fs = std::filesystem;

// The literal text before and after the placeholder of a file-name pattern ("{{" / "}}" unescaped).
struct PatternParts {
  std::string prefix;
  std::string suffix;
  int placeholders = 0;
  bool any_padding = false;  // the placeholder is "{}": it matches the number with any zero padding
};

PatternParts split_pattern(const std::string& text) {
  PatternParts parts;
  std::string* out = &parts.prefix;
  for (std::size_t i = 0; i < text.size(); ++i) {
    const char c = text[i];
    if ((c == '{' || c == '}') && i + 1 < text.size() && text[i + 1] == c) {
      *out += c;
      ++i;
    } else if (c == '{') {
      const std::size_t close = text.find('}', i);
      if (close == std::string::npos) break;  // malformed: expand_sequence() says so
      ++parts.placeholders;
      parts.any_padding = close == i + 1;
      out = &parts.suffix;
      i = close;
    } else {
      *out += c;
    }
  }
  return parts;
}

CliError usage(const std::string& message) { return CliError(ExitCode::kUsage, message); }

std::vector<fs::path> expand(const std::string& pattern, int start, int end, const std::string& where) {
  try {
    return expand_sequence(pattern, start, end);
  } catch (const Error& e) {
    throw usage(where + ": " + e.what());
  }
}

// The files in the pattern's directory that the pattern names, by frame number: exactly as expand_sequence() names
// them, or for "{}" with any zero padding (fluid_7.bgeo, fluid_0007.bgeo); two files of one number are an error.
std::map<int, fs::path> frames_present(const std::string& pattern, const std::string& where) {
  const fs::path path(pattern);
  const fs::path dir = path.has_parent_path() ? path.parent_path() : fs::path(".");
  if (split_pattern(dir.string()).placeholders != 0) {
    throw usage(where + ": the placeholder is in a directory name; give --start and --end");
  }
  const PatternParts parts = split_pattern(path.filename().string());
  if (parts.placeholders != 1) {
    expand(pattern, 0, 0, where);  // names the problem with the placeholder
    throw usage(where + ": needs exactly one placeholder such as {} or {:04d}");
  }
  std::error_code ec;
  fs::directory_iterator it(dir, ec);
  if (ec) throw usage(where + ": cannot list " + dir.string() + ": " + ec.message());
  std::map<int, fs::path> frames;
  for (const fs::directory_entry& entry : it) {
    const std::string name = entry.path().filename().string();
    if (name.size() <= parts.prefix.size() + parts.suffix.size() || name.rfind(parts.prefix, 0) != 0 ||
        name.compare(name.size() - parts.suffix.size(), parts.suffix.size(), parts.suffix) != 0) {
      continue;
    }
    const std::string middle =
        name.substr(parts.prefix.size(), name.size() - parts.prefix.size() - parts.suffix.size());
    int number = 0;
    auto [end, ec2] = std::from_chars(middle.data(), middle.data() + middle.size(), number);
    if (ec2 != std::errc() || end != middle.data() + middle.size()) continue;
    // The pattern must produce exactly this name (e.g. {:04d} does not name fluid_7.ply); {} takes any padding.
    if (!parts.any_padding && expand(pattern, number, number, where).front().filename() != entry.path().filename()) {
      continue;
    }
    const fs::path file = dir == "." && !path.has_parent_path() ? fs::path(name) : dir / name;
    const auto [at, inserted] = frames.emplace(number, file);
    if (!inserted) {
      const std::string other = at->second.filename().string();
      throw usage(where + ": " + std::min(other, name) + " and " + std::max(other, name) + " are both frame " +
                  std::to_string(number) + "; remove one, or give the padding, e.g. {:04d}");
    }
  }
  return frames;
}

void require_exists(const fs::path& file, const std::string& where) {
  std::error_code ec;
  if (!fs::is_regular_file(file, ec)) {
    throw usage(where + ": " + file.string() + (fs::exists(file, ec) ? " is not a regular file" : " does not exist"));
  }
}

void put_float(std::string& out, double value) {
  const std::uint32_t bits = std::bit_cast<std::uint32_t>(static_cast<float>(value));
  const char bytes[4] = {static_cast<char>(bits & 0xff), static_cast<char>((bits >> 8) & 0xff),
                         static_cast<char>((bits >> 16) & 0xff), static_cast<char>((bits >> 24) & 0xff)};
  out.append(bytes, 4);
}

bool fits_float(double v) { return std::isfinite(v) && std::abs(v) <= std::numeric_limits<float>::max(); }

// What reading one file may amount to, from what the server accepts: particles (at least 12 bytes of upload each),
// and the file's bytes per particle: exactly 12 in a raw .bin, at most kFileBytesPerParticle in the other formats.
ParticleReadLimits particle_read_limits(const fs::path& path, const InputLimits& limits) {
  constexpr std::uint64_t kFileBytesPerParticle = 256;
  constexpr std::uint64_t kHeaderBytes = std::uint64_t{64} << 10;
  constexpr std::uint64_t kRecordBytes = 12;
  ParticleReadLimits out;
  const std::uint64_t particles =
      std::min(static_cast<std::uint64_t>(std::max<std::int64_t>(0, limits.max_particles)),
               static_cast<std::uint64_t>(std::max<std::int64_t>(0, limits.max_upload_bytes)) / kRecordBytes);
  out.max_particles = static_cast<std::int64_t>(particles);
  ParticleFormat format = ParticleFormat::kXyz;
  try {
    format = particle_format_from_path(path);
  } catch (const Error&) {
    return out;  // read_particles names the extension
  }
  const std::uint64_t per = format == ParticleFormat::kBin ? kRecordBytes : kFileBytesPerParticle;
  if (particles < (out.max_bytes - kHeaderBytes) / per) out.max_bytes = particles * per + kHeaderBytes;
  return out;
}

// "; the server takes at most N particles per frame ..." for messages about a frame the server would refuse.
std::string server_limits_text(const InputLimits& limits) {
  return "; the server takes at most " + std::to_string(limits.max_particles) +
         " particles per frame (its --max-particles) and " + std::to_string(limits.max_upload_bytes) +
         " bytes per upload (its --max-upload-bytes, or what the token's quota has left)";
}

}  // namespace

bool is_sequence_pattern(const std::string& input) { return split_pattern(input).placeholders > 0; }

ParticleInputFiles expand_particle_sequence(const ParticleInputOptions& options, const std::string& flag) {
  if (options.inputs.empty()) throw usage(flag + " is required: a particle file or a pattern such as fluid_{}.bgeo");
  if (options.start && options.end && *options.end < *options.start) {
    throw usage("--end (" + std::to_string(*options.end) + ") must not be below --start (" +
                std::to_string(*options.start) + ")");
  }
  bool any_pattern = false;
  ParticleInputFiles out;
  for (const std::string& input : options.inputs) {
    const std::string where = flag + " " + input;
    if (!is_sequence_pattern(input)) {
      require_exists(input, where);
      out.files.emplace_back(input);
      out.numbers.emplace_back(std::nullopt);
      continue;
    }
    any_pattern = true;
    // "{}" in the file name matches any zero padding: the directory is listed even when --start and --end are given.
    const bool any_padding = split_pattern(fs::path(input).filename().string()).any_padding &&
                             split_pattern(fs::path(input).parent_path().string()).placeholders == 0;
    std::map<int, fs::path> present;
    int start = 0;
    int end = 0;
    if (any_padding || !(options.start && options.end)) present = frames_present(input, where);
    if (options.start && options.end) {
      start = *options.start;
      end = *options.end;
    } else {
      if (present.empty()) {
        throw usage(where + ": no file in " +
                    (fs::path(input).has_parent_path() ? fs::path(input).parent_path().string() : std::string(".")) +
                    " matches the pattern");
      }
      start = options.start.value_or(present.begin()->first);
      end = options.end.value_or(present.rbegin()->first);
      if (end < start) {
        throw usage(where + ": no frame in the range " + std::to_string(start) + ".." + std::to_string(end) +
                    " (files present: " + std::to_string(present.begin()->first) + ".." +
                    std::to_string(present.rbegin()->first) + ")");
      }
    }
    const std::vector<fs::path> sequence = expand(input, start, end, where);
    std::size_t missing = 0;
    std::string first_missing;
    for (std::size_t k = 0; k < sequence.size(); ++k) {
      const int number = start + static_cast<int>(k);
      fs::path file = sequence[k];
      if (any_padding) {
        const auto it = present.find(number);
        if (it != present.end()) file = it->second;
      }
      std::error_code ec;
      if (!fs::is_regular_file(file, ec)) {
        if (missing++ == 0) first_missing = file.string() + (any_padding ? " (with any zero padding)" : "");
        continue;
      }
      out.files.push_back(file);
      out.numbers.emplace_back(number);
    }
    if (missing > 0) {
      throw usage(where + ": " + std::to_string(missing) + " of the " + std::to_string(sequence.size()) + " frames " +
                  std::to_string(start) + ".." + std::to_string(end) + " are missing, the first " + first_missing +
                  " (set --start/--end to the frames present)");
    }
  }
  if ((options.start || options.end) && !any_pattern) {
    throw usage("--start/--end select frames of a sequence pattern (" + flag +
                " fluid_{:04d}.ply); no input is a pattern");
  }
  return out;
}

std::vector<fs::path> expand_particle_inputs(const ParticleInputOptions& options, const std::string& flag) {
  return expand_particle_sequence(options, flag).files;
}

ParticleRecords read_particle_records(const fs::path& path, const InputLimits& limits,
                                      const std::vector<std::string>& attributes) {
  const std::string name = path.string();
  const bool limited =
      limits.max_particles != InputLimits{}.max_particles || limits.max_upload_bytes != InputLimits{}.max_upload_bytes;
  const std::string server_limits = server_limits_text(limits);
  ParticleFrame frame;
  try {
    frame = read_particles(path, particle_read_limits(path, limits));
  } catch (const Error& e) {
    std::string message = e.what();
    if (message.find(path.string()) == std::string::npos && message.find(path.filename().string()) != 0) {
      message = path.string() + ": " + message;
    }
    if (e.kind() == ErrorKind::kResourceLimit && limited) message += server_limits;
    throw usage(message);
  } catch (const std::bad_alloc&) {
    throw usage(name + ": reading it needs more memory than there is");
  }
  return pack_particle_records(frame, name, limits, attributes);
}

ParticleRecords pack_particle_records(const ParticleFrame& frame, const std::string& name, const InputLimits& limits,
                                      const std::vector<std::string>& attributes) {
  const std::string server_limits = server_limits_text(limits);
  if (frame.positions.empty()) throw usage(name + ": no particles; every frame needs at least one");
  if (static_cast<std::uint64_t>(frame.positions.size()) > static_cast<std::uint64_t>(limits.max_particles)) {
    throw usage(name + ": " + std::to_string(frame.positions.size()) + " particles" + server_limits);
  }
  const bool with_radius = !frame.radii.empty();
  if (with_radius && frame.radii.size() != frame.positions.size()) {
    throw usage(name + ": " + std::to_string(frame.radii.size()) + " radii for " +
                std::to_string(frame.positions.size()) + " particles; give one per particle or none");
  }
  std::vector<const Attribute*> packed;
  if (attributes.size() == 1 && attributes[0] == "all") {
    for (const Attribute& a : frame.attributes) packed.push_back(&a);
  } else {
    for (const std::string& attribute : attributes) {
      const Attribute* a = find_attribute(frame, attribute);
      if (a == nullptr) {
        throw usage(name + ": no attribute \"" + attribute + "\" to interpolate; the file has " +
                    attribute_list(frame));
      }
      if (a->count() != frame.positions.size()) {
        throw usage(name + ": attribute " + attribute + " has " + std::to_string(a->count()) + " values for " +
                    std::to_string(frame.positions.size()) + " particles");
      }
      packed.push_back(a);
    }
  }
  ParticleRecords records;
  records.with_radius = with_radius;
  for (const Attribute* a : packed) records.attributes.emplace_back(a->name, a->components);
  records.count = static_cast<std::int64_t>(frame.positions.size());
  records.bytes.reserve(frame.positions.size() * (with_radius ? 16 : 12));
  for (std::size_t i = 0; i < frame.positions.size(); ++i) {
    const Vec3& p = frame.positions[i];
    if (!fits_float(p.x()) || !fits_float(p.y()) || !fits_float(p.z())) {
      throw usage(name + ": particle " + std::to_string(i) +
                  " has a coordinate that is not finite or does not fit "
                  "in float32");
    }
    put_float(records.bytes, p.x());
    put_float(records.bytes, p.y());
    put_float(records.bytes, p.z());
    if (with_radius) {
      const double r = frame.radii[i];
      if (!fits_float(r) || r < 0) {
        throw usage(name + ": particle " + std::to_string(i) + " has radius " + std::to_string(r) +
                    "; radii must be finite and >= 0");
      }
      put_float(records.bytes, r);
    }
    for (const Attribute* a : packed) {
      const std::size_t c = static_cast<std::size_t>(a->components);
      for (std::size_t k = 0; k < c; ++k) {
        const double v = a->values[i * c + k];
        if (!fits_float(v)) {
          throw usage(name + ": attribute " + a->name + " of particle " + std::to_string(i) +
                      " is not finite or does not fit in float32");
        }
        put_float(records.bytes, v);
      }
    }
  }
  if (records.bytes.size() > static_cast<std::uint64_t>(limits.max_upload_bytes)) {
    throw usage(name + ": " + std::to_string(records.count) + " particles make an upload of " +
                std::to_string(records.bytes.size()) + " bytes" + server_limits);
  }
  return records;
}

}  // namespace surfacer::client
