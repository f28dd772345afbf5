// The client's link believes its server only as far as what it says can be true: a DirectForce
// that is not finite is refused (said and counted, not rendered), an acknowledgement of
// samples past the last one sent is not believed (the samples it would let the client forget
// are kept), a flood of models it refuses is counted and said only a few times, and event text
// reaches the student's terminal without control characters. The server here is a participant
// of the test's own that answers the OPEN, in a domain (by PID) and partition of its own, on
// loopback.
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
#include "telehand/core/printable.h"
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
        forces(participant, topics.direct_force, dds::qos::directForce(64)),
        models(participant, topics.joint_model, dds::qos::jointModel().keepLast(1024)),
        events(participant, topics.session_event, dds::qos::sessionEvent()) {}

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
  void sendModel(const JointModelParams& p, uint32_t version) {
    telehand_msg_JointModel m{};
    JointModelParams v = p;
    v.version = version;
    toWire(v, kSession, m);
    ASSERT_EQ(models.write(m), DDS_RETCODE_OK);
  }
  void sendEvent(telehand_msg_EventKind kind, uint64_t from_client, const std::string& text) {
    telehand_msg_SessionEvent e{};
    e.session_id = kSession;
    e.seq = ++event_seq;
    e.source_time_ns = wallNs();
    e.kind = kind;
    e.client_id = from_client;
    copyString(e.text, text);
    ASSERT_EQ(events.write(e), DDS_RETCODE_OK);
  }

  dds::Writer<telehand_msg_DirectForce> forces;
  dds::Writer<telehand_msg_JointModel> models;
  dds::Writer<telehand_msg_SessionEvent> events;
  uint64_t client_id = 0;
  uint64_t event_seq = 0;
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

TEST_F(LinkRefusalsTest, AFloodOfRefusedModelsIsCountedAndSaidAFewTimes) {
  const auto o = options("models");
  FakeServer server(o);
  ASSERT_NO_FATAL_FAILURE(openOn(server, o));
  ASSERT_TRUE(waitFor([&] { return server.models.matchedReaders() > 0; }));
  const auto& st = link_->stats();

  // A server that sends a model whose flexion force falls with the angle, again and again.
  JointModelParams bad = healthyIndexMcp();
  bad.axes[kFlexion].coeffs = {0.0, 0.0, -0.05, 0.0};
  constexpr uint32_t kSent = 1000;
  for (uint32_t v = 1; v <= kSent; ++v) {
    ASSERT_NO_FATAL_FAILURE(server.sendModel(bad, v));
    // The link's reader keeps 256 unread: sent in steps it takes.
    if (v % 100 == 0) {
      ASSERT_TRUE(waitFor([&] { return st.models_rejected.load() == v; })) << v;
    }
  }
  ASSERT_TRUE(waitFor([&] { return st.models_rejected.load() == kSent; }))
      << st.models_rejected.load();
  EXPECT_EQ(st.models_received.load(), 0u);
  // A good model after them is taken: the link went on listening.
  ASSERT_NO_FATAL_FAILURE(server.sendModel(healthyIndexMcp(), kSent + 1));
  EXPECT_TRUE(waitFor([&] { return st.models_received.load() == 1; }));
  link_->stop();

  const auto said = link_->takeMessages();
  EXPECT_LE(said.size(), 257u);
  std::size_t refusals = 0;
  for (const auto& m : said) {
    if (m.find("rejected JointModel") == std::string::npos) continue;
    ++refusals;
    EXPECT_NE(m.find("flexion"), std::string::npos) << m;
  }
  EXPECT_GT(refusals, 0u);
  EXPECT_LE(refusals, 8u) << "said only for the first few";
  ASSERT_FALSE(said.empty());
  bool counted = false;
  for (const auto& m : said) counted = counted || m.find("counted, not said") != std::string::npos;
  EXPECT_TRUE(counted);
}

