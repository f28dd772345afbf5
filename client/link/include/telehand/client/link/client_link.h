#pragma once
/// The client's link thread: drains the loop's sample ring into DeviceState (live,
/// best-effort) and RecordChunk (the record, reliable), and brings JointModel updates from
/// the server back into the loop's model ring. Opens and closes the session.
#include <atomic>
#include <chrono>
#include <cstdint>
#include <deque>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "telehand/client/link/knn_keeper.h"
#include "telehand/client/link/open_request.h"
#include "telehand/client/link/resume_requests.h"
#include "telehand/client/link/spill_queue.h"
#include "telehand/client/loop/haptic_loop.h"
#include "telehand/core/knn_model.h"
#include "telehand/devices/mf2_device.h"
#include "telehand/protocol/dds.h"
#include "telehand/protocol/dds_capture.h"
#include "telehand/protocol/deadband.h"

namespace telehand::client::link {

struct LinkStats {
  std::atomic<uint64_t> samples_sent{0};  ///< DeviceState writes attempted
  std::atomic<uint64_t> live_write_errors{0};
  std::atomic<uint64_t> samples_chunked{0};  ///< samples handed to the reliable record path
  std::atomic<uint64_t> chunks_sent{0};
  std::atomic<uint64_t> chunk_retries{0};
  std::atomic<uint64_t> models_received{0};
  std::atomic<uint64_t> models_rejected{0};
  /// Models, statuses and forces for this session from a participant other than the server
  /// that acknowledged the OPEN: ignored.
  std::atomic<uint64_t> foreign_refused{0};
  std::atomic<uint64_t> last_seq{0};
  std::atomic<uint64_t> live_sent{0};      ///< DeviceState packets that went out (deadband)
  std::atomic<uint64_t> direct_forces{0};  ///< DirectForce packets received (direct mode)
  /// DirectForces refused for a component that is not finite: not rendered (the loop holds
  /// the last good one for its age limit, then renders nothing).
  std::atomic<uint64_t> direct_rejected{0};
  /// Statuses whose stored_below is past anything this client sent: not believed (the
  /// samples they would let the client forget are kept).
  std::atomic<uint64_t> acks_rejected{0};
  /// Recovery (docs/recovery.md): sessions taken on again by a server after theirs went
  /// away, chunks sent again to it, chunks kept until the server says they are stored.
  std::atomic<uint64_t> resumes{0};
  std::atomic<uint64_t> chunks_resent{0};
  std::atomic<uint64_t> retained_samples{0};
  std::atomic<uint64_t> retained_on_disk_bytes{0};
  std::atomic<uint64_t> retained_dropped{0};  ///< the spill file was full: never sent again
  std::atomic<uint64_t> stored_below{0};      ///< the server's acknowledgement
};

struct CloseResult {
  bool confirmed = false;  ///< the server reported the session closed
  uint64_t samples_recorded = 0;
  uint64_t samples_missing = 0;
  std::string record;     ///< where the server keeps it
  double waited_s = 0.0;  ///< how long the close took, or was waited for in vain
};

class ClientLink {
 public:
  ClientLink(const dds::Options& options, loop::HapticLoop& loop);
  ~ClientLink();

  /// Ask the server for a session; throws Error naming the domain and partition when no
  /// server answers within `timeout`. Returns the session id.
  uint64_t open(const OpenRequest& req, std::chrono::milliseconds timeout);
  /// Wait for the session's first JointModel and hand it to the loop; false on timeout.
  bool awaitModel(std::chrono::milliseconds timeout);

  /// Deadband coding of the live DeviceState stream (set before start).
  void setDeadband(const DeadbandConfig& c) { deadband_ = DeviceStateDeadband(c); }

