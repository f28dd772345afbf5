// DDS Security end to end (docs/security.md): the server, the device client and the
// supervisor's watcher run under a PKI this test makes; an unauthenticated participant on
// the same domain and partition receives nothing, a participant with a certificate from
// another CA finds no session, and a supervisor's identity cannot write a JointModel.
#include <arpa/inet.h>
#include <gtest/gtest.h>
#include <linux/if_ether.h>
#include <net/if.h>
#include <netinet/in.h>
#include <netpacket/packet.h>
#include <stdlib.h>
#include <sys/socket.h>
#include <unistd.h>

#include <array>
#include <atomic>
#include <chrono>
#include <cstring>
#include <filesystem>
#include <iostream>
#include <memory>
#include <optional>
#include <regex>
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

/// The environment of this process with TELEHAND_DDS_CRYPTO set to `which`, and without the
/// PKI variables this process's own secured participants left (the children take --pki).
std::vector<std::string> cryptoEnv(const std::string& which) {
  std::vector<std::string> env;
  for (char** e = environ; *e != nullptr; ++e) {
    const std::string_view v(*e);
    if (!v.starts_with("TELEHAND_DDS_CRYPTO") && !v.starts_with("TELEHAND_PKI=") &&
        !v.starts_with("TELEHAND_IDENTITY=")) {
      env.emplace_back(*e);
    }
  }
  env.push_back("TELEHAND_DDS_CRYPTO=" + which);
  return env;
}

/// The four counts of a "telehand's cryptography: ..." line in `out` (nothing: no such line).
std::optional<std::array<uint64_t, 4>> cryptoLine(const std::string& out) {
  std::smatch m;
  static const std::regex re(
      R"(telehand's cryptography: (\d+) data submessages encrypted, (\d+) decrypted, (\d+) )"
      R"(refused, (\d+) calls)");
  if (!std::regex_search(out, m, re)) return std::nullopt;
  return std::array<uint64_t, 4>{std::stoull(m[1]), std::stoull(m[2]), std::stoull(m[3]),
                                 std::stoull(m[4])};
}

TEST_F(SecurityTest, TelehandAndCycloneCryptographyReadEachOther) {
  // telehand's cryptography plugin writes and reads the wire format Cyclone's does, with
  // Cyclone's keys: a server with one and a client with the other hold a complete session,
  // both ways round; the side with telehand's did the data submessages' AES-GCM itself.
  for (const bool server_cyclone : {true, false}) {
    const std::string tag = server_cyclone ? "cyclone-server" : "cyclone-client";
    const std::string db = path(tag + ".db");
    Process server(cmd(TELEHAND_SERVER_BIN, {"--db", db, "--seconds", "60", "--log-level", "info"}),
                   path(tag + "-server.log"), 0,
                   cryptoEnv(server_cyclone ? "cyclone" : "telehand"));
    Process client(cmd(TELEHAND_CLIENT_BIN, {"--seconds", "3"}), path(tag + "-client.log"), 0,
                   cryptoEnv(server_cyclone ? "telehand" : "cyclone"));
    const auto rc = client.wait(30s);
    EXPECT_EQ(server.stop(), 0) << server.output();
    ASSERT_EQ(rc, std::optional<int>(0)) << client.output();  // 0: recorded = sent, 0 missing
    const std::string out = client.output();
    const uint64_t session = matchNumber(out, R"(session (\d+) open)");
    const uint64_t sent = matchNumber(out, R"((\d+) samples sent)");
    ASSERT_GT(sent, 2500u) << out;
    server::store::SqliteStore store(db, server::store::SqliteStore::Mode::kReadOnly);
    const auto info = store.session(session);
    ASSERT_TRUE(info.has_value());
    EXPECT_EQ(info->state, "closed");
    EXPECT_EQ(info->samples, sent);
    const auto mine = cryptoLine(server_cyclone ? out : server.output());
    const auto theirs = cryptoLine(server_cyclone ? server.output() : out);
    ASSERT_TRUE(mine.has_value()) << (server_cyclone ? out : server.output());
    EXPECT_FALSE(theirs.has_value()) << "Cyclone's plugin was asked for, telehand's ran";
    if (server_cyclone) {
      EXPECT_GE((*mine)[0], sent) << out;  // every DeviceState sample it sent, encrypted by it
    } else {
      EXPECT_GE((*mine)[1], sent) << server.output();  // ... decrypted by it
    }
    EXPECT_EQ((*mine)[2], 0u) << "nothing was tampered with";
  }
}

