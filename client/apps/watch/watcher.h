#pragma once
// The readers of the four session topics and what they have told so far.
#include <unistd.h>

#include "model.h"

namespace telehand::client::watch {

class Watcher {
 public:
  explicit Watcher(const dds::Options& options)
      : participant_(options),
        topics_(participant_),
        status_reader_(participant_, topics_.session_status, dds::qos::sessionStatus()),
        model_reader_(participant_, topics_.joint_model, dds::qos::jointModel()),
        hand_reader_(participant_, topics_.hand_state, dds::qos::handStateReader(kHandReaderDepth)),
        event_reader_(participant_, topics_.session_event, dds::qos::sessionEvent()),
        command_writer_(participant_, topics_.session_command, dds::qos::sessionCommand()),
        waitset_(participant_) {
    waitset_.attach(status_reader_.handle(), 1);
    waitset_.attach(model_reader_.handle(), 2);
    waitset_.attach(hand_reader_.handle(), 3);
    waitset_.attach(event_reader_.handle(), 4);
  }

  /// Sleeps until a reader has data or `timeout` passes.
  void wait(int64_t timeout_ns) {
    if (timeout_ns > 0) waitset_.wait(std::chrono::nanoseconds(timeout_ns));
  }

  /// Takes everything that arrived. `now_ns` is the steady clock.
  void poll(int64_t now_ns) {
    const int64_t wall_ns = wallNs();
    status_reader_.take([&](const telehand_msg_SessionStatus& s,
                            const dds_sample_info_t&) { sessions_[s.session_id].status = s; },
                        kTakeAll);
    model_reader_.take(
        [&](const telehand_msg_JointModel& m, const dds_sample_info_t&) {
          SessionView& v = sessions_[m.session_id];
          ++v.models;
          if (!v.model || m.version >= v.model->version) v.model = m;
        },
        kTakeAll);
    hand_reader_.take(
        [&](const telehand_msg_HandState& h, const dds_sample_info_t&) {
          onHand(sessions_[h.session_id], h, now_ns, wall_ns);
        },
        kTakeAll);
    event_reader_.take(
        [&](const telehand_msg_SessionEvent& e, const dds_sample_info_t&) { onEvent(e); },
        kTakeAll);
  }

  const SessionView* find(uint64_t id) const {
    const auto it = sessions_.find(id);
    return it == sessions_.end() || !it->second.status ? nullptr : &it->second;
  }

  /// The most recently started ACTIVE session; 0 when there is none.
  uint64_t mostRecentActive() const {
    uint64_t best = 0;
    int64_t best_started = INT64_MIN;
    for (const auto& [id, v] : sessions_) {
      if (!v.status || v.status->state != telehand_msg_SESSION_ACTIVE) continue;
      if (v.status->started_ns >= best_started) {
        best = id;
        best_started = v.status->started_ns;
      }
    }
    return best;
  }

  /// Sessions with a status, newest first: "7 active, 6 closed" or "none".
  std::string known() const {
    std::string out;
    int shown = 0;
    for (auto it = sessions_.rbegin(); it != sessions_.rend(); ++it) {
      if (!it->second.status) continue;
      if (shown++ == 10) return out + ", ...";
      out += fmt::format("{}{} {}", out.empty() ? "" : ", ", it->first,
                         stateName(it->second.status->state));
    }
    return out.empty() ? "none" : out;
  }

  /// Events of `session` and the server's errors not tied to a session, oldest first.
  std::vector<const EventLine*> eventsFor(uint64_t session) const {
    std::vector<const EventLine*> out;
    if (const auto it = sessions_.find(session); it != sessions_.end()) {
      for (const auto& e : it->second.events) out.push_back(&e);
    }
    if (const auto it = sessions_.find(0); session != 0 && it != sessions_.end()) {
      for (const auto& e : it->second.events) {
        if (e.kind == telehand_msg_EVENT_ERROR) out.push_back(&e);
      }
    }
    std::sort(out.begin(), out.end(),
              [](const EventLine* a, const EventLine* b) { return before(*a, *b); });
    return out;
  }

  /// Whether a server (the HandState writer) is matched right now.
  bool serverMatched() const noexcept { return hand_reader_.matchedWriters() > 0; }

