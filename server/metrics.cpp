#include "server/metrics.h"

#include <algorithm>
#include <charconv>
#include <cmath>
#include <stdexcept>
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

const char* type_name(MetricType type) {
  switch (type) {
    case MetricType::kCounter:
      return "counter";
    case MetricType::kGauge:
      return "gauge";
    case MetricType::kHistogram:
      return "histogram";
  }
  return "untyped";
}

// Appends `<name><suffix>{l1="v1",...,le="<le>"} <value>\n`.
void append_sample(std::string& out, std::string_view name, std::string_view suffix,
                   const std::vector<std::string>& label_names, std::span<const std::string> label_values,
                   std::string_view le, std::string_view value) {
  out += name;
  out += suffix;
  if (!label_names.empty() || !le.empty()) {
    out += '{';
    for (std::size_t i = 0; i < label_names.size(); ++i) {
      if (i > 0) out += ',';
      out += label_names[i];
      out += "=\"";
      out += escape_label_value(label_values[i]);
      out += '"';
    }
    if (!le.empty()) {
      if (!label_names.empty()) out += ',';
      out += "le=\"";
      out += le;
      out += '"';
    }
    out += '}';
  }
  out += ' ';
  out += value;
  out += '\n';
}

// A gauge family whose samples come from a callback at render time.
class CallbackGaugeFamily final : public detail::FamilyBase {
 public:
  CallbackGaugeFamily(std::string name, std::string help, MetricType type, std::vector<std::string> label_names,
                      std::function<std::vector<LabelledValue>()> sample)
      : FamilyBase(std::move(name), std::move(help), type, std::move(label_names)), sample_(std::move(sample)) {}

 private:
  void render_samples(std::string& out) const override {
    std::vector<LabelledValue> values = sample_();
    for (const LabelledValue& v : values) check_arity(v.label_values.size());
    std::sort(values.begin(), values.end(), [](const LabelledValue& a, const LabelledValue& b) {
      return detail::LabelsLess{}(a.label_values, b.label_values);
    });
    for (std::size_t i = 0; i < values.size(); ++i) {
      if (i > 0 && values[i].label_values == values[i - 1].label_values) {
        std::string tuple;
        for (const std::string& value : values[i].label_values) tuple += (tuple.empty() ? "" : ",") + value;
        throw std::invalid_argument("metric " + quote(name()) + ": the callback returned the label values {" + tuple +
                                    "} more than once; return each tuple once");
      }
      append_sample(out, name(), "", label_names(), values[i].label_values, "", format_metric_value(values[i].value));
    }
  }

  std::function<std::vector<LabelledValue>()> sample_;
};

