// DDS Security end to end (docs/security.md): the server, the device client and the
// supervisor's watcher run under a PKI this test makes; an unauthenticated participant on
// the same domain and partition receives nothing, a participant with a certificate from
// another CA finds no session, and a supervisor's identity cannot write a JointModel.
#include <arpa/inet.h>
#include <gtest/gtest.h>
#include <linux/if_ether.h>
#include <net/if.h>
#include <netpacket/packet.h>
#include <stdlib.h>
#include <sys/socket.h>
#include <unistd.h>

#include <atomic>
#include <filesystem>
#include <memory>
#include <string_view>
#include <thread>
#include <vector>

#include "process.h"
#include "process_test.h"
#include "telehand/core/error.h"
#include "telehand/protocol/dds.h"
#include "telehand/server/store/sqlite_store.h"

namespace telehand::test {
namespace {

using namespace std::chrono_literals;

class SecurityTest : public ProcessTest {
 protected:
  SecurityTest() : ProcessTest("sec", TELEHAND_LOOPBACK_XML) {}
  void SetUp() override {
    ProcessTest::SetUp();
    pki_ = makePki("pki");
  }
  std::string makePki(const std::string& name) {
    const std::string dir = path(name);
    Process make({TELEHAND_MAKE_PKI, dir}, path(name + ".log"));
    const auto rc = make.wait(60s);
    EXPECT_EQ(rc, std::optional<int>(0)) << make.output();
    return dir;
  }
};

/// Every sample of every session topic an unauthenticated participant receives.
struct Eavesdropper {
  explicit Eavesdropper(const dds::Options& o)
      : participant(o),
        topics(participant),
        device(participant, topics.device_state, dds::qos::deviceState()),
        chunk(participant, topics.record_chunk, dds::qos::recordChunk()),
        model(participant, topics.joint_model, dds::qos::jointModel()),
        hand(participant, topics.hand_state, dds::qos::handState()),
        command(participant, topics.session_command, dds::qos::sessionCommand()),
        status(participant, topics.session_status, dds::qos::sessionStatus()),
        event(participant, topics.session_event, dds::qos::sessionEvent()) {}

  /// Takes whatever arrived; returns how many samples that was.
  uint64_t drain() {
    const auto any = [](const auto&, const dds_sample_info_t&) {};
    return device.take(any, 1024) + chunk.take(any, 1024) + model.take(any, 1024) +
           hand.take(any, 1024) + command.take(any, 1024) + status.take(any, 1024) +
           event.take(any, 1024);
  }

