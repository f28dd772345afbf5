#pragma once
/// The server's session logic, independent of DDS: opens and closes sessions on commands,
/// records what clients send, computes the decimated HandState from the shared joint model,
/// and reports bad input as events without disturbing other sessions.
#include <array>
#include <atomic>
#include <cstdint>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "telehand.h"
#include "telehand/config/config.h"
#include "telehand/core/joint_model.h"
#include "telehand/protocol/deadband.h"
#include "telehand/server/estimate/live_refit.h"
#include "telehand/server/session/drift.h"
#include "telehand/server/session/exploration.h"
#include "telehand/server/session/outbox.h"
#include "telehand/server/session/session_context.h"
#include "telehand/server/sim/hand_model.h"
#include "telehand/server/sim/hand_sim.h"
#include "telehand/server/store/batch_writer.h"
#include "telehand/server/store/store.h"

namespace telehand::server::session {

class Session;

using store::EventRecord;
using store::SessionFile;
using store::SessionInfo;
using store::SessionStore;

/// Who sent a message: the DDS participant behind the writer. ServerLink finds it from the
/// sample's publication handle; under DDS Security the GUID is bound to the participant's
/// authenticated certificate. `participant` 0: not known (callers without DDS, e.g. tests),
/// which no ownership check refuses.
struct Origin {
  uint64_t participant = 0;  ///< the participant's instance handle in this process
  std::string guid;          ///< its GUID, hex, as the record keeps it
  /// Under DDS Security, the identity behind the participant: the first 48 bits of its
  /// GUID, which the authentication plugin derives from the certificate's subject (the
  /// same for every participant of one identity). Empty without security.
  std::string identity;
  /// A network sender the link could not name: its writer had left (deleted, or its
  /// participant gone) before the sample was read, so Cyclone no longer knew it. Everything
  /// from it is refused: it could be anyone's. (A default Origin, participant 0 and not
  /// unknown, is a caller without DDS: tests and tools in this process.)
  bool unknown = false;
};

class SessionManager {
 public:
  /// With `hand`, every session runs the Bullet hand (server/sim) and HandState comes from
  /// it; without, from the shared joint model.
  SessionManager(SessionStore& store, Outbox& out, const ServerConfig& config,
                 const sim::HandModel* hand = nullptr);
  ~SessionManager();

