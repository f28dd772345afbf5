#include "telehand/server/link/server_link.h"

#include <spdlog/spdlog.h>

#include <thread>

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

ServerLink::Entities::Entities(const dds::Options& options, ServerLink* link)
    : participant(options),
      topics(participant),
      device_reader(participant, topics.device_state,
                    dds::qos::deviceStateReader(kDeviceReaderDepth)),
      chunk_reader(participant, topics.record_chunk, dds::qos::recordChunk()),
      command_reader(participant, topics.session_command, dds::qos::sessionCommand()),
      model_writer(participant, topics.joint_model, dds::qos::jointModel()),
      hand_writer(participant, topics.hand_state, dds::qos::handState()),
      status_writer(participant, topics.session_status, dds::qos::sessionStatus()),
      event_writer(participant, topics.session_event, dds::qos::sessionEvent()),
      direct_writer(participant, topics.direct_force, dds::qos::directForce()),
      ping_reader(participant, topics.latency_ping, dds::qos::latencyProbe()),
      pong_writer(participant, topics.latency_pong, dds::qos::latencyProbe()),
      wake(participant),
      waitset(participant),
      capture_topics(participant),
      file_reader(participant, capture_topics.session_file, dds::qos::sessionFile()),
      knn_writer(participant, capture_topics.knn_model, dds::qos::knnModel()) {
  waitset.attach(file_reader.handle(), kFiles);
  waitset.attach(wake.handle(), kWake);
  waitset.attach(command_reader.handle(), kCommands);
  waitset.attach(device_reader.handle(), kDevice);
  waitset.attach(chunk_reader.handle(), kChunks);
  // Last: the echo answers as soon as the rest of the link exists.
  echo.emplace(ping_reader.handle(), Echo{link, this});
}

// Before any member goes: waits for an echo under way, and no echo runs after.
ServerLink::Entities::~Entities() { echo.reset(); }

ServerLink::ServerLink(const dds::Options& options, bool renew_when_idle)
    : options_(options),
      renew_when_idle_(renew_when_idle),
      secured_(!options.pki.empty()),
      e_(std::make_unique<Entities>(options, this)) {}

ServerLink::~ServerLink() {
  const std::lock_guard lock(entities_mu_);
  e_.reset();
}

void ServerLink::wake() noexcept {
  const std::lock_guard lock(entities_mu_);
  if (e_) e_->wake.trigger();
}

bool ServerLink::renew() noexcept {
  const std::lock_guard lock(entities_mu_);
  // Handles and writers of the old participant mean nothing in the new one.
  origins_.clear();
  last_publication_ = 0;
  last_origin_ = nullptr;
  written_.clear();
  const auto start = std::chrono::steady_clock::now();
  e_.reset();  // the last participant of the domain: Cyclone deletes the domain with it
  try {
    e_ = std::make_unique<Entities>(options_, this);
  } catch (const std::exception& err) {
    if (failed_renewals_++ == 0) {
      spdlog::error("cannot make the DDS participant again (tried again every second): {}",
                    err.what());
    }
    return false;
  }
  if (failed_renewals_ > 0) {
    spdlog::info("DDS participant made again after {} failed attempts", failed_renewals_);
    failed_renewals_ = 0;
    return true;
  }
  spdlog::info(
      "no session left: DDS participant made again in {:.0f} ms",
      std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count());
  return true;
}