  dds::Participant participant;
  dds::Topics topics;
  dds::Reader<telehand_msg_DeviceState> device;
  dds::Reader<telehand_msg_RecordChunk> chunk;
  dds::Reader<telehand_msg_JointModel> model;
  dds::Reader<telehand_msg_HandState> hand;
  dds::Reader<telehand_msg_SessionCommand> command;
  dds::Reader<telehand_msg_SessionStatus> status;
  dds::Reader<telehand_msg_SessionEvent> event;
};

TEST_F(SecurityTest, OnlyAuthenticatedParticipantsTakePart) {
  const std::string db = path("records.db");
  Process server(cmd(TELEHAND_SERVER_BIN, {"--db", db, "--seconds", "60"}), path("server.log"));

  // Listening without an identity, on the same domain and partition, from the start.
  dds::Options open;
  open.config = TELEHAND_LOOPBACK_XML;
  open.partition = partition_;
  auto eve = std::make_unique<Eavesdropper>(open);

  Process client(cmd(TELEHAND_CLIENT_BIN, {"--seconds", "5", "-q"}), path("client.log"));
  std::this_thread::sleep_for(1500ms);
  Process watcher(cmd(TELEHAND_WATCH_BIN, {"--plain", "--exit-on-close", "--wait", "20"}),
                  path("watch.log"));
  // A watcher whose certificate another CA signed: it authenticates to nobody here.
  const std::string rogue_pki = makePki("rogue-pki");
  Process rogue({TELEHAND_WATCH_BIN, "--plain", "--exit-on-close", "--wait", "6", "--dds-config",
                 TELEHAND_LOOPBACK_XML, "--partition", partition_, "--pki", rogue_pki},
                path("rogue.log"));
  uint64_t overheard = 0;
  while (!client.wait(0ms)) {
    overheard += eve->drain();
    std::this_thread::sleep_for(20ms);
  }
  overheard += eve->drain();
  eve.reset();
  // An unauthenticated client trying to close a session finds no server to talk to (run
  // once the eavesdropper, whose readers it would match, is gone).
  Process inject({TELEHAND_INJECT_BIN, "close-unknown", "--session", "1", "--dds-config",
                  TELEHAND_LOOPBACK_XML, "--partition", partition_, "--insecure"},
                 path("inject.log"));
  const auto client_rc = client.wait(30s);
  ASSERT_TRUE(client_rc.has_value()) << client.output();
  EXPECT_EQ(*client_rc, 0) << client.output();
  const auto watch_rc = watcher.wait(20s);
  ASSERT_TRUE(watch_rc.has_value()) << watcher.output();
  EXPECT_EQ(*watch_rc, 0) << watcher.output();
  const auto rogue_rc = rogue.wait(20s);
  ASSERT_TRUE(rogue_rc.has_value()) << rogue.output();
  EXPECT_NE(*rogue_rc, 0) << "a participant from another CA found the session\n" << rogue.output();
  const auto inject_rc = inject.wait(30s);
  ASSERT_TRUE(inject_rc.has_value()) << inject.output();
  EXPECT_NE(inject.output().find("no server"), std::string::npos) << inject.output();
  EXPECT_EQ(server.stop(), 0) << server.output();

  EXPECT_EQ(overheard, 0u) << "an unauthenticated participant received samples";

  // The session itself went on as usual: authenticated, recorded in full, watched.
  const std::string out = client.output();
  const uint64_t session = matchNumber(out, R"(session (\d+) open)");
  const uint64_t sent = matchNumber(out, R"((\d+) samples sent)");
  ASSERT_GT(session, 0u) << out;
  ASSERT_GT(sent, 4000u) << out;
  EXPECT_NE(watcher.output().find("session=" + std::to_string(session)), std::string::npos)
      << watcher.output();
  server::store::SqliteStore store(db, server::store::SqliteStore::Mode::kReadOnly);
  const auto info = store.session(session);
  ASSERT_TRUE(info.has_value());
  EXPECT_EQ(info->state, "closed");
  EXPECT_EQ(info->samples, sent);
}

/// Every packet on the loopback interface while it runs (AF_PACKET, needs CAP_NET_RAW),
/// searched for a string.
class WireSniffer {
 public:
  explicit WireSniffer(std::string needle) : needle_(std::move(needle)) {
    fd_ = ::socket(AF_PACKET, SOCK_RAW, htons(ETH_P_ALL));
    if (fd_ < 0) return;
    sockaddr_ll a{};
    a.sll_family = AF_PACKET;
    a.sll_protocol = htons(ETH_P_ALL);
    a.sll_ifindex = static_cast<int>(if_nametoindex("lo"));
    if (::bind(fd_, reinterpret_cast<sockaddr*>(&a), sizeof a) != 0) {
      ::close(fd_);
      fd_ = -1;
      return;
    }
    timeval tv{0, 100'000};
    ::setsockopt(fd_, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof tv);
    thread_ = std::thread([this] {
      std::vector<char> buf(65536);
      while (!stop_.load()) {
        const ssize_t n = ::recv(fd_, buf.data(), buf.size(), 0);
        if (n <= 0) continue;
        ++packets_;
        if (std::string_view(buf.data(), static_cast<std::size_t>(n)).find(needle_) !=
            std::string_view::npos)
          ++hits_;
      }
    });
  }
  ~WireSniffer() { stopNow(); }
  bool ok() const { return fd_ >= 0; }
  void stopNow() {
    stop_.store(true);
    if (thread_.joinable()) thread_.join();
    if (fd_ >= 0) ::close(fd_);
    fd_ = -1;
  }
  uint64_t packets() const { return packets_.load(); }
  uint64_t hits() const { return hits_.load(); }

 private:
  std::string needle_;
  int fd_ = -1;
  std::atomic<bool> stop_{false};
  std::atomic<uint64_t> packets_{0}, hits_{0};
  std::thread thread_;
};

TEST_F(SecurityTest, TheWireCarriesNoPlaintext) {
  // A session whose user name is on the wire in SessionCommand and SessionStatus: under
  // security no packet holds it; without, some do (the sniffer sees what it should).
  for (const bool secure : {true, false}) {
    const std::string user = "wire" + std::to_string(getpid()) + (secure ? "s" : "i");
    WireSniffer sniff(user);
    if (!sniff.ok()) GTEST_SKIP() << "no raw socket on lo (needs CAP_NET_RAW)";
    const std::string saved = pki_;
    if (!secure) pki_.clear();
    const std::string tag = secure ? "secure" : "insecure";
    Process server(cmd(TELEHAND_SERVER_BIN, {"--db", path(tag + ".db"), "--seconds", "60"}),
                   path(tag + "-server.log"));
    Process client(cmd(TELEHAND_CLIENT_BIN, {"--seconds", "3", "-q", "--user", user}),
                   path(tag + "-client.log"));
    const auto rc = client.wait(30s);
    pki_ = saved;
    EXPECT_EQ(server.stop(), 0) << server.output();
    sniff.stopNow();
    ASSERT_EQ(rc, std::optional<int>(0)) << client.output();
    EXPECT_GT(sniff.packets(), 1000u) << tag;
    if (secure) {
      EXPECT_EQ(sniff.hits(), 0u) << "the user name crossed loopback in clear";
    } else {
      EXPECT_GT(sniff.hits(), 0u) << "the sniffer did not see the unsecured session";
    }
  }
}

TEST_F(SecurityTest, EachRoleWritesOnlyItsTopics) {
  // Local access control: creating a writer the identity's permissions do not grant fails.
  // A domain id of its own: this process holds domain 0 unsecured in the other test.
  auto as = [&](const std::string& identity, uint32_t domain) {
    dds::Options o;
    o.domain = domain;
    o.config = TELEHAND_LOOPBACK_XML;
    o.partition = partition_;
    o.pki = pki_;
    o.identity = identity;
    return o;
  };
  {
    dds::Participant supervisor(as("supervisor", 41));
    dds::Topics t(supervisor);
    EXPECT_THROW(
        dds::Writer<telehand_msg_JointModel>(supervisor, t.joint_model, dds::qos::jointModel()),
        DdsError);
    EXPECT_THROW(
        dds::Writer<telehand_msg_DeviceState>(supervisor, t.device_state, dds::qos::deviceState()),
        DdsError);
    EXPECT_THROW(dds::Writer<telehand_msg_SessionStatus>(supervisor, t.session_status,
                                                         dds::qos::sessionStatus()),
                 DdsError);
    // What a supervisor may do: read everything, send commands (marks).
    EXPECT_NO_THROW(
        dds::Reader<telehand_msg_HandState>(supervisor, t.hand_state, dds::qos::handState()));
    EXPECT_NO_THROW(dds::Writer<telehand_msg_SessionCommand>(supervisor, t.session_command,
                                                             dds::qos::sessionCommand()));
  }
  {
    dds::Participant device(as("device", 41));
    dds::Topics t(device);
    EXPECT_NO_THROW(
        dds::Writer<telehand_msg_DeviceState>(device, t.device_state, dds::qos::deviceState()));
    EXPECT_THROW(
        dds::Writer<telehand_msg_JointModel>(device, t.joint_model, dds::qos::jointModel()),
        DdsError);
    EXPECT_THROW(dds::Writer<telehand_msg_HandState>(device, t.hand_state, dds::qos::handState()),
                 DdsError);
  }
  {
    dds::Participant server(as("server", 41));
    dds::Topics t(server);
    EXPECT_NO_THROW(
        dds::Writer<telehand_msg_JointModel>(server, t.joint_model, dds::qos::jointModel()));
    EXPECT_THROW(
        dds::Writer<telehand_msg_DeviceState>(server, t.device_state, dds::qos::deviceState()),
        DdsError);
  }
}

TEST_F(SecurityTest, ProgramsRefuseToRunUnsecuredUnlessTold) {
  ::unsetenv("TELEHAND_PKI");  // what the children inherit
  // No --pki, no TELEHAND_PKI, no --insecure: a clear refusal, exit 2.
  Process server(
      {TELEHAND_SERVER_BIN, "--db", path("x.db"), "--seconds", "1", "--partition", partition_},
      path("server.log"));
  EXPECT_EQ(server.wait(20s), std::optional<int>(2)) << server.output();
  EXPECT_NE(server.output().find("--insecure"), std::string::npos) << server.output();
  // An identity the PKI does not hold is named.
  Process client(cmd(TELEHAND_CLIENT_BIN, {"--seconds", "1", "--identity", "nobody"}),
                 path("client.log"));
  EXPECT_EQ(client.wait(20s), std::optional<int>(2)) << client.output();
  EXPECT_NE(client.output().find("nobody"), std::string::npos) << client.output();
}

}  // namespace
}  // namespace telehand::test
