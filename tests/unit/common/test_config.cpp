// TOML configuration: good files load, bad ones give a ConfigError naming origin, line, key.
#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <string>

#include "telehand/config/config.h"
#include "telehand/core/error.h"

namespace telehand {
namespace {

using ::testing::AllOf;
using ::testing::HasSubstr;

constexpr const char* kOrigin = "client.toml";

/// The message of the ConfigError that parsing `text` throws ("" if none is thrown).
std::string clientError(const std::string& text) {
  try {
    parseClientConfig(text, kOrigin);
  } catch (const ConfigError& e) {
    return e.what();
  }
  return "";
}

std::string serverError(const std::string& text) {
  try {
    parseServerConfig(text, "server.toml");
  } catch (const ConfigError& e) {
    return e.what();
  }
  return "";
}

constexpr const char* kFullClient = R"toml(
# A complete client configuration.
[operator]
frequency_hz = 4.5
band_min_n = 10.0
band_max_n = 18.0
ramp_s = 2.0
sensor_noise_n = 0.05
seed = 42

[safety]
max_force_n = 3.5
max_rate_n_per_s = 150.0
watchdog_ms = 10.0

[loop]
rate_hz = 2000.0
rt_priority = 80
)toml";

TEST(ClientConfig, FullFileParses) {
  const ClientConfig c = parseClientConfig(kFullClient, kOrigin);
  EXPECT_DOUBLE_EQ(c.op.frequency_hz, 4.5);
  EXPECT_DOUBLE_EQ(c.op.band_min_n, 10.0);
  EXPECT_DOUBLE_EQ(c.op.band_max_n, 18.0);
  EXPECT_DOUBLE_EQ(c.op.ramp_s, 2.0);
  EXPECT_DOUBLE_EQ(c.op.sensor_noise_n, 0.05);
  EXPECT_EQ(c.op.seed, 42u);
  EXPECT_DOUBLE_EQ(c.safety.max_force_n, 3.5);
  EXPECT_DOUBLE_EQ(c.safety.max_rate_n_per_s, 150.0);
  EXPECT_EQ(c.safety.watchdog_ns, 10'000'000);
  EXPECT_DOUBLE_EQ(c.loop.rate_hz, 2000.0);
  EXPECT_EQ(c.loop.rt_priority, 80);
}

TEST(ClientConfig, EmptyTextGivesTheDefaults) {
  const ClientConfig c = parseClientConfig("", kOrigin);
  const ClientConfig d;
  EXPECT_EQ(c.op.frequency_hz, d.op.frequency_hz);
  EXPECT_EQ(c.op.band_min_n, 12.0);  // paper: 12-16 N
  EXPECT_EQ(c.op.band_max_n, 16.0);
  EXPECT_EQ(c.safety.max_force_n, 4.0);  // MF-2 maximum
  EXPECT_EQ(c.safety.watchdog_ns, d.safety.watchdog_ns);
  EXPECT_EQ(c.loop.rate_hz, 1000.0);
}

TEST(ClientConfig, IntegerWhereANumberIsExpectedIsAccepted) {
  const ClientConfig c = parseClientConfig("[operator]\nfrequency_hz = 2\n", kOrigin);
  EXPECT_DOUBLE_EQ(c.op.frequency_hz, 2.0);
}

TEST(ClientConfig, LoadsFromAFile) {
  const auto path = std::filesystem::temp_directory_path() /
                    ("telehand-config-test-" + std::to_string(::getpid()) + ".toml");
  {
    std::ofstream out(path);
    out << kFullClient;
  }
  const ClientConfig c = loadClientConfig(path.string());
  std::filesystem::remove(path);
  EXPECT_EQ(c.op.seed, 42u);
  EXPECT_EQ(c.loop.rt_priority, 80);
}

TEST(ClientConfig, MissingFileNamesThePath) {
  const std::string path = "/nonexistent/telehand/client.toml";
  try {
    loadClientConfig(path);
    FAIL() << "no error";
  } catch (const ConfigError& e) {
    EXPECT_THAT(e.what(), HasSubstr(path));
  }
}

TEST(ClientConfig, MalformedTomlNamesOriginAndLine) {
  const std::string msg = clientError("[operator]\nfrequency_hz = 3.0\nramp_s = = 2\n");
  EXPECT_THAT(msg, AllOf(HasSubstr(kOrigin), HasSubstr("line 3")));
  const std::string unterminated = clientError("[operator]\n\n\n[safety\nmax_force_n = 2.0\n");
  EXPECT_THAT(unterminated, AllOf(HasSubstr(kOrigin), HasSubstr("line 4")));
}

TEST(ClientConfig, ErrorIsAlsoATelehandError) {
  EXPECT_THROW(parseClientConfig("this is not toml", kOrigin), Error);
}

TEST(ClientConfig, UnknownKeyIsNamedWithItsTableAndLine) {
  const std::string msg = clientError("[operator]\nfrequency_hz = 3.0\nfrequncy_hz = 4.0\n");
  EXPECT_THAT(msg, AllOf(HasSubstr(kOrigin), HasSubstr("line 3"), HasSubstr("operator.frequncy_hz"),
                         HasSubstr("unknown key")));
  EXPECT_THAT(clientError("[safety]\nmax_force = 2.0\n"), HasSubstr("safety.max_force"));
  EXPECT_THAT(clientError("[loop]\nrate = 2.0\n"), HasSubstr("loop.rate"));
}

TEST(ClientConfig, UnknownTableIsNamed) {
  const std::string msg = clientError("[operator]\nseed = 1\n\n[oprator]\nseed = 2\n");
  EXPECT_THAT(msg, AllOf(HasSubstr(kOrigin), HasSubstr("oprator"), HasSubstr("line 4")));
}

TEST(ClientConfig, TableThatIsNotATableIsNamed) {
  EXPECT_THAT(clientError("operator = 3\n"), AllOf(HasSubstr(kOrigin), HasSubstr("operator")));
}

TEST(ClientConfig, WrongTypeNamesKeyAndLine) {
  const std::string msg = clientError("[operator]\n\nfrequency_hz = \"fast\"\n");
  EXPECT_THAT(msg, AllOf(HasSubstr(kOrigin), HasSubstr("line 3"),
                         HasSubstr("operator.frequency_hz"), HasSubstr("number")));
  EXPECT_THAT(clientError("[operator]\nseed = 1.5\n"), HasSubstr("operator.seed"));
  EXPECT_THAT(clientError("[operator]\nseed = -3\n"),
              AllOf(HasSubstr("operator.seed"), HasSubstr("non-negative")));
  EXPECT_THAT(clientError("[loop]\nrt_priority = true\n"), HasSubstr("loop.rt_priority"));
  EXPECT_THAT(clientError("[safety]\nwatchdog_ms = [1, 2]\n"), HasSubstr("safety.watchdog_ms"));
}

// The loop's rate: both ends of LoopConfig's range are taken; just past them is refused with
// the value and the range as written, not rounded onto the bound.
TEST(ClientConfig, LoopRateRangeEndsAreTakenAndTheValueIsShownAsWritten) {
  EXPECT_EQ(parseClientConfig("[loop]\nrate_hz = 800.0\n", kOrigin).loop.rate_hz,
            LoopConfig::kMinRateHz);
  EXPECT_EQ(parseClientConfig("[loop]\nrate_hz = 4000.0\n", kOrigin).loop.rate_hz,
            LoopConfig::kMaxRateHz);
  EXPECT_THAT(clientError("[loop]\nrate_hz = 799.9999999\n"),
              HasSubstr("'loop.rate_hz' = 799.9999999 is outside [800, 4000]"));
  EXPECT_THAT(clientError("[safety]\nwatchdog_ms = 0.25\n"),
              HasSubstr("= 0.25 is outside [1, 1000]"));
}

TEST(ClientConfig, OutOfRangeValueNamesTheKey) {
  struct Case {
    const char* text;
    const char* key;
  };
  const Case cases[] = {
      {"[operator]\nfrequency_hz = 50.0\n", "operator.frequency_hz"},
      {"[operator]\nfrequency_hz = 0.0\n", "operator.frequency_hz"},
      {"[operator]\nfrequency_hz = nan\n", "operator.frequency_hz"},
      {"[operator]\nband_min_n = -1.0\n", "operator.band_min_n"},
      {"[operator]\nband_min_n = 14.0\nband_max_n = 13.0\n", "operator.band_max_n"},
      {"[operator]\nramp_s = 100.0\n", "operator.ramp_s"},
      {"[operator]\nsensor_noise_n = 9.0\n", "operator.sensor_noise_n"},
      {"[safety]\nmax_force_n = 5.0\n", "safety.max_force_n"},  // above the MF-2's 4 N
      {"[safety]\nmax_rate_n_per_s = 0.5\n", "safety.max_rate_n_per_s"},
      {"[safety]\nwatchdog_ms = 0.1\n", "safety.watchdog_ms"},
      {"[safety]\nwatchdog_ms = 5000.0\n", "safety.watchdog_ms"},
      {"[safety]\nwatchdog_ms = inf\n", "safety.watchdog_ms"},
      {"[safety]\nwatchdog_ms = 1e300\n", "safety.watchdog_ms"},
      {"[loop]\nrate_hz = 10.0\n", "loop.rate_hz"},
      {"[loop]\nrate_hz = 500.0\n", "loop.rate_hz"},  // under the stable wall's rate
      {"[loop]\nrate_hz = 5000.0\n", "loop.rate_hz"},
      {"[loop]\nrt_priority = 200\n", "loop.rt_priority"},
      // 2^32 + 1 must not wrap into a valid priority.
      {"[loop]\nrt_priority = 4294967297\n", "loop.rt_priority"},
  };
  for (const Case& c : cases) {
    const std::string msg = clientError(c.text);
    EXPECT_THAT(msg, AllOf(HasSubstr(kOrigin), HasSubstr(c.key))) << c.text;
  }
}

TEST(ServerConfig, ValidFileParses) {
  const ServerConfig c = parseServerConfig(
      "[server]\ndb = \"/var/lib/telehand/r.db\"\nhand_state_hz = 60.0\nclose_grace_s = 2.5\n",
      "server.toml");
  EXPECT_EQ(c.db_path, "/var/lib/telehand/r.db");
  EXPECT_DOUBLE_EQ(c.hand_state_hz, 60.0);
  EXPECT_DOUBLE_EQ(c.close_grace_s, 2.5);
  EXPECT_EQ(parseServerConfig("", "server.toml").db_path, ServerConfig{}.db_path);
  EXPECT_TRUE(parseServerConfig("", "server.toml").drift_correction);
  EXPECT_FALSE(
      parseServerConfig("[server]\ndrift_correction = false\n", "server.toml").drift_correction);
  EXPECT_TRUE(parseServerConfig("", "server.toml").renew_when_idle);
  EXPECT_FALSE(
      parseServerConfig("[server]\nrenew_when_idle = false\n", "server.toml").renew_when_idle);
}

TEST(ServerConfig, ErrorsNameOriginAndKey) {
  EXPECT_THAT(serverError("[server]\ndb = \"\"\n"),
              AllOf(HasSubstr("server.toml"), HasSubstr("server.db")));
  EXPECT_THAT(serverError("[server]\ndb = 3\n"),
              AllOf(HasSubstr("line 2"), HasSubstr("server.db"), HasSubstr("string")));
  EXPECT_THAT(serverError("[server]\nhand_state_hz = 0.0\n"), HasSubstr("server.hand_state_hz"));
  EXPECT_THAT(serverError("[server]\nclose_grace_s = -1.0\n"), HasSubstr("server.close_grace_s"));
  EXPECT_THAT(serverError("[server]\nhandstate_hz = 60.0\n"),
              AllOf(HasSubstr("line 2"), HasSubstr("server.handstate_hz")));
  EXPECT_THAT(serverError("[operator]\nseed = 1\n"), HasSubstr("operator"));
  EXPECT_THAT(
      serverError("[server]\ndrift_correction = 0\n"),
      AllOf(HasSubstr("line 2"), HasSubstr("server.drift_correction"), HasSubstr("true or false")));
  EXPECT_THAT(serverError("[server]\nrenew_when_idle = \"yes\"\n"),
              AllOf(HasSubstr("line 2"), HasSubstr("server.renew_when_idle")));
  EXPECT_THAT(serverError("[server\n"), AllOf(HasSubstr("server.toml"), HasSubstr("line 1")));
}

}  // namespace
}  // namespace telehand