  /// A session belongs to the participant that opened it: its CLOSE, MARK, samples, chunks
  /// and files are taken from that participant only; anyone else's are refused, counted
  /// (ManagerStats::refused) and reported as a security event at most once per 5 s per
  /// session.
  void onCommand(const telehand_msg_SessionCommand& cmd, int64_t now_ns, const Origin& from = {});
  /// Live stream: feeds HandState and link health.
  void onDeviceState(const telehand_msg_DeviceState& s, int64_t now_ns, const Origin& from = {});
  /// The same, already decoded.
  void onSample(const Sample& s, int64_t now_ns, const Origin& from = {});
  /// Record stream: every sample is stored once (and feeds a capture's live fit). Samples
  /// outside the sequence window (kSeqWindow of the session's highest) are refused.
  void onChunk(const telehand_msg_RecordChunk& c, int64_t now_ns, const Origin& from = {});
  /// A capture's device or calibration file: kept with the record, within the file limits.
  void onFile(const telehand_msg_SessionFile& f, int64_t now_ns, const Origin& from = {});
  /// Publish due HandStates, finish closing sessions, retry unstored samples.
  void tick(int64_t now_ns);
  /// Server shutdown (docs/recovery.md): nothing received is left unstored; a session
  /// whose CLOSE is under way is closed, every other one is suspended in the record (its
  /// client keeps what was not acknowledged and resumes it on the next server).
  void closeAll(int64_t now_ns);
  /// At start: every session the record holds as active or suspended (its server died or
  /// stopped) is announced SUSPENDED and waits server.resume_wait_s for its client to resume
  /// it (CMD_OPEN with its id), then is closed as interrupted with `missing` counting what
  /// the record lacks. Returns how many were found. `take_active` false (a record shared
  /// by several servers, PostgreSQL): sessions still active belong to a server that may be
  /// running; only suspended ones are taken.
  std::size_t recoverFromStore(int64_t now_ns, bool take_active = true);
  /// Serve as one server of a pool sharing the record (docs/pool.md), named `server` in it:
  /// the server renews its lease every kPoolHeartbeatNs, takes the OPENs the record assigns
  /// it (the least loaded), checkpoints its sessions' hands every kCheckpointNs, takes over
  /// the sessions of a server whose lease ran out (announcing them SUSPENDED, so that their
  /// clients resume them here at once, the hand from its checkpoint), lets go of a session
  /// another server took over, and keeps out of the other servers' sessions.
  void joinPool(const std::string& server);
  /// A server of a pool that stops: its lease ends at once (after closeAll()).
  void leavePool();
  bool pooled() const noexcept { return !pool_id_.empty(); }
  const std::string& poolId() const noexcept { return pool_id_; }
  static constexpr int64_t kPoolHeartbeatNs = 200'000'000;
  static constexpr int64_t kPoolLeaseNs = 1'000'000'000;
  /// How often telehand-server's lease thread renews the lease: ten chances within it, so
  /// that a renewal held up behind the record's other writers does not lose it.
  static constexpr int64_t kLeaseRenewNs = 100'000'000;
  /// The lease is renewed on a thread of its own (telehand-server), and only while the serve
  /// loop gets on: one that has handled nothing (no round, command or chunk) for this long is
  /// wedged, lets its lease run out, and the pool takes its sessions over.
  static constexpr int64_t kServeStallNs = 20'000'000'000;
  /// Counts the serve loop's rounds and the commands and chunks it handled; read from the
  /// lease's thread, which renews only while it grows.
  uint64_t progress() const noexcept { return progress_.load(std::memory_order_relaxed); }
  /// Pool: the lease's thread saw orphans in the record (a server's lease ran out): the serve
  /// loop runs its pool round at its next round rather than at its next heartbeat (safe from
  /// any thread; wake the loop after it).
  void claimSoon() noexcept { claim_soon_.store(true, std::memory_order_relaxed); }
  static constexpr int64_t kCheckpointNs = 500'000'000;
  /// Orphans one server claims per heartbeat: the others get their share of a dead one's.
  static constexpr int kMaxClaimsPerBeat = 2;

  /// Sessions found in the record that wait for their client.
  std::size_t suspendedSessions() const noexcept { return suspended_.size(); }

  std::size_t activeSessions() const noexcept { return sessions_.size(); }
  const ManagerStats& stats() const noexcept { return stats_; }

