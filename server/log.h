// Structured logs on stderr, one logfmt line per event:
//   ts=2026-11-22T08:10:00.123Z level=info event=job_submitted job=j-3f2a kind=isosurface frames=3
#pragma once

#include <initializer_list>
#include <span>
#include <string>
#include <string_view>
#include <utility>

namespace surfacer::server {

enum class LogLevel { kDebug, kInfo, kWarn, kError };

using LogField = std::pair<std::string_view, std::string>;

void log_event(LogLevel level, std::string_view event, std::span<const LogField> fields);
inline void log_event(LogLevel level, std::string_view event, std::initializer_list<LogField> fields = {}) {
  log_event(level, event, std::span<const LogField>(fields.begin(), fields.size()));
}
// Messages below this level are dropped (default kInfo).
void set_log_level(LogLevel level);

}  // namespace surfacer::server
