// Strict command lines for the bench programs. A bench that shrugs off a typo runs minutes of the wrong measurement,
// so an unknown argument, a flag without its value or a value that is not a number in the flag's range ends the
// program: "<program>: <what the flag needs>" and the usage on stderr, exit code 2. --help and -h print the usage on
// stdout and exit 0.
//
//   bench::Args args(argc, argv, "tiles_bench", kUsage);
//   while (args.next()) {
//     if (args.flag() == "--quick") {
//       quick = true;
//     } else if (args.flag() == "--section") {
//       section = args.integer(1, 5);
//     } else {
//       args.unknown();
//     }
//   }
#pragma once

#include <charconv>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <limits>
#include <string>
#include <system_error>

namespace surfacer::bench {

// The range of a floating-point value; an open end excludes its bound.
struct Range {
  double min = -std::numeric_limits<double>::infinity();
  double max = std::numeric_limits<double>::infinity();
  bool min_open = false, max_open = false;
};

class Args {
 public:
  // usage: the program's usage line(s), each ending in '\n'. help (optional) prints more on stdout after the usage
  // for --help (a function, so that a library's own flag list can be printed).
  Args(int argc, char** argv, const char* program, const char* usage, void (*help)() = nullptr)
      : argc_(argc), argv_(argv), program_(program), usage_(usage), help_(help) {}

  // Steps to the next argument: false when there is none left. --help and -h print the usage and exit 0.
  bool next() {
    if (++index_ >= argc_) return false;
    flag_ = argv_[index_];
    if (flag_ == "--help" || flag_ == "-h") {
      std::fputs(usage_, stdout);
      if (help_ != nullptr) help_();
      std::exit(0);
    }
    return true;
  }

  // The argument next() stepped to.
  const std::string& flag() const { return flag_; }

  // The flag's value (the argument after it, whatever it looks like); `what` names it in the error when it is missing.
  std::string value(const std::string& what = "a value") {
    if (index_ + 1 >= argc_) error(flag_ + " needs " + what);
    return argv_[++index_];
  }

  // The flag's value as an integer in [min, max].
  template <class Int>
  Int integer(Int min, Int max = std::numeric_limits<Int>::max()) {
    const std::string what = max == std::numeric_limits<Int>::max()
                                 ? "an integer >= " + std::to_string(min)
                                 : "an integer from " + std::to_string(min) + " to " + std::to_string(max);
    const std::string text = value(what);
    Int v{};
    const auto [end, ec] = std::from_chars(text.data(), text.data() + text.size(), v);
    if (ec != std::errc() || end != text.data() + text.size() || v < min || v > max) bad(what, text);
    return v;
  }

  // The flag's value as a finite number in `range`.
  double number(const Range& range) {
    std::string what = "a number";
    const bool has_min = std::isfinite(range.min), has_max = std::isfinite(range.max);
    if (has_min && has_max && !range.min_open && !range.max_open) {
      what += " from " + text_of(range.min) + " to " + text_of(range.max);
    } else {
      if (has_min) what += (range.min_open ? " > " : " >= ") + text_of(range.min);
      if (has_min && has_max) what += " and";
      if (has_max) what += (range.max_open ? " < " : " <= ") + text_of(range.max);
    }
    const std::string text = value(what);
    double v = 0.0;
    const auto [end, ec] = std::from_chars(text.data(), text.data() + text.size(), v);
    if (ec != std::errc() || end != text.data() + text.size() || !std::isfinite(v) || v < range.min ||
        (range.min_open && v == range.min) || v > range.max || (range.max_open && v == range.max)) {
      bad(what, text);
    }
    return v;
  }

  [[noreturn]] void error(const std::string& message) const {
    std::fprintf(stderr, "%s: %s\n%s", program_, message.c_str(), usage_);
    std::exit(2);
  }

  [[noreturn]] void unknown() const { error("unknown argument '" + flag_ + "'"); }

 private:
  [[noreturn]] void bad(const std::string& what, const std::string& text) const {
    error(flag_ + " needs " + what + ", got '" + text + "'");
  }

  static std::string text_of(double x) {
    char buf[32];
    std::snprintf(buf, sizeof buf, "%g", x);
    return buf;
  }

  int argc_;
  char** argv_;
  const char* program_;
  const char* usage_;
  void (*help_)();
  int index_ = 0;
  std::string flag_;
};

}  // namespace surfacer::bench