  /// Idle sessions (no data at all for this long) are closed as abandoned.
  static constexpr int64_t kIdleTimeoutNs = 30'000'000'000;
  /// A closing session waits server.close_grace_s for the samples its record lacks; each
  /// chunk that comes meanwhile puts that off by another grace, up to this many graces after
  /// the first CLOSE (a client's backlog after a resume, on a loaded server).
  static constexpr int64_t kMaxCloseGraces = 12;
  /// A recovering joint's range is republished when it has grown by this much.
  static constexpr double kRecoveryStepDeg = 0.5;
  /// Simulation steps one live sample may trigger (itself plus lost predecessors): 50 ms of
  /// device time, about 0.8 ms of CPU at 15.7 µs per pinched step (README, Performance).
  static constexpr uint64_t kMaxCatchUpSteps = 50;
  /// How the hand of sessions opened later is simulated.
  void setHandConfig(const sim::HandSimConfig& c) { hand_config_ = c; }
  /// Where the Bullet hands step (docs/design.md "Threads", docs/performance.md "Capacity").
  /// 0 (the manager's default, for callers in simulated time such as the teleoperation
  /// harness): each live sample steps its session's hand as it is taken. Otherwise
  /// the live samples wait in their session's queue and tick() steps the hands, session
  /// after session in turn, for at most `slice_ns` (steady clock) per call: taking and
  /// recording what arrives never waits for more than one slice of the hands, and hands
  /// short of CPU fall behind the live stream and then step over samples (every other one
  /// of a queue of kMaxHandQueue, counted in ManagerStats::hand_samples_skipped) while the
  /// record keeps every sample. telehand-server uses kHandSliceNs unless told otherwise
  /// (`--hand-slice-ms`).
  void setHandSlice(int64_t slice_ns);
  int64_t handSlice() const noexcept { return hand_slice_ns_; }
  /// The hands' budget with a slice: at most this share of the serving thread's wall time
  /// (0 < share <= 1) goes to stepping them. Hands short of it fall behind and step over
  /// samples; the thread sleeps rather than spend more, so that the record, the lease and
  /// the other processes on the machine (a pool's servers, the database) keep their CPU.
  void setHandShare(double share);
  double handShare() const noexcept { return hand_share_; }
  /// Samples to the record on a thread and a connection of their own, where the store offers
  /// one (SessionStore::openWriter: PostgreSQL): a round's samples are handed over and the
  /// loop goes on; they are acknowledged once written. False (the store has none): they
  /// stay on the serve loop. StoreError when the connection cannot be opened.
  bool writeSamplesOnThread();
  bool samplesOnThread() const noexcept { return writer_ != nullptr; }
  /// How long the serve loop may sleep before the hands can step again: 0 when live samples
  /// wait for their hand and the budget has time for them; -1 when no hand waits.
  int64_t handWaitNs(int64_t now_ns) const noexcept;
  /// Live samples waiting for their hand.
  bool handPending() const noexcept;
  static constexpr int64_t kHandSliceNs = 2'000'000;
  static constexpr double kHandShare = 0.75;
  /// Live samples one session's deferred hand may fall behind (100 ms at 1 kHz).
  static constexpr std::size_t kMaxHandQueue = 100;
  /// Steps one deadband-coded sample may trigger: the withheld samples it stands for, held
  /// at the last value received (zero-order hold). Beyond this the hand skips time.
  static constexpr uint64_t kMaxHeldSteps = 200;
  /// Unknown session ids remembered for rate-limited error events.
  static constexpr std::size_t kMaxUnknownIds = 1024;
  /// Events about bad commands said to one participant per 5 s (badCommand).
  static constexpr int kBadCommandEvents = 8;
  /// A drift correction this large (any axis, degrees) is reported as a SessionEvent.
  static constexpr double kDriftEventDeg = 1.0;
  /// Samples more than this many sequence numbers (10 min at 1 kHz) from the highest the
  /// session has taken are refused: a client's stream does not jump, a forgery might.
  static constexpr uint64_t kSeqWindow = 600'000;
  /// Owners of ended sessions remembered, for their late chunks (oldest forgotten first).
  static constexpr std::size_t kMaxEndedOwners = 4096;
  /// Marks one session keeps from participants other than its owner (supervisors).
  static constexpr int kMaxForeignMarks = 256;

