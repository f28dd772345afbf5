// The client's link believes its server only as far as what it says can be true: a DirectForce
// that is not finite is refused (said and counted, not rendered), and an acknowledgement of
// samples past the last one sent is not believed (the samples it would let the client forget
// are kept). The server here is a participant of the test's own that answers the OPEN, in a
// domain (by PID) and partition of its own, on loopback.
#include <gtest/gtest.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <functional>
#include <limits>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include "telehand/client/link/client_link.h"
#include "telehand/client/loop/haptic_loop.h"
#include "telehand/core/clock.h"
#include "telehand/devices/simulated_mf2.h"
#include "telehand/protocol/dds.h"
#include "telehand/protocol/wire.h"

namespace telehand::client {
namespace {

using namespace std::chrono_literals;

dds::Options options(const std::string& name) {
  dds::Options o;
  o.domain = 100 + static_cast<uint32_t>(getpid() % 100);
  o.config = TELEHAND_DEPLOY_DIR "/cyclonedds/loopback.xml";
  o.partition = "link-refusals-" + std::to_string(getpid()) + "-" + name;
  return o;
}

/// What the session's server sends: it answers the first OPEN with session kSession.
struct FakeServer {
  static constexpr uint64_t kSession = 41;
  explicit FakeServer(const dds::Options& o)
      : participant(o),
        topics(participant),
        commands(participant, topics.session_command, dds::qos::sessionCommand()),
        status(participant, topics.session_status, dds::qos::sessionStatus()),
        forces(participant, topics.direct_force, dds::qos::directForce(64)) {}

  /// Answers the first OPEN within `timeout`; false when none came.
  bool answerOpen(std::chrono::milliseconds timeout) {
    const auto deadline = std::chrono::steady_clock::now() + timeout;
    while (std::chrono::steady_clock::now() < deadline) {
      bool answered = false;
      commands.take([&](const telehand_msg_SessionCommand& c, const dds_sample_info_t&) {
        if (answered || c.kind != telehand_msg_CMD_OPEN) return;
        client_id = c.client_id;
        sendStatus(c.request_seq, 0);
        answered = true;
      });
      if (answered) return true;
      std::this_thread::sleep_for(5ms);
    }
    return false;
  }
  void sendStatus(uint32_t request_seq, uint64_t stored_below) {
    telehand_msg_SessionStatus st{};
    st.session_id = kSession;
    st.client_id = client_id;
    st.request_seq = request_seq;
    st.state = telehand_msg_SESSION_ACTIVE;
    st.mode = telehand_msg_MODE_MOBILIZATION;
    st.stored_below = stored_below;
    copyString(st.case_name, "healthy");
    ASSERT_EQ(status.write(st), DDS_RETCODE_OK);
  }
  void sendForce(uint64_t device_seq, double thumb_z) {
    telehand_msg_DirectForce f{};
    f.session_id = kSession;
    f.device_seq = device_seq;
    f.force_n[0][2] = thumb_z;
    f.force_n[1][2] = -1.0;
    ASSERT_EQ(forces.write(f), DDS_RETCODE_OK);
  }

  dds::Participant participant;
  dds::Topics topics;
  dds::Reader<telehand_msg_SessionCommand> commands;
  dds::Writer<telehand_msg_SessionStatus> status;
  dds::Writer<telehand_msg_DirectForce> forces;
  uint64_t client_id = 0;
};

class LinkRefusalsTest : public ::testing::Test {
 protected:
  /// Opens a session on the fake server and starts the link thread.
  void openOn(FakeServer& server, const dds::Options& o) {
    link_ = std::make_unique<link::ClientLink>(o, loop_);
    std::thread answer([&] { answered_ = server.answerOpen(10s); });
    link::OpenRequest req;
    req.direct_force = true;
    const uint64_t id = link_->open(req, 10s);
    answer.join();
    ASSERT_TRUE(answered_);
    ASSERT_EQ(id, FakeServer::kSession);
    ASSERT_TRUE(waitFor([&] { return server.forces.matchedReaders() > 0; }));
    link_->start();
  }
  /// Waits (bounded) until `done` holds.
  static bool waitFor(const std::function<bool()>& done) {
    for (int i = 0; i < 400; ++i) {
      if (done()) return true;
      std::this_thread::sleep_for(5ms);
    }
    return done();
  }
  bool saidSomething(const std::string& part) {
    for (const auto& m : link_->takeMessages()) {
      said_.push_back(m);
    }
    for (const auto& m : said_)
      if (m.find(part) != std::string::npos) return true;
    return false;
  }

  ManualClock clock_{kNsPerS};
  devices::SimulatedMf2 dev_{healthyIndexMcp(), OperatorConfig{}, clock_};
  loop::HapticLoop loop_{dev_, clock_, healthyIndexMcp(), SafetyLimits{}, LoopConfig{}};
  std::unique_ptr<link::ClientLink> link_;
  std::atomic<bool> answered_{false};
  std::vector<std::string> said_;
};

TEST_F(LinkRefusalsTest, AForceThatIsNotFiniteIsRefusedSaidAndCounted) {
  const auto o = options("force");
  FakeServer server(o);
  ASSERT_NO_FATAL_FAILURE(openOn(server, o));
  const auto& st = link_->stats();

  server.sendForce(0, std::numeric_limits<double>::quiet_NaN());
  server.sendForce(1, std::numeric_limits<double>::infinity());
  ASSERT_TRUE(waitFor([&] { return st.direct_rejected.load() == 2; })) << st.direct_rejected.load();
  EXPECT_EQ(st.direct_forces.load(), 0u);
  EXPECT_TRUE(waitFor([&] { return saidSomething("not finite"); }));
  EXPECT_TRUE(saidSomething("sample 0")) << (said_.empty() ? "" : said_.front());

  // A finite force from the same server is taken.
  server.sendForce(2, 1.5);
  EXPECT_TRUE(waitFor([&] { return st.direct_forces.load() == 1; }));
  EXPECT_EQ(st.direct_rejected.load(), 2u);

  // A flood is counted, and said only for the first few.
  for (uint64_t i = 0; i < 40; ++i) server.sendForce(10 + i, std::nan(""));
  EXPECT_TRUE(waitFor([&] { return st.direct_rejected.load() == 42; }))
      << st.direct_rejected.load();
  link_->stop();
  saidSomething("");
  std::size_t refusals_said = 0;
  for (const auto& m : said_) refusals_said += m.find("not finite") != std::string::npos;
  EXPECT_GT(refusals_said, 0u);
  EXPECT_LT(refusals_said, 42u);
}

TEST_F(LinkRefusalsTest, AnAcknowledgementPastWhatWasSentIsNotBelieved) {
  const auto o = options("ack");
  FakeServer server(o);
  ASSERT_NO_FATAL_FAILURE(openOn(server, o));
  const auto& st = link_->stats();
  ASSERT_EQ(st.last_seq.load(), 0u);  // nothing sent: the loop has not stepped

  // "Everything below 1,000,000 is stored": the client sent nothing of the kind.
  server.sendStatus(0, 1'000'000);
  ASSERT_TRUE(waitFor([&] { return st.acks_rejected.load() == 1; }));
  EXPECT_EQ(st.stored_below.load(), 0u);
  EXPECT_TRUE(waitFor([&] { return saidSomething("1000000"); }));

  // An acknowledgement that can be true is believed.
  server.sendStatus(0, 1);
  EXPECT_TRUE(waitFor([&] { return st.stored_below.load() == 1; }));
  EXPECT_EQ(st.acks_rejected.load(), 1u);
  link_->stop();
}

}  // namespace
}  // namespace telehand::client
