// telehand-test-inject: a misbehaving client for integration tests. Sends what a correct
// client never would (commands for sessions nobody opened, samples with NaN) and reports
// what the server answered.
#include <cmath>
#include <iostream>
#include <thread>

#include "telehand/app/cli.h"
#include "telehand/app/dds_cli.h"
#include "telehand/core/clock.h"
#include "telehand/protocol/dds.h"
#include "telehand/protocol/wire.h"

namespace {

using namespace telehand;
using namespace std::chrono_literals;

struct Peer {
  explicit Peer(const dds::Options& o)
      : participant(o),
        topics(participant),
        device(participant, topics.device_state, dds::qos::deviceState()),
        chunk(participant, topics.record_chunk, dds::qos::recordChunk()),
        command(participant, topics.session_command, dds::qos::sessionCommand()),
        status(participant, topics.session_status, dds::qos::sessionStatus()),
        events(participant, topics.session_event, dds::qos::sessionEvent()) {}

  bool awaitServer(std::chrono::seconds timeout) {
    const auto deadline = std::chrono::steady_clock::now() + timeout;
    while (command.matchedReaders() == 0 || chunk.matchedReaders() == 0 ||
           device.matchedReaders() == 0) {
      if (std::chrono::steady_clock::now() > deadline) return false;
      std::this_thread::sleep_for(10ms);
    }
    return true;
  }

  void send(telehand_msg_CommandKind kind, uint64_t session, uint64_t samples_sent = 0) {
    telehand_msg_SessionCommand c{};
    c.client_id = client_id;
    c.request_seq = ++request_seq;
    c.source_time_ns = wallNs();
    c.kind = kind;
    c.session_id = session;
    c.samples_sent = samples_sent;
    c.last_seq = samples_sent ? samples_sent - 1 : 0;
    copyString(c.case_name, "healthy");
    copyString(c.user, "inject");
    copyString(c.text, "");
    command.write(c);
  }

  /// First error event addressed to this client or session that contains `needle`.
  std::optional<std::string> awaitError(const std::string& needle, uint64_t session,
                                        std::chrono::seconds timeout) {
    const auto deadline = std::chrono::steady_clock::now() + timeout;
    std::optional<std::string> found;
    while (!found && std::chrono::steady_clock::now() < deadline) {
      events.take([&](const telehand_msg_SessionEvent& e, const dds_sample_info_t&) {
        const std::string text = e.text;
        const bool mine =
            e.client_id == client_id || (session && e.session_id == session) || e.session_id == 0;
        if (!found && mine && e.kind == telehand_msg_EVENT_ERROR &&
            text.find(needle) != std::string::npos) {
          found = text;
        }
      });
      std::this_thread::sleep_for(10ms);
    }
    return found;
  }

  dds::Participant participant;
  dds::Topics topics;
  dds::Writer<telehand_msg_DeviceState> device;
  dds::Writer<telehand_msg_RecordChunk> chunk;
  dds::Writer<telehand_msg_SessionCommand> command;
  dds::Reader<telehand_msg_SessionStatus> status;
  dds::Reader<telehand_msg_SessionEvent> events;
  uint64_t client_id = 0x1badc0de;
  uint32_t request_seq = 0;
};

telehand_msg_DeviceState plausibleSample(uint64_t session, uint64_t seq) {
  telehand_msg_DeviceState s{};
  s.session_id = session;
  s.seq = seq;
  s.source_time_ns = wallNs();
  s.model_version = 1;
  for (int k = 0; k < 2; ++k) {
    s.fingers[k].position_m[0] = 0.01;
    s.fingers[k].position_m[2] = k == 0 ? 0.008 : -0.008;
    s.fingers[k].orientation_q[0] = 1.0;
  }
  return s;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"telehand-test-inject: send bad input to a telehand server and report its answer"};
  dds::Options o;
  std::string what;
  uint64_t session = 0;
  uint64_t count = 200;
  app.add_option("what", what, "close-unknown | unknown-state | nan")
      ->required()
      ->check(CLI::IsMember({"close-unknown", "unknown-state", "nan"}));
  app.add_option("--session", session, "session id for close-unknown / unknown-state");
  app.add_option("--count", count, "samples to send for nan (one of them has a NaN)");
  bool insecure = false;
  app::addDdsOptions(app, o, insecure, "device");
  TELEHAND_CLI_PARSE(app, argc, argv)

