// telehand-test-inject: a misbehaving client for integration tests. Sends what a correct
// client never would (commands for sessions nobody opened, samples with NaN) and reports
// what the server answered. The attack modes act on someone else's session from a
// participant of their own: a RecordChunk just ahead of the owner's sequence numbers, a
// CLOSE, a SessionFile, a forged SessionStatus or JointModel, a flood of OPENs.
#include <cmath>
#include <iostream>
#include <memory>
#include <optional>
#include <set>
#include <string>
#include <thread>
#include <vector>

#include "telehand/app/cli.h"
#include "telehand/app/dds_cli.h"
#include "telehand/core/clock.h"
#include "telehand/core/error.h"
#include "telehand/protocol/dds.h"
#include "telehand/protocol/dds_capture.h"
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
        // Deeper than the topic's 1 per session: other writers (forgeries of another
        // inject) must not push the server's status out before it is read.
        status(participant, topics.session_status, dds::qos::sessionStatus().keepLast(256)),
        events(participant, topics.session_event, dds::qos::sessionEvent()),
        live(participant, topics.device_state, dds::qos::deviceState()),
        models(participant, topics.joint_model, dds::qos::jointModel()) {}

  bool awaitServer(std::chrono::seconds timeout) {
    const auto deadline = std::chrono::steady_clock::now() + timeout;
    // As ClientLink::open: the server's status writer as well, or its answers to the first
    // OPENs can come before this reader is matched (a server that has just made its
    // participant again is still discovering the flood's participants).
    while (command.matchedReaders() == 0 || chunk.matchedReaders() == 0 ||
           device.matchedReaders() == 0 || status.matchedWriters() == 0) {
      if (std::chrono::steady_clock::now() > deadline) return false;
      std::this_thread::sleep_for(10ms);
    }
    return true;
  }

  void send(telehand_msg_CommandKind kind, uint64_t session, uint64_t samples_sent = 0) {
    last = sessionCommand(kind, client_id, ++request_seq, session);
    last.samples_sent = samples_sent;
    last.last_seq = samples_sent ? samples_sent - 1 : 0;
    copyString(last.case_name, "healthy");
    copyString(last.user, "inject");
    copyString(last.text, "");
    command.write(last);
  }

  /// The last command again, as it was (the same request_seq).
  void repeat() { command.write(last); }

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
  dds::Reader<telehand_msg_DeviceState> live;
  dds::Reader<telehand_msg_JointModel> models;
  uint64_t client_id = 0x1badc0de;
  uint32_t request_seq = 0;
  telehand_msg_SessionCommand last{};
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

/// What the attack modes write into someone else's session, so that a record can be
/// searched for it: a JointModel version no server reaches in a test, a marker position.
constexpr uint32_t kForgedVersion = 4242;
constexpr double kMarkerM = 0.0424242;

/// The session to attack: `session`, or (0) the first active one another client opened.
/// Returns its id and its client's id, or {0, 0} when none showed up in time.
std::pair<uint64_t, uint64_t> findVictim(Peer& peer, uint64_t session,
                                         std::chrono::seconds timeout) {
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  std::pair<uint64_t, uint64_t> found{0, 0};
  while (found.first == 0 && std::chrono::steady_clock::now() < deadline) {
    peer.status.take([&](const telehand_msg_SessionStatus& st, const dds_sample_info_t&) {
      const bool wanted =
          session == 0 ? st.state == telehand_msg_SESSION_ACTIVE : st.session_id == session;
      if (found.first == 0 && wanted && st.client_id != peer.client_id) {
        found = {st.session_id, st.client_id};
      }
    });
    std::this_thread::sleep_for(10ms);
  }
  return found;
}

/// The newest sequence number of `session`'s live stream (0: none seen in time).
uint64_t newestSeq(Peer& peer, uint64_t session, std::chrono::seconds timeout) {
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  uint64_t high = 0;
  int rounds_after_first = 0;
  while (std::chrono::steady_clock::now() < deadline && rounds_after_first < 20) {
    peer.live.take(
        [&](const telehand_msg_DeviceState& d, const dds_sample_info_t&) {
          if (d.session_id == session) high = std::max(high, d.seq);
        },
        4096);
    if (high > 0) ++rounds_after_first;
    std::this_thread::sleep_for(10ms);
  }
  return high;
}

