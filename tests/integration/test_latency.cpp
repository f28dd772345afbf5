// telehand-latency as a process: round trips through a self echo taken either way (listener,
// waitset), through telehand-server's echo and in rounds with ddsperf, checked by the JSON it
// writes. No timing is asserted (figures belong to docs/performance.md): only that pings come
// back, each counted once, and that what the server says it echoed covers them.
#include <chrono>
#include <fstream>
#include <sstream>
#include <string>

#include "process.h"
#include "process_test.h"

namespace telehand::test {
namespace {

using namespace std::chrono_literals;

class LatencyTest : public ProcessTest {
 protected:
  LatencyTest() : ProcessTest("latency", TELEHAND_LOOPBACK_XML) {}

  std::string readFile(const std::string& name) const {
    std::ifstream in(path(name));
    std::ostringstream ss;
    ss << in.rdbuf();
    return ss.str();
  }

  /// Runs a short probe (200 Hz, 1 s after 0.2 s warm-up) with `args`; returns its JSON.
  std::string probe(std::vector<std::string> args, const std::string& name) {
    args.insert(args.end(), {"--seconds", "1", "--rate", "200", "--warmup", "0.2", "-q", "--json",
                             path(name + ".json")});
    Process p(cmd(TELEHAND_LATENCY_BIN, args), path(name + ".log"));
    const auto rc = p.wait(60s);
    EXPECT_TRUE(rc.has_value()) << "telehand-latency did not finish\n" << p.output();
    EXPECT_EQ(rc.value_or(-1), 0) << p.output();
    return readFile(name + ".json");
  }

  /// The probe's own figures: what it sent, what came back, nothing twice.
  static void expectAnswered(const std::string& json, const std::string& take) {
    EXPECT_NE(json.find("\"take\": \"" + take + "\""), std::string::npos) << json;
    const uint64_t sent = matchNumber(json, "\"sent\": (\\d+)");
    const uint64_t received = matchNumber(json, "\"received\": (\\d+)");
    const uint64_t lost = matchNumber(json, "\"lost\": (\\d+)");
    EXPECT_EQ(sent, 200u) << json;
    // Best-effort may lose a few on a loaded machine; most come back.
    EXPECT_GT(received, sent / 2) << json;
    EXPECT_EQ(received + lost, sent) << json;
    EXPECT_EQ(matchNumber(json, "\"duplicates\": (\\d+)"), 0u) << json;
    EXPECT_EQ(matchNumber(json, "\"pooled\": \\{\"count\": (\\d+)"), received) << json;
  }
};

TEST_F(LatencyTest, SelfEchoAnswersThroughListeners) {
  const std::string json = probe({"--echo", "self", "--take", "listener"}, "listener");
  expectAnswered(json, "listener");
  EXPECT_NE(json.find("\"echo\": \"self"), std::string::npos) << json;
}

TEST_F(LatencyTest, SelfEchoAnswersThroughWaitsets) {
  const std::string json = probe({"--echo", "self", "--take", "waitset"}, "waitset");
  expectAnswered(json, "waitset");
}

TEST_F(LatencyTest, ServerEchoAnswersEveryPingItGets) {
  Process server(cmd(TELEHAND_SERVER_BIN, {"--db", path("records.db"), "--seconds", "60"}),
                 path("server.log"));
  const std::string json = probe({"--echo", "server"}, "server");
  expectAnswered(json, "listener");
  EXPECT_NE(json.find("\"echo\": \"external"), std::string::npos) << json;
  EXPECT_EQ(server.stop(), 0) << server.output();
  // Warm-up pings are echoed too; every pong the probe counted was one of the server's.
  const uint64_t echoes = matchNumber(server.output(), "(\\d+) echoes");
  EXPECT_GE(echoes, matchNumber(json, "\"received\": (\\d+)")) << server.output();
}

TEST_F(LatencyTest, EchoOnlyStopsAfterItsSecondsAndSaysHowManyItAnswered) {
  Process echo(cmd(TELEHAND_LATENCY_BIN, {"--echo-only", "--seconds", "1"}), path("echo.log"));
  const auto rc = echo.wait(30s);
  ASSERT_TRUE(rc.has_value()) << "the echo did not stop after --seconds\n" << echo.output();
  EXPECT_EQ(*rc, 0) << echo.output();
  EXPECT_NE(echo.output().find("(take: listener)"), std::string::npos) << echo.output();
  EXPECT_NE(echo.output().find("echo stopped after 0 echoes, 0 write errors"), std::string::npos)
      << echo.output();
}

TEST_F(LatencyTest, RoundsTakeTurnsWithDdsperfAndAddUp) {
  useOwnDomain();  // ddsperf sees every ddsperf of its domain, whatever the partition
  Process p(cmd(TELEHAND_LATENCY_BIN,
                {"--echo", "self", "--compare-ddsperf", "--rounds", "2", "--seconds", "2", "--rate",
                 "200", "--warmup", "0.2", "-q", "--json", path("rounds.json")}),
            path("rounds.log"));
  const auto rc = p.wait(90s);
  ASSERT_TRUE(rc.has_value()) << "telehand-latency did not finish\n" << p.output();
  ASSERT_EQ(*rc, 0) << p.output();
  const std::string json = readFile("rounds.json");
  EXPECT_NE(json.find("\"rounds\": 2"), std::string::npos) << json;
  // Two rounds of 1 s at 200 Hz each: the pings of both are counted once.
  EXPECT_EQ(matchNumber(json, "\"sent\": (\\d+)"), 400u) << json;
  EXPECT_GT(matchNumber(json, "\"received\": (\\d+)"), 200u) << json;
  // Each round's ddsperf reported at least one second after its warm-up.
  EXPECT_GE(matchNumber(json, "\"ddsperf\": \\{.*\"seconds\": (\\d+)"), 2u) << json;
  EXPECT_NE(p.output().find("in 2 rounds taking turns with telehand"), std::string::npos)
      << p.output();
}

TEST_F(LatencyTest, RoundsShorterThanASecondAreRefused) {
  Process p(cmd(TELEHAND_LATENCY_BIN, {"--compare-ddsperf", "--rounds", "3", "--seconds", "2"}),
            path("short.log"));
  EXPECT_EQ(p.wait(30s), 2) << p.output();
  EXPECT_NE(p.output().find("--seconds 2 / --rounds 3 is under 1 s"), std::string::npos)
      << p.output();
}

TEST_F(LatencyTest, AnUnknownTakeIsRefused) {
  Process p(cmd(TELEHAND_LATENCY_BIN, {"--take", "poll"}), path("bad.log"));
  EXPECT_EQ(p.wait(30s), 2) << p.output();
  EXPECT_NE(p.output().find("--take"), std::string::npos) << p.output();
}

}  // namespace
}  // namespace telehand::test