  try {
    app::resolveDdsSecurity(o, insecure, "device", "telehand-test-inject");
    Peer peer(o);
    if (!peer.awaitServer(10s)) {
      std::cerr << "inject: no server\n";
      return 1;
    }
    if (what == "close-unknown") {
      peer.send(telehand_msg_CMD_CLOSE, session, 10);
      auto err = peer.awaitError("unknown session " + std::to_string(session), 0, 10s);
      std::cout << "error: " << err.value_or("<none>") << "\n";
      return err ? 0 : 1;
    }
    if (what == "unknown-state") {
      for (int i = 0; i < 50; ++i) {
        peer.device.write(plausibleSample(session, static_cast<uint64_t>(i)));
        std::this_thread::sleep_for(2ms);
      }
      auto err = peer.awaitError("unknown session " + std::to_string(session), 0, 10s);
      std::cout << "error: " << err.value_or("<none>") << "\n";
      return err ? 0 : 1;
    }
    // nan: a session of our own whose middle sample has a NaN position.
    peer.send(telehand_msg_CMD_OPEN, 0);
    uint64_t id = 0;
    const auto deadline = std::chrono::steady_clock::now() + 10s;
    while (id == 0 && std::chrono::steady_clock::now() < deadline) {
      peer.status.take([&](const telehand_msg_SessionStatus& st, const dds_sample_info_t&) {
        if (st.client_id == peer.client_id) id = st.session_id;
      });
      std::this_thread::sleep_for(10ms);
    }
    if (id == 0) {
      std::cerr << "inject: the server opened no session\n";
      return 1;
    }
    std::vector<telehand_msg_DeviceState> samples;
    for (uint64_t i = 0; i < count; ++i) {
      auto s = plausibleSample(id, i);
      if (i == count / 2) s.fingers[1].position_m[0] = std::nan("");
      peer.device.write(s);
      samples.push_back(s);
      std::this_thread::sleep_for(1ms);
    }
    for (std::size_t first = 0; first < samples.size(); first += 100) {  // IDL bound: 256
      telehand_msg_RecordChunk c{};
      c.session_id = id;
      c.chunk_seq = first / 100;
      c.samples._buffer = samples.data() + first;
      c.samples._length = c.samples._maximum =
          static_cast<uint32_t>(std::min<std::size_t>(100, samples.size() - first));
      c.samples._release = false;
      dds::check(peer.chunk.write(c), "write RecordChunk");
    }
    auto err = peer.awaitError("non-finite", id, 10s);
    peer.send(telehand_msg_CMD_CLOSE, id, count);
    uint64_t recorded = 0, missing = 0;
    bool closed = false;
    const auto close_deadline = std::chrono::steady_clock::now() + 15s;
    while (!closed && std::chrono::steady_clock::now() < close_deadline) {
      peer.status.take([&](const telehand_msg_SessionStatus& st, const dds_sample_info_t&) {
        if (st.session_id == id && st.state == telehand_msg_SESSION_CLOSED) {
          closed = true;
          recorded = st.samples_recorded;
          missing = st.samples_missing;
        }
      });
      std::this_thread::sleep_for(10ms);
    }
    std::cout << "session=" << id << " closed=" << closed << " recorded=" << recorded
              << " missing=" << missing << " error: " << err.value_or("<none>") << "\n";
    return err && closed ? 0 : 1;
  } catch (const telehand::Error& e) {
    std::cerr << "inject: " << e.what() << "\n";
    return 2;
  }
}
