// Files for tests: a fresh scratch directory, whole files read and written as bytes, lines counted, gzip data.
#pragma once

#include <filesystem>
#include <string>

namespace surfacer::testing {

// <system temp>/surfacer_NAME_PID, emptied and created (the process id keeps parallel test processes apart).
std::filesystem::path fresh_temp_dir(const std::string& name);

// `root`/<name of the running test>, created.
std::filesystem::path current_test_dir(const std::filesystem::path& root);

// A whole file as it is on disk ("" when it is missing or unreadable).
std::string read_file(const std::filesystem::path& path);

// Replaces the file at `path` with `bytes`.
void write_file(const std::filesystem::path& path, const std::string& bytes);

// The number of '\n' in `text`.
int count_lines(const std::string& text);

// `data` as one gzip member.
std::string gzip(const std::string& data);

}  // namespace surfacer::testing