/// Every "security: refused" event about `session` within `wait`, printed.
int printRefusals(Peer& peer, uint64_t session, std::chrono::seconds wait) {
  const auto deadline = std::chrono::steady_clock::now() + wait;
  int seen = 0;
  while (std::chrono::steady_clock::now() < deadline) {
    peer.events.take([&](const telehand_msg_SessionEvent& e, const dds_sample_info_t&) {
      const std::string text = e.text;
      if ((e.session_id == session || e.session_id == 0) &&
          text.find("security: refused") != std::string::npos) {
        std::cout << "refused: " << text << "\n";
        ++seen;
      }
    });
    std::this_thread::sleep_for(10ms);
  }
  std::cout << "refusal events: " << seen << "\n" << std::flush;
  return seen;
}

/// `n` samples of `session` from `first` on, marked, in RecordChunks of 250 (the IDL's 256).
void sendChunks(Peer& peer, uint64_t session, uint64_t first, uint64_t n) {
  std::vector<telehand_msg_DeviceState> samples;
  for (uint64_t q = first; q < first + n; ++q) {
    auto s = plausibleSample(session, q);
    s.model_version = kForgedVersion;
    s.fingers[0].position_m[0] = kMarkerM;
    samples.push_back(s);
  }
  for (std::size_t at = 0; at < samples.size(); at += 250) {
    telehand_msg_RecordChunk c{};
    c.session_id = session;
    c.chunk_seq = 1'000'000 + at / 250;
    c.samples._buffer = samples.data() + at;
    c.samples._length = c.samples._maximum =
        static_cast<uint32_t>(std::min<std::size_t>(250, samples.size() - at));
    c.samples._release = false;
    dds::check(peer.chunk.write(c), "write RecordChunk");
  }
}

/// Tries to create a writer the identity's permissions may not grant: nullptr (and says so)
/// when access control refuses it.
template <typename T>
std::unique_ptr<dds::Writer<T>> tryWriter(Peer& peer, const dds::Topic<T>& topic,
                                          const dds::Qos& qos, const char* name) {
  try {
    return std::make_unique<dds::Writer<T>>(peer.participant, topic, qos);
  } catch (const telehand::DdsError& e) {
    std::cout << "writer refused: " << name << ": " << e.what() << "\n";
    return nullptr;
  }
}

