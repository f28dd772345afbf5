#pragma once
/// The server's DDS side: takes commands, live device states and record chunks, hands them
/// to the SessionManager, publishes what it produces, and echoes latency probes inside
/// Cyclone's receive thread (a DATA_AVAILABLE listener, as ddsperf answers its pings), so
/// that neither recording nor a thread wake-up delays an echo.
#include <atomic>
#include <memory>
#include <mutex>
#include <optional>
#include <unordered_map>

#include "telehand/protocol/dds.h"
#include "telehand/protocol/dds_capture.h"
#include "telehand/server/session/session_manager.h"

namespace telehand::server::link {

struct LinkCounters {
  std::atomic<uint64_t> commands{0};
  std::atomic<uint64_t> device_states{0};
  std::atomic<uint64_t> chunks{0};
  std::atomic<uint64_t> echoes{0};
  std::atomic<uint64_t> publish_errors{0};
};

class ServerLink final : public session::Outbox {
 public:
  /// `renew_when_idle`: settle() also replaces the DDS participant (see settle).
  explicit ServerLink(const dds::Options& options, bool renew_when_idle = false);
  ~ServerLink() override;

  void publish(const telehand_msg_SessionStatus& s) override;
  void publish(const telehand_msg_JointModel& m) override;
  void publish(const telehand_msg_HandState& h) override;
  void publish(const telehand_msg_SessionEvent& e) override;
  void publish(const telehand_msg_KnnModel& k) override;
  void publish(const telehand_msg_DirectForce& f) override;
  void retire(uint64_t session_id) override;
  // Frees the spare nodes of Cyclone's writer histories and its pooled samples
  // (dds::releaseWriterHistoryNodes, dds::releasePooledSamples); settle: the samples that
  // came back to the pool since, and with renew_when_idle the participant itself: deleted
  // (and with it Cyclone's domain, whose tables and buffers a flood of sessions grew and
  // never shrinks) and made again. A client asking for a session in between asks again
  // (ClientLink::open repeats its OPEN every second).
  void idle() override;
  void settle() override;

  /// Serve until `stop` becomes true; ticks the manager at least every `tick`.
  void serve(session::SessionManager& manager, const std::atomic<bool>& stop,
             std::chrono::nanoseconds tick);
  /// Wake serve() (from a signal-safe context use the stop flag and wait one tick).
  void wake() noexcept;

  const LinkCounters& counters() const noexcept { return counters_; }

 private:
  struct Entities;
  /// Answers the pings waiting in `e`'s ping reader (the echo listener's call).
  void echo(Entities& e) noexcept;
  struct Echo {
    ServerLink* link;
    Entities* e;
    void operator()() const noexcept { link->echo(*e); }
  };
  /// The manager's view of who wrote a sample a reader took (valid until the next call).
  const session::Origin& origin(dds_entity_t reader, const dds_sample_info_t& info);
  /// Deletes the participant and everything in it, then makes them again; false when that
  /// failed (logged once, until it succeeds): serve() tries again every second.
  bool renew() noexcept;

  /// Everything of the link that lives in the DDS participant.
  struct Entities {
    Entities(const dds::Options& options, ServerLink* link);
    ~Entities();
    dds::Participant participant;
    dds::Topics topics;
    dds::Reader<telehand_msg_DeviceState> device_reader;
    dds::Reader<telehand_msg_RecordChunk> chunk_reader;
    dds::Reader<telehand_msg_SessionCommand> command_reader;
    dds::Writer<telehand_msg_JointModel> model_writer;
    dds::Writer<telehand_msg_HandState> hand_writer;
    dds::Writer<telehand_msg_SessionStatus> status_writer;
    dds::Writer<telehand_msg_SessionEvent> event_writer;
    dds::Writer<telehand_msg_DirectForce> direct_writer;
    dds::Reader<telehand_msg_DeviceState> ping_reader;
    dds::Writer<telehand_msg_DeviceState> pong_writer;
    dds::GuardCondition wake;
    dds::WaitSet waitset;
    dds::CaptureTopics capture_topics;
    dds::Reader<telehand_msg_SessionFile> file_reader;
    dds::Writer<telehand_msg_KnnModel> knn_writer;
    dds::SenderCache senders;
    // Last member: attached when everything it uses exists, detached first.
    std::optional<dds::DataListener<Echo>> echo;
  };

  const dds::Options options_;
  const bool renew_when_idle_;
  bool secured_;  // DDS Security: senders carry their identity (Origin::identity)
  LinkCounters counters_;
  int failed_renewals_ = 0;  // attempts since the participant could last be made
  // Held by wake() (other threads) and while the entities are replaced.
  std::mutex entities_mu_;
  std::unique_ptr<Entities> e_;
  // Origins by publication handle (at most kMaxOrigins writers, then starting over), and the
  // last one looked up.
  static constexpr std::size_t kMaxOrigins = 4096;
  std::unordered_map<dds_instance_handle_t, session::Origin> origins_;
  dds_instance_handle_t last_publication_ = 0;
  const session::Origin* last_origin_ = nullptr;
  session::Origin unknown_origin_;
  // The transient-local topics each session not yet retired was written on (kStatus...):
  // what retire() must hand back to Cyclone (dds::Writer::unregister).
  enum : unsigned { kStatus = 1, kModel = 2, kEvent = 4, kKnn = 8 };
  std::unordered_map<uint64_t, unsigned> written_;
};

}  // namespace telehand::server::link
