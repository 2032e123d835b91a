#include "server/metrics.h"

#include <prometheus/check_names.h>
#include <prometheus/counter.h>
#include <prometheus/family.h>
#include <prometheus/gauge.h>
#include <prometheus/histogram.h>
#include <prometheus/registry.h>
#include <prometheus/text_serializer.h>

#include <algorithm>
#include <charconv>
#include <cmath>
#include <stdexcept>
#include <type_traits>
#include <utility>

#include "core/util/format.h"

namespace surfacer::server {
namespace {

// Escapes backslash, newline and (when `quote`) double quote; replaces invalid UTF-8 bytes with U+FFFD.
std::string escape(std::string_view text, bool quote) {
  std::string out;
  out.reserve(text.size());
  append_utf8_escaped(out, text, [quote](std::string& o, char c) {
    if (c == '\\') {
      o += "\\\\";
    } else if (c == '\n') {
      o += "\\n";
    } else if (c == '"' && quote) {
      o += "\\\"";
    } else {
      o += c;
    }
  });
  return out;
}

// A label value as it may reach prometheus-cpp, whose TextSerializer escapes \, " and newline but copies every other
// byte: invalid UTF-8 bytes become U+FFFD, so the exposition stays valid UTF-8.
std::string sanitize_label_value(std::string_view value) {
  std::string out;
  out.reserve(value.size());
  append_utf8_escaped(out, value, [](std::string& o, char c) { o += c; });
  return out;
}

std::string joined(const std::vector<std::string>& parts) {
  std::string out;
  for (const std::string& part : parts) out += (out.empty() ? "" : ",") + part;
  return out;
}

// A gauge family whose samples come from a callback at render time.
class CallbackGaugeFamily final : public detail::FamilyBase {
 public:
  CallbackGaugeFamily(std::string name, std::string help, std::vector<std::string> label_names,
                      std::function<std::vector<LabelledValue>()> sample)
      : FamilyBase(std::move(name), std::move(help), prometheus::MetricType::Gauge, std::move(label_names)),
        sample_(std::move(sample)) {}

 private:
  std::vector<prometheus::ClientMetric> collect_samples() const override {
    std::vector<prometheus::ClientMetric> samples;
    for (const LabelledValue& value : sample_()) {
      check_arity(value.label_values.size());
      prometheus::ClientMetric& sample = samples.emplace_back();
      for (std::size_t i = 0; i < value.label_values.size(); ++i) {
        sample.label.push_back({label_names()[i], sanitize_label_value(value.label_values[i])});
      }
      sample.gauge.value = value.value;
    }
    return samples;
  }