  void start();
  /// Drain every remaining sample and chunk (the loop must be stopped first).
  void stop();
  /// Sends what the record lacks and the CLOSE, and waits for the server's CLOSED: up to
  /// `timeout` without progress, a wait that starts again whenever the record acknowledges
  /// more of the session or a server resumes it, and at most kCloseWaits timeouts in all.
  CloseResult close(std::chrono::milliseconds timeout);
  static constexpr int kCloseWaits = 8;

  /// Send a mark/feedback event into the session.
  void mark(const std::string& text);
  /// A lesson run's next phase (docs/lessons.md): `last_seq` is the last sample sent before
  /// it, `value` the guide's authority of a guided trial.
  void phase(const std::string& name, double value, uint64_t last_seq);
  /// MODE_LESSON: the plan the server sent with the OPEN's answer (empty otherwise).
  const std::string& lessonPlan() const noexcept { return lesson_plan_; }
  /// The patient case the server opened the session on (a lesson's is the lesson's).
  const std::string& openedCase() const noexcept { return opened_case_; }
  /// Score events of this session from its server (a trial's and the run's; oscillations
  /// are left in the record), in arrival order; drained on read.
  std::vector<std::string> takeScores();
  /// Send files to keep with the session's record (a capture's device and calibration files).
  void sendFiles(const std::vector<mf2::NamedFile>& files);

  const LinkStats& stats() const noexcept { return stats_; }
  /// The digest of every sample handed to the record (core/sample.h SampleDigest): equal to
  /// `telehand-records show`'s of the session when the record holds them all, field for
  /// field. Read it after stop().
  const SampleDigest& recordDigest() const noexcept { return record_digest_; }
  uint64_t sessionId() const noexcept { return session_id_; }
  uint64_t clientId() const noexcept { return client_id_; }
  /// Events for this session or client (errors from the server), formatted; drained on read.
  std::vector<std::string> takeMessages();

 private:
  /// True when the sample comes from the server that acknowledged the OPEN (or none yet).
  bool fromServer(dds_entity_t reader, const dds_sample_info_t& info);
  dds::SenderCache senders_{64};
  dds_instance_handle_t server_ = 0;
  void run();
  /// A command from this client for its session, with the next request number.
  telehand_msg_SessionCommand command(telehand_msg_CommandKind kind);
  void pump(bool final_flush);
  void flushChunk(bool force);
  /// Write one chunk of the record; false when the writer could not take it now.
  bool writeChunk(const SpillQueue::Chunk& samples);
  /// Keep a sent chunk until the server acknowledges it.
  void keep(SpillQueue::Chunk&& c);
  /// The session's statuses: acknowledgements, a suspension, a resume's answer, the close.
  void pollStatus();
  void acknowledge(uint64_t stored_below);
  /// Notice a server that went away and ask (again) for the session to be resumed.
  void watchServer();
  void beginResume(const std::string& why);
  /// Adds a line for takeMessages; beyond kMessagesKept unread lines, only counted (and the
  /// count said as one more line).
  void message(std::string text);
  static constexpr std::size_t kMessagesKept = 256;
  /// Counts a refusal in `refused`; true for the first kRefusalsSaid, which are said
  /// (message), so that a flood is counted rather than said line by line.
  static bool firstFew(std::atomic<uint64_t>& refused);
  static constexpr uint64_t kRefusalsSaid = 8;
  /// A model (`what`: a JointModel or its k-nearest-neighbour samples) refused: counted in
  /// models_rejected, said for the first few (firstFew).
  void modelRejected(const std::string& what, uint32_t version, const std::string& why);
  void pollModels();
  void pollEvents();
  void pollDirectForces();

  loop::HapticLoop& loop_;
  dds::Participant participant_;
  dds::Topics topics_;
  dds::Writer<telehand_msg_DeviceState> device_writer_;
  dds::Writer<telehand_msg_RecordChunk> chunk_writer_;
  dds::Writer<telehand_msg_SessionCommand> command_writer_;
  dds::Reader<telehand_msg_JointModel> model_reader_;
  dds::Reader<telehand_msg_SessionStatus> status_reader_;
  dds::Reader<telehand_msg_SessionEvent> event_reader_;
  dds::Reader<telehand_msg_DirectForce> direct_reader_;
  DeviceStateDeadband deadband_;