 private:
  /// A new session, or (`resumed`) one the record holds, taken on again with the same id.
  void open(const telehand_msg_SessionCommand& cmd, int64_t now_ns, const Origin& from,
            const SessionInfo* resumed = nullptr);
  /// CMD_OPEN with a session id: its owner's client resumes it after its server went away.
  void resume(const telehand_msg_SessionCommand& cmd, int64_t now_ns, const Origin& from);
  /// A session of the record that will not be resumed: closed as interrupted, `missing`
  /// counting the sequence numbers below its last stored one that the record lacks.
  void closeUnresumed(uint64_t session_id, int64_t now_ns, const std::string& why);
  /// SessionStatus for a session of the record that no Session runs here.
  void publishRecordStatus(const SessionInfo& info, telehand_msg_SessionState state,
                           uint64_t client_id, uint32_t request_seq);
  void requestClose(const telehand_msg_SessionCommand& cmd, int64_t now_ns, const Origin& from);
  /// Whether the record holds every sequence number below what the session's client said it
  /// sent (Session::stored_of_expected set from the record).
  bool recordComplete(Session& s);
  /// A command that cannot be carried out: counted (ManagerStats::bad_commands) and said in an
  /// ERROR event to its client, at most kBadCommandEvents per participant per 5 s.
  void badCommand(uint64_t client_id, const Origin& from, const std::string& what, int64_t now_ns);
  /// True when `from` opened session `s` (or either is unknown).
  static bool owns(const Session& s, const Origin& from);
  /// True when `from` may act on session `s`; otherwise counts and reports the refusal.
  bool owns(Session& s, const Origin& from, const char* what, uint64_t count, int64_t now_ns);
  /// Refuse `what` for a session: counted, one security event per session per 5 s.
  /// `rate_key`: what the once-per-5-s limit counts by (default: the session; an OPEN's
  /// refusals count by their sender, so that each one hears of its own).
  void refuse(uint64_t session_id, uint64_t client_id, const std::string& what, uint64_t count,
              int64_t now_ns, std::optional<uint64_t> rate_key = std::nullopt);
  /// End a session: score its exploration, part it from its capture or followers, close it.
  void finish(Session& s, int64_t now_ns, const std::string& state);
  void event(uint64_t session_id, uint64_t client_id, telehand_msg_EventKind kind,
             const std::string& text, int64_t now_ns);
  /// Error about a session id nobody opened, at most once per id per 5 s.
  void unknownSession(uint64_t session_id, const std::string& what, int64_t now_ns);
  Session* find(uint64_t session_id);
  /// What this round took for every session, in one write (SessionStore::appendSampleBatches).
  void flushRecords();
  /// With no session left: frees the record side's reusable buffers and caches.
  void releaseRecordMemory();
  /// The writer thread's finished write: each session's outcome to its recorder.
  void landWrites();
  /// Pool: heartbeat, let go of sessions lost, claim orphans, checkpoint hands.
  void poolTick(int64_t now_ns);
  /// Pool: lets go of the sessions (open or suspended) that are not in `mine`, the ones the
  /// record says are this server's: another server took them over while this one's lease had
  /// run out.
  void letGoOfTakenSessions(std::vector<uint64_t> mine);
  /// Pool: a session this server just claimed from the record (its owner's lease ran out).
  void takeOver(uint64_t session_id, const store::PoolClaim& claim, int64_t now_ns);
  /// Pool: a session that no Session runs here and that this server does not wait for
  /// belongs to another server of the pool; what comes for it is none of this one's business.
  bool elsewhere(uint64_t session_id) const;