  std::function<std::vector<LabelledValue>()> sample_;
};

void validate_family(const std::string& name, const std::string& help, prometheus::MetricType type,
                     const std::vector<std::string>& label_names) {
  if (!prometheus::CheckMetricName(name)) {
    throw std::invalid_argument("metric name " + quote(name) +
                                " is invalid: use letters, digits, '_' and ':', not starting with a digit or '__'");
  }
  if (help.empty()) {
    throw std::invalid_argument("metric " + quote(name) + ": help text is empty; say what it measures");
  }
  for (std::size_t i = 0; i < label_names.size(); ++i) {
    const std::string& label = label_names[i];
    if (label.starts_with("__")) {
      throw std::invalid_argument("metric " + quote(name) + ": label name " + quote(label) +
                                  " starts with '__', which is reserved for Prometheus");
    }
    if (!prometheus::CheckLabelName(label)) {
      throw std::invalid_argument("metric " + quote(name) + ": label name " + quote(label) +
                                  " is invalid: use letters, digits and '_', not starting with a digit");
    }
    if (type == prometheus::MetricType::Histogram && label == "le") {
      throw std::invalid_argument("metric " + quote(name) +
                                  ": label name 'le' is reserved for histogram buckets; choose another name");
    }
    if (std::find(label_names.begin(), label_names.begin() + static_cast<std::ptrdiff_t>(i), label) !=
        label_names.begin() + static_cast<std::ptrdiff_t>(i)) {
      throw std::invalid_argument("metric " + quote(name) + ": label name " + quote(label) + " is repeated");
    }
  }
}

void validate_buckets(const std::string& name, const std::vector<double>& buckets) {
  for (std::size_t i = 0; i < buckets.size(); ++i) {
    if (!std::isfinite(buckets[i])) {
      throw std::invalid_argument("histogram " + quote(name) + ": bucket bound " + format_metric_value(buckets[i]) +
                                  " is not finite; +Inf is added implicitly");
    }
    if (i > 0 && !(buckets[i] > buckets[i - 1])) {
      throw std::invalid_argument("histogram " + quote(name) + ": bucket bounds must be strictly increasing (" +
                                  format_metric_value(buckets[i - 1]) + " then " + format_metric_value(buckets[i]) +
                                  ")");
    }
  }
}

}  // namespace

// --- Text-format building blocks --------------------------------------------------------------------------------

std::string format_metric_value(double value) {
  if (std::isnan(value)) return "NaN";
  if (std::isinf(value)) return value > 0 ? "+Inf" : "-Inf";
  char buffer[64];
  const auto result = std::to_chars(buffer, buffer + sizeof buffer, value);
  return std::string(buffer, result.ptr);
}

std::string escape_label_value(std::string_view value) { return escape(value, /*quote=*/true); }

std::string escape_help(std::string_view help) { return escape(help, /*quote=*/false); }

// --- Metrics --------------------------------------------------------------------------------------------------

void Counter::inc(double amount) {
  // prometheus::Counter ignores a negative amount and adds NaN; both are caller bugs worth an exception.
  if (!(amount >= 0.0)) {
    throw std::invalid_argument("Counter::inc: amount " + format_metric_value(amount) +
                                " must be >= 0 (counters only go up; use a Gauge for values that go down)");
  }
  counter_.Increment(amount);
}

double Counter::value() const { return counter_.Value(); }

void Gauge::set(double value) { gauge_.Set(value); }

void Gauge::add(double delta) { gauge_.Increment(delta); }

double Gauge::value() const { return gauge_.Value(); }

void Histogram::observe(double value) { histogram_.Observe(value); }

Histogram::Snapshot Histogram::snapshot() const {
  const prometheus::ClientMetric collected = histogram_.Collect();
  Snapshot snapshot;
  for (const prometheus::ClientMetric::Bucket& bucket : collected.histogram.bucket) {
    if (std::isfinite(bucket.upper_bound)) snapshot.bounds.push_back(bucket.upper_bound);
    snapshot.cumulative.push_back(bucket.cumulative_count);
  }
  snapshot.count = collected.histogram.sample_count;
  snapshot.sum = collected.histogram.sample_sum;
  return snapshot;
}

std::vector<double> latency_buckets() {
  return {0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1, 2.5, 5, 10, 25, 50, 100, 250, 600};
}

std::vector<double> byte_buckets() { return exponential_buckets(1024.0, 4.0, 11); }

std::vector<double> exponential_buckets(double start, double factor, int count) {
  if (!(start > 0.0) || !(factor > 1.0) || count < 1) {
    throw std::invalid_argument("exponential_buckets: need start > 0, factor > 1 and count >= 1 (got start " +
                                format_metric_value(start) + ", factor " + format_metric_value(factor) + ", count " +
                                std::to_string(count) + ")");
  }
  std::vector<double> bounds;
  bounds.reserve(static_cast<std::size_t>(count));
  double bound = start;
  for (int i = 0; i < count; ++i, bound *= factor) bounds.push_back(bound);
  return bounds;
}

std::vector<double> linear_buckets(double start, double width, int count) {
  if (!std::isfinite(start) || !(width > 0.0) || count < 1) {
    throw std::invalid_argument("linear_buckets: need a finite start, width > 0 and count >= 1 (got start " +
                                format_metric_value(start) + ", width " + format_metric_value(width) + ", count " +
                                std::to_string(count) + ")");
  }
  std::vector<double> bounds;
  bounds.reserve(static_cast<std::size_t>(count));
  for (int i = 0; i < count; ++i) bounds.push_back(start + width * i);
  return bounds;
}

// --- Families -------------------------------------------------------------------------------------------------

prometheus::MetricFamily detail::FamilyBase::collect() const {
  prometheus::MetricFamily family;
  family.name = name_;
  family.help = escape_help(help_);
  family.type = type_;
  family.metric = collect_samples();
  // prometheus::Labels is a std::map, so a collected sample's labels come sorted by name: put them back in
  // declaration order, the order the samples are then sorted by.
  for (prometheus::ClientMetric& sample : family.metric) {
    std::vector<prometheus::ClientMetric::Label> ordered;
    ordered.reserve(label_names_.size());
    for (const std::string& label : label_names_) {
      const auto it = std::find_if(sample.label.begin(), sample.label.end(),
                                   [&](const prometheus::ClientMetric::Label& l) { return l.name == label; });
      if (it != sample.label.end()) ordered.push_back(std::move(*it));
    }
    sample.label = std::move(ordered);
  }
  const auto values_less = [](const prometheus::ClientMetric& a, const prometheus::ClientMetric& b) {
    return std::lexicographical_compare(a.label.begin(), a.label.end(), b.label.begin(), b.label.end(),
                                        [](const prometheus::ClientMetric::Label& x,
                                           const prometheus::ClientMetric::Label& y) { return x.value < y.value; });
  };
  std::sort(family.metric.begin(), family.metric.end(), values_less);
  // Only a callback can repeat a tuple (a prometheus::Family keeps one metric per label set).
  for (std::size_t i = 1; i < family.metric.size(); ++i) {
    if (!values_less(family.metric[i - 1], family.metric[i])) {
      std::vector<std::string> values;
      for (const prometheus::ClientMetric::Label& label : family.metric[i].label) values.push_back(label.value);
      throw std::invalid_argument("metric " + quote(name_) + ": the callback returned the label values {" +
                                  joined(values) + "} more than once; return each tuple once");
    }
  }
  return family;
}

void detail::FamilyBase::check_arity(std::size_t values) const {
  if (values != label_names_.size()) {
    throw std::invalid_argument("metric " + quote(name_) + ": got " + std::to_string(values) +
                                " label values, expected " + std::to_string(label_names_.size()) + " {" +
                                joined(label_names_) + "}");
  }
}

template <class Metric>
MetricFamily<Metric>::MetricFamily(std::string name, std::string help, std::vector<std::string> label_names,
                                   prometheus::Family<typename Metric::Library>& family, std::vector<double> bounds)
    : FamilyBase(std::move(name), std::move(help), Metric::kType, std::move(label_names)),
      family_(family),
      bounds_(std::move(bounds)) {}

template <class Metric>
Metric& MetricFamily<Metric>::with(std::initializer_list<std::string_view> label_values) {
  return with_span(std::span<const std::string_view>(label_values.begin(), label_values.size()));
}

template <class Metric>
Metric& MetricFamily<Metric>::with(const std::vector<std::string>& label_values) {
  const std::vector<std::string_view> views(label_values.begin(), label_values.end());
  return with_span(views);
}

template <class Metric>
Metric& MetricFamily<Metric>::with_span(std::span<const std::string_view> label_values) {
  check_arity(label_values.size());
  std::lock_guard lock(mutex_);
  auto it = children_.find(label_values);
  if (it == children_.end()) {
    prometheus::Labels labels;
    for (std::size_t i = 0; i < label_values.size(); ++i) {
      labels.emplace(label_names()[i], sanitize_label_value(label_values[i]));
    }
    typename Metric::Library* metric = nullptr;
    if constexpr (std::is_same_v<Metric, Histogram>) {
      metric = &family_.Add(labels, bounds_);
    } else {
      metric = &family_.Add(labels);
    }
    it = children_
             .emplace(std::vector<std::string>(label_values.begin(), label_values.end()),
                      std::make_unique<Metric>(*metric))
             .first;
  }
  return *it->second;
}

template <class Metric>
std::vector<prometheus::ClientMetric> MetricFamily<Metric>::collect_samples() const {
  std::vector<prometheus::MetricFamily> collected = family_.Collect();  // none until a sample exists
  return collected.empty() ? std::vector<prometheus::ClientMetric>{} : std::move(collected.front().metric);
}

template class MetricFamily<Counter>;
template class MetricFamily<Gauge>;
template class MetricFamily<Histogram>;

// --- Registry -------------------------------------------------------------------------------------------------

MetricsRegistry::MetricsRegistry() : registry_(std::make_unique<prometheus::Registry>()) {}

MetricsRegistry::~MetricsRegistry() = default;

detail::FamilyBase& MetricsRegistry::add(const std::string& name, const std::string& help, prometheus::MetricType type,
                                         const std::vector<std::string>& label_names,
                                         const std::function<std::unique_ptr<detail::FamilyBase>()>& make) {
  validate_family(name, help, type, label_names);
  std::vector<std::string> series{name};
  if (type == prometheus::MetricType::Histogram) {
    for (const char* suffix : {"_bucket", "_sum", "_count"}) series.push_back(name + suffix);
  }
  std::lock_guard lock(mutex_);
  for (const std::string& s : series) {
    if (std::find(series_names_.begin(), series_names_.end(), s) != series_names_.end()) {
      throw std::invalid_argument("metric " + quote(name) + ": the series name " + quote(s) +
                                  " is already registered; metric names must be unique");
    }
  }
  families_.push_back(make());
  series_names_.insert(series_names_.end(), series.begin(), series.end());
  return *families_.back();
}

CounterFamily& MetricsRegistry::counter(const std::string& name, const std::string& help,
                                        const std::vector<std::string>& label_names) {
  auto& family = static_cast<CounterFamily&>(add(name, help, Counter::kType, label_names, [&] {
    auto& library = prometheus::BuildCounter().Name(name).Help(help).Register(*registry_);
    return std::make_unique<CounterFamily>(name, help, label_names, library, std::vector<double>{});
  }));
  if (label_names.empty()) family.with();
  return family;
}

GaugeFamily& MetricsRegistry::gauge(const std::string& name, const std::string& help,
                                    const std::vector<std::string>& label_names) {
  auto& family = static_cast<GaugeFamily&>(add(name, help, Gauge::kType, label_names, [&] {
    auto& library = prometheus::BuildGauge().Name(name).Help(help).Register(*registry_);
    return std::make_unique<GaugeFamily>(name, help, label_names, library, std::vector<double>{});
  }));
  if (label_names.empty()) family.with();
  return family;
}

HistogramFamily& MetricsRegistry::histogram(const std::string& name, const std::string& help,
                                            const std::vector<double>& buckets,
                                            const std::vector<std::string>& label_names) {
  validate_buckets(name, buckets);
  auto& family = static_cast<HistogramFamily&>(add(name, help, Histogram::kType, label_names, [&] {
    auto& library = prometheus::BuildHistogram().Name(name).Help(help).Register(*registry_);
    return std::make_unique<HistogramFamily>(name, help, label_names, library, buckets);
  }));
  if (label_names.empty()) family.with();
  return family;
}

void MetricsRegistry::gauge_callback(const std::string& name, const std::string& help, std::function<double()> sample) {
  if (!sample) throw std::invalid_argument("metric " + quote(name) + ": the callback is empty");
  gauge_callback_family(name, help, {}, [sample = std::move(sample)] {
    return std::vector<LabelledValue>{{{}, sample()}};
  });
}

void MetricsRegistry::gauge_callback_family(const std::string& name, const std::string& help,
                                            const std::vector<std::string>& label_names,
                                            std::function<std::vector<LabelledValue>()> sample) {
  if (!sample) throw std::invalid_argument("metric " + quote(name) + ": the callback is empty");
  add(name, help, prometheus::MetricType::Gauge, label_names,
      [&] { return std::make_unique<CallbackGaugeFamily>(name, help, label_names, std::move(sample)); });
}

std::string MetricsRegistry::render() const {
  std::vector<const detail::FamilyBase*> families;
  {
    std::lock_guard lock(mutex_);
    families.reserve(families_.size());
    for (const auto& family : families_) families.push_back(family.get());
  }
  // Family by family in registration order (prometheus::Registry::Collect() would group them by type).
  std::vector<prometheus::MetricFamily> collected;
  collected.reserve(families.size());
  for (const detail::FamilyBase* family : families) collected.push_back(family->collect());
  return prometheus::TextSerializer().Serialize(collected);
}

}  // namespace surfacer::server