TEST_F(LinkRefusalsTest, MarksAndErrorsArriveWithoutControlCharacters) {
  const auto o = options("marks");
  FakeServer server(o);
  ASSERT_NO_FATAL_FAILURE(openOn(server, o));
  ASSERT_TRUE(waitFor([&] { return server.events.matchedReaders() > 0; }));

  // A supervisor's mark that would clear the student's terminal and ring its bell.
  server.sendEvent(telehand_msg_EVENT_MARK, server.client_id + 1,
                   "good\x1b[2J\x1b[H grip\x07 \xc2\x9b"
                   "2J 12 \xc2\xb1 1 N");
  ASSERT_TRUE(waitFor([&] { return saidSomething("mark: good"); }));
  // An error naming what a client sent (a case name, say) is shown the same way.
  server.sendEvent(telehand_msg_EVENT_ERROR, server.client_id,
                   "unknown patient case '\x1b]0;x\x07'");
  ASSERT_TRUE(waitFor([&] { return saidSomething("unknown patient case"); }));
  link_->stop();
  saidSomething("");
  bool mark_seen = false;
  for (const auto& m : said_) {
    for (char c : m) {
      const auto u = static_cast<unsigned char>(c);
      EXPECT_TRUE(u >= 0x20 && u != 0x7f) << "control character " << int{u} << " in: " << m;
    }
    EXPECT_EQ(m.find("\xc2\x9b"), std::string::npos) << m;
    if (m.starts_with("mark: ")) {
      mark_seen = true;
      EXPECT_EQ(m, "mark: good?[2J?[H grip? ?2J 12 \xc2\xb1 1 N");
    }
  }
  EXPECT_TRUE(mark_seen);
}

TEST_F(LinkRefusalsTest, TheMessageListIsBoundedAndSaysWhatItDropped) {
  const auto o = options("bounded");
  FakeServer server(o);
  ASSERT_NO_FATAL_FAILURE(openOn(server, o));
  ASSERT_TRUE(waitFor([&] { return server.events.matchedReaders() > 0; }));
  // More errors than the list keeps, none read in between (the link's reader keeps 64 unread:
  // sent in steps it takes).
  constexpr int kSent = 300;
  for (int i = 0; i < kSent; ++i) {
    ASSERT_NO_FATAL_FAILURE(
        server.sendEvent(telehand_msg_EVENT_ERROR, server.client_id, "error " + std::to_string(i)));
    if (i % 16 == 15) std::this_thread::sleep_for(30ms);
  }
  std::this_thread::sleep_for(200ms);
  link_->stop();
  const auto said = link_->takeMessages();
  ASSERT_EQ(said.size(), 257u);
  EXPECT_EQ(said.front(), "error 0");
  EXPECT_EQ(said[255], "error 255");
  EXPECT_EQ(said.back(), "44 more message(s) not kept: at most 256 are kept between reads");
  // Read, the list starts again.
  EXPECT_TRUE(link_->takeMessages().empty());
}

TEST(Printable, ControlCharactersBecomeQuestionMarksAndTextStays) {
  EXPECT_EQ(printable("plain text, 12-16 N"), "plain text, 12-16 N");
  EXPECT_EQ(printable(std::string("\x1b[2Jcleared\r\n\t\x7f")), "?[2Jcleared????");
  // UTF-8 stays; C1 controls (U+0080..U+009F) and bytes of no UTF-8 character do not.
  EXPECT_EQ(printable("\xc2\xb1 3 \xc2\xb0, caf\xc3\xa9, \xe2\x80\x94, \xf0\x9f\x91\x8d"),
            "\xc2\xb1 3 \xc2\xb0, caf\xc3\xa9, \xe2\x80\x94, \xf0\x9f\x91\x8d");
  EXPECT_EQ(printable("a\xc2\x9b"
                      "2Jb"),
            "a?2Jb");
  EXPECT_EQ(printable("a\x9b"
                      "2Jb"),
            "a?2Jb");                                     // a lone 8-bit CSI
  EXPECT_EQ(printable("\xc0\x9b\xe0\x82\x9b"), "?????");  // overlong forms
  EXPECT_EQ(printable("\xed\xa0\x80"), "???");            // a surrogate
  EXPECT_EQ(printable("end\xe2\x80"), "end??");           // cut short
  // A fixed-size field: up to its first NUL, never past its end.
  const char field[8] = {'a', 'b', '\x1b', 'c', 'd', 'e', 'f', 'g'};
  EXPECT_EQ(printable(field), "ab?cdefg");
  const char short_field[8] = "ok";
  EXPECT_EQ(printable(short_field), "ok");
}

}  // namespace
}  // namespace telehand::client
