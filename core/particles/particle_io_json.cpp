// JSON particle positions (core/particles/particle_io.h): splashsurf's `[[x, y, z], ...]`, or an object of arrays
// {"positions": [[x, y, z], ...], "radius": [r, ...], "velocity": [[u, v, w], ...], "density": [d, ...]}.
#include <cmath>
#include <string>
#include <utility>
#include <vector>

#include "core/particles/particle_io_detail.h"

namespace surfacer::particle_io_detail {
namespace {

class JsonPoints {
 public:
  JsonPoints(std::string_view text, const std::string& name) : text_(text), name_(name) {}

  ParticleFrame read() {
    if (text_.substr(0, 3) == "\xEF\xBB\xBF") pos_ = 3;  // a UTF-8 byte order mark
    if (peek('{')) return read_object();
    ParticleFrame frame;
    expect('[', "'[' to open the list of particles ([[x, y, z], ...])");
    frame.positions.reserve(capped_reserve(static_cast<std::int64_t>(text_.size()), text_.size(), 8));
    if (!peek(']')) {
      while (true) {
        const std::string which = "particle " + std::to_string(frame.positions.size());
        expect('[', "'[' to open " + which + " ([x, y, z])");
        double c[3];
        for (int k = 0; k < 3; ++k) {
          c[k] = number(which);
          if (k < 2) expect(',', "',' after coordinate " + std::to_string(k) + " of " + which + " ([x, y, z])");
        }
        expect(']', "']' after the 3 coordinates of " + which + " (each particle is [x, y, z])");
        const Vec3 p(c[0], c[1], c[2]);
        // (the line is found only on failure: counting lines from the start for every particle is quadratic)
        if (!p.allFinite()) check_finite(p, name_, where());
        frame.positions.push_back(p);
        if (peek(',')) {
          ++pos_;
          continue;
        }
        break;
      }
    }
    expect(']', "',' or the ']' that closes the list");
    skip_space();
    if (pos_ < text_.size()) fail(name_, where(), "text after the closing ']'");
    return frame;
  }

 private:
  // {"positions": [[x, y, z], ...], NAME: [v, ...] or [[v0, v1, ...], ...], ...}: a radius or pscale list gives the
  // radii, every other array an attribute of its inner lists' length (1 for plain numbers).
  ParticleFrame read_object() {
    expect('{', "'{'");
    ParticleFrame frame;
    std::vector<std::pair<std::string, std::pair<std::int64_t, std::vector<double>>>> arrays;
    bool have_positions = false;
    if (!peek('}')) {
      while (true) {
        const std::string key = string_value();
        expect(':', "':' after \"" + key + "\"");
        auto [components, values] = array_value(key);
        if (key == "positions") {
          if (components != 3) fail(name_, where(), "\"positions\" must be a list of [x, y, z]");
          frame.positions.resize(values.size() / 3);
          for (std::size_t i = 0; i < frame.positions.size(); ++i) {
            frame.positions[i] = Vec3(values[3 * i], values[3 * i + 1], values[3 * i + 2]);
            if (!frame.positions[i].allFinite()) check_finite(frame.positions[i], name_, where());
          }
          have_positions = true;
        } else if (is_radius_name(key) && components == 1 && frame.radii.empty()) {
          frame.radii = std::move(values);
        } else {
          arrays.emplace_back(key, std::make_pair(components, std::move(values)));
        }
        if (peek(',')) {
          ++pos_;
          continue;
        }
        break;
      }
    }
    expect('}', "',' or the '}' that closes the object");
    skip_space();
    if (pos_ < text_.size()) fail(name_, where(), "text after the closing '}'");
    if (!have_positions) {
      fail(name_, where(),
           "the object has no \"positions\": expected '[' to open the list of particles ([[x, y, z], ...]) or an "
           "object with \"positions\": [[x, y, z], ...]");
    }
    const std::size_t n = frame.positions.size();
    if (!frame.radii.empty() && frame.radii.size() != n) {
      fail(name_, where(),
           "radius list has " + std::to_string(frame.radii.size()) + " values for " + std::to_string(n) + " positions");
    }
    for (const auto& [key, array] : arrays) {
      if (array.second.size() != n * static_cast<std::size_t>(array.first)) {
        fail(name_, where(),
             "\"" + key + "\" has " + std::to_string(array.second.size() / array.first) + " entries for " +
                 std::to_string(n) + " positions");
      }
      keep_attribute(frame, key, array.first, array.second);
    }
    return frame;
  }

