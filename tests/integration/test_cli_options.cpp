// The programs' command lines (client and server side): every floating-point option refuses a
// value that is not a finite number (CLI11's own ranges pass NaN), naming the option, with the "bad
// input" exit code 2; --connect-timeout has a range. The floating-point options are read from each
// program's --help, so that one added later is held to it too.
#include <gtest/gtest.h>

#include <memory>
#include <regex>
#include <set>
#include <sstream>

#include "process.h"
#include "process_test.h"

namespace telehand::test {
namespace {

using namespace std::chrono_literals;

struct Program {
  const char* name;
  const char* bin;
  bool dds;                          ///< takes the DDS options
  std::set<std::string> known;       ///< floating-point options it has today (at least these)
  const char* subcommand = nullptr;  ///< the options are this subcommand's
};

const Program kPrograms[] = {
    {"client",
     TELEHAND_CLIENT_BIN,
     true,
     {"--device-timeout", "--seconds", "--frequency", "--band-min", "--band-max", "--force-bias",
      "--frequency-error", "--tremor", "--connect-timeout", "--deadband", "--thimble-noise",
      "--sweep-seconds", "--explore-seconds", "--watch-speed"}},
    {"latency", TELEHAND_LATENCY_BIN, true, {"--seconds", "--rate", "--warmup"}},
    {"probe", TELEHAND_PROBE_BIN, false, {"--live", "--rate"}},
    {"watch",
     TELEHAND_WATCH_BIN,
     true,
     {"--refresh-hz", "--band-min", "--band-max", "--seconds", "--wait", "--speed"}},
    {"server",
     TELEHAND_SERVER_BIN,
     true,
     {"--hand-rate", "--hand-deadband", "--hand-slice-ms", "--hand-share", "--seconds"}},
    {"records-synth",
     TELEHAND_RECORDS_BIN,
     false,
     {"--noise", "--seconds-per-axis", "--frequency", "--max-force", "--seconds"},
     "synth"},
};

class CliOptionsTest : public ProcessTest {
 protected:
  CliOptionsTest() : ProcessTest("cli", TELEHAND_LOOPBACK_XML) {}

  std::vector<std::string> argv(const Program& p, std::vector<std::string> args) const {
    if (p.subcommand) args.insert(args.begin(), p.subcommand);
    if (p.dds) return cmd(p.bin, std::move(args));
    std::vector<std::string> v{p.bin};
    v.insert(v.end(), args.begin(), args.end());
    return v;
  }

  /// The options --help lists with the type FLOAT.
  std::set<std::string> floatOptions(const Program& p) {
    std::vector<std::string> help_argv{p.bin};
    if (p.subcommand) help_argv.emplace_back(p.subcommand);
    help_argv.emplace_back("--help");
    Process help(help_argv, path(std::string(p.name) + "-help.log"));
    EXPECT_EQ(help.wait(30s), 0) << help.output();
    std::set<std::string> found;
    std::istringstream lines(help.output());
    const std::regex option(R"(^\s+(?:-\w,)?(--[a-z0-9-]+) FLOAT)");
    std::smatch m;
    for (std::string line; std::getline(lines, line);) {
      if (std::regex_search(line, m, option)) found.insert(m[1]);
    }
    return found;
  }
};

TEST_F(CliOptionsTest, EveryFloatingPointOptionRefusesWhatIsNotAFiniteNumber) {
  struct Run {
    std::string what, option;
    std::unique_ptr<Process> process;
  };
  std::vector<Run> runs;
  for (const Program& p : kPrograms) {
    const std::set<std::string> options = floatOptions(p);
    for (const auto& known : p.known) {
      EXPECT_TRUE(options.count(known)) << p.name << " " << known << " is not listed as FLOAT";
    }
    for (const auto& option : options) {
      for (const char* bad : {"nan", "inf", "-inf"}) {
        Run r;
        r.what = std::string(p.name) + " " + option + " " + bad;
        r.option = option;
        r.process = std::make_unique<Process>(
            argv(p, {option + "=" + bad}),
            path(std::string(p.name) + option + "-" + bad + std::to_string(runs.size()) + ".log"));
        runs.push_back(std::move(r));
      }
    }
  }
  ASSERT_GT(runs.size(), 3u * 20u);
  for (auto& r : runs) {
    const auto rc = r.process->wait(60s);
    const std::string out = r.process->output();
    EXPECT_EQ(rc, std::optional<int>(2)) << r.what << "\n" << out;
    EXPECT_NE(out.find(r.option + ": "), std::string::npos) << r.what << "\n" << out;
    EXPECT_NE(out.find("is not a finite number"), std::string::npos) << r.what << "\n" << out;
  }
}

TEST_F(CliOptionsTest, TheTimeoutsArePositiveAndBounded) {
  // A huge one would overflow the nanoseconds it becomes.
  const Program& client = kPrograms[0];
  for (const char* option : {"--connect-timeout", "--device-timeout"}) {
    for (const char* bad : {"0", "-1", "0.01", "3601", "1e9", "1e300"}) {
      Process p(argv(client, {std::string(option) + "=" + bad}),
                path(std::string(option).substr(2) + bad));
      EXPECT_EQ(p.wait(30s), std::optional<int>(2)) << option << bad << "\n" << p.output();
      EXPECT_NE(p.output().find(option), std::string::npos) << option << bad << p.output();
    }
  }
}

}  // namespace
}  // namespace telehand::test
