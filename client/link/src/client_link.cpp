#include "telehand/client/link/client_link.h"

#include <sys/prctl.h>

#include <algorithm>
#include <cstdlib>
#include <cstring>
#include <random>

#include "telehand/core/clock.h"
#include "telehand/core/printable.h"
#include "telehand/protocol/wire.h"

namespace telehand::client::link {

namespace {
constexpr std::size_t kChunkSamples = 100;  // the record travels 10 chunks per second
constexpr auto kChunkMaxAge = std::chrono::milliseconds(100);

/// Where unacknowledged samples go when memory would not hold them.
std::string spillDir() {
  const char* tmp = std::getenv("TMPDIR");
  return tmp && *tmp ? tmp : "/tmp";
}

uint64_t randomClientId() {
  std::random_device rd;
  const uint64_t id = (static_cast<uint64_t>(rd()) << 32) ^ rd();
  return id == 0 ? 1 : id;
}
}  // namespace

ClientLink::ClientLink(const dds::Options& options, loop::HapticLoop& loop)
    : loop_(loop),
      participant_(options),
      topics_(participant_),
      device_writer_(participant_, topics_.device_state, dds::qos::deviceState()),
      // A full reliable history (a long, lossy link) must not hold up the live stream that
      // shares this thread: the chunk is kept and retried instead of blocking.
      chunk_writer_(participant_, topics_.record_chunk,
                    dds::qos::recordChunk().reliable(std::chrono::milliseconds(1))),
      command_writer_(participant_, topics_.session_command, dds::qos::sessionCommand()),
      model_reader_(participant_, topics_.joint_model,
                    dds::qos::jointModel().keepLast(kServerTopicHistory)),
      status_reader_(participant_, topics_.session_status,
                     dds::qos::sessionStatus().keepLast(kServerTopicHistory)),
      event_reader_(participant_, topics_.session_event, dds::qos::sessionEvent()),
      direct_reader_(participant_, topics_.direct_force, dds::qos::directForce(64)),
      client_id_(randomClientId()),
      retained_(kRetainInMemory, kRetainOnDisk, spillDir()),
      capture_topics_(participant_),
      file_writer_(participant_, capture_topics_.session_file, dds::qos::sessionFile()),
      knn_reader_(participant_, capture_topics_.knn_model, dds::qos::knnModel()) {
  chunk_.reserve(kChunkSamples);
}

ClientLink::~ClientLink() { stop(); }

uint64_t ClientLink::open(const OpenRequest& req, std::chrono::milliseconds timeout) {
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  while (command_writer_.matchedReaders() == 0 || status_reader_.matchedWriters() == 0) {
    if (std::chrono::steady_clock::now() > deadline) {
      const auto& o = participant_.options();
      throw Error("no telehand server found within " + std::to_string(timeout.count()) +
                  " ms on DDS domain " + std::to_string(o.domain) + ", partition '" + o.partition +
                  "' (is telehand-server running with the same --domain, " +
                  "--partition and --dds-config?)");
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  telehand_msg_SessionCommand cmd = command(telehand_msg_CMD_OPEN);
  describeOpen(req, cmd);
  opened_ = req;
  dds::check(command_writer_.write(cmd), "write SessionCommand OPEN");
  // Asked again, the same request, every second until answered: a server discovered after
  // the first write (a pool whose assigned server had not matched yet) hears it then; the
  // server that made the session answers a repeat with the same session.
  auto next_ask = std::chrono::steady_clock::now() + std::chrono::seconds(1);

  while (std::chrono::steady_clock::now() < deadline) {
    if (std::chrono::steady_clock::now() >= next_ask) {
      next_ask += std::chrono::seconds(1);
      command_writer_.write(cmd);
    }
    status_reader_.take([&](const telehand_msg_SessionStatus& st, const dds_sample_info_t& info) {
      if (st.client_id == client_id_ && st.request_seq == cmd.request_seq) {
        session_id_ = st.session_id;
        // From now on the session's models and status come from this server only.
        server_ = senders_.of(status_reader_.handle(), info.publication_handle).participant;
        lesson_plan_.assign(st.lesson, strnlen(st.lesson, sizeof st.lesson));
        opened_case_.assign(st.case_name, strnlen(st.case_name, sizeof st.case_name));
      }
    });
    pollEvents();
    if (session_id_ != 0) {
      loop_.setSession(session_id_);
      return session_id_;
    }
    std::lock_guard lock(messages_mu_);
    if (!messages_.empty()) throw Error("server refused the session: " + messages_.back());
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
  throw Error("the server did not answer the session request within " +
              std::to_string(timeout.count()) + " ms");
}

bool ClientLink::awaitModel(std::chrono::milliseconds timeout) {
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  while (std::chrono::steady_clock::now() < deadline) {
    pollModels();
    if (model_version_ != 0) return true;
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
  return false;
}

void ClientLink::start() {
  if (running_.exchange(true)) return;
  chunk_started_ = std::chrono::steady_clock::now();
  thread_ = std::thread([this] { run(); });
}

void ClientLink::stop() {
  if (running_.exchange(false) && thread_.joinable()) thread_.join();
  pump(true);
}

void ClientLink::run() {
  pthread_setname_np(pthread_self(), "telehand-link");
  prctl(PR_SET_TIMERSLACK, 1UL, 0UL, 0UL, 0UL);  // its 0.5 ms naps are the samples' latency
  while (running_.load(std::memory_order_acquire)) {
    pollStatus();
    watchServer();
    pump(false);
    pollDirectForces();
    pollModels();
    pollEvents();
    std::this_thread::sleep_for(std::chrono::microseconds(500));
  }
}

void ClientLink::pump(bool final_flush) {
  Sample s;
  telehand_msg_DeviceState w;
  while (loop_.samples().tryPop(s)) {
    // Deadband: the live stream carries only what a remote side would notice; the record
    // (chunks below) carries every sample, marked with whether it also went out live.
    if (deadband_.config().enabled()) s.flags |= sample_flags::kDeadband;
    const bool live = deadband_.admit(s, s.source_time_ns);
    if (live) s.flags |= sample_flags::kSentLive;
    toWire(s, w);
    if (live) {
      if (device_writer_.write(w) < 0) stats_.live_write_errors.fetch_add(1);
      stats_.live_sent.fetch_add(1, std::memory_order_relaxed);
    }
    stats_.samples_sent.fetch_add(1, std::memory_order_relaxed);
    stats_.last_seq.store(s.seq, std::memory_order_relaxed);
    if (chunk_.empty()) chunk_started_ = std::chrono::steady_clock::now();
    record_digest_.add(fromWire(w));  // the sample as the record will decode it
    chunk_.push_back(w);
    if (chunk_.size() == kChunkSamples) flushChunk(false);
  }
  if (!chunk_.empty() &&
      (final_flush || std::chrono::steady_clock::now() - chunk_started_ > kChunkMaxAge)) {
    flushChunk(false);
  }
  if (final_flush) {
    // Retry what the server has not accepted yet, for a bounded time.
    const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(10);
    while (!unsent_.empty() && std::chrono::steady_clock::now() < deadline) flushChunk(true);
  } else if (!unsent_.empty()) {
    flushChunk(true);
  }
}

void ClientLink::flushChunk(bool retry_only) {
  if (!retry_only && !chunk_.empty()) {
    unsent_.push_back(std::move(chunk_));
    chunk_ = {};
    chunk_.reserve(kChunkSamples);
  }
  if (resuming_) {
    // No server to send to: everything is kept (memory, then disk) for the one that
    // resumes the session.
    while (!unsent_.empty()) {
      stats_.samples_chunked.fetch_add(unsent_.front().size(), std::memory_order_relaxed);
      keep(std::move(unsent_.front()));
      unsent_.pop_front();
    }
    return;
  }
  // After a resume, first what the new server's record may lack, oldest first.
  while (resend_left_ > 0 || resending_) {
    if (!resending_) {
      SpillQueue::Chunk c;
      --resend_left_;
      try {
        if (!retained_.pop(c)) {
          resend_left_ = 0;
          break;
        }
      } catch (const Error& e) {
        message(e.what());
        resend_left_ = 0;
        break;
      }
      resending_ = std::move(c);
    }
    if (!writeChunk(*resending_)) return;
    stats_.chunks_resent.fetch_add(1, std::memory_order_relaxed);
    keep(std::move(*resending_));
    resending_.reset();
  }
  while (!unsent_.empty()) {
    auto& samples = unsent_.front();
    if (!writeChunk(samples)) return;
    stats_.samples_chunked.fetch_add(samples.size(), std::memory_order_relaxed);
    stats_.chunks_sent.fetch_add(1, std::memory_order_relaxed);
    keep(std::move(samples));
    unsent_.pop_front();
  }
}

bool ClientLink::writeChunk(const SpillQueue::Chunk& samples) {
  telehand_msg_RecordChunk c{};
  c.session_id = session_id_;
  c.chunk_seq = chunk_seq_;
  borrowSamples(c, const_cast<SpillQueue::Chunk&>(samples));
  if (chunk_writer_.write(c) < 0) {  // writer blocked past max_blocking: keep it, retry
    stats_.chunk_retries.fetch_add(1, std::memory_order_relaxed);
    return false;
  }
  ++chunk_seq_;
  return true;
}

void ClientLink::keep(SpillQueue::Chunk&& c) {
  if (c.empty()) return;
  if (c.back().seq < stored_below_) return;  // the record has it already
  if (retained_.empty()) last_ack_ = std::chrono::steady_clock::now();
  try {
    retained_.push(std::move(c));
  } catch (const Error& e) {
    message(e.what());
  }
  stats_.retained_samples.store(retained_.samples(), std::memory_order_relaxed);
  stats_.retained_on_disk_bytes.store(retained_.bytesOnDisk(), std::memory_order_relaxed);
  stats_.retained_dropped.store(retained_.droppedSamples(), std::memory_order_relaxed);
}

void ClientLink::acknowledge(uint64_t stored_below) {
  if (stored_below <= stored_below_) return;
  if (const uint64_t last = stats_.last_seq.load(std::memory_order_relaxed);
      stored_below > last + 1) {
    // Stored past anything sent: not a record's acknowledgement (a server at fault, or a
    // status not from the session's server). Believed, it would let the client forget
    // samples the record does not hold.
    if (firstFew(stats_.acks_rejected)) {
      message("rejected a status saying samples below " + std::to_string(stored_below) +
              " are stored: the last sample sent is " + std::to_string(last));
    }
    return;
  }
  stored_below_ = stored_below;
  stats_.stored_below.store(stored_below, std::memory_order_relaxed);
  try {
    retained_.forgetBelow(stored_below);
  } catch (const Error& e) {
    message(e.what());
  }
  stats_.retained_samples.store(retained_.samples(), std::memory_order_relaxed);
  stats_.retained_on_disk_bytes.store(retained_.bytesOnDisk(), std::memory_order_relaxed);
}

void ClientLink::pollStatus() {
  status_reader_.take([&](const telehand_msg_SessionStatus& st, const dds_sample_info_t& info) {
    if (session_id_ == 0 || st.session_id != session_id_) return;
    const auto now = std::chrono::steady_clock::now();
    const uint64_t sender =
        senders_.of(status_reader_.handle(), info.publication_handle).participant;
    if (resuming_ && st.client_id == client_id_ && resume_requests_.answers(st.request_seq) &&
        st.state == telehand_msg_SESSION_ACTIVE) {
      // A server took the session on: from now on it is the session's server. Its models
      // start again from version 1; what its record lacks is sent again.
      server_ = sender;
      resuming_ = false;
      model_version_ = 0;
      waiting_knn_.reset();
      knn_samples_.reset();
      pending_model_.reset();
      last_ack_ = now;
      acknowledge(st.stored_below);
      resend_left_ = retained_.size();
      stats_.resumes.fetch_add(1, std::memory_order_relaxed);
      message("resumed on a server: its record holds " + std::to_string(st.samples_recorded) +
              " samples; sending again the " + std::to_string(retained_.samples()) +
              " not acknowledged");
      return;
    }
    if (sender != server_) {
      // A server announcing what it recovered, or a forgery: not this session's server.
      if (st.state != telehand_msg_SESSION_SUSPENDED) {
        stats_.foreign_refused.fetch_add(1, std::memory_order_relaxed);
      } else if (!resume_refused_ && st.request_seq == 0) {
        // Another server holds the session for its client (a server of the pool took it
        // over from one whose lease ran out, or recovered it from the record): ask for it to
        // be resumed now rather than after kAckTimeout or the next kResumeEvery. Whoever runs
        // the session answers; if that is still this session's server, nothing changes.
        if (!resuming_) {
          beginResume("a server announced the session suspended (its server went away)");
        } else {
          next_resume_ = now;
        }
      }
      return;
    }
    last_ack_ = now;
    acknowledge(st.stored_below);
    if (st.state == telehand_msg_SESSION_SUSPENDED && !resuming_ && !resume_refused_) {
      beginResume("the server stopped and suspended the session");
    } else if (st.state == telehand_msg_SESSION_CLOSED) {
      CloseResult r;
      r.confirmed = true;
      r.samples_recorded = st.samples_recorded;
      r.samples_missing = st.samples_missing;
      r.record = st.record;
      closed_ = r;
    }
  });
}

void ClientLink::beginResume(const std::string& why) {
  resuming_ = true;
  resume_requests_.begin();
  next_resume_ = std::chrono::steady_clock::now();
  message(why + ": the session goes on here and keeps every sample until a server resumes it");
}

void ClientLink::watchServer() {
  if (session_id_ == 0 || resume_refused_) return;
  const auto now = std::chrono::steady_clock::now();
  if (!resuming_ && !retained_.empty() && now - last_ack_ > kAckTimeout) {
    beginResume(
        "no acknowledgement from the server for " +
        std::to_string(std::chrono::duration_cast<std::chrono::seconds>(kAckTimeout).count()) +
        " s");
  }
  if (!resuming_ || now < next_resume_) return;
  next_resume_ = now + kResumeEvery;
  telehand_msg_SessionCommand cmd = command(telehand_msg_CMD_OPEN);
  describeResume(opened_, opened_case_, stats_.last_seq.load(std::memory_order_relaxed), cmd);
  resume_requests_.sent(cmd.request_seq);
  command_writer_.write(cmd);  // no server yet: asked again in a second
}

bool ClientLink::firstFew(std::atomic<uint64_t>& refused) {
  return refused.fetch_add(1, std::memory_order_relaxed) < kRefusalsSaid;
}

void ClientLink::message(std::string text) {
  std::lock_guard lock(messages_mu_);
  if (messages_.size() < kMessagesKept) {
    messages_.push_back(std::move(text));
  } else {
    ++messages_dropped_;
  }
}

void ClientLink::modelRejected(const std::string& what, uint32_t version, const std::string& why) {
  // As firstFew, and the last one said says that the rest are only counted.
  const uint64_t before = stats_.models_rejected.fetch_add(1, std::memory_order_relaxed);
  if (before >= kRefusalsSaid) return;
  std::string text = "rejected " + what + " v" + std::to_string(version) + ": " + why;
  if (before + 1 == kRefusalsSaid) text += " (further rejected models are counted, not said)";
  message(std::move(text));
}

void ClientLink::pollModels() {
  knn_reader_.take([&](const telehand_msg_KnnModel& k, const dds_sample_info_t& info) {
    if (k.session_id != session_id_ || !fromServer(knn_reader_.handle(), info)) return;
    if (knn_samples_ && k.version <= knn_samples_->version) return;
    KnnReceived r;
    r.version = k.version;
    r.model = fromWire(k, &r.why);  // built here, on the link thread, never in the loop
    knn_samples_ = std::move(r);
  });
  model_reader_.take([&](const telehand_msg_JointModel& m, const dds_sample_info_t& info) {
    if (m.session_id != session_id_ || !fromServer(model_reader_.handle(), info)) return;
    if (m.version <= model_version_) return;
    std::string why;
    auto params = fromWire(m, &why);
    if (!params) {
      // A server that sends the same bad model again is counted each time, said a few times.
      modelRejected("JointModel", m.version, why);
      return;
    }
    model_version_ = m.version;
    stats_.models_received.fetch_add(1);
    if (m.kind == telehand_msg_STIFFNESS_KNN) {
      waiting_knn_ = *params;  // until its samples are here
    } else {
      waiting_knn_.reset();
      pending_model_ = *params;  // the newest wins; it is never sent again (keep-last 1)
    }
  });
  if (waiting_knn_ && knn_samples_ && knn_samples_->version == waiting_knn_->version) {
    if (knn_samples_->model) {
      waiting_knn_->knn = knn_kept_.keep(std::move(knn_samples_->model));
      pending_model_ = *waiting_knn_;
    } else {
      modelRejected("k-nearest-neighbour model", waiting_knn_->version, knn_samples_->why);
    }
    waiting_knn_.reset();
  }
  if (pending_model_ && loop_.models().tryPush(*pending_model_)) {
    knn_kept_.pushed(*pending_model_, models_pushed_++);
    pending_model_.reset();
  }
  knn_kept_.release(loop_.knnInUse(), pending_model_ ? pending_model_->knn : nullptr);
}

void ClientLink::sendFiles(const std::vector<mf2::NamedFile>& files) {
  for (const auto& f : files) {
    telehand_msg_SessionFile w{};
    w.session_id = session_id_;
    w.source_time_ns = wallNs();
    copyString(w.name, f.name);
    w.content = const_cast<char*>(f.content.c_str());
    dds::check(file_writer_.write(w), "write SessionFile");
  }
}

void ClientLink::pollDirectForces() {
  direct_reader_.take([&](const telehand_msg_DirectForce& f, const dds_sample_info_t& info) {
    if (f.session_id != session_id_ || !fromServer(direct_reader_.handle(), info)) return;
    loop::DirectForceSample d;
    d.device_seq = f.device_seq;
    d.force_n = forcesFromWire(f);
    if (!d.force_n[0].allFinite() || !d.force_n[1].allFinite()) {
      // The gate would zero it; refused here, so that it is said and counted, not rendered as
      // a silent zero.
      if (firstFew(stats_.direct_rejected)) {
        message("rejected DirectForce for sample " + std::to_string(f.device_seq) +
                ": a force that is not finite");
      }
      return;
    }
    stats_.direct_forces.fetch_add(1, std::memory_order_relaxed);
    loop_.directForces().tryPush(d);  // full: the loop holds the last one it took
  });
}

bool ClientLink::fromServer(dds_entity_t reader, const dds_sample_info_t& info) {
  if (server_ == 0) return true;
  if (senders_.of(reader, info.publication_handle).participant == server_) return true;
  stats_.foreign_refused.fetch_add(1, std::memory_order_relaxed);
  return false;
}

void ClientLink::pollEvents() {
  event_reader_.take([&](const telehand_msg_SessionEvent& e, const dds_sample_info_t& info) {
    const bool mine =
        (session_id_ != 0 && e.session_id == session_id_) || e.client_id == client_id_;
    if (!mine) return;
    // Shown on the student's terminal: no escape sequence or other control character in it.
    const std::string text = printable(e.text);
    if (e.kind == telehand_msg_EVENT_SCORE) {
      // Scores steer what the student is shown: the acknowledging server's only.
      if (session_id_ == 0 || e.session_id != session_id_ ||
          !fromServer(event_reader_.handle(), info) ||
          text.find(" oscillation ") != std::string::npos) {
        return;
      }
      std::lock_guard lock(messages_mu_);
      if (scores_.size() < 256) scores_.push_back(text);
      return;
    }
    // Errors, and a supervisor's marks on this session (shown to the student at once).
    if (e.kind == telehand_msg_EVENT_ERROR && e.client_id == client_id_ && resuming_ &&
        std::string_view(e.text).starts_with("cannot resume session")) {
      resuming_ = false;
      resume_refused_ = true;  // what is kept stays kept; nobody will take it
    }
    const bool others_mark = e.kind == telehand_msg_EVENT_MARK && e.client_id != client_id_;
    if (e.kind != telehand_msg_EVENT_ERROR && !others_mark) return;
    message(others_mark ? "mark: " + text : text);
  });
}

std::vector<std::string> ClientLink::takeScores() {
  std::lock_guard lock(messages_mu_);
  return std::exchange(scores_, {});
}

void ClientLink::phase(const std::string& name, double value, uint64_t last_seq) {
  telehand_msg_SessionCommand cmd = command(telehand_msg_CMD_PHASE);
  copyString(cmd.text, name);
  cmd.value = value;
  cmd.last_seq = last_seq;
  command_writer_.write(cmd);
}

std::vector<std::string> ClientLink::takeMessages() {
  std::lock_guard lock(messages_mu_);
  std::vector<std::string> out = std::exchange(messages_, {});
  if (messages_dropped_ > 0) {
    out.push_back(std::to_string(messages_dropped_) + " more message(s) not kept: at most " +
                  std::to_string(kMessagesKept) + " are kept between reads");
    messages_dropped_ = 0;
  }
  return out;
}

telehand_msg_SessionCommand ClientLink::command(telehand_msg_CommandKind kind) {
  return sessionCommand(kind, client_id_, request_seq_.fetch_add(1) + 1, session_id_);
}

void ClientLink::mark(const std::string& text) {
  telehand_msg_SessionCommand cmd = command(telehand_msg_CMD_MARK);
  copyString(cmd.text, text);
  command_writer_.write(cmd);
}

CloseResult ClientLink::close(std::chrono::milliseconds timeout) {
  // The CLOSE goes to the session's server once everything it lacks was sent; a server
  // that goes away meanwhile is replaced as during the session (docs/recovery.md).
  const auto start = std::chrono::steady_clock::now();
  const auto last = start + timeout * kCloseWaits;
  auto deadline = start + timeout;
  uint64_t below = stored_below_, resumes = stats_.resumes.load();
  closed_.reset();
  while (!closed_ && std::chrono::steady_clock::now() < deadline) {
    // A close that progresses (a backlog being stored on a loaded server) is waited for.
    if (stored_below_ > below || stats_.resumes.load() > resumes) {
      below = stored_below_;
      resumes = stats_.resumes.load();
      deadline = std::min(last, std::chrono::steady_clock::now() + timeout);
    }
    pollStatus();
    pollEvents();  // the scores of a lesson's last trials come with the close
    watchServer();
    if (!resuming_ && (resending_ || resend_left_ > 0 || !unsent_.empty())) {
      flushChunk(true);
    } else if (!resuming_ && close_to_ != server_ + 1) {
      const uint64_t sent = stats_.samples_sent.load();
      telehand_msg_SessionCommand cmd = command(telehand_msg_CMD_CLOSE);
      cmd.samples_sent = sent;
      cmd.last_seq = sent == 0 ? 0 : stats_.last_seq.load();
      if (command_writer_.write(cmd) >= 0) close_to_ = server_ + 1;
    }
    if (!closed_) std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  CloseResult r = closed_.value_or(CloseResult{});
  r.waited_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return r;
}

}  // namespace telehand::client::link
