#pragma once
/// One open session: who opened it and on what case, the joint model it renders (and the
/// k-nearest-neighbour models that model may use), and its parts: the live stream, the
/// record, the hand and, for captures and their followers, the live fit's fan-out.
#include <algorithm>
#include <cstdint>
#include <deque>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "telehand.h"
#include "telehand/config/config.h"
#include "telehand/core/joint_model.h"
#include "telehand/core/knn_model.h"
#include "telehand/server/session/capture_fanout.h"
#include "telehand/server/session/hand_runner.h"
#include "telehand/server/session/lesson_run.h"
#include "telehand/server/session/live_stream.h"
#include "telehand/server/session/recorder.h"
#include "telehand/server/session/replay.h"
#include "telehand/server/session/session_context.h"

namespace telehand::server::session {

/// The model a session on `patient` opens with (version 1; a replay of its record starts
/// there too, without a guide: Session::startReplay).
JointModelParams openingModel(const PatientCase& patient);

/// A session's SessionStatus from its record's row (what a server that does not run it can
/// say: recovered, suspended, closed as interrupted).
telehand_msg_SessionStatus statusOf(const store::SessionInfo& info, telehand_msg_SessionState state,
                                    uint64_t client_id, uint32_t request_seq,
                                    const std::string& location);

class Session {
 public:
  Session(SessionContext& ctx, const store::SessionInfo& info,
          const telehand_msg_SessionCommand& cmd, const PatientCase& patient,
          const sim::HandModel* hand, const sim::HandSimConfig& hand_config, int64_t now_ns);
  Session(const Session&) = delete;
  Session& operator=(const Session&) = delete;

  /// Make `next` the session's model: the next version, the session's drift correction kept
  /// (the grip on the finger did not change with the stiffness), in the hand and the direct
  /// renderer, published. `knn`: the data-driven model `next.knn` points at, held while
  /// anything here can still render it.
  void adoptModel(JointModelParams next, std::shared_ptr<const KnnTorqueModel> knn);
  void publishModel();
  void publishStatus(telehand_msg_SessionState state);

  /// A live sample of this session. The hand steps to it at once, or (hand_deferred) when
  /// stepHand() gets to it.
  void onLive(const Sample& d, int64_t now_ns);
  /// Step the hand to the live samples waiting for it, in order, until they are done (true)
  /// or the steady clock reaches `deadline_ns` (false: the rest wait for the next turn).
  bool stepHand(int64_t deadline_ns, int64_t now_ns);
  /// Step the hand to every live sample waiting for it (before anything reads or changes the
  /// hand on the session's behalf: a command, the close).
  void flushHand(int64_t now_ns) { stepHand(INT64_MAX, now_ns); }
  std::size_t handPending() const noexcept { return hand_queue_.size(); }
  /// Live samples the hand did not step to, thinned out of a full queue (an overloaded server).
  uint64_t handSkipped() const noexcept { return hand_skipped_; }
  /// An exploration phase begins on the hand (HandRunner::beginExploration), its count of
  /// samples stepped over from now.
  void beginExploration(const std::string& phase);
  /// The exploration under way ends (HandRunner::endExploration), with the samples the hand
  /// stepped over during it.
  void endExploration(uint64_t client, int64_t now_ns);
  /// Recorded samples of this session (`valid` per sample): the live fit, then the record.
  void onRecord(std::vector<Sample>&& samples, std::vector<uint8_t>&& valid, int64_t now_ns);
  /// Periodic work of its own: rate, due HandState, store retries.
  void tick(int64_t now_ns);
  /// A recovering joint: republish its range once a second when it has grown enough.
  void recoverIfDue(int64_t now_ns);
  /// Report the link's rates and the outcome, close the record, publish CLOSED. False when the
  /// record would not take the close (a store error, said as an event): nothing is published,
  /// and the caller closes the record later with `closed_ns` and `expected`.
  bool close(const std::string& state, int64_t now_ns);
  int64_t closed_ns = 0;  ///< the wall time close() closed the record at
  /// A lesson run's or a replay's PHASE command (docs/lessons.md); errors go out as events.
  void onPhase(const telehand_msg_SessionCommand& cmd, int64_t now_ns);
  /// A TAKEOVER (docs/lessons.md "Take-over"): the guided trials follow `source`'s live
  /// movement from now on (nullptr: the demonstration again). `who` names the requester for
  /// the record. Refused with an event unless this is a lesson run whose lesson allows it.
  void onTakeover(const telehand_msg_SessionCommand& cmd, const Session* source,
                  const std::string& who, int64_t now_ns);
  /// Replay session `source` of the record as this session's HandState (a replay session's
  /// whole content, or a lesson's watch phase); throws Error when it cannot be read.
  void startReplay(uint64_t source, const JointModelParams& model, double speed, int64_t now_ns);

