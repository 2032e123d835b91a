// Prometheus metrics on prometheus-cpp (Debian prometheus-cpp-dev): counters, gauges and histograms in labelled
// families held by a prometheus::Registry, gauge callbacks sampled at scrape time, and the text exposition format
// 0.0.4 (https://prometheus.io/docs/instrumenting/exposition_formats/) written by prometheus::TextSerializer. Served
// over HTTP by MetricsHttpServer (server/metrics_http.h).
//
//   MetricsRegistry registry;
//   auto& frames = registry.counter("surfacer_frames_total", "Frames finished", {"kind"});
//   Counter& iso_frames = frames.with({"isosurface"});   // stable reference: cache it
//   iso_frames.inc();
//   auto& stage = registry.histogram("surfacer_stage_seconds", "Stage latency", latency_buckets(), {"stage"});
//   { ScopedTimer t(stage.with({"polygonize"})); ... }  // observes the elapsed seconds on scope exit
//   registry.gauge_callback("surfacer_queue_depth", "Jobs waiting", [&] { return double(sched.queued_jobs()); });
//   std::string text = registry.render();
//
// What this layer adds to prometheus-cpp: the registration checks below (with messages that say how to fix them),
// counters that refuse to go down, callback gauges, label values made valid UTF-8, and a stable text: families in
// registration order, labels in declaration order and samples sorted by label values (prometheus-cpp collects
// families by type, labels by name and samples in hash order).
//
// Thread safety: everything here may be called from any thread. Counter and Gauge updates are atomics; a Histogram
// update takes that histogram's own mutex. Registration and family.with() take a mutex (with() returns the same
// reference for the same label values for the registry's lifetime, so look it up once and keep the reference on hot
// paths). render() takes the registry mutex only to copy the family list; callbacks run without any registry lock.
//
// Lifetime: metric references stay valid as long as the registry. Callbacks are invoked by render() (on the
// scrape thread); whatever they capture must outlive the last render() - stop the MetricsHttpServer before
// destroying the objects the callbacks read.
#pragma once

#include <prometheus/metric_type.h>

#include <chrono>
#include <cstdint>
#include <functional>
#include <initializer_list>
#include <map>
#include <memory>
#include <mutex>
#include <span>
#include <string>
#include <string_view>
#include <vector>

namespace prometheus {
class Counter;
class Gauge;
class Histogram;
class Registry;
template <typename T>
class Family;
struct ClientMetric;
struct MetricFamily;
}  // namespace prometheus

namespace surfacer::server {

// A monotonically increasing value (events, bytes, seconds spent). Starts at 0.
class Counter {
 public:
  using Library = prometheus::Counter;
  static constexpr prometheus::MetricType kType = prometheus::MetricType::Counter;
  explicit Counter(prometheus::Counter& counter) : counter_(counter) {}

  // Adds `amount` (default 1). Throws std::invalid_argument when amount is negative or NaN.
  void inc(double amount = 1.0);
  double value() const;

 private:
  prometheus::Counter& counter_;
};

// A value that goes up and down (bytes in use, threads busy). Starts at 0.
class Gauge {
 public:
  using Library = prometheus::Gauge;
  static constexpr prometheus::MetricType kType = prometheus::MetricType::Gauge;
  explicit Gauge(prometheus::Gauge& gauge) : gauge_(gauge) {}

  void set(double value);
  void add(double delta);
  void inc() { add(1.0); }
  void dec() { add(-1.0); }
  double value() const;

 private:
  prometheus::Gauge& gauge_;
};

// Observations counted into fixed buckets. Rendered as cumulative `<name>_bucket{le="<bound>"}` samples (one per
// upper bound, then le="+Inf"), `<name>_sum` and `<name>_count`. An observation v falls into the first bucket with
// v <= bound; NaN counts only in +Inf (and makes the sum NaN).
class Histogram {
 public:
  using Library = prometheus::Histogram;
  static constexpr prometheus::MetricType kType = prometheus::MetricType::Histogram;
  explicit Histogram(prometheus::Histogram& histogram) : histogram_(histogram) {}

  void observe(double value);
  // Observes a duration in seconds.
  template <class Rep, class Period>
  void observe_duration(std::chrono::duration<Rep, Period> elapsed) {
    observe(std::chrono::duration<double>(elapsed).count());
  }