/// OPENs from `participants` participants of this process, `count` in all; holds the
/// sessions it got for `hold`, then closes them. Prints what it opened and closed.
int openFlood(const dds::Options& o, uint64_t count, int participants, std::chrono::seconds hold) {
  std::vector<std::unique_ptr<Peer>> peers;
  for (int i = 0; i < participants; ++i) {
    peers.push_back(std::make_unique<Peer>(o));
    peers.back()->client_id = 0xf100d000 + static_cast<uint64_t>(i);
  }
  for (auto& p : peers) {
    if (!p->awaitServer(10s)) {
      std::cerr << "inject: no server\n";
      return 1;
    }
  }
  std::vector<std::set<uint64_t>> opened(peers.size());
  // Each participant's first OPEN is asked again every second until answered, as a client
  // asks (ClientLink::open): that this writer has matched the server's reader does not mean
  // the server's reader has matched this writer yet, and what it sends before then is lost.
  // The rest of the flood is sent once: every OPEN of it reaches a server that knows its
  // sender.
  uint64_t first_opens = 0;
  for (std::size_t i = 0; i < peers.size() && first_opens < count; ++i, ++first_opens) {
    Peer& p = *peers[i];
    p.send(telehand_msg_CMD_OPEN, 0);
    const auto deadline = std::chrono::steady_clock::now() + 10s;
    auto next_ask = std::chrono::steady_clock::now() + 1s;
    while (opened[i].empty()) {
      if (std::chrono::steady_clock::now() > deadline) {
        std::cerr << "inject: participant " << i << "'s first OPEN was not answered in 10 s\n";
        return 1;
      }
      if (std::chrono::steady_clock::now() >= next_ask) {
        next_ask += 1s;
        p.repeat();
      }
      p.status.take([&](const telehand_msg_SessionStatus& st, const dds_sample_info_t&) {
        if (st.client_id == p.client_id && st.request_seq == p.request_seq &&
            st.state == telehand_msg_SESSION_ACTIVE)
          opened[i].insert(st.session_id);
      });
      std::this_thread::sleep_for(5ms);
    }
  }
  const auto collect = [&] {
    for (std::size_t i = 0; i < peers.size(); ++i) {
      peers[i]->status.take(
          [&](const telehand_msg_SessionStatus& st, const dds_sample_info_t&) {
            if (st.client_id == peers[i]->client_id && st.state == telehand_msg_SESSION_ACTIVE)
              opened[i].insert(st.session_id);
          },
          4096);
    }
  };
  const auto t0 = std::chrono::steady_clock::now();
  for (uint64_t k = first_opens; k < count; ++k) {
    peers[k % peers.size()]->send(telehand_msg_CMD_OPEN, 0);
    if (k % 256 == 255) collect();
  }
  const double send_s =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  std::size_t total = 0;
  for (int settle = 0; settle < 300; ++settle) {  // until the count holds for 1 s
    collect();
    std::size_t now_total = 0;
    for (const auto& s : opened) now_total += s.size();
    if (now_total == total && settle >= 100) break;
    if (now_total != total) settle = 0;
    total = now_total;
    std::this_thread::sleep_for(10ms);
  }
  std::cout << "sent=" << count << " in " << send_s << " s, opened=" << total << "\n" << std::flush;
  std::this_thread::sleep_for(hold);
  std::size_t closed = 0;
  std::vector<std::set<uint64_t>> open_left = opened;
  for (std::size_t i = 0; i < peers.size(); ++i) {
    for (uint64_t id : opened[i]) peers[i]->send(telehand_msg_CMD_CLOSE, id, 0);
  }
  const auto deadline = std::chrono::steady_clock::now() + 20s;
  while (closed < total && std::chrono::steady_clock::now() < deadline) {
    for (std::size_t i = 0; i < peers.size(); ++i) {
      peers[i]->status.take(
          [&](const telehand_msg_SessionStatus& st, const dds_sample_info_t&) {
            if (st.state == telehand_msg_SESSION_CLOSED && open_left[i].erase(st.session_id))
              ++closed;
          },
          4096);
    }
    std::this_thread::sleep_for(10ms);
  }
  std::cout << "closed=" << closed << "\n" << std::flush;
  return closed == total ? 0 : 1;
}

