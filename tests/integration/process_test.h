#pragma once
// A test of programs run as processes: a scratch directory (kept when the test fails, or
// always with TELEHAND_KEEP_TEST_DIRS=1, for its logs) and a DDS partition of its own, so tests
// never see each other's sessions.
#include <gtest/gtest.h>
#include <stdlib.h>
#include <unistd.h>

#include <chrono>
#include <cstdint>
#include <filesystem>
#include <iostream>
#include <regex>
#include <string>
#include <thread>
#include <vector>

namespace telehand::test {

/// The first number `pattern`'s group 1 matches in `text` (0 if none).
inline uint64_t matchNumber(const std::string& text, const std::string& pattern) {
  std::smatch m;
  if (!std::regex_search(text, m, std::regex(pattern))) return 0;
  return std::stoull(m[1]);
}

/// How many times `needle` stands in `text`.
inline std::size_t occurrences(const std::string& text, const std::string& needle) {
  std::size_t n = 0;
  for (auto at = text.find(needle); at != std::string::npos; at = text.find(needle, at + 1)) ++n;
  return n;
}

/// Waits (polling every 100 ms) until the text `read()` returns holds `needle` at least `n`
/// times, or `timeout` has passed; returns how many times it held it last.
template <typename Read>
std::size_t awaitOccurrences(Read read, const std::string& needle, std::size_t n,
                             std::chrono::milliseconds timeout) {
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  std::size_t seen = occurrences(read(), needle);
  while (seen < n && std::chrono::steady_clock::now() < deadline) {
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
    seen = occurrences(read(), needle);
  }
  return seen;
}

class ProcessTest : public ::testing::Test {
 protected:
  /// `prefix` names the directory and partition; `dds_config` is passed to every program.
  ProcessTest(std::string prefix, std::string dds_config)
      : prefix_(std::move(prefix)), dds_config_(std::move(dds_config)) {}
  void SetUp() override {
    std::string tmpl = "/tmp/telehand-" + prefix_ + "-XXXXXX";
    dir_ = mkdtemp(tmpl.data());
    const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
    partition_ = prefix_ + "-" + std::to_string(getpid()) + "-" + info->name();
  }
  void TearDown() override {
    if (HasFailure() || getenv("TELEHAND_KEEP_TEST_DIRS") != nullptr) {
      std::cout << "logs kept in " << dir_ << "\n";
      return;
    }
    std::filesystem::remove_all(dir_);
  }
  std::vector<std::string> dds() const {
    std::vector<std::string> v{"--dds-config", dds_config_, "--partition", partition_};
    if (domain_ >= 0) {
      v.push_back("--domain");
      v.push_back(std::to_string(domain_));
    }
    if (!pki_.empty()) {
      v.push_back("--pki");
      v.push_back(pki_);
    } else {
      v.push_back("--insecure");
    }
    return v;
  }
  /// A DDS domain of this test process's own (ids 100..199, by PID), for tests that measure
  /// what a participant holds: another test's participants on the same domain are
  /// discovered (and remembered) even on another partition.
  void useOwnDomain() { domain_ = 100 + static_cast<int>(getpid() % 100); }
  /// `bin args... --dds-config X --partition P (--insecure | --pki DIR)`
  std::vector<std::string> cmd(std::string bin, std::vector<std::string> args) const {
    std::vector<std::string> v{std::move(bin)};
    v.insert(v.end(), args.begin(), args.end());
    for (auto& a : dds()) v.push_back(a);
    return v;
  }
  std::string path(const std::string& name) const {
    return (std::filesystem::path(dir_) / name).string();
  }

  std::string prefix_, dds_config_;
  /// A PKI (deploy/pki/make-pki.sh) to run the programs under DDS Security with, each as its
  /// role's default identity; empty: --insecure.
  std::string pki_;
  std::string dir_;
  std::string partition_;
  int domain_ = -1;  ///< -1: the configuration's
};

}  // namespace telehand::test
