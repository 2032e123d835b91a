// Metrics: the registry's text exposition (parsed back with a strict parser of the 0.0.4 grammar), thread safety,
// registration errors, and the HTTP endpoint over real loopback sockets.
#include "server/metrics.h"

#include <arpa/inet.h>
#include <gtest/gtest.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstring>
#include <latch>
#include <limits>
#include <map>
#include <optional>
#include <random>
#include <set>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

#include "server/http_request_head.h"
#include "server/metrics_http.h"

namespace surfacer::server {
namespace {

using namespace std::chrono_literals;
using namespace std::string_view_literals;
using Clock = std::chrono::steady_clock;

// --- A strict parser of the text exposition format 0.0.4 --------------------------------------------------------

struct ParsedSample {
  std::string name;
  std::vector<std::pair<std::string, std::string>> labels;  // in line order, values unescaped
  double value = 0.0;

  std::string label(const std::string& key) const {
    for (const auto& [k, v] : labels) {
      if (k == key) return v;
    }
    return "<missing>";
  }
};

struct ParsedFamily {
  std::string name;
  std::string help;  // unescaped
  std::string type;
  bool has_help = false;
  bool has_type = false;
  std::vector<ParsedSample> samples;
};

struct Exposition {
  std::vector<ParsedFamily> families;  // in text order