  struct Snapshot {
    std::vector<double> bounds;             // finite upper bounds
    std::vector<std::uint64_t> cumulative;  // bounds.size() + 1 entries, the last one is +Inf == count
    double sum = 0.0;
    std::uint64_t count = 0;
  };
  // A consistent copy (taken under the histogram's mutex): count equals the +Inf bucket, sum matches the counts.
  Snapshot snapshot() const;

 private:
  prometheus::Histogram& histogram_;
};

// Measures the time from construction to destruction and observes it (seconds) into a histogram.
class ScopedTimer {
 public:
  explicit ScopedTimer(Histogram& histogram) : histogram_(histogram), start_(std::chrono::steady_clock::now()) {}
  ~ScopedTimer() { histogram_.observe_duration(std::chrono::steady_clock::now() - start_); }
  ScopedTimer(const ScopedTimer&) = delete;
  ScopedTimer& operator=(const ScopedTimer&) = delete;

 private:
  Histogram& histogram_;
  std::chrono::steady_clock::time_point start_;
};

// --- Bucket helpers (upper bounds; +Inf is always added implicitly) --------------------------------------------
// Latency in seconds, roughly exponential: 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1, 2.5, 5, 10, 25, 50, 100,
// 250, 600.
std::vector<double> latency_buckets();
// Sizes in bytes, powers of 4 from 1 KiB to 1 GiB (11 bounds).
std::vector<double> byte_buckets();
// start, start*factor, ... (count bounds). Throws std::invalid_argument unless start > 0, factor > 1, count >= 1.
std::vector<double> exponential_buckets(double start, double factor, int count);
// start, start+width, ... (count bounds). Throws std::invalid_argument unless width > 0, count >= 1.
std::vector<double> linear_buckets(double start, double width, int count);

namespace detail {

// Compares label-value sequences of std::string or std::string_view, so lookups need no allocation.
struct LabelsLess {
  using is_transparent = void;
  template <class A, class B>
  bool operator()(const A& a, const B& b) const {
    return std::lexicographical_compare(a.begin(), a.end(), b.begin(), b.end(),
                                        [](std::string_view x, std::string_view y) { return x < y; });
  }
};

class FamilyBase {
 public:
  FamilyBase(std::string name, std::string help, prometheus::MetricType type, std::vector<std::string> label_names)
      : name_(std::move(name)), help_(std::move(help)), type_(type), label_names_(std::move(label_names)) {}
  virtual ~FamilyBase() = default;
  FamilyBase(const FamilyBase&) = delete;
  FamilyBase& operator=(const FamilyBase&) = delete;

  const std::string& name() const { return name_; }
  const std::string& help() const { return help_; }
  const std::vector<std::string>& label_names() const { return label_names_; }

  // The family as prometheus::TextSerializer writes it: help escaped, each sample's labels in declaration order,
  // samples sorted by label values. May throw (a callback's exception, or a callback result of the wrong shape).
  prometheus::MetricFamily collect() const;

 protected:
  // The samples, their labels in any order. May throw as collect().
  virtual std::vector<prometheus::ClientMetric> collect_samples() const = 0;
  // Throws std::invalid_argument unless values.size() == label_names().size().
  void check_arity(std::size_t values) const;

 private:
  const std::string name_;
  const std::string help_;
  const prometheus::MetricType type_;
  const std::vector<std::string> label_names_;
};

}  // namespace detail

// Metrics of one name and type, one per distinct tuple of label values. Created by MetricsRegistry.
template <class Metric>
class MetricFamily final : public detail::FamilyBase {
 public:
  // `bounds`: the finite bucket bounds of a histogram family, empty otherwise.
  MetricFamily(std::string name, std::string help, std::vector<std::string> label_names,
               prometheus::Family<typename Metric::Library>& family, std::vector<double> bounds);

  // The metric for these label values (in the order of label_names()), created at 0 on first use. The reference
  // is stable for the registry's lifetime. Takes the family's mutex: cache the result on hot paths. Label values
  // may be any string (escaped when rendered; invalid UTF-8 is rendered as U+FFFD, so two values that differ only
  // in invalid bytes share one sample). Throws std::invalid_argument when the number of values differs from the
  // number of label names. A family without labels: with().
  Metric& with(std::initializer_list<std::string_view> label_values = {});
  Metric& with(const std::vector<std::string>& label_values);

 private:
  Metric& with_span(std::span<const std::string_view> label_values);
  std::vector<prometheus::ClientMetric> collect_samples() const override;