/// Sessions opened and closed at once, over and over, from `participants` participants of
/// this process: each keeps at most `per_participant` OPENs unanswered or sessions not yet
/// CLOSED, so that (with the server's limits at least as large) every OPEN is taken, until
/// `count` OPENs were sent. Prints how many sessions opened and closed.
int openChurn(const dds::Options& o, uint64_t count, int participants, int per_participant) {
  std::vector<std::unique_ptr<Peer>> peers;
  for (int i = 0; i < participants; ++i) {
    peers.push_back(std::make_unique<Peer>(o));
    peers.back()->client_id = 0xc4c4d000 + static_cast<uint64_t>(i);
  }
  for (auto& p : peers) {
    if (!p->awaitServer(10s)) {
      std::cerr << "inject: no server\n";
      return 1;
    }
  }
  struct Load {
    int in_flight = 0;  // OPENs sent whose session has not yet CLOSED
    std::set<uint64_t> active;
    std::chrono::steady_clock::time_point progress = std::chrono::steady_clock::now();
  };
  std::vector<Load> load(peers.size());
  uint64_t sent = 0, opened = 0, closed = 0, lost = 0;
  const auto t0 = std::chrono::steady_clock::now();
  auto last_progress = t0;
  while (std::chrono::steady_clock::now() - last_progress < 20s) {
    bool idle = sent >= count;
    for (std::size_t i = 0; i < peers.size(); ++i) {
      Peer& p = *peers[i];
      Load& l = load[i];
      p.status.take(
          [&](const telehand_msg_SessionStatus& st, const dds_sample_info_t&) {
            if (st.client_id != p.client_id) return;
            if (st.state == telehand_msg_SESSION_ACTIVE && l.active.insert(st.session_id).second) {
              ++opened;
              p.send(telehand_msg_CMD_CLOSE, st.session_id, 0);
            } else if (st.state == telehand_msg_SESSION_CLOSED && l.active.erase(st.session_id)) {
              ++closed;
              --l.in_flight;
              l.progress = last_progress = std::chrono::steady_clock::now();
            }
          },
          4096);
      // An OPEN the server did not take (refused, lost): given up after 5 s without progress.
      if (l.in_flight > static_cast<int>(l.active.size()) &&
          std::chrono::steady_clock::now() - l.progress > 5s) {
        lost += static_cast<uint64_t>(l.in_flight) - l.active.size();
        l.in_flight = static_cast<int>(l.active.size());
      }
      while (sent < count && l.in_flight < per_participant) {
        p.send(telehand_msg_CMD_OPEN, 0);
        ++sent;
        ++l.in_flight;
        l.progress = std::chrono::steady_clock::now();
      }
      if (l.in_flight > 0) idle = false;
    }
    if (idle) break;
    std::this_thread::sleep_for(2ms);
  }
  const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  std::cout << "sent=" << sent << " opened=" << opened << " closed=" << closed << " lost=" << lost
            << " in " << s << " s\n"
            << std::flush;
  return closed == opened && sent == count ? 0 : 1;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"telehand-test-inject: send bad input to a telehand server and report its answer"};
  dds::Options o;
  std::string what;
  uint64_t session = 0;
  uint64_t count = 200;
  uint64_t bytes = 20'000'000;
  int participants = 1;
  int wait_s = 5;
  int hold_s = 2;
  int period_ms = 50;
  const std::vector<std::string> modes{
      "close-unknown", "unknown-state", "nan",  "chunk-ahead", "close",
      "forge-status",  "forge-model",   "file", "open-flood",  "open-churn"};
  app.add_option("what", what,
                 "close-unknown | unknown-state | nan; attacks on another session: chunk-ahead "
                 "| close | forge-status | forge-model | file; open-flood, open-churn")
      ->required()
      ->check(CLI::IsMember(modes));
  app.add_option("--session", session,
                 "session id (attacks: 0 = the first active session another client opened)");
  app.add_option("--count", count, "samples to send for nan; OPENs for open-flood and open-churn");
  app.add_option("--bytes", bytes, "size of the SessionFile for file");
  app.add_option("--participants", participants, "participants sending the OPENs of open-flood")
      ->check(CLI::Range(1, 64));
  app.add_option("--wait", wait_s,
                 "attacks: seconds to keep forging and to listen for refusals afterwards");
  app.add_option("--period-ms", period_ms, "forge-status, forge-model: ms between forgeries")
      ->check(CLI::Range(0, 10000));
  app.add_option("--hold", hold_s, "open-flood: seconds to hold the sessions opened");
  int per_participant = 4;
  app.add_option("--per-participant", per_participant,
                 "open-churn: sessions each participant keeps opening or open at once")
      ->check(CLI::Range(1, 64));
  bool insecure = false;
  app::addDdsOptions(app, o, insecure, "device");
  TELEHAND_CLI_PARSE(app, argc, argv)

  try {
    app::resolveDdsSecurity(o, insecure, "device", "telehand-test-inject");
    if (what == "open-flood")
      return openFlood(o, count, participants, std::chrono::seconds(hold_s));
    if (what == "open-churn") return openChurn(o, count, participants, per_participant);
    Peer peer(o);
    if (!peer.awaitServer(10s)) {
      std::cerr << "inject: no server\n";
      return 1;
    }
    const std::set<std::string> attacks{"chunk-ahead", "close", "forge-status", "forge-model",
                                        "file"};
    if (attacks.count(what)) {
      const auto [victim, victim_client] = findVictim(peer, session, 15s);
      if (victim == 0) {
        std::cerr << "inject: no session to attack\n";
        return 1;
      }
      std::cout << "attacking session " << victim << "\n" << std::flush;
      const auto wait = std::chrono::seconds(wait_s);
      if (what == "chunk-ahead") {
        const uint64_t high = newestSeq(peer, victim, 10s);
        if (high == 0) {
          std::cerr << "inject: session " << victim << " sends nothing live\n";
          return 1;
        }
        sendChunks(peer, victim, high + 1, 1000);
        std::cout << "sent seq " << high + 1 << ".." << high + 1000 << "\n" << std::flush;
      } else if (what == "close") {
        peer.send(telehand_msg_CMD_CLOSE, victim, 1);
        std::cout << "sent CLOSE\n" << std::flush;
      } else if (what == "file") {
        dds::CaptureTopics capture(peer.participant);
        dds::Writer<telehand_msg_SessionFile> files(peer.participant, capture.session_file,
                                                    dds::qos::sessionFile());
        const auto until = std::chrono::steady_clock::now() + 5s;
        while (files.matchedReaders() == 0 && std::chrono::steady_clock::now() < until)
          std::this_thread::sleep_for(10ms);
        std::string content(bytes, 'x');
        telehand_msg_SessionFile f{};
        f.session_id = victim;
        f.source_time_ns = wallNs();
        copyString(f.name, "device.toml");
        f.content = content.data();
        dds::check(files.write(f), "write SessionFile");
        std::cout << "sent a SessionFile of " << bytes << " bytes\n" << std::flush;
      } else if (what == "forge-status") {
        auto w =
            tryWriter(peer, peer.topics.session_status, dds::qos::sessionStatus(), "SessionStatus");
        if (!w) return 4;
        telehand_msg_SessionStatus st{};
        st.session_id = victim;
        st.client_id = victim_client;
        st.state = telehand_msg_SESSION_CLOSED;
        st.samples_recorded = 123;
        st.samples_missing = 0;
        copyString(st.case_name, "healthy");
        copyString(st.record, "forged");
        int written = 0;
        for (auto until = std::chrono::steady_clock::now() + wait;
             std::chrono::steady_clock::now() < until; ++written) {
          st.source_time_ns = wallNs();
          dds::check(w->write(st), "write SessionStatus");
          std::this_thread::sleep_for(std::chrono::milliseconds(period_ms));
        }
        std::cout << "forged " << written << " SessionStatus CLOSED\n" << std::flush;
        return 0;
      } else {  // forge-model
        auto w = tryWriter(peer, peer.topics.joint_model, dds::qos::jointModel(), "JointModel");
        if (!w) return 4;
        std::optional<telehand_msg_JointModel> model;
        const auto until = std::chrono::steady_clock::now() + 5s;
        while (!model && std::chrono::steady_clock::now() < until) {
          peer.models.take([&](const telehand_msg_JointModel& m, const dds_sample_info_t&) {
            if (m.session_id == victim) model = m;
          });
          std::this_thread::sleep_for(10ms);
        }
        if (!model) {
          std::cerr << "inject: no JointModel of session " << victim << "\n";
          return 1;
        }
        model->version = kForgedVersion;
        for (auto& axis : model->axes) {
          for (auto& c : axis.coeffs) c *= 100.0;
        }
        int written = 0;
        for (auto stop = std::chrono::steady_clock::now() + wait;
             std::chrono::steady_clock::now() < stop; ++written) {
          model->source_time_ns = wallNs();
          dds::check(w->write(*model), "write JointModel");
          std::this_thread::sleep_for(std::chrono::milliseconds(period_ms));
        }
        std::cout << "forged " << written << " JointModel v" << kForgedVersion << "\n"
                  << std::flush;
        return 0;
      }
      printRefusals(peer, victim, wait);
      return 0;
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