  uint64_t client_id_;
  /// Commands come from the main thread (PHASE, MARK, CLOSE) and the link thread (resume):
  /// each takes its own number.
  std::atomic<uint32_t> request_seq_{0};
  uint64_t session_id_ = 0;
  uint64_t chunk_seq_ = 0;
  std::vector<telehand_msg_DeviceState> chunk_;
  std::deque<std::vector<telehand_msg_DeviceState>> unsent_;  // chunks the server has not taken
  // Recovery (docs/recovery.md). Sent chunks stay in retained_ until SessionStatus says
  // they are stored; when the server goes away (no acknowledgement for kAckTimeout, or a
  // SUSPENDED status) the link asks every kResumeEvery for the session to be resumed, keeps
  // everything meanwhile, and sends the new server what its record lacks.
  static constexpr auto kAckTimeout = std::chrono::seconds(4);
  static constexpr auto kResumeEvery = std::chrono::seconds(1);
  static constexpr std::size_t kRetainInMemory = 600;           // chunks: 60 s at 1 kHz
  static constexpr uint64_t kRetainOnDisk = uint64_t{4} << 30;  // bytes: about 3.5 h more
  SpillQueue retained_;
  std::optional<SpillQueue::Chunk> resending_;  // taken from retained_, not yet written
  std::size_t resend_left_ = 0;  // retained chunks still to send again after a resume
  bool resuming_ = false;
  bool resume_refused_ = false;
  ResumeRequests resume_requests_;
  std::chrono::steady_clock::time_point last_ack_{}, next_resume_{};
  uint64_t stored_below_ = 0;
  uint64_t close_to_ = 0;  // the server the CLOSE went to (0: not sent)
  std::optional<CloseResult> closed_;
  std::chrono::steady_clock::time_point chunk_started_;
  std::atomic<bool> running_{false};
  std::thread thread_;
  LinkStats stats_;
  SampleDigest record_digest_;  // the link thread's
  std::mutex messages_mu_;
  std::vector<std::string> messages_;
  uint64_t messages_dropped_ = 0;    // under messages_mu_: lines past kMessagesKept
  std::vector<std::string> scores_;  // under messages_mu_
  std::string lesson_plan_;
  OpenRequest opened_;  // what the session was opened with (asked again on a resume)
  std::string opened_case_;
  uint32_t model_version_ = 0;
  std::optional<JointModelParams> pending_model_;  // taken but not yet in the loop's ring
  // Data-driven models: a STIFFNESS_KNN JointModel waits for the KnnModel of its version.
  dds::CaptureTopics capture_topics_;
  dds::Writer<telehand_msg_SessionFile> file_writer_;
  dds::Reader<telehand_msg_KnnModel> knn_reader_;
  struct KnnReceived {
    uint32_t version = 0;
    std::unique_ptr<const KnnTorqueModel> model;  // null: rejected, for `why`
    std::string why;
  };
  std::optional<KnnReceived> knn_samples_;
  std::optional<JointModelParams> waiting_knn_;
  /// Every k-NN model the loop may still read (in its ring, held by its proxy, or pending
  /// here); the others are freed here, never on the loop's thread.
  KnnKeeper knn_kept_;
  uint64_t models_pushed_ = 0;  // models handed to the loop's ring
  /// Reader history of SessionStatus and JointModel per session (the topics keep the last
  /// one per session): samples from other writers (forgeries, which fromServer() drops)
  /// share the session's instance, and with a history of 1 they could push the server's
  /// CLOSED or newest model out before this link takes it.
  static constexpr int32_t kServerTopicHistory = 256;
};

}  // namespace telehand::client::link