  const ParsedFamily* find(const std::string& name) const {
    for (const auto& f : families) {
      if (f.name == name) return &f;
    }
    return nullptr;
  }
};

[[noreturn]] void fail(int line, const std::string& what) {
  throw std::runtime_error("line " + std::to_string(line) + ": " + what);
}

bool name_start(char c) { return (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || c == '_' || c == ':'; }
bool name_char(char c) { return name_start(c) || (c >= '0' && c <= '9'); }

// Reads a metric or label name at s[i]; labels may not contain ':'.
std::string read_name(std::string_view s, std::size_t& i, bool label, int line) {
  const std::size_t start = i;
  if (i >= s.size() || !name_start(s[i]) || (label && s[i] == ':')) fail(line, "expected a name");
  while (i < s.size() && name_char(s[i]) && !(label && s[i] == ':')) ++i;
  return std::string(s.substr(start, i - start));
}

double parse_value(std::string_view text, int line) {
  if (text == "+Inf") return std::numeric_limits<double>::infinity();
  if (text == "-Inf") return -std::numeric_limits<double>::infinity();
  if (text == "NaN") return std::numeric_limits<double>::quiet_NaN();
  const std::string copy(text);
  char* end = nullptr;
  const double value = std::strtod(copy.c_str(), &end);
  if (copy.empty() || end != copy.c_str() + copy.size() || copy.find_first_of("iInN") != std::string::npos) {
    fail(line, "bad value '" + copy + "'");
  }
  return value;
}

// Samples of a family: the family name itself, or for a histogram name_bucket, name_sum, name_count.
bool belongs(const ParsedFamily& family, const std::string& sample_name) {
  if (family.type == "histogram") {
    return sample_name == family.name + "_bucket" || sample_name == family.name + "_sum" ||
           sample_name == family.name + "_count";
  }
  return sample_name == family.name;
}

Exposition parse_exposition(const std::string& text) {
  Exposition out;
  if (!text.empty() && text.back() != '\n') throw std::runtime_error("the text does not end with a newline");
  std::set<std::string> seen_families;
  std::set<std::string> seen_series;  // sample name + labels
  int line_number = 0;
  std::size_t pos = 0;
  while (pos < text.size()) {
    const std::size_t end = text.find('\n', pos);
    const std::string_view line(text.data() + pos, end - pos);
    pos = end + 1;
    ++line_number;
    if (line.empty()) fail(line_number, "empty line");
    if (line.starts_with('#')) {
      const bool help = line.starts_with("# HELP ");
      const bool type = line.starts_with("# TYPE ");
      if (!help && !type) fail(line_number, "unexpected comment");
      std::size_t i = 7;
      const std::string name = read_name(line, i, false, line_number);
      if (i >= line.size() || line[i] != ' ') fail(line_number, "expected a space after the name");
      const std::string_view rest = line.substr(i + 1);
      if (out.families.empty() || out.families.back().name != name) {
        if (!seen_families.insert(name).second) fail(line_number, "family " + name + " appears twice");
        out.families.push_back({});
        out.families.back().name = name;
      }
      ParsedFamily& family = out.families.back();
      if (!family.samples.empty()) fail(line_number, "HELP/TYPE after samples of " + name);
      if (help) {
        if (family.has_help) fail(line_number, "second HELP for " + name);
        family.has_help = true;
        for (std::size_t k = 0; k < rest.size(); ++k) {
          if (rest[k] != '\\') {
            family.help += rest[k];
          } else if (k + 1 < rest.size() && rest[k + 1] == '\\') {
            family.help += '\\';
            ++k;
          } else if (k + 1 < rest.size() && rest[k + 1] == 'n') {
            family.help += '\n';
            ++k;
          } else {
            fail(line_number, "bad escape in HELP");
          }
        }
      } else {
        if (family.has_type) fail(line_number, "second TYPE for " + name);
        static const std::set<std::string> kTypes = {"counter", "gauge", "histogram", "summary", "untyped"};
        if (!kTypes.count(std::string(rest))) fail(line_number, "unknown type '" + std::string(rest) + "'");
        family.has_type = true;
        family.type = std::string(rest);
      }
      continue;
    }
    ParsedSample sample;
    std::size_t i = 0;
    sample.name = read_name(line, i, false, line_number);
    if (i < line.size() && line[i] == '{') {
      ++i;
      while (i < line.size() && line[i] != '}') {
        std::string key = read_name(line, i, true, line_number);
        if (i + 1 >= line.size() || line[i] != '=' || line[i + 1] != '"') fail(line_number, "expected =\"");
        i += 2;
        std::string value;
        for (;;) {
          if (i >= line.size()) fail(line_number, "unterminated label value");
          const char c = line[i++];
          if (c == '"') break;
          if (c != '\\') {
            value += c;
            continue;
          }
          if (i >= line.size()) fail(line_number, "dangling backslash");
          const char e = line[i++];
          if (e == '\\') {
            value += '\\';
          } else if (e == '"') {
            value += '"';
          } else if (e == 'n') {
            value += '\n';
          } else {
            fail(line_number, "bad escape in a label value");
          }
        }
        for (const auto& [k, v] : sample.labels) {
          if (k == key) fail(line_number, "label " + key + " repeated");
        }
        sample.labels.emplace_back(std::move(key), std::move(value));
        if (i < line.size() && line[i] == ',') ++i;
      }
      if (i >= line.size()) fail(line_number, "unterminated label set");
      ++i;  // '}'
    }
    if (i >= line.size() || line[i] != ' ') fail(line_number, "expected a space before the value");
    const std::string_view value_text = line.substr(i + 1);
    if (value_text.find(' ') != std::string_view::npos) fail(line_number, "unexpected timestamp or trailing text");
    sample.value = parse_value(value_text, line_number);
    if (out.families.empty() || !belongs(out.families.back(), sample.name)) {
      fail(line_number, "sample " + sample.name + " is not in the family declared just before it");
    }
    if (!out.families.back().has_help || !out.families.back().has_type) {
      fail(line_number, "sample before HELP and TYPE");
    }
    std::string series = sample.name;
    for (const auto& [k, v] : sample.labels) series += "|" + k + "=" + v;
    if (!seen_series.insert(series).second) fail(line_number, "duplicate series " + series);
    out.families.back().samples.push_back(std::move(sample));
  }
  return out;
}

// Checks every histogram: per label set, le bounds increasing and ending in +Inf, cumulative counts monotone,
// _count equal to the +Inf bucket, a _sum present. Returns the number of histogram series checked.
int check_histograms(const Exposition& exposition) {
  int checked = 0;
  for (const ParsedFamily& family : exposition.families) {
    if (family.type != "histogram") continue;
    struct Series {
      std::vector<std::pair<double, double>> buckets;  // (le, cumulative count)
      std::optional<double> sum, count;
    };
    std::map<std::string, Series> by_labels;
    for (const ParsedSample& s : family.samples) {
      std::string key;
      for (const auto& [k, v] : s.labels) {
        if (k != "le") key += k + "=" + v + ";";
      }
      Series& series = by_labels[key];
      if (s.name == family.name + "_bucket") {
        const std::string le = s.label("le");
        EXPECT_NE(le, "<missing>") << family.name;
        series.buckets.emplace_back(parse_value(le, 0), s.value);
      } else if (s.name == family.name + "_sum") {
        series.sum = s.value;
      } else {
        series.count = s.value;
      }
    }
    for (const auto& [key, series] : by_labels) {
      SCOPED_TRACE(family.name + " {" + key + "}");
      if (series.buckets.empty() || !series.count.has_value() || !series.sum.has_value()) {
        ADD_FAILURE() << "a histogram series lacks buckets, _sum or _count";
        continue;
      }
      EXPECT_TRUE(std::isinf(series.buckets.back().first)) << "the last bucket must be +Inf";
      for (std::size_t i = 1; i < series.buckets.size(); ++i) {
        EXPECT_LT(series.buckets[i - 1].first, series.buckets[i].first) << "le bounds must increase";
        EXPECT_LE(series.buckets[i - 1].second, series.buckets[i].second) << "buckets must be cumulative";
      }
      EXPECT_EQ(*series.count, series.buckets.back().second) << "_count must equal the +Inf bucket";
      ++checked;
    }
  }
  return checked;
}

Exposition parse_or_fail(const std::string& text) {
  try {
    return parse_exposition(text);
  } catch (const std::exception& e) {
    ADD_FAILURE() << "not valid exposition text: " << e.what() << "\n" << text;
    return {};
  }
}

bool contains_line(const std::string& text, const std::string& line) {
  return ("\n" + text).find("\n" + line + "\n") != std::string::npos;
}

// --- Registry and format ---------------------------------------------------------------------------------------

TEST(MetricsFormat, RendersEveryKindInRegistrationOrder) {
  MetricsRegistry registry;
  auto& frames = registry.counter("surfacer_frames_total", "Frames finished", {"kind"});
  auto& queue = registry.gauge("surfacer_busy_workers", "Workers running a task");
  auto& stage = registry.histogram("surfacer_stage_seconds", "Stage latency", {0.1, 1, 10}, {"kind", "stage"});
  registry.gauge_callback("surfacer_queue_depth", "Jobs waiting for a worker", [] { return 7.0; });
  registry.gauge_callback_family("surfacer_jobs", "Jobs by state", {"state"}, [] {
    return std::vector<LabelledValue>{{{"running"}, 2}, {{"queued"}, 3}, {{"succeeded"}, 10}};
  });
  auto& bytes = registry.counter("surfacer_bytes_received_total", "Upload bytes");

  frames.with({"isosurface"}).inc();
  frames.with({"isosurface"}).inc(2);
  frames.with({"particles"}).inc();
  queue.with().set(1.5);
  stage.with({"isosurface", "polygonize"}).observe(0.05);
  stage.with({"isosurface", "polygonize"}).observe(0.5);
  stage.with({"isosurface", "polygonize"}).observe(100);
  bytes.with().inc(1 << 20);

  const std::string text = registry.render();
  const Exposition exposition = parse_or_fail(text);
  std::vector<std::string> names;
  for (const auto& f : exposition.families) names.push_back(f.name);
  EXPECT_EQ(names,
            (std::vector<std::string>{"surfacer_frames_total", "surfacer_busy_workers", "surfacer_stage_seconds",
                                      "surfacer_queue_depth", "surfacer_jobs", "surfacer_bytes_received_total"}));
  const std::vector<std::string> types = {"counter", "gauge", "histogram", "gauge", "gauge", "counter"};
  for (std::size_t i = 0; i < types.size() && i < exposition.families.size(); ++i) {
    EXPECT_EQ(exposition.families[i].type, types[i]) << names[i];
  }
  EXPECT_TRUE(contains_line(text, "# HELP surfacer_frames_total Frames finished")) << text;
  EXPECT_TRUE(contains_line(text, "# TYPE surfacer_frames_total counter")) << text;
  EXPECT_TRUE(contains_line(text, R"(surfacer_frames_total{kind="isosurface"} 3)")) << text;
  EXPECT_TRUE(contains_line(text, R"(surfacer_frames_total{kind="particles"} 1)")) << text;
  EXPECT_TRUE(contains_line(text, "surfacer_busy_workers 1.5")) << text;
  EXPECT_TRUE(contains_line(text, R"(surfacer_stage_seconds_bucket{kind="isosurface",stage="polygonize",le="0.1"} 1)"))
      << text;
  EXPECT_TRUE(contains_line(text, R"(surfacer_stage_seconds_bucket{kind="isosurface",stage="polygonize",le="1"} 2)"))
      << text;
  EXPECT_TRUE(contains_line(text, R"(surfacer_stage_seconds_bucket{kind="isosurface",stage="polygonize",le="10"} 2)"))
      << text;
  EXPECT_TRUE(contains_line(text, R"(surfacer_stage_seconds_bucket{kind="isosurface",stage="polygonize",le="+Inf"} 3)"))
      << text;
  EXPECT_TRUE(contains_line(text, R"(surfacer_stage_seconds_count{kind="isosurface",stage="polygonize"} 3)")) << text;
  EXPECT_TRUE(contains_line(text, "surfacer_queue_depth 7")) << text;
  EXPECT_TRUE(contains_line(text, "surfacer_bytes_received_total 1048576")) << text;

  // Callback samples sorted by label value.
  const ParsedFamily* jobs = exposition.find("surfacer_jobs");
  ASSERT_NE(jobs, nullptr);
  ASSERT_EQ(jobs->samples.size(), 3u);
  EXPECT_EQ(jobs->samples[0].label("state"), "queued");
  EXPECT_EQ(jobs->samples[0].value, 3);
  EXPECT_EQ(jobs->samples[1].label("state"), "running");
  EXPECT_EQ(jobs->samples[2].label("state"), "succeeded");
  EXPECT_EQ(check_histograms(exposition), 1);

  const ParsedFamily* stage_family = exposition.find("surfacer_stage_seconds");
  ASSERT_NE(stage_family, nullptr);
  for (const auto& s : stage_family->samples) {
    if (s.name == "surfacer_stage_seconds_sum") {
      EXPECT_DOUBLE_EQ(s.value, 100.55);
    }
  }
}

TEST(MetricsFormat, UnlabelledFamiliesRenderZeroAtOnceLabelledOnesOnUse) {
  MetricsRegistry registry;
  registry.counter("a_total", "A");
  registry.histogram("b_seconds", "B", {1.0});
  auto& c = registry.counter("c_total", "C", {"method"});
  std::string text = registry.render();
  EXPECT_TRUE(contains_line(text, "a_total 0")) << text;
  EXPECT_TRUE(contains_line(text, R"(b_seconds_bucket{le="+Inf"} 0)")) << text;
  EXPECT_TRUE(contains_line(text, "b_seconds_count 0")) << text;
  EXPECT_TRUE(contains_line(text, "# TYPE c_total counter")) << text;
  EXPECT_EQ(text.find("c_total{"), std::string::npos) << text;
  c.with({"SubmitJob"});
  text = registry.render();
  EXPECT_TRUE(contains_line(text, R"(c_total{method="SubmitJob"} 0)")) << text;
  EXPECT_EQ(check_histograms(parse_or_fail(text)), 1);
}

TEST(MetricsFormat, HistogramBucketsAreCumulativeAndCountMatchesInf) {
  MetricsRegistry registry;
  auto& h = registry.histogram("latency_seconds", "Latency", latency_buckets(), {"stage"});
  std::mt19937 rng(42);
  std::lognormal_distribution<double> dist(0.0, 2.5);
  double sum = 0.0;
  int above_max = 0, at_or_below_0_005 = 0;
  for (int i = 0; i < 5000; ++i) {
    const double v = dist(rng);
    h.with({"sample"}).observe(v);
    sum += v;
    above_max += v > 600;
    at_or_below_0_005 += v <= 0.005;
  }
  // Bounds are inclusive: a value equal to a bound counts in that bucket.
  h.with({"edges"}).observe(0.005);
  h.with({"edges"}).observe(600);
  h.with({"edges"}).observe(600.0001);
  h.with({"edges"}).observe_duration(250ms);
  const std::string text = registry.render();
  const Exposition exposition = parse_or_fail(text);
  EXPECT_EQ(check_histograms(exposition), 2);
  EXPECT_TRUE(contains_line(text, R"(latency_seconds_bucket{stage="edges",le="0.005"} 1)")) << text;
  EXPECT_TRUE(contains_line(text, R"(latency_seconds_bucket{stage="edges",le="0.1"} 1)")) << text;
  EXPECT_TRUE(contains_line(text, R"(latency_seconds_bucket{stage="edges",le="0.25"} 2)")) << text;
  EXPECT_TRUE(contains_line(text, R"(latency_seconds_bucket{stage="edges",le="600"} 3)")) << text;
  EXPECT_TRUE(contains_line(text, R"(latency_seconds_bucket{stage="edges",le="+Inf"} 4)")) << text;
  EXPECT_TRUE(contains_line(text, R"(latency_seconds_bucket{stage="sample",le="+Inf"} 5000)")) << text;
  EXPECT_TRUE(
      contains_line(text, R"(latency_seconds_bucket{stage="sample",le="0.005"} )" + std::to_string(at_or_below_0_005)))
      << text;
  const auto snapshot = h.with({"sample"}).snapshot();
  EXPECT_EQ(snapshot.count, 5000u);
  EXPECT_EQ(snapshot.count - snapshot.cumulative[snapshot.bounds.size() - 1], static_cast<std::uint64_t>(above_max));
  EXPECT_NEAR(snapshot.sum, sum, 1e-9 * std::abs(sum));
}

TEST(MetricsFormat, EscapingRoundTrips) {
  MetricsRegistry registry;
  const std::string help = "Help with a backslash \\ and a\nnewline and \"quotes\"";
  auto& family = registry.counter("escapes_total", help, {"value"});
  const std::vector<std::string> values = {
      "plain", "back\\slash", "say \"hi\"", "two\nlines", "all \\\"\n at once \\n", "unicode é ✓ 🙂",
      "",      "{a=\"b\"}"};
  for (std::size_t i = 0; i < values.size(); ++i) family.with({values[i]}).inc(static_cast<double>(i + 1));
  family.with({std::string("bad \xff utf8")}).inc();
  const std::string text = registry.render();
  const Exposition exposition = parse_or_fail(text);
  const ParsedFamily* parsed = exposition.find("escapes_total");
  ASSERT_NE(parsed, nullptr);
  EXPECT_EQ(parsed->help, help);
  std::map<std::string, double> by_value;
  for (const auto& s : parsed->samples) by_value[s.label("value")] = s.value;
  for (std::size_t i = 0; i < values.size(); ++i) {
    ASSERT_TRUE(by_value.count(values[i])) << "missing label value: " << values[i] << "\n" << text;
    EXPECT_EQ(by_value[values[i]], static_cast<double>(i + 1));
  }
  EXPECT_TRUE(by_value.count("bad \xEF\xBF\xBD utf8")) << "invalid UTF-8 should render as U+FFFD\n" << text;
  // Exactly one physical line per sample: newlines never leak into the text.
  EXPECT_EQ(static_cast<std::size_t>(std::count(text.begin(), text.end(), '\n')), 2 + values.size() + 1);

  EXPECT_EQ(escape_label_value("a\\b\"c\nd"), "a\\\\b\\\"c\\nd");
  EXPECT_EQ(escape_help("a\\b\"c\nd"), "a\\\\b\"c\\nd");
  EXPECT_EQ(escape_label_value("\xc3\x28"), "\xEF\xBF\xBD(");                             // truncated 2-byte sequence
  EXPECT_EQ(escape_label_value("\xed\xa0\x80"), "\xEF\xBF\xBD\xEF\xBF\xBD\xEF\xBF\xBD");  // a surrogate
}

// Label values reach the exposition as valid UTF-8 (each invalid byte U+FFFD), so two values that differ only in
// invalid bytes are one series: one sample carrying both increments, never a duplicate series.
TEST(MetricsFormat, InvalidUtf8LabelValuesShareOneSeries) {
  MetricsRegistry registry;
  auto& family = registry.counter("names_total", "Names seen", {"name"});
  family.with({std::string("a\xff")}).inc();
  family.with({std::string("a\xfe")}).inc(2);
  registry.gauge_callback_family("callback_names", "Names from a callback", {"name"}, [] {
    return std::vector<LabelledValue>{{{std::string("b\xc3")}, 4}};
  });
  const std::string text = registry.render();
  const Exposition exposition = parse_or_fail(text);
  const ParsedFamily* counted = exposition.find("names_total");
  ASSERT_NE(counted, nullptr);
  ASSERT_EQ(counted->samples.size(), 1u) << text;
  EXPECT_EQ(counted->samples[0].label("name"), "a\xEF\xBF\xBD");
  EXPECT_EQ(counted->samples[0].value, 3);
  EXPECT_TRUE(contains_line(text, "callback_names{name=\"b\xEF\xBF\xBD\"} 4")) << text;
}

TEST(MetricsFormat, OrderIsDeterministic) {
  std::vector<std::vector<std::string>> tuples;
  for (const char* method : {"SubmitJob", "WatchJob", "GetJob", "Upload"}) {
    for (const char* code : {"OK", "NOT_FOUND", "INVALID_ARGUMENT"}) tuples.push_back({method, code});
  }
  std::string reference;
  std::mt19937 rng(7);
  for (int round = 0; round < 4; ++round) {
    std::shuffle(tuples.begin(), tuples.end(), rng);
    MetricsRegistry registry;
    auto& rpcs = registry.counter("rpcs_total", "RPCs by method and code", {"method", "code"});
    for (const auto& t : tuples) rpcs.with(t).inc();
    const std::string text = registry.render();
    if (round == 0) {
      reference = text;
      const Exposition exposition = parse_or_fail(text);
      ASSERT_EQ(exposition.families.size(), 1u);
      const auto& samples = exposition.families[0].samples;
      ASSERT_EQ(samples.size(), tuples.size());
      for (std::size_t i = 0; i < samples.size(); ++i) {
        ASSERT_EQ(samples[i].labels.size(), 2u);
        EXPECT_EQ(samples[i].labels[0].first, "method");  // declaration order
        EXPECT_EQ(samples[i].labels[1].first, "code");
        if (i > 0) {
          EXPECT_LT(std::make_pair(samples[i - 1].labels[0].second, samples[i - 1].labels[1].second),
                    std::make_pair(samples[i].labels[0].second, samples[i].labels[1].second));
        }
      }
    } else {
      EXPECT_EQ(text, reference) << "insertion order changed the output";
    }
  }
}

TEST(MetricsFormat, Values) {
  EXPECT_EQ(format_metric_value(0), "0");
  EXPECT_EQ(format_metric_value(3), "3");
  EXPECT_EQ(format_metric_value(-2.5), "-2.5");
  EXPECT_EQ(format_metric_value(0.005), "0.005");
  EXPECT_EQ(format_metric_value(std::numeric_limits<double>::infinity()), "+Inf");
  EXPECT_EQ(format_metric_value(-std::numeric_limits<double>::infinity()), "-Inf");
  EXPECT_EQ(format_metric_value(std::nan("")), "NaN");
  for (double v : {1e-9, 1.0 / 3.0, 123456789.123, 1e300, 9007199254740993.0}) {
    EXPECT_EQ(std::strtod(format_metric_value(v).c_str(), nullptr), v) << "round trip of " << v;
  }
}

TEST(MetricsFormat, BucketHelpers) {
  const auto latency = latency_buckets();
  ASSERT_FALSE(latency.empty());
  EXPECT_DOUBLE_EQ(latency.front(), 0.005);
  EXPECT_DOUBLE_EQ(latency.back(), 600);
  for (std::size_t i = 1; i < latency.size(); ++i) {
    EXPECT_GT(latency[i], latency[i - 1]);
    EXPECT_LE(latency[i] / latency[i - 1], 2.6) << "roughly exponential, no big gaps";
  }
  const auto bytes = byte_buckets();
  EXPECT_DOUBLE_EQ(bytes.front(), 1024);
  EXPECT_DOUBLE_EQ(bytes.back(), 1024.0 * 1024 * 1024);
  EXPECT_EQ(exponential_buckets(1, 2, 4), (std::vector<double>{1, 2, 4, 8}));
  EXPECT_EQ(linear_buckets(0, 0.5, 3), (std::vector<double>{0, 0.5, 1}));
  EXPECT_THROW(exponential_buckets(0, 2, 3), std::invalid_argument);
  EXPECT_THROW(exponential_buckets(1, 1, 3), std::invalid_argument);
  EXPECT_THROW(linear_buckets(0, 1, 0), std::invalid_argument);
  MetricsRegistry registry;
  EXPECT_NO_THROW(registry.histogram("bytes", "B", bytes));
  EXPECT_NO_THROW(registry.histogram("latency", "L", latency));
}

// --- Registration errors ----------------------------------------------------------------------------------------

template <class F>
std::string invalid_argument_message(F&& f) {
  try {
    f();
  } catch (const std::invalid_argument& e) {
    return e.what();
  } catch (const std::exception& e) {
    return std::string("wrong exception type: ") + e.what();
  }
  return "no exception";
}

TEST(MetricsRegistry, BadNamesAndShapesThrow) {
  MetricsRegistry registry;
  for (const char* bad : {"", "1abc", "a-b", "a b", "é", "a.b"}) {
    const std::string message = invalid_argument_message([&] { registry.counter(bad, "help"); });
    EXPECT_NE(message.find("is invalid"), std::string::npos) << "name '" << bad << "': " << message;
  }
  EXPECT_NO_THROW(registry.counter("ok:name_1", "help", {"_x", "Y2"}));
  for (const std::vector<std::string>& labels :
       std::vector<std::vector<std::string>>{{"1x"}, {"a-b"}, {"a:b"}, {""}, {"__reserved"}, {"dup", "dup"}}) {
    const std::string message = invalid_argument_message([&] { registry.counter("m_total", "help", labels); });
    EXPECT_NE(message.find("m_total"), std::string::npos) << message;
    EXPECT_NE(message.find("label name"), std::string::npos) << message;
  }
  EXPECT_NE(invalid_argument_message([&] { registry.histogram("h", "help", {1}, {"le"}); }).find("reserved"),
            std::string::npos);
  EXPECT_NE(invalid_argument_message([&] { registry.counter("no_help", ""); }).find("help"), std::string::npos);

  // Unique names, including the series a histogram adds.
  registry.counter("dup_total", "first");
  EXPECT_NE(invalid_argument_message([&] { registry.gauge("dup_total", "second"); }).find("already registered"),
            std::string::npos);
  registry.histogram("rt_seconds", "help", {1});
  EXPECT_NE(invalid_argument_message([&] { registry.counter("rt_seconds_count", "clash"); }).find("rt_seconds_count"),
            std::string::npos);
  registry.counter("x_sum", "help");
  EXPECT_THROW(registry.histogram("x", "help", {1}), std::invalid_argument);
  EXPECT_THROW(registry.gauge_callback("rt_seconds", "help", [] { return 1.0; }), std::invalid_argument);

  // Buckets.
  EXPECT_NE(invalid_argument_message([&] {
              registry.histogram("b1", "h", {1, 1});
            }).find("strictly increasing"),
            std::string::npos);
  EXPECT_THROW(registry.histogram("b2", "h", {2, 1}), std::invalid_argument);
  EXPECT_THROW(registry.histogram("b3", "h", {1, std::numeric_limits<double>::infinity()}), std::invalid_argument);
  EXPECT_THROW(registry.histogram("b4", "h", {std::nan("")}), std::invalid_argument);

  // Label arity and counter direction.
  auto& rpcs = registry.counter("rpcs_total", "RPCs", {"method", "code"});
  EXPECT_NE(invalid_argument_message([&] { rpcs.with({"SubmitJob"}); }).find("expected 2"), std::string::npos);
  EXPECT_THROW(rpcs.with({"a", "b", "c"}), std::invalid_argument);
  EXPECT_THROW(rpcs.with(), std::invalid_argument);
  EXPECT_THROW(rpcs.with({"a", "b"}).inc(-1), std::invalid_argument);
  EXPECT_THROW(rpcs.with({"a", "b"}).inc(std::nan("")), std::invalid_argument);
  EXPECT_EQ(rpcs.with({"a", "b"}).value(), 0.0);

  // The failed registrations left nothing behind: the output still parses.
  parse_or_fail(registry.render());
}

TEST(MetricsRegistry, WithReturnsStableReferences) {
  MetricsRegistry registry;
  auto& family = registry.gauge("g", "help", {"k"});
  Gauge& first = family.with({"a"});
  first.set(4);
  for (int i = 0; i < 1000; ++i) family.with({std::to_string(i)}).set(i);
  EXPECT_EQ(&family.with({"a"}), &first);
  EXPECT_EQ(&family.with(std::vector<std::string>{"a"}), &first);
  EXPECT_NE(&family.with({"b"}), &first);
  EXPECT_EQ(first.value(), 4);
  first.add(-1.5);
  first.dec();
  EXPECT_EQ(family.with({"a"}).value(), 1.5);
}

TEST(MetricsRegistry, CallbackErrorsSurfaceAtRender) {
  {
    MetricsRegistry registry;
    registry.gauge_callback_family("jobs", "help", {"state"}, [] {
      return std::vector<LabelledValue>{{{"a", "b"}, 1}};
    });
    EXPECT_THROW(registry.render(), std::invalid_argument);
  }
  {
    MetricsRegistry registry;
    registry.gauge_callback_family("jobs", "help", {"state"}, [] {
      return std::vector<LabelledValue>{{{"a"}, 1}, {{"a"}, 2}};
    });
    EXPECT_NE(invalid_argument_message([&] { registry.render(); }).find("more than once"), std::string::npos);
  }
  {
    MetricsRegistry registry;
    registry.gauge_callback("depth", "help", []() -> double { throw std::runtime_error("scheduler gone"); });
    EXPECT_THROW(registry.render(), std::runtime_error);
  }
  MetricsRegistry registry;
  EXPECT_THROW(registry.gauge_callback("depth", "help", nullptr), std::invalid_argument);
  // A callback may itself use the registry (it runs without the registry lock).
  auto& scrapes = registry.counter("scrapes_total", "Renders");
  registry.gauge_callback("self", "help", [&] {
    scrapes.with().inc();
    return scrapes.with().value();
  });
  registry.render();
  EXPECT_TRUE(contains_line(registry.render(), "self 2"));
}

// --- Concurrency ------------------------------------------------------------------------------------------------

TEST(MetricsConcurrency, ParallelUpdatesAreExactAndScrapesStayValid) {
  MetricsRegistry registry;
  auto& frames = registry.counter("frames_total", "Frames", {"kind"});
  auto& busy = registry.gauge("busy", "Busy");
  auto& stage = registry.histogram("stage_seconds", "Stage", latency_buckets(), {"stage"});
  constexpr int kThreads = 8;
  constexpr int kIterations = 400000;
  std::atomic<bool> done{false};
  std::atomic<int> scrapes{0};
  std::thread scraper([&] {
    while (!done.load()) {
      const Exposition e = parse_or_fail(registry.render());
      check_histograms(e);
      scrapes.fetch_add(1);
    }
  });
  std::vector<std::thread> threads;
  std::latch start(kThreads);
  for (int t = 0; t < kThreads; ++t) {
    threads.emplace_back([&, t] {
      start.arrive_and_wait();  // maximal overlap
      Counter& cached = frames.with({"isosurface"});
      Histogram& polygonize = stage.with({"polygonize"});
      Gauge& busy_gauge = busy.with();
      // Tight loops on cached references (where a non-atomic update would lose increments) ...
      for (int i = 0; i < kIterations; ++i) cached.inc();
      for (int i = 0; i < kIterations; ++i) polygonize.observe(0.001 * (i % 1000));
      for (int i = 0; i < kIterations; ++i) {
        busy_gauge.inc();
        busy_gauge.dec();
      }
      // ... and lookups racing with first-time creation.
      for (int i = 0; i < kIterations / 10; ++i) frames.with({t % 2 ? "odd" : "even"}).inc(0.5);
    });
  }
  for (auto& thread : threads) thread.join();
  done.store(true);
  scraper.join();
  EXPECT_EQ(frames.with({"isosurface"}).value(), double{kThreads} * kIterations);
  EXPECT_EQ(frames.with({"odd"}).value(), 0.5 * (kThreads / 2) * (kIterations / 10));
  EXPECT_EQ(busy.with().value(), 0.0);
  const auto snapshot = stage.with({"polygonize"}).snapshot();
  EXPECT_EQ(snapshot.count, static_cast<std::uint64_t>(kThreads) * kIterations);
  EXPECT_NEAR(snapshot.sum, kThreads * (kIterations / 1000) * 0.001 * (999 * 1000 / 2), 1e-3);
  EXPECT_GT(scrapes.load(), 0);
  EXPECT_EQ(check_histograms(parse_or_fail(registry.render())), 1);
}

// --- HTTP endpoint ----------------------------------------------------------------------------------------------

struct HttpResponse {
  int status = 0;
  std::map<std::string, std::string> headers;  // lower-case names
  std::string body;
  std::string raw;
};

int connect_to(int port, int family = AF_INET) {
  const int fd = socket(family, SOCK_STREAM | SOCK_CLOEXEC, 0);
  if (fd < 0) return -1;
  timeval tv{5, 0};
  setsockopt(fd, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof tv);
  setsockopt(fd, SOL_SOCKET, SO_SNDTIMEO, &tv, sizeof tv);
  int rc;
  if (family == AF_INET6) {
    sockaddr_in6 a{};
    a.sin6_family = AF_INET6;
    a.sin6_port = htons(static_cast<std::uint16_t>(port));
    a.sin6_addr = in6addr_loopback;
    rc = connect(fd, reinterpret_cast<sockaddr*>(&a), sizeof a);
  } else {
    sockaddr_in a{};
    a.sin_family = AF_INET;
    a.sin_port = htons(static_cast<std::uint16_t>(port));
    a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    rc = connect(fd, reinterpret_cast<sockaddr*>(&a), sizeof a);
  }
  if (rc != 0) {
    close(fd);
    return -1;
  }
  return fd;
}

bool send_all(int fd, std::string_view data) {
  while (!data.empty()) {
    const ssize_t n = send(fd, data.data(), data.size(), MSG_NOSIGNAL);
    if (n <= 0) return false;
    data.remove_prefix(static_cast<std::size_t>(n));
  }
  return true;
}

// Reads until the server closes (or 5 s pass).
std::string read_all(int fd) {
  std::string out;
  char buffer[4096];
  for (;;) {
    const ssize_t n = recv(fd, buffer, sizeof buffer, 0);
    if (n <= 0) break;
    out.append(buffer, static_cast<std::size_t>(n));
  }
  return out;
}

HttpResponse parse_response(std::string raw) {
  HttpResponse r;
  r.raw = raw;
  const std::size_t end = raw.find("\r\n\r\n");
  if (raw.rfind("HTTP/1.1 ", 0) != 0 || end == std::string::npos) return r;
  r.status = std::atoi(raw.c_str() + 9);
  std::size_t pos = raw.find("\r\n") + 2;
  while (pos < end) {
    const std::size_t eol = raw.find("\r\n", pos);
    const std::string line = raw.substr(pos, eol - pos);
    const std::size_t colon = line.find(':');
    std::string name = line.substr(0, colon);
    std::transform(name.begin(), name.end(), name.begin(), [](unsigned char c) { return std::tolower(c); });
    r.headers[name] = line.substr(std::min(line.size(), colon + 2));
    pos = eol + 2;
  }
  r.body = raw.substr(end + 4);
  return r;
}

HttpResponse http_exchange(int port, std::string_view request, int family = AF_INET) {
  const int fd = connect_to(port, family);
  if (fd < 0) return {};
  send_all(fd, request);
  HttpResponse r = parse_response(read_all(fd));
  close(fd);
  return r;
}

HttpResponse get(int port, const std::string& path) {
  return http_exchange(port, "GET " + path + " HTTP/1.1\r\nHost: localhost\r\nUser-Agent: test\r\n\r\n");
}

struct MetricsHttpTest : ::testing::Test {
  void SetUp() override {
    registry.counter("surfacer_frames_total", "Frames finished", {"kind"}).with({"isosurface"}).inc(5);
    registry.histogram("surfacer_stage_seconds", "Stage latency", latency_buckets(), {"stage"})
        .with({"encode"})
        .observe(0.02);
  }
  MetricsRegistry registry;
};

TEST_F(MetricsHttpTest, ServesMetricsAndHealth) {
  auto server = MetricsHttpServer::start(registry, "127.0.0.1:0");
  ASSERT_GT(server->port(), 0);
  EXPECT_EQ(server->address(), "127.0.0.1:" + std::to_string(server->port()));

  const HttpResponse metrics = get(server->port(), "/metrics");
  ASSERT_EQ(metrics.status, 200) << metrics.raw;
  EXPECT_EQ(metrics.headers.at("content-type"), "text/plain; version=0.0.4; charset=utf-8");
  EXPECT_EQ(metrics.headers.at("connection"), "close");
  EXPECT_EQ(metrics.headers.at("content-length"), std::to_string(metrics.body.size()));
  EXPECT_EQ(metrics.body, registry.render());
  EXPECT_TRUE(contains_line(metrics.body, R"(surfacer_frames_total{kind="isosurface"} 5)"));
  EXPECT_EQ(check_histograms(parse_or_fail(metrics.body)), 1);

  EXPECT_EQ(get(server->port(), "/metrics?name[]=x").status, 200);
  const HttpResponse head = http_exchange(server->port(), "HEAD /metrics HTTP/1.0\r\n\r\n");
  EXPECT_EQ(head.status, 200) << head.raw;
  EXPECT_TRUE(head.body.empty());
  EXPECT_EQ(head.headers.at("content-length"), std::to_string(metrics.body.size()));

  const HttpResponse health = get(server->port(), "/healthz");
  EXPECT_EQ(health.status, 200);
  EXPECT_EQ(health.body, "ok\n");
  // Bare LF line endings are accepted too.
  EXPECT_EQ(http_exchange(server->port(), "GET /healthz HTTP/1.1\nHost: x\n\n").status, 200);
}

TEST_F(MetricsHttpTest, ErrorStatuses) {
  MetricsHttpOptions options;
  options.read_timeout = 300ms;
  auto server = MetricsHttpServer::start(registry, "127.0.0.1:0", options);
  const int port = server->port();
  EXPECT_EQ(get(port, "/").status, 404);
  EXPECT_EQ(get(port, "/metricsx").status, 404);
  const HttpResponse post = http_exchange(port, "POST /metrics HTTP/1.1\r\nContent-Length: 3\r\n\r\nabc");
  EXPECT_EQ(post.status, 405) << post.raw;
  EXPECT_EQ(post.headers.count("allow") ? post.headers.at("allow") : "<none>", "GET, HEAD");
  EXPECT_EQ(http_exchange(port, "DELETE /healthz HTTP/1.1\r\n\r\n").status, 405);
  EXPECT_EQ(http_exchange(port, "GET /metrics HTTP/2.0\r\n\r\n").status, 505);
  for (std::string_view garbage : {"\x16\x03\x01\x02\x00\x01\r\n\r\n"sv, "GET\r\n\r\n"sv,
                                   "GET  /metrics HTTP/1.1\r\n\r\n"sv, "GET metrics HTTP/1.1\r\n\r\n"sv,
                                   "GET /metrics FTP/1.0\r\n\r\n"sv, "GET /metrics HTTP/1.1\r\nno colon here\r\n\r\n"sv,
                                   "G(T /metrics HTTP/1.1\r\n\r\n"sv, "GET /metrics\x00 HTTP/1.1\r\n\r\n"sv}) {
    const HttpResponse r = http_exchange(port, garbage);
    EXPECT_EQ(r.status, 400) << "request: " << garbage << "\nresponse: " << r.raw;
  }
  // Head larger than 8 KiB: 431; the server stops reading early, and the response must still arrive whole
  // (before closing it drains what the client sent, so the close is not a reset).
  const HttpResponse big =
      http_exchange(port, "GET /metrics HTTP/1.1\r\nX-Big: " + std::string(64 * 1024, 'a') + "\r\n\r\n");
  EXPECT_EQ(big.status, 431) << big.raw.substr(0, 200);
  // Half a request, then nothing: 408 after read_timeout.
  const auto start = Clock::now();
  const HttpResponse slow = http_exchange(port, "GET /metr");
  EXPECT_EQ(slow.status, 408) << slow.raw;
  EXPECT_GE(Clock::now() - start, 250ms);
  EXPECT_LT(Clock::now() - start, 3s);
  // Half a request, then the client half-closes: 400.
  {
    const int fd = connect_to(port);
    ASSERT_GE(fd, 0);
    send_all(fd, "GET /metrics HTTP/1.1\r\n");
    shutdown(fd, SHUT_WR);
    EXPECT_EQ(parse_response(read_all(fd)).status, 400);
    close(fd);
  }
  EXPECT_EQ(get(port, "/metrics").status, 200);
}

TEST_F(MetricsHttpTest, GarbageAndAbruptClientsDoNotKillTheServer) {
  auto server = MetricsHttpServer::start(registry, "127.0.0.1:0");
  const int port = server->port();
  std::mt19937 rng(3);
  for (int i = 0; i < 20; ++i) {
    std::string junk(1 + rng() % 3000, '\0');
    for (char& c : junk) c = static_cast<char>(rng());
    const int fd = connect_to(port);
    ASSERT_GE(fd, 0);
    send_all(fd, junk);
    if (i % 2 == 0) {
      // Reset the connection instead of closing it cleanly.
      linger l{1, 0};
      setsockopt(fd, SOL_SOCKET, SO_LINGER, &l, sizeof l);
    }
    close(fd);
  }
  // Connect and vanish without sending anything.
  for (int i = 0; i < 5; ++i) close(connect_to(port));
  const HttpResponse after = get(port, "/metrics");
  EXPECT_EQ(after.status, 200);
  EXPECT_EQ(after.body, registry.render());
}

TEST_F(MetricsHttpTest, SlowAndIdleClientsDoNotBlockOthers) {
  auto server = MetricsHttpServer::start(registry, "127.0.0.1:0");  // default read timeout: 5 s
  const int port = server->port();
  std::vector<int> stalled;
  for (int i = 0; i < 5; ++i) {
    const int fd = connect_to(port);
    ASSERT_GE(fd, 0);
    if (i % 2 == 0) send_all(fd, "GET /metrics HTTP/1.1\r\nHost: slow");
    stalled.push_back(fd);
  }
  const auto start = Clock::now();
  std::vector<std::thread> clients;
  std::atomic<int> ok{0};
  for (int t = 0; t < 8; ++t) {
    clients.emplace_back([&] {
      for (int i = 0; i < 10; ++i) ok += get(port, i % 2 ? "/metrics" : "/healthz").status == 200;
    });
  }
  for (auto& c : clients) c.join();
  EXPECT_EQ(ok.load(), 80);
  EXPECT_LT(Clock::now() - start, 3s) << "requests waited for the stalled clients";
  for (int fd : stalled) close(fd);
}

TEST_F(MetricsHttpTest, StopIsPromptWhileAClientHoldsAnIdleConnection) {
  auto server = MetricsHttpServer::start(registry, "127.0.0.1:0");
  const int port = server->port();
  const int idle = connect_to(port);
  ASSERT_GE(idle, 0);
  const int partial = connect_to(port);
  ASSERT_GE(partial, 0);
  send_all(partial, "GET /met");
  EXPECT_EQ(get(port, "/healthz").status, 200);  // the server has accepted both by now
  const auto start = Clock::now();
  server->stop();
  const auto elapsed = Clock::now() - start;
  EXPECT_LT(elapsed, 500ms) << std::chrono::duration<double>(elapsed).count() << " s";
  // The idle client sees the connection closed, and nobody listens any more.
  char byte;
  EXPECT_LE(recv(idle, &byte, 1, 0), 0);
  EXPECT_LT(connect_to(port), 0);
  server->stop();  // idempotent
  close(idle);
  close(partial);
}

// A connection from `source` (an IPv4 loopback address such as "127.0.0.2") to the server's loopback port.
int connect_from(const char* source, int port) {
  const int fd = socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
  if (fd < 0) return -1;
  sockaddr_in local{};
  local.sin_family = AF_INET;
  inet_pton(AF_INET, source, &local.sin_addr);
  sockaddr_in remote{};
  remote.sin_family = AF_INET;
  remote.sin_port = htons(static_cast<std::uint16_t>(port));
  remote.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  if (bind(fd, reinterpret_cast<sockaddr*>(&local), sizeof local) != 0 ||
      connect(fd, reinterpret_cast<sockaddr*>(&remote), sizeof remote) != 0) {
    close(fd);
    return -1;
  }
  timeval tv{5, 0};
  setsockopt(fd, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof tv);
  return fd;
}

// 200 idle connections from one peer (more than max_connections) used to take every slot: every scrape was closed
// unanswered for as long as they were held. Now the oldest idle connection gives way to each new one, one peer holds
// at most max_connections_per_peer, and another peer's connection is left alone.
TEST_F(MetricsHttpTest, IdleConnectionsFromOnePeerDoNotLockScrapesOut) {
  auto server = MetricsHttpServer::start(registry, "127.0.0.1:0");
  const int port = server->port();
  const int other_peer = connect_from("127.0.0.2", port);
  ASSERT_GE(other_peer, 0) << std::strerror(errno);
  std::vector<int> idle;
  for (int i = 0; i < 200; ++i) {
    const int fd = connect_to(port);
    ASSERT_GE(fd, 0) << "connection " << i;
    idle.push_back(fd);
  }
  EXPECT_EQ(get(port, "/healthz").status, 200);  // the server has seen all of them by now
  // The other peer's connection, idle all along (within the read timeout), still serves its request.
  ASSERT_TRUE(send_all(other_peer, "GET /metrics HTTP/1.1\r\n\r\n"));
  EXPECT_EQ(parse_response(read_all(other_peer)).status, 200);
  close(other_peer);
  const auto start = Clock::now();
  int ok = 0;
  for (int i = 0; i < 50; ++i) ok += get(port, "/metrics").status == 200;
  EXPECT_EQ(ok, 50);
  EXPECT_LT(Clock::now() - start, 2s);
  // The attacker keeps at most max_connections_per_peer of its 200: the rest were closed by the server.
  int open = 0;
  for (const int fd : idle) {
    pollfd p{fd, POLLIN, 0};
    char byte;
    open += poll(&p, 1, 0) == 0 || recv(fd, &byte, 1, MSG_DONTWAIT) > 0;
  }
  EXPECT_LE(open, MetricsHttpOptions{}.max_connections_per_peer);
  for (const int fd : idle) close(fd);
}

// A client that has connected but not yet sent its request is the freshest connection there is: when its address is
// at max_connections_per_peer, the connections that sent part of a request and then went quiet give way first. Each
// connection below is known to be accepted (a request from another address is answered after it) before the next.
TEST_F(MetricsHttpTest, AClientAboutToSendOutlastsStalledOnes) {
  auto server = MetricsHttpServer::start(registry, "127.0.0.1:0");
  const int port = server->port();
  const auto accepted = [&] {
    const int probe = connect_from("127.0.0.2", port);
    ASSERT_GE(probe, 0) << std::strerror(errno);
    ASSERT_TRUE(send_all(probe, "GET /healthz HTTP/1.1\r\n\r\n"));
    ASSERT_EQ(parse_response(read_all(probe)).status, 200);
    close(probe);
  };
  std::vector<int> stalled;
  for (int i = 0; i < MetricsHttpOptions{}.max_connections_per_peer; ++i) {
    stalled.push_back(connect_to(port));
    ASSERT_GE(stalled.back(), 0);
    ASSERT_TRUE(send_all(stalled.back(), "GET /metrics HTTP/1.1\r\nHost: slow"));
  }
  accepted();
  std::this_thread::sleep_for(20ms);  // the stalled ones are now quiet for a while
  for (int round = 0; round < 3; ++round) {
    const int about_to_send = connect_to(port);
    ASSERT_GE(about_to_send, 0);
    accepted();
    const int next = connect_to(port);  // the peer is over its limit again
    ASSERT_GE(next, 0);
    accepted();
    ASSERT_TRUE(send_all(about_to_send, "GET /healthz HTTP/1.1\r\n\r\n")) << "round " << round;
    EXPECT_EQ(parse_response(read_all(about_to_send)).status, 200) << "round " << round;
    close(about_to_send);
    ASSERT_TRUE(send_all(next, "GET /healthz HTTP/1.1\r\n\r\n"));
    EXPECT_EQ(parse_response(read_all(next)).status, 200) << "round " << round;
    close(next);
  }
  for (const int fd : stalled) close(fd);
}

TEST_F(MetricsHttpTest, IdleConnectionsAreClosedAfterTheReadTimeout) {
  MetricsHttpOptions options;
  options.read_timeout = 200ms;
  auto server = MetricsHttpServer::start(registry, "127.0.0.1:0", options);
  const int fd = connect_to(server->port());
  ASSERT_GE(fd, 0);
  const auto start = Clock::now();
  const HttpResponse closed = parse_response(read_all(fd));  // returns once the server closes
  EXPECT_EQ(closed.status, 408) << closed.raw;
  EXPECT_LT(Clock::now() - start, 1500ms);
  close(fd);
}

TEST(HttpRequestHead, ParsesAndRefuses) {
  const std::string_view request = "GET /metrics?x=1 HTTP/1.1\r\nHost: a\r\n\r\ntrailing";
  ASSERT_EQ(request_head_end(request), request.find("trailing"));
  const RequestHead ok = parse_request_head(request.substr(0, request_head_end(request)));
  EXPECT_EQ(ok.error_status, 0) << ok.error;
  EXPECT_EQ(ok.method, "GET");
  EXPECT_EQ(ok.path, "/metrics");
  EXPECT_EQ(request_head_end("GET / HTTP/1.1\r\nHost: a\r\n"), std::string_view::npos);
  EXPECT_EQ(request_head_end("GET / HTTP/1.1\n\n"), 16u);
  EXPECT_EQ(parse_request_head("GET / HTTP/2\r\n\r\n").error_status, 505);
  for (std::string_view bad : {""sv, "GET\r\n\r\n"sv, "GET / HTTP/1.1\r\n: x\r\n\r\n"sv, "GET x HTTP/1.1\r\n\r\n"sv,
                               "G@T / HTTP/1.1\r\n\r\n"sv}) {
    EXPECT_EQ(parse_request_head(bad).error_status, 400) << bad;
  }
}

TEST_F(MetricsHttpTest, HealthCallbackAndRenderFailures) {
  std::atomic<bool> healthy{true};
  std::atomic<bool> broken{false};
  registry.gauge_callback("flaky", "Throws when broken", [&]() -> double {
    if (broken.load()) throw std::runtime_error("queue is gone");
    return 1;
  });
  MetricsHttpOptions options;
  options.healthy = [&] { return healthy.load(); };
  auto server = MetricsHttpServer::start(registry, "localhost:0", options);
  const int family = server->address().starts_with("[") ? AF_INET6 : AF_INET;
  EXPECT_EQ(http_exchange(server->port(), "GET /healthz HTTP/1.1\r\n\r\n", family).status, 200);
  healthy = false;
  const HttpResponse draining = http_exchange(server->port(), "GET /healthz HTTP/1.1\r\n\r\n", family);
  EXPECT_EQ(draining.status, 503);
  broken = true;
  const HttpResponse failed = http_exchange(server->port(), "GET /metrics HTTP/1.1\r\n\r\n", family);
  EXPECT_EQ(failed.status, 500);
  EXPECT_NE(failed.body.find("queue is gone"), std::string::npos) << failed.raw;
  broken = false;
  EXPECT_EQ(http_exchange(server->port(), "GET /metrics HTTP/1.1\r\n\r\n", family).status, 200);
}

TEST_F(MetricsHttpTest, AddressForms) {
  {
    auto any = MetricsHttpServer::start(registry, "0.0.0.0:0");
    EXPECT_EQ(get(any->port(), "/healthz").status, 200);
  }
  {
    std::unique_ptr<MetricsHttpServer> v6;
    try {
      v6 = MetricsHttpServer::start(registry, "[::1]:0");
    } catch (const std::runtime_error& e) {
      GTEST_SKIP() << "no IPv6 loopback here: " << e.what();
    }
    EXPECT_EQ(v6->address(), "[::1]:" + std::to_string(v6->port()));
    EXPECT_EQ(http_exchange(v6->port(), "GET /healthz HTTP/1.1\r\n\r\n", AF_INET6).status, 200);
  }
}

TEST_F(MetricsHttpTest, BindFailuresAndBadAddressesThrowClearly) {
  auto first = MetricsHttpServer::start(registry, "127.0.0.1:0");
  const std::string taken = "127.0.0.1:" + std::to_string(first->port());
  try {
    MetricsHttpServer::start(registry, taken);
    ADD_FAILURE() << "binding a taken port succeeded";
  } catch (const std::runtime_error& e) {
    const std::string message = e.what();
    EXPECT_NE(message.find(taken), std::string::npos) << message;
    EXPECT_NE(message.find("in use"), std::string::npos) << message;
  }
  for (const char* bad : {"nonsense", "127.0.0.1", "127.0.0.1:99999", "127.0.0.1:-1", "127.0.0.1:http", ":9090",
                          "::1:9090", "[::1]9090", "[::1", "192.0.2.1:0"}) {
    try {
      MetricsHttpServer::start(registry, bad);
      ADD_FAILURE() << "'" << bad << "' was accepted";
    } catch (const std::runtime_error& e) {
      EXPECT_NE(std::string(e.what()).find(bad), std::string::npos) << e.what();
    }
  }
  EXPECT_EQ(get(first->port(), "/healthz").status, 200);
}

}  // namespace
}  // namespace surfacer::server