  SessionContext& ctx;
  store::SessionInfo info;
  uint64_t client_id = 0;
  uint32_t request_seq = 0;    // the OPEN this session answers
  uint64_t owner = 0;          // the participant that opened it (Origin::participant), 0: unknown
  std::string owner_identity;  // its Origin::identity (DDS Security), empty without
  uint64_t seq_high = 0;       // highest sequence number taken, live or recorded
  bool have_seq = false;
  int files = 0;          // SessionFiles kept
  int foreign_marks = 0;  // MARKs kept from participants other than the owner (supervisors)
  telehand_msg_SessionMode mode = telehand_msg_MODE_MOBILIZATION;
  PatientCase patient;
  JointModelParams params;
  JointModel model{params};
  int64_t opened_ns = 0;
  // closing
  bool closing = false;
  uint64_t expected = 0;
  /// The record's rows of sequence numbers below `expected`, counted when the session ends
  /// (SessionManager::recordComplete); unset, the recorder's count stands for it. "Missing" is
  /// what this lacks of `expected`: rows of other sequence numbers do not make up for them.
  std::optional<uint64_t> stored_of_expected;
  uint64_t storedOfExpected() const noexcept {
    return stored_of_expected.value_or(recorder.recorded());
  }
  int64_t recount_ns = 0;  // pool: when the record's own count is read next while closing
  /// How long a closing session waits for the samples its record lacks: a grace after the
  /// CLOSE, put off by another grace whenever samples still arrive (a client's backlog sent
  /// after a resume can outlast one grace on a loaded server), up to a cap.
  struct CloseWait {
    int64_t deadline_ns = 0;
    int64_t grace_ns = 0;
    int64_t cap_ns = 0;  // 0: never put off
    /// A CLOSE (the first sets the cap, `graces` graces from now; a repeated one waits anew).
    void closeAsked(int64_t now_ns, int64_t grace, int64_t graces, bool first) noexcept {
      if (first) cap_ns = now_ns + grace * graces;
      grace_ns = grace;
      deadline_ns = std::min(now_ns + grace, cap_ns);
    }
    /// Samples arrived while closing.
    void samplesCame(int64_t now_ns) noexcept {
      if (cap_ns > deadline_ns)
        deadline_ns = std::max(deadline_ns, std::min(now_ns + grace_ns, cap_ns));
    }
    bool due(int64_t now_ns) const noexcept { return now_ns >= deadline_ns; }
  } close_wait;

  /// The hand steps in SessionManager::tick, within its slice, rather than with each live
  /// sample (SessionManager::setHandSlice).
  bool hand_deferred = false;

  LiveStream live;
  Recorder recorder;
  HandRunner hand;
  CaptureFanout capture;
  std::unique_ptr<LessonRun> lesson;  // MODE_LESSON
  std::unique_ptr<Replay> replay;     // MODE_REPLAY, or a lesson's watch phase

  /// Refused TAKEOVERs said as events (and kept in the record): anyone may ask, so a flood of
  /// asks is counted (ManagerStats::bad_commands) past this many, not written row by row.
  static constexpr int kMaxTakeoverRefusals = 16;