namespace telehand {
namespace {

/// The network configs bound the size of a DDS sample (Cyclone's MaxSampleSize, 2 GiB by
/// default: a peer could make a server reassemble that much before refusing it), and the
/// bound lets every SessionFile through that a server may be configured to keep.
TEST(NetworkConfigs, BoundTheSampleSizeAboveTheLargestFileAServerKeeps) {
  for (const char* name : {"loopback.xml", "wan.xml"}) {
    const std::string path = std::string(TELEHAND_DEPLOY_DIR) + "/cyclonedds/" + name;
    std::ifstream in(path);
    ASSERT_TRUE(in) << path;
    const std::string xml((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    const auto at = xml.find("<MaxSampleSize>");
    ASSERT_NE(at, std::string::npos) << name;
    std::size_t used = 0;
    const long long mib = std::stoll(xml.substr(at + 15), &used);
    EXPECT_EQ(xml.substr(at + 15 + used, 3), "MiB") << name;
    const long long bytes = mib * 1024 * 1024;
    // A file's name (string<128>), session id and time, and the CDR header: well under 1 MiB.
    EXPECT_GE(bytes, static_cast<long long>(kMaxFileBytesLimit) + 1024 * 1024) << name;
    EXPECT_LE(bytes, 2LL * kMaxFileBytesLimit) << name;
  }
}

}  // namespace
}  // namespace telehand