  // A JSON string (escapes \" and \\ and \/ kept as the character; others as written).
  std::string string_value() {
    expect('"', "'\"' to open a name");
    std::string out;
    while (pos_ < text_.size() && text_[pos_] != '"') {
      if (text_[pos_] == '\\' && pos_ + 1 < text_.size()) ++pos_;
      out += text_[pos_++];
    }
    expect('"', "'\"' to close the name \"" + out.substr(0, 40) + "\"");
    return out;
  }

  // [v, ...] (1 component) or [[v0, v1, ...], ...] (inner lists of one length): the components and the values.
  std::pair<std::int64_t, std::vector<double>> array_value(const std::string& key) {
    expect('[', "'[' to open the list \"" + key + "\"");
    std::vector<double> values;
    std::int64_t components = 1;
    if (peek(']')) {
      ++pos_;
      return {key == "positions" ? 3 : 1, values};
    }
    const bool nested = peek('[');
    components = -1;
    for (std::size_t item = 0;; ++item) {
      const std::string which = "\"" + key + "\" entry " + std::to_string(item);
      if (nested) {
        expect('[', "'[' to open " + which);
        std::int64_t count = 0;
        while (true) {
          values.push_back(number(which));
          ++count;
          if (peek(',')) {
            ++pos_;
            continue;
          }
          break;
        }
        expect(']', "']' to close " + which);
        if (components >= 0 && count != components) {
          fail(name_, where(),
               which + " has " + std::to_string(count) + " values, the first had " + std::to_string(components));
        }
        components = count;
      } else {
        values.push_back(number(which));
        components = 1;
      }
      if (peek(',')) {
        ++pos_;
        continue;
      }
      break;
    }
    expect(']', "',' or the ']' that closes \"" + key + "\"");
    return {components, std::move(values)};
  }

  std::string where() const { return line_at(line_of(text_, pos_)); }

  void skip_space() {
    while (pos_ < text_.size() &&
           (text_[pos_] == ' ' || text_[pos_] == '\t' || text_[pos_] == '\n' || text_[pos_] == '\r')) {
      ++pos_;
    }
  }

  bool peek(char c) {
    skip_space();
    return pos_ < text_.size() && text_[pos_] == c;
  }

  void expect(char c, const std::string& what) {
    if (!peek(c)) {
      fail(name_, where(),
           "expected " + what + (pos_ < text_.size() ? ", found " + quote(text_.substr(pos_, 1)) : ", found the end"));
    }
    ++pos_;
  }

  double number(const std::string& which) {
    skip_space();
    const std::size_t start = pos_;
    while (pos_ < text_.size()) {
      const char c = text_[pos_];
      if (!((c >= '0' && c <= '9') || c == '-' || c == '+' || c == '.' || c == 'e' || c == 'E')) break;
      ++pos_;
    }
    double v = 0.0;
    if (pos_ == start || !parse_double(text_.substr(start, pos_ - start), v)) {
      pos_ = start;
      fail(name_, where(),
           "expected a number in " + which +
               (start < text_.size()
                    ? ", found " + quote(text_.substr(start, std::min<std::size_t>(20, text_.size() - start)))
                    : ", found the end"));
    }
    return v;
  }

  std::string_view text_;
  const std::string& name_;
  std::size_t pos_ = 0;
};

}  // namespace

ParticleFrame parse_json_points(std::string_view bytes, const std::string& name) {
  return JsonPoints(bytes, name).read();
}

}  // namespace surfacer::particle_io_detail