 private:
  /// The session's own model with the guide of `authority` (0: none), adopted and published:
  /// the demonstration's path, or under a take-over the taking-over session's latest.
  void setGuide(double authority, int64_t now_ns);
  /// The guide's targets from the taking-over session's latest record (kTakeoverWindow
  /// samples), nullopt (and an event when the reason changed) when they cannot be derived.
  std::optional<technique::Targets> takeoverTargets(int64_t now_ns);
  /// Under a take-over, during a guided trial: follow the taking-over session's movement
  /// (every kTakeoverRefreshNs, adopted when its path or period changed noticeably).
  void followTakeover(int64_t now_ns);
  void announceTakeover(const technique::Targets& t, int64_t now_ns);
  /// The replay (if any) ends; the session's own hand numbers its HandStates on from it.
  void endReplay();
  /// A lesson's demonstration ended before its end (`why`: what ended it): the record says
  /// how much of it was seen; then endReplay().
  void cutReplay(const std::string& why, int64_t now_ns);
  void recover(int64_t now_ns);
  /// Free the k-NN models nothing here can render any more (the model, the hand and the
  /// direct renderer's current, fading-out and waiting versions).
  void releaseKnn();

  static constexpr uint64_t kTakeoverWindow = 4000;             // samples (4 s at 1 kHz)
  static constexpr int64_t kTakeoverRefreshNs = 2'000'000'000;  // 2 s
  static constexpr int kMaxTakeovers = 32;                      // requests per run
  static constexpr double kTakeoverPathDeg = 1.5;               // a path moved this far is adopted
  static constexpr double kTakeoverPeriodChange = 0.05;         // so is a period changed by 5 %
  uint64_t takeover_source_ = 0;    // the session leading the guide (0: the demonstration)
  int takeovers_ = 0;               // TAKEOVER requests taken
  int takeover_refusals_ = 0;       // refused TAKEOVERs so far (kMaxTakeoverRefusals)
  double guide_authority_ = 0.0;    // the guided trial's under way (0: none)
  int64_t next_takeover_ns_ = 0;    // next refresh of the taken-over guide
  uint64_t takeover_last_seq_ = 0;  // the source's last sample the guide was derived up to
  std::string takeover_problem_;    // why the last derivation failed ('' : it did not)

  static constexpr int64_t kAckPeriodNs = 500'000'000;    // SessionStatus.stored_below
  static constexpr int64_t kHeartbeatNs = 1'000'000'000;  // a status at least this often
  int64_t next_ack_ns_ = 0;
  int64_t last_status_ns_ = 0;  // the last acknowledgement or heartbeat
  uint64_t acked_below_ = 0;

  /// Step the hand to one live sample (`steps` 1 ms steps) and adopt a drift correction.
  void stepTo(const Sample& d, const PerFinger<Vec3>& grip, uint64_t steps, bool coded,
              int64_t now_ns);
  struct PendingStep {
    Sample d;
    PerFinger<Vec3> grip;
    uint64_t steps = 1;
    bool coded = false;
  };
  std::deque<PendingStep> hand_queue_;  // live samples the deferred hand has yet to step to
  uint64_t hand_skipped_ = 0;
  uint64_t exploration_skipped_from_ = 0;  // hand_skipped_ when the exploration began

  const sim::HandModel* hand_model_;
  sim::HandSimConfig hand_config_;
  int64_t next_recovery_check_ns_ = 0;
  std::unique_ptr<JointProxy> direct_;  // direct mode: the server renders the force
  uint64_t direct_sent_ = 0;
  std::vector<std::shared_ptr<const KnnTorqueModel>> knn_held_;
  const KnnTorqueModel* direct_knn_ = nullptr;       // the direct renderer's current model's
  const KnnTorqueModel* direct_knn_prev_ = nullptr;  // and the one it may be fading out
};

}  // namespace telehand::server::session