  /// Asks the servers to replay recorded session `source` (docs/lessons.md "Watch") and waits
  /// for the answer: the replay's own session id, or 0 with `why` (no server, a refusal).
  uint64_t openReplay(uint64_t source, int64_t timeout_ns, std::string& why) {
    SteadyClock clock;
    const int64_t deadline = clock.nowNs() + timeout_ns;
    while (command_writer_.matchedReaders() == 0) {
      if (clock.nowNs() > deadline) {
        why = "no telehand-server took the request (is one running on this domain?)";
        return 0;
      }
      wait(10 * kNsPerMs);
    }
    telehand_msg_SessionCommand cmd = command(telehand_msg_CMD_OPEN, 0);
    cmd.mode = telehand_msg_MODE_REPLAY;
    cmd.follow_session = source;
    copyString(cmd.user, "supervisor");
    command_writer_.write(cmd);
    while (clock.nowNs() < deadline) {
      wait(20 * kNsPerMs);
      poll(clock.nowNs());
      for (const auto& [id, v] : sessions_) {
        if (v.status && v.status->client_id == client_id_ &&
            v.status->request_seq == cmd.request_seq) {
          return id;
        }
      }
      for (const auto& e : sessions_[0].events) {
        if (e.kind == telehand_msg_EVENT_ERROR && e.text.find("replay") != std::string::npos) {
          why = e.text;
          return 0;
        }
      }
    }
    why = "the server did not answer within the wait";
    return 0;
  }
  /// A replay's control (pause, play, speed, loop) or the end of it (close).
  void control(uint64_t session, telehand_msg_CommandKind kind, const char* phase, double value) {
    telehand_msg_SessionCommand cmd = command(kind, session);
    copyString(cmd.text, phase);
    cmd.value = value;
    command_writer_.write(cmd);
  }

 private:
  telehand_msg_SessionCommand command(telehand_msg_CommandKind kind, uint64_t session) {
    return sessionCommand(kind, client_id_, ++request_seq_, session);
  }

  static void onHand(SessionView& v, const telehand_msg_HandState& h, int64_t now_ns,
                     int64_t wall_ns) {
    ++v.hand_states;
    if (v.hand && h.seq <= v.hand->seq) {
      ++v.hand_reordered;
      return;
    }
    if (v.hand && h.seq > v.hand->seq + 1) v.hand_gaps += h.seq - v.hand->seq - 1;
    v.hand = h;
    v.hand_rx_ns = now_ns;
    if (v.first_hand_rx_ns == 0) v.first_hand_rx_ns = now_ns;
    v.hand_delay_ns = wall_ns - h.source_time_ns;
    // device_time_ns should be the client's wall clock (IDL), but a client stamping with its
    // monotonic clock yields nonsense: show a delay only when it is plausible at all.
    const int64_t device_delay_ns = wall_ns - h.device_time_ns;
    v.device_delay_ns = h.device_time_ns > 0 && std::llabs(device_delay_ns) < kPlausibleDelayNs
                            ? device_delay_ns
                            : 0;
    v.hand_rx.push_back(now_ns);
    while (v.hand_rx.front() < now_ns - kRateWindowNs) v.hand_rx.pop_front();
  }

  void onEvent(const telehand_msg_SessionEvent& e) {
    SessionView& v = sessions_[e.session_id];
    ++v.events_seen;
    EventLine line{++arrivals_, e.session_id, e.seq, e.source_time_ns, e.kind, printable(e.text)};
    // One writer's events arrive in order, but a restarted or second server in the partition
    // writes its own: keep the history sorted, so "the last few" are the latest.
    const auto pos = std::upper_bound(v.events.begin(), v.events.end(), line, before);
    v.events.insert(pos, std::move(line));
    if (v.events.size() > kEventsKept) v.events.pop_front();
  }

  dds::Participant participant_;
  dds::Topics topics_;
  dds::Reader<telehand_msg_SessionStatus> status_reader_;
  dds::Reader<telehand_msg_JointModel> model_reader_;
  dds::Reader<telehand_msg_HandState> hand_reader_;
  dds::Reader<telehand_msg_SessionEvent> event_reader_;
  dds::Writer<telehand_msg_SessionCommand> command_writer_;  // replays only
  dds::WaitSet waitset_;
  uint64_t client_id_ = (static_cast<uint64_t>(::getpid()) << 32) ^
                        static_cast<uint64_t>(wallNs()) ^ 0x5757'0000'0000'0000ULL;
  uint32_t request_seq_ = 0;
  std::map<uint64_t, SessionView> sessions_;  // 0 holds events not tied to a session
  uint64_t arrivals_ = 0;
};

}  // namespace telehand::client::watch