  prometheus::Family<typename Metric::Library>& family_;  // owned by the registry's prometheus::Registry
  const std::vector<double> bounds_;                      // histograms only
  mutable std::mutex mutex_;
  std::map<std::vector<std::string>, std::unique_ptr<Metric>, detail::LabelsLess> children_;
};

extern template class MetricFamily<Counter>;
extern template class MetricFamily<Gauge>;
extern template class MetricFamily<Histogram>;

using CounterFamily = MetricFamily<Counter>;
using GaugeFamily = MetricFamily<Gauge>;
using HistogramFamily = MetricFamily<Histogram>;

// One sample of a labelled gauge callback: label values in the order of the family's label names, and the value.
struct LabelledValue {
  std::vector<std::string> label_values;
  double value = 0.0;
};

class MetricsRegistry {
 public:
  MetricsRegistry();
  ~MetricsRegistry();
  MetricsRegistry(const MetricsRegistry&) = delete;
  MetricsRegistry& operator=(const MetricsRegistry&) = delete;

  // Registration. `name` must match [a-zA-Z_:][a-zA-Z0-9_:]* without a leading "__", each label name
  // [a-zA-Z_][a-zA-Z0-9_]* without a leading "__" (and not "le" for histograms), label names distinct, help
  // non-empty (any text; escaped when rendered). Names must be unique across the registry, including the
  // _bucket/_sum/_count series of histograms. Violations throw std::invalid_argument naming the metric and the rule.
  // The returned family lives as long as the registry. A family without labels renders its single sample (0) from
  // registration on; a labelled one renders a sample per label tuple used so far.
  CounterFamily& counter(const std::string& name, const std::string& help,
                         const std::vector<std::string>& label_names = {});
  GaugeFamily& gauge(const std::string& name, const std::string& help,
                     const std::vector<std::string>& label_names = {});
  // `buckets`: finite, strictly increasing upper bounds (e.g. latency_buckets()); +Inf is added implicitly.
  HistogramFamily& histogram(const std::string& name, const std::string& help, const std::vector<double>& buckets,
                             const std::vector<std::string>& label_names = {});

  // A gauge whose value is read by calling `sample` at every render() (queue depth, running jobs).
  void gauge_callback(const std::string& name, const std::string& help, std::function<double()> sample);
  // A labelled gauge family read at every render(): `sample` returns one LabelledValue per label tuple (jobs by
  // state: {{"queued"}, 3}, {{"running"}, 2}, ...). Samples are rendered sorted by label values. render() throws
  // std::invalid_argument if a result has the wrong number of label values or repeats a tuple.
  void gauge_callback_family(const std::string& name, const std::string& help,
                             const std::vector<std::string>& label_names,
                             std::function<std::vector<LabelledValue>()> sample);

  // The whole registry in the text exposition format 0.0.4 (Content-Type `text/plain; version=0.0.4;
  // charset=utf-8`), by prometheus::TextSerializer: families in registration order, `# HELP` and `# TYPE` once per
  // family, samples sorted by label values, label names in declaration order; values with 16 significant digits
  // (NaN written "Nan", which Prometheus reads). Propagates exceptions thrown by callbacks.
  std::string render() const;

 private:
  // Checks the name, help and label names and that the family's series names are free; then, under the registry
  // mutex, reserves the names and keeps make()'s family in registration order. Throws as the registration methods.
  detail::FamilyBase& add(const std::string& name, const std::string& help, prometheus::MetricType type,
                          const std::vector<std::string>& label_names,
                          const std::function<std::unique_ptr<detail::FamilyBase>()>& make);

  const std::unique_ptr<prometheus::Registry> registry_;  // owns the families' metrics
  mutable std::mutex mutex_;
  std::vector<std::unique_ptr<detail::FamilyBase>> families_;  // registration order
  std::vector<std::string> series_names_;                      // every sample name in use
};

// --- Text-format building blocks -------------------------------------------------------------------------------
// Formats a value for messages: shortest round-trip decimal, or +Inf, -Inf, NaN.
std::string format_metric_value(double value);
// Escapes a label value: backslash, double quote and newline become \\, \" and \n; invalid UTF-8 becomes U+FFFD.
// (render() makes label values valid UTF-8 and leaves the escapes to prometheus::TextSerializer.)
std::string escape_label_value(std::string_view value);
// Escapes HELP text: backslash and newline become \\ and \n; invalid UTF-8 becomes U+FFFD. prometheus-cpp 1.0.1
// writes HELP verbatim, so render() hands it this.
std::string escape_help(std::string_view help);

}  // namespace surfacer::server