void ServerLink::publish(const telehand_msg_SessionStatus& s) {
  if (!e_ || e_->status_writer.write(s) < 0) {
    counters_.publish_errors.fetch_add(1);
  } else if (s.session_id != 0) {
    written_[s.session_id] |= kStatus;
  }
}
void ServerLink::publish(const telehand_msg_JointModel& m) {
  if (!e_ || e_->model_writer.write(m) < 0) {
    counters_.publish_errors.fetch_add(1);
  } else if (m.session_id != 0) {
    written_[m.session_id] |= kModel;
  }
}
void ServerLink::publish(const telehand_msg_HandState& h) {
  if (!e_ || e_->hand_writer.write(h) < 0) counters_.publish_errors.fetch_add(1);
}
void ServerLink::publish(const telehand_msg_KnnModel& k) {
  if (!e_ || e_->knn_writer.write(k) < 0) {
    counters_.publish_errors.fetch_add(1);
  } else if (k.session_id != 0) {
    written_[k.session_id] |= kKnn;
  }
}
void ServerLink::publish(const telehand_msg_DirectForce& f) {
  if (!e_ || e_->direct_writer.write(f) < 0) counters_.publish_errors.fetch_add(1);
}
void ServerLink::publish(const telehand_msg_SessionEvent& e) {
  if (!e_ || e_->event_writer.write(e) < 0) {
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
  if (!e_) return;
  unregisterSession(e_->status_writer, session_id, written & kStatus);
  unregisterSession(e_->model_writer, session_id, written & kModel);
  unregisterSession(e_->knn_writer, session_id, written & kKnn);
  // The keyed topics without late joiners keep an instance per session all the same (and
  // SessionEvent its last 64 events): freed here too, or each session would leave ~20 KB.
  unregisterSession(e_->event_writer, session_id, written & kEvent);
  unregisterSession(e_->hand_writer, session_id);
  unregisterSession(e_->direct_writer, session_id);
}

// The pool's and the histories' release read the domain this thread last called into
// (common/protocol/src/cyclone_instance_fix.c): never without a participant, whose domain
// may be gone.
void ServerLink::idle() {
  if (!e_) return;
  dds::releaseWriterHistoryNodes(e_->participant, e_->topics.direct_force);
  dds::releasePooledSamples();
}

void ServerLink::settle() {
  if (!e_) return;
  if (renew_when_idle_) {
    renew();  // the pool goes with the domain
    return;
  }
  dds::releasePooledSamples();
}

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
  const dds::Sender& s = e_->senders.of(reader, info.publication_handle);
  // An authenticated participant's GUID begins with 48 bits of its certificate subject's
  // hash (DDS Security: the same for all participants of one identity); the hex GUID's
  // first 12 characters.
  session::Origin o{s.participant, s.guid,
                    secured_ && s.guid.size() >= 12 ? s.guid.substr(0, 12) : ""};
  if (s.participant == 0) {
    // Cyclone no longer knows the writer (it left before its sample was read): not
    // remembered, and nothing it sent is taken (Origin::unknown).
    unknown_origin_ = std::move(o);
    unknown_origin_.unknown = true;
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
  int64_t next_renew_ns = 0;
  while (!stop.load(std::memory_order_acquire)) {
    if (!e_) {
      // No participant (it could not be made again): nothing arrives, the manager still
      // ticks (the pool's lease, the record), and the participant is tried once a second.
      const int64_t now = clock.nowNs();
      if (now < next_renew_ns || !renew()) {
        if (now >= next_renew_ns) next_renew_ns = now + 1'000'000'000;
        std::this_thread::sleep_for(tick);
        manager.tick(clock.nowNs());
        continue;
      }
    }
    // Valid until the manager's tick (which may make the participant again: settle).
    Entities& e = *e_;
    // Hands behind the live stream step in the tick, a slice at a time, between rounds of
    // taking what arrived: the loop sleeps only as long as their budget is spent.
    const int64_t hand_wait = manager.handWaitNs(clock.nowNs());
    e.waitset.wait(hand_wait < 0 ? tick : std::min(tick, std::chrono::nanoseconds(hand_wait)));
    e.wake.clear();
    const int64_t now = clock.nowNs();
    // Commands first so that an OPEN is known before its first samples are handled.
    counters_.commands += e.command_reader.take(
        [&](const telehand_msg_SessionCommand& c, const dds_sample_info_t& info) {
          manager.onCommand(c, now, origin(e.command_reader.handle(), info));
        });
    e.file_reader.take([&](const telehand_msg_SessionFile& f, const dds_sample_info_t& info) {
      manager.onFile(f, now, origin(e.file_reader.handle(), info));
    });
    counters_.chunks += e.chunk_reader.take(
        [&](const telehand_msg_RecordChunk& c, const dds_sample_info_t& info) {
          manager.onChunk(c, now, origin(e.chunk_reader.handle(), info));
        },
        1024);
    // Then tick: HandState and closing sessions wait at most one batch. A live sample whose
    // hand steps later (SessionManager::setHandSlice) costs a copy into its session's queue:
    // the batch is larger, or a round's hand slice would outlast the samples it takes.
    counters_.device_states += e.device_reader.take(
        [&](const telehand_msg_DeviceState& d, const dds_sample_info_t& info) {
          manager.onDeviceState(d, now, origin(e.device_reader.handle(), info));
        },
        manager.handSlice() > 0 ? kDeferredLiveBatch : kLiveBatch);
    manager.tick(clock.nowNs());
  }
  // Whatever is still in the readers belongs in the record.
  const int64_t now = clock.nowNs();
  if (e_) {
    e_->chunk_reader.take(
        [&](const telehand_msg_RecordChunk& c, const dds_sample_info_t& info) {
          manager.onChunk(c, now, origin(e_->chunk_reader.handle(), info));
        },
        SIZE_MAX);
  }
  manager.closeAll(now);
}

// On Cyclone's receive thread (dds::DataListener): a loaned take, a best-effort write of the
// same sample and an atomic counter. Nothing here allocates, locks or waits, and the
// latency-probe writer is best-effort keep-last 1, so the write never waits for an
// acknowledgement or for room in its history. Nothing in this process reads the pong topic,
// so the write cannot call back into a listener of ours.
void ServerLink::echo(Entities& e) noexcept {
  e.ping_reader.take([&](const telehand_msg_DeviceState& s, const dds_sample_info_t&) {
    if (e.pong_writer.write(s) >= 0) counters_.echoes.fetch_add(1, std::memory_order_relaxed);
  });
}

}  // namespace telehand::server::link