void validate_family(const std::string& name, const std::string& help, MetricType type,
                     const std::vector<std::string>& label_names) {
  if (!valid_metric_name(name)) {
    throw std::invalid_argument("metric name " + quote(name) +
                                " is invalid: use letters, digits, '_' and ':', not starting with a digit");
  }
  if (help.empty()) {
    throw std::invalid_argument("metric " + quote(name) + ": help text is empty; say what it measures");
  }
  for (std::size_t i = 0; i < label_names.size(); ++i) {
    const std::string& label = label_names[i];
    if (!valid_label_name(label)) {
      throw std::invalid_argument("metric " + quote(name) + ": label name " + quote(label) +
                                  " is invalid: use letters, digits and '_', not starting with a digit");
    }
    if (label.starts_with("__")) {
      throw std::invalid_argument("metric " + quote(name) + ": label name " + quote(label) +
                                  " starts with '__', which is reserved for Prometheus");
    }
    if (type == MetricType::kHistogram && label == "le") {
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

bool valid_metric_name(std::string_view name) {
  if (name.empty()) return false;
  for (std::size_t i = 0; i < name.size(); ++i) {
    const char c = name[i];
    const bool alpha = (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || c == '_' || c == ':';
    const bool digit = c >= '0' && c <= '9';
    if (!alpha && !(digit && i > 0)) return false;
  }
  return true;
}

bool valid_label_name(std::string_view name) {
  if (name.empty()) return false;
  for (std::size_t i = 0; i < name.size(); ++i) {
    const char c = name[i];
    const bool alpha = (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || c == '_';
    const bool digit = c >= '0' && c <= '9';
    if (!alpha && !(digit && i > 0)) return false;
  }
  return true;
}

// --- Metrics --------------------------------------------------------------------------------------------------

void Counter::inc(double amount) {
  if (!(amount >= 0.0)) {
    throw std::invalid_argument("Counter::inc: amount " + format_metric_value(amount) +
                                " must be >= 0 (counters only go up; use a Gauge for values that go down)");
  }
  value_.fetch_add(amount, std::memory_order_relaxed);
}

Histogram::Histogram(std::shared_ptr<const std::vector<double>> bounds)
    : bounds_(std::move(bounds)), counts_(new std::atomic<std::uint64_t>[bounds_->size() + 1]) {
  for (std::size_t i = 0; i <= bounds_->size(); ++i) counts_[i].store(0, std::memory_order_relaxed);
}

void Histogram::observe(double value) {
  const std::vector<double>& bounds = *bounds_;
  const std::size_t bucket =
      std::isnan(value)
          ? bounds.size()
          : static_cast<std::size_t>(std::lower_bound(bounds.begin(), bounds.end(), value) - bounds.begin());
  counts_[bucket].fetch_add(1, std::memory_order_relaxed);
  sum_.fetch_add(value, std::memory_order_relaxed);
}

Histogram::Snapshot Histogram::snapshot() const {
  Snapshot snapshot;
  snapshot.bounds = *bounds_;
  snapshot.cumulative.resize(bounds_->size() + 1);
  std::uint64_t total = 0;
  for (std::size_t i = 0; i <= bounds_->size(); ++i) {
    total += counts_[i].load(std::memory_order_relaxed);
    snapshot.cumulative[i] = total;
  }
  snapshot.count = total;
  snapshot.sum = sum_.load(std::memory_order_relaxed);
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

void detail::FamilyBase::render(std::string& out) const {
  std::string samples;
  render_samples(samples);  // first, so that a throwing callback leaves `out` untouched
  out += "# HELP ";
  out += name_;
  out += ' ';
  out += escape_help(help_);
  out += "\n# TYPE ";
  out += name_;
  out += ' ';
  out += type_name(type_);
  out += '\n';
  out += samples;
}

void detail::FamilyBase::check_arity(std::size_t values) const {
  if (values != label_names_.size()) {
    std::string names;
    for (const std::string& label : label_names_) names += (names.empty() ? "" : ",") + label;
    throw std::invalid_argument("metric " + quote(name_) + ": got " + std::to_string(values) +
                                " label values, expected " + std::to_string(label_names_.size()) + " {" + names + "}");
  }
}

template <class Metric>
MetricFamily<Metric>::MetricFamily(std::string name, std::string help, MetricType type,
                                   std::vector<std::string> label_names,
                                   std::shared_ptr<const std::vector<double>> bounds)
    : FamilyBase(std::move(name), std::move(help), type, std::move(label_names)), bounds_(std::move(bounds)) {}

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
    std::unique_ptr<Metric> metric;
    if constexpr (std::is_same_v<Metric, Histogram>) {
      metric = std::make_unique<Histogram>(bounds_);
    } else {
      metric = std::make_unique<Metric>();
    }
    it = children_.emplace(std::vector<std::string>(label_values.begin(), label_values.end()), std::move(metric)).first;
  }
  return *it->second;
}

template <class Metric>
void MetricFamily<Metric>::render_samples(std::string& out) const {
  std::lock_guard lock(mutex_);
  for (const auto& [label_values, metric] : children_) {
    if constexpr (std::is_same_v<Metric, Histogram>) {
      const Histogram::Snapshot snapshot = metric->snapshot();
      for (std::size_t i = 0; i < snapshot.bounds.size(); ++i) {
        append_sample(out, name(), "_bucket", label_names(), label_values, format_metric_value(snapshot.bounds[i]),
                      std::to_string(snapshot.cumulative[i]));
      }
      append_sample(out, name(), "_bucket", label_names(), label_values, "+Inf", std::to_string(snapshot.count));
      append_sample(out, name(), "_sum", label_names(), label_values, "", format_metric_value(snapshot.sum));
      append_sample(out, name(), "_count", label_names(), label_values, "", std::to_string(snapshot.count));
    } else {
      append_sample(out, name(), "", label_names(), label_values, "", format_metric_value(metric->value()));
    }
  }
}

template class MetricFamily<Counter>;
template class MetricFamily<Gauge>;
template class MetricFamily<Histogram>;

// --- Registry -------------------------------------------------------------------------------------------------

template <class Family, class... Args>
Family& MetricsRegistry::add(const std::string& name, const std::string& help, MetricType type,
                             const std::vector<std::string>& label_names, Args&&... args) {
  validate_family(name, help, type, label_names);
  std::vector<std::string> series{name};
  if (type == MetricType::kHistogram) {
    for (const char* suffix : {"_bucket", "_sum", "_count"}) series.push_back(name + suffix);
  }
  auto family = std::make_unique<Family>(name, help, type, label_names, std::forward<Args>(args)...);
  Family& ref = *family;
  std::lock_guard lock(mutex_);
  for (const std::string& s : series) {
    if (std::find(series_names_.begin(), series_names_.end(), s) != series_names_.end()) {
      throw std::invalid_argument("metric " + quote(name) + ": the series name " + quote(s) +
                                  " is already registered; metric names must be unique");
    }
  }
  series_names_.insert(series_names_.end(), series.begin(), series.end());
  families_.push_back(std::move(family));
  return ref;
}

CounterFamily& MetricsRegistry::counter(const std::string& name, const std::string& help,
                                        const std::vector<std::string>& label_names) {
  CounterFamily& family = add<CounterFamily>(name, help, MetricType::kCounter, label_names, nullptr);
  if (label_names.empty()) family.with();
  return family;
}

GaugeFamily& MetricsRegistry::gauge(const std::string& name, const std::string& help,
                                    const std::vector<std::string>& label_names) {
  GaugeFamily& family = add<GaugeFamily>(name, help, MetricType::kGauge, label_names, nullptr);
  if (label_names.empty()) family.with();
  return family;
}

HistogramFamily& MetricsRegistry::histogram(const std::string& name, const std::string& help,
                                            const std::vector<double>& buckets,
                                            const std::vector<std::string>& label_names) {
  validate_buckets(name, buckets);
  HistogramFamily& family = add<HistogramFamily>(name, help, MetricType::kHistogram, label_names,
                                                 std::make_shared<const std::vector<double>>(buckets));
  if (label_names.empty()) family.with();
  return family;
}

void MetricsRegistry::gauge_callback(const std::string& name, const std::string& help, std::function<double()> sample) {
  if (!sample) throw std::invalid_argument("metric " + quote(name) + ": the callback is empty");
  add<CallbackGaugeFamily>(name, help, MetricType::kGauge, {}, [sample = std::move(sample)] {
    return std::vector<LabelledValue>{{{}, sample()}};
  });
}

void MetricsRegistry::gauge_callback_family(const std::string& name, const std::string& help,
                                            const std::vector<std::string>& label_names,
                                            std::function<std::vector<LabelledValue>()> sample) {
  if (!sample) throw std::invalid_argument("metric " + quote(name) + ": the callback is empty");
  add<CallbackGaugeFamily>(name, help, MetricType::kGauge, label_names, std::move(sample));
}

std::string MetricsRegistry::render() const {
  std::vector<const detail::FamilyBase*> families;
  {
    std::lock_guard lock(mutex_);
    families.reserve(families_.size());
    for (const auto& family : families_) families.push_back(family.get());
  }
  std::string out;
  for (const detail::FamilyBase* family : families) family->render(out);
  return out;
}

}  // namespace surfacer::server