  SessionStore& store_;
  Outbox& out_;
  ServerConfig config_;
  const sim::HandModel* hand_;
  std::map<uint64_t, Session> sessions_;
  std::map<uint64_t, int64_t> unknown_reported_ns_;
  std::map<uint64_t, std::pair<int64_t, int>> bad_commands_by_;  // participant: window, events
  std::map<uint64_t, int64_t> refused_reported_ns_;  // per session id, bounded like unknown ids
  /// Owner of an ended session (GUID hex, NUL-terminated), in a ring of kMaxEndedOwners
  /// reserved at construction: remembering them allocates nothing per session.
  struct EndedOwner {
    uint64_t session_id = 0;
    std::array<char, 40> guid{};
  };
  /// Remembers a session's owner (ended here, suspended here awaiting its client, or looked
  /// up in the record for a late chunk) in the ring; an empty owner is remembered too (a
  /// session opened without DDS takes anyone's).
  void rememberOwner(uint64_t session_id, const std::string& owner);
  const EndedOwner* rememberedOwner(uint64_t session_id) const;
  std::vector<EndedOwner> ended_owners_;
  std::size_t ended_next_ = 0;  // where the next one goes (the oldest, once full)
  std::vector<std::pair<int64_t, uint64_t>> retiring_;  // (when, session id), in time order
  /// Closes the record would not take when their sessions ended: tried again every
  /// kOwedCloseEveryNs until it does, then CLOSED is published from the record.
  struct OwedClose {
    uint64_t session_id = 0;
    int64_t ended_ns = 0;
    uint64_t samples_expected = 0;
    std::string state;
    uint64_t client_id = 0;
  };
  std::vector<OwedClose> owed_closes_;
  int64_t next_owed_close_ns_ = 0;
  static constexpr int64_t kOwedCloseEveryNs = 1'000'000'000;
  static constexpr std::size_t kMaxOwedCloses = 4096;
  void closeOwed(int64_t now_ns, bool last_try);
  /// Whether the session ended here and its close is owed to the record.
  bool closeOwed(uint64_t session_id) const;
  /// Pool: whether this server still owns the session in the record (claimed again, which
  /// renews nothing another server holds); one another server took over is let go here.
  /// Without a pool, always.
  bool stillOurs(uint64_t session_id);
  // When the link's idle() freed what Cyclone frees later, on its garbage collector's thread:
  // settle() and a trim once that has run (0: none due).
  static constexpr int64_t kSettleNs = 500'000'000;
  int64_t settle_ns_ = 0;
  std::map<uint64_t, int64_t> suspended_;  // sessions of the record awaiting their client: deadline
  uint64_t event_seq_ = 0;
  ManagerStats stats_;
  estimate::LiveRefitOptions refit_options_;
  sim::HandSimConfig hand_config_;
  /// OPENs answered (sender, client id, request number -> session): a client asks again
  /// until answered, and a repeat gets the session it made, not another one. The last
  /// kMaxAnsweredOpens, in a ring reserved at construction: remembering them allocates
  /// nothing per session (each allocation outliving its session among the short-lived ones
  /// kept pages of the serving thread's heap resident after the sessions ended).
  struct AnsweredOpen {
    uint64_t client_id = 0;
    uint32_t request_seq = 0;
    uint64_t session_id = 0;
    std::array<char, 40> guid{};  // the sender's GUID, hex, NUL-terminated ("?": unknown)
  };
  std::vector<AnsweredOpen> answered_opens_;
  std::size_t answered_next_ = 0;  // where the next one goes (the oldest, once full)
  static constexpr std::size_t kMaxAnsweredOpens = 1024;
  int64_t hand_slice_ns_ = 0;  // 0: the hands step with each live sample
  uint64_t hand_cursor_ = 0;   // the session whose hand steps first in the next slice
  double hand_share_ = kHandShare;
  int64_t hand_credit_ns_ = 0;  // the hands' budget left (negative: overspent)
  int64_t hand_credit_at_ns_ = 0;
  void stepHands(int64_t now_ns);
  std::string pool_id_;  // '' : not in a pool
  int64_t last_beat_ns_ = 0;
  int64_t records_ns_ = 0;      // spent writing samples since the last heartbeat (flushRecords)
  uint64_t beat_progress_ = 0;  // progress() at the last heartbeat
  std::atomic<uint64_t> progress_{0};
  std::atomic<bool> claim_soon_{false};
  std::vector<store::SessionStore::SampleBatch> batches_;  // flushRecords', kept for reuse
  std::vector<Session*> batch_sessions_;
  std::unique_ptr<store::BatchWriter> writer_;  // writeSamplesOnThread
  std::vector<store::BatchWriter::Job> jobs_;   // its jobs, handed back and forth for reuse
  int64_t next_pool_ns_ = 0;
  int64_t next_checkpoint_ns_ = 0;
  SessionContext ctx_;  // for the sessions' parts: the members above
};

}  // namespace telehand::server::session