/// Sends, for each secured submessage that crosses the loopback interface from `after` on, a
/// copy with one byte of its encrypted body changed to where the original went, at most
/// `limit` copies (AF_PACKET and a UDP socket; needs CAP_NET_RAW). From `after`: once the
/// session is running, every reader has its writers' keys, so each copy reaching one is
/// decrypted (and refused) by telehand's plugin rather than passed to Cyclone's before the
/// keys came.
class Tamperer {
 public:
  Tamperer(uint64_t limit, std::chrono::milliseconds after)
      : limit_(limit), start_(std::chrono::steady_clock::now() + after) {
    rx_ = ::socket(AF_PACKET, SOCK_RAW, htons(ETH_P_ALL));
    tx_ = ::socket(AF_INET, SOCK_DGRAM, 0);
    if (rx_ < 0 || tx_ < 0) return;
    sockaddr_ll a{};
    a.sll_family = AF_PACKET;
    a.sll_protocol = htons(ETH_P_ALL);
    a.sll_ifindex = static_cast<int>(if_nametoindex("lo"));
    sockaddr_in me{};
    me.sin_family = AF_INET;
    me.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    socklen_t len = sizeof me;
    if (::bind(rx_, reinterpret_cast<sockaddr*>(&a), sizeof a) != 0 ||
        ::bind(tx_, reinterpret_cast<sockaddr*>(&me), sizeof me) != 0 ||
        ::getsockname(tx_, reinterpret_cast<sockaddr*>(&me), &len) != 0) {
      close();
      return;
    }
    own_port_ = ntohs(me.sin_port);
    timeval tv{0, 100'000};
    ::setsockopt(rx_, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof tv);
    thread_ = std::thread([this] { run(); });
  }
  ~Tamperer() { stopNow(); }
  bool ok() const { return rx_ >= 0 && tx_ >= 0; }
  void stopNow() {
    stop_.store(true);
    if (thread_.joinable()) thread_.join();
    close();
  }
  uint64_t sent() const { return sent_.load(); }

 private:
  void close() {
    if (rx_ >= 0) ::close(rx_);
    if (tx_ >= 0) ::close(tx_);
    rx_ = tx_ = -1;
  }
  void run() {
    std::vector<uint8_t> buf(65536);
    while (!stop_.load()) {
      sockaddr_ll from{};
      socklen_t fl = sizeof from;
      const ssize_t n =
          ::recvfrom(rx_, buf.data(), buf.size(), 0, reinterpret_cast<sockaddr*>(&from), &fl);
      if (n <= 0 || from.sll_pkttype == PACKET_OUTGOING || sent_.load() >= limit_ ||
          std::chrono::steady_clock::now() < start_) {
        continue;
      }
      tamper(buf.data(), static_cast<size_t>(n));
    }
  }
  void tamper(uint8_t* f, size_t n) {
    // Ethernet (14), IPv4, UDP (8), RTPS header (20), then the submessages.
    if (n < 14 + 20 + 8 + 20 || f[12] != 0x08 || f[13] != 0x00) return;
    const uint8_t* ip = f + 14;
    const size_t ihl = size_t{ip[0] & 0x0fu} * 4;
    if ((ip[0] >> 4) != 4 || ip[9] != 17 || n < 14 + ihl + 8 + 20) return;
    uint8_t* udp = f + 14 + ihl;
    const uint16_t src_port = static_cast<uint16_t>((udp[0] << 8) | udp[1]);
    if (src_port == own_port_) return;
    uint8_t* rtps = udp + 8;
    const size_t rtps_len = n - 14 - ihl - 8;
    if (std::memcmp(rtps, "RTPS", 4) != 0) return;
    size_t at = 20;
    while (at + 4 <= rtps_len) {
      const uint8_t id = rtps[at];
      const bool le = rtps[at + 1] & 1;
      const size_t len = le ? size_t{rtps[at + 2]} | size_t{rtps[at + 3]} << 8
                            : size_t{rtps[at + 2]} << 8 | size_t{rtps[at + 3]};
      const size_t next = at + 4 + len;
      if (len == 0 || next > rtps_len) return;
      if (id == 0x31 && next + 4 + 8 <= rtps_len && rtps[next] == 0x30) {  // SEC_PREFIX, SEC_BODY
        const bool ble = rtps[next + 1] & 1;
        const size_t blen = ble ? size_t{rtps[next + 2]} | size_t{rtps[next + 3]} << 8
                                : size_t{rtps[next + 2]} << 8 | size_t{rtps[next + 3]};
        if (blen < 8 || next + 4 + blen > rtps_len) return;
        rtps[next + 4 + 4 + (blen - 4) / 2] ^= 0x5a;  // a byte inside the ciphertext
        sockaddr_in to{};
        to.sin_family = AF_INET;
        std::memcpy(&to.sin_addr.s_addr, ip + 16, 4);
        std::memcpy(&to.sin_port, udp + 2, 2);
        if (::sendto(tx_, rtps, rtps_len, 0, reinterpret_cast<sockaddr*>(&to), sizeof to) ==
            static_cast<ssize_t>(rtps_len)) {
          sent_.fetch_add(1);
        }
        return;
      }
      at = next;
    }
  }

  uint64_t limit_;
  std::chrono::steady_clock::time_point start_;
  int rx_ = -1;
  int tx_ = -1;
  uint16_t own_port_ = 0;
  std::atomic<bool> stop_{false};
  std::atomic<uint64_t> sent_{0};
  std::thread thread_;
};

TEST_F(SecurityTest, ATamperedSubmessageIsRefused) {
  // Copies of the session's secured submessages with one encrypted byte changed, sent to where
  // the originals went: telehand's cryptography refuses each (its GCM tag does not hold) and
  // so does Cyclone's after it; the record is the client's samples, complete and unchanged.
  Tamperer tamper(400, 2000ms);
  if (!tamper.ok()) GTEST_SKIP() << "no raw socket on lo (needs CAP_NET_RAW)";
  const std::string db = path("tamper.db");
  Process server(cmd(TELEHAND_SERVER_BIN, {"--db", db, "--seconds", "60", "--log-level", "info"}),
                 path("server.log"), 0, cryptoEnv("telehand"));
  Process client(cmd(TELEHAND_CLIENT_BIN, {"--seconds", "5"}), path("client.log"), 0,
                 cryptoEnv("telehand"));
  const auto rc = client.wait(30s);
  tamper.stopNow();
  EXPECT_EQ(server.stop(), 0) << server.output();
  ASSERT_EQ(rc, std::optional<int>(0)) << client.output();  // recorded = sent, 0 missing
  EXPECT_NE(server.output().find(" 0 invalid"), std::string::npos) << server.output();
  const auto c = cryptoLine(client.output());
  const auto s = cryptoLine(server.output());
  ASSERT_TRUE(c.has_value()) << client.output();
  ASSERT_TRUE(s.has_value()) << server.output();
  const uint64_t refused = (*c)[2] + (*s)[2];
  std::cout << "tampered copies sent " << tamper.sent() << ", refused " << refused << "\n";
  EXPECT_GE(tamper.sent(), 100u);
  // The copies that reached a reader were refused by telehand's plugin (the few others were
  // data readers' submessages, which Cyclone's refuses), and nothing else was.
  EXPECT_GE(refused, tamper.sent() * 3 / 4) << "sent " << tamper.sent();
  EXPECT_LE(refused, tamper.sent());
}

}  // namespace
}  // namespace telehand::test
