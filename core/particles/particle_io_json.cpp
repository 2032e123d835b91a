// JSON particle positions (core/particles/particle_io.h): splashsurf's `[[x, y, z], ...]`.
#include <cmath>
#include <string>

#include "core/particles/particle_io_detail.h"

namespace surfacer::particle_io_detail {
namespace {

class JsonPoints {
 public:
  JsonPoints(std::string_view text, const std::string& name) : text_(text), name_(name) {}

  ParticleFrame read() {
    if (text_.substr(0, 3) == "\xEF\xBB\xBF") pos_ = 3;  // a UTF-8 byte order mark
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
