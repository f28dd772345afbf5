#include "telehand/server/link/server_link.h"

#include "telehand/core/clock.h"

namespace telehand::server::link {

namespace {
// The server takes the live stream in batches; a deep reader history keeps a slow tick
// (a large SQLite commit) from overwriting samples that HandState and the rate need.
constexpr int32_t kDeviceReaderDepth = 256;
// DeviceStates taken per round: the hands stepping with them, or later (deferred).
constexpr std::size_t kLiveBatch = 256;
constexpr std::size_t kDeferredLiveBatch = 4096;
enum Attach : dds_attach_t { kWake = 1, kCommands, kDevice, kChunks, kFiles };
}  // namespace

ServerLink::ServerLink(const dds::Options& options)
    : secured_(!options.pki.empty()),
      participant_(options),
      topics_(participant_),
      device_reader_(participant_, topics_.device_state,
                     dds::qos::deviceStateReader(kDeviceReaderDepth)),
      chunk_reader_(participant_, topics_.record_chunk, dds::qos::recordChunk()),
      command_reader_(participant_, topics_.session_command, dds::qos::sessionCommand()),
      model_writer_(participant_, topics_.joint_model, dds::qos::jointModel()),
      hand_writer_(participant_, topics_.hand_state, dds::qos::handState()),
      status_writer_(participant_, topics_.session_status, dds::qos::sessionStatus()),
      event_writer_(participant_, topics_.session_event, dds::qos::sessionEvent()),
      direct_writer_(participant_, topics_.direct_force, dds::qos::directForce()),
      ping_reader_(participant_, topics_.latency_ping, dds::qos::latencyProbe()),
      pong_writer_(participant_, topics_.latency_pong, dds::qos::latencyProbe()),
      wake_(participant_),
      waitset_(participant_),
      capture_topics_(participant_),
      file_reader_(participant_, capture_topics_.session_file, dds::qos::sessionFile()),
      knn_writer_(participant_, capture_topics_.knn_model, dds::qos::knnModel()) {
  waitset_.attach(file_reader_.handle(), kFiles);
  waitset_.attach(wake_.handle(), kWake);
  waitset_.attach(command_reader_.handle(), kCommands);
  waitset_.attach(device_reader_.handle(), kDevice);
  waitset_.attach(chunk_reader_.handle(), kChunks);
  // Last: the echo answers as soon as the rest of the link exists.
  echo_.emplace(ping_reader_.handle(), Echo{this});
}

// Before any member goes: waits for an echo under way, and no echo runs after.
ServerLink::~ServerLink() { echo_.reset(); }

void ServerLink::publish(const telehand_msg_SessionStatus& s) {
  if (status_writer_.write(s) < 0) {
    counters_.publish_errors.fetch_add(1);
  } else if (s.session_id != 0) {
    written_[s.session_id] |= kStatus;
  }
}
void ServerLink::publish(const telehand_msg_JointModel& m) {
  if (model_writer_.write(m) < 0) {
    counters_.publish_errors.fetch_add(1);
  } else if (m.session_id != 0) {
    written_[m.session_id] |= kModel;
  }
}
void ServerLink::publish(const telehand_msg_HandState& h) {
  if (hand_writer_.write(h) < 0) counters_.publish_errors.fetch_add(1);
}
void ServerLink::publish(const telehand_msg_KnnModel& k) {
  if (knn_writer_.write(k) < 0) {
    counters_.publish_errors.fetch_add(1);
  } else if (k.session_id != 0) {
    written_[k.session_id] |= kKnn;
  }
}
void ServerLink::publish(const telehand_msg_DirectForce& f) {
  if (direct_writer_.write(f) < 0) counters_.publish_errors.fetch_add(1);
}
void ServerLink::publish(const telehand_msg_SessionEvent& e) {
  if (event_writer_.write(e) < 0) {
    counters_.publish_errors.fetch_add(1);
  } else if (e.session_id != 0) {
    written_[e.session_id] |= kEvent;
  }
}

namespace {
/// Ends a session's instance on a topic keyed by session_id; `written`: a transient-local
/// writer that wrote it (dds::Writer::unregister).
template <typename T>
void unregisterSession(dds::Writer<T>& writer, uint64_t session_id, bool written = false) {
  T key{};
  key.session_id = session_id;
  writer.unregister(key, written);
}
}  // namespace

void ServerLink::retire(uint64_t session_id) {
  const auto it = written_.find(session_id);
  const unsigned written = it == written_.end() ? 0u : it->second;
  if (it != written_.end()) written_.erase(it);
  unregisterSession(status_writer_, session_id, written & kStatus);
  unregisterSession(model_writer_, session_id, written & kModel);
  unregisterSession(knn_writer_, session_id, written & kKnn);
  // The keyed topics without late joiners keep an instance per session all the same (and
  // SessionEvent its last 64 events): freed here too, or each session would leave ~20 KB.
  unregisterSession(event_writer_, session_id, written & kEvent);
  unregisterSession(hand_writer_, session_id);
  unregisterSession(direct_writer_, session_id);
}

void ServerLink::idle() {
  dds::releaseWriterHistoryNodes(participant_, topics_.direct_force);
  dds::releasePooledSamples();
}

void ServerLink::settle() { dds::releasePooledSamples(); }

const session::Origin& ServerLink::origin(dds_entity_t reader, const dds_sample_info_t& info) {
  // Per sample (1 kHz per client): the last writer's origin, or one lookup; built once per
  // writer (DDS Security adds no work of telehand's per sample).
  if (info.publication_handle == last_publication_ && last_origin_ != nullptr) {
    return *last_origin_;
  }
  if (const auto it = origins_.find(info.publication_handle); it != origins_.end()) {
    last_publication_ = info.publication_handle;
    last_origin_ = &it->second;
    return it->second;
  }
  const dds::Sender& s = senders_.of(reader, info.publication_handle);
  // An authenticated participant's GUID begins with 48 bits of its certificate subject's
  // hash (DDS Security: the same for all participants of one identity); the hex GUID's
  // first 12 characters.
  session::Origin o{s.participant, s.guid,
                    secured_ && s.guid.size() >= 12 ? s.guid.substr(0, 12) : ""};
  if (s.participant == 0) {  // Cyclone no longer knows the writer: not remembered
    unknown_origin_ = std::move(o);
    return unknown_origin_;
  }
  if (origins_.size() >= kMaxOrigins) origins_.clear();
  last_publication_ = info.publication_handle;
  last_origin_ = &origins_.emplace(info.publication_handle, std::move(o)).first->second;
  return *last_origin_;
}

void ServerLink::serve(session::SessionManager& manager, const std::atomic<bool>& stop,
                       std::chrono::nanoseconds tick) {
  SteadyClock clock;
  while (!stop.load(std::memory_order_acquire)) {
    // Hands behind the live stream step in the tick, a slice at a time, between rounds of
    // taking what arrived: the loop sleeps only as long as their budget is spent.
    const int64_t hand_wait = manager.handWaitNs(clock.nowNs());
    waitset_.wait(hand_wait < 0 ? tick : std::min(tick, std::chrono::nanoseconds(hand_wait)));
    wake_.clear();
    const int64_t now = clock.nowNs();
    // Commands first so that an OPEN is known before its first samples are handled.
    counters_.commands += command_reader_.take(
        [&](const telehand_msg_SessionCommand& c, const dds_sample_info_t& info) {
          manager.onCommand(c, now, origin(command_reader_.handle(), info));
        });
    file_reader_.take([&](const telehand_msg_SessionFile& f, const dds_sample_info_t& info) {
      manager.onFile(f, now, origin(file_reader_.handle(), info));
    });
    counters_.chunks += chunk_reader_.take(
        [&](const telehand_msg_RecordChunk& c, const dds_sample_info_t& info) {
          manager.onChunk(c, now, origin(chunk_reader_.handle(), info));
        },
        1024);
    // Then tick: HandState and closing sessions wait at most one batch. A live sample whose
    // hand steps later (SessionManager::setHandSlice) costs a copy into its session's queue:
    // the batch is larger, or a round's hand slice would outlast the samples it takes.
    counters_.device_states += device_reader_.take(
        [&](const telehand_msg_DeviceState& d, const dds_sample_info_t& info) {
          manager.onDeviceState(d, now, origin(device_reader_.handle(), info));
        },
        manager.handSlice() > 0 ? kDeferredLiveBatch : kLiveBatch);
    manager.tick(clock.nowNs());
  }
  // Whatever is still in the readers belongs in the record.
  const int64_t now = clock.nowNs();
  chunk_reader_.take(
      [&](const telehand_msg_RecordChunk& c, const dds_sample_info_t& info) {
        manager.onChunk(c, now, origin(chunk_reader_.handle(), info));
      },
      SIZE_MAX);
  manager.closeAll(now);
}

// On Cyclone's receive thread (dds::DataListener): a loaned take, a best-effort write of the
// same sample and an atomic counter. Nothing here allocates, locks or waits, and the
// latency-probe writer is best-effort keep-last 1, so the write never waits for an
// acknowledgement or for room in its history. Nothing in this process reads the pong topic,
// so the write cannot call back into a listener of ours.
void ServerLink::echo() noexcept {
  ping_reader_.take([&](const telehand_msg_DeviceState& s, const dds_sample_info_t&) {
    if (pong_writer_.write(s) >= 0) counters_.echoes.fetch_add(1, std::memory_order_relaxed);
  });
}

}  // namespace telehand::server::link
