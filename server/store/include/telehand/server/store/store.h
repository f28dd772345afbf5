#pragma once
/// The session record: every sample a client sent and every event, per session. Two
/// implementations keep it in the same tables: SqliteStore (a file, the embedded default)
/// and PgStore (a PostgreSQL database several servers can share); openStore()
/// (open_store.h) picks one from what `--db` says.
#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "telehand/core/sample.h"

namespace telehand::server::store {

struct SessionInfo {
  uint64_t id = 0;
  std::string user;
  std::string case_name;
  std::string mode;
  std::string state;       ///< active, closed, abandoned
  int64_t started_ns = 0;  ///< wall clock
  int64_t ended_ns = 0;
  uint64_t samples = 0;           ///< distinct sequence numbers stored
  uint64_t samples_expected = 0;  ///< what the client said it sent (0 = unknown)
  /// Of the samples stored, those below samples_expected: rows past what the client said
  /// it sent do not make up for missing ones.
  uint64_t samples_below_expected = 0;
  uint64_t rejected = 0;  ///< samples stored flagged invalid (non-finite fields)
  /// Who opened it: the DDS participant's GUID (under DDS Security, derived from its
  /// authenticated certificate), and the identity's name where known. '' before schema 3.
  std::string owner;
  /// Ended: neither running (active) nor waiting for its client (suspended).
  bool ended() const noexcept { return state != "active" && state != "suspended"; }
  /// Samples the client said it sent that the record lacks (0 when it never said).
  uint64_t missing() const noexcept {
    return samples_expected > samples_below_expected ? samples_expected - samples_below_expected
                                                     : 0;
  }
};

struct EventRecord {
  int64_t time_ns = 0;
  std::string kind;
  std::string text;
};

/// A file kept with a session (a capture's device and thimble calibration files).
struct SessionFile {
  std::string name;
  std::string content;
};

/// A lesson (docs/lessons.md): a demonstration session, the patient case and technique it
/// was made on, the targets derived from it and how the student's run is organised.
struct LessonInfo {
  uint64_t id = 0;
  std::string name;
  uint64_t demo_session = 0;
  std::string case_name;
  std::string technique = "mobilization";
  /// Feedback schedule: concurrent, terminal, faded or self (self-requested).
  std::string schedule = "terminal";
  int guided = 2;          ///< guided trials (authority full, then partial, ... down to none)
  int attempts = 3;        ///< free attempts after them
  double trial_s = 8.0;    ///< length of each trial
  bool assessment = true;  ///< exploration baseline before and reassessment after
  /// A supervisor may take over the demonstration: their own MF-2 session's live movement
  /// becomes the guided trials' guide (docs/lessons.md "Take-over").
  bool takeover = false;
  std::string targets;  ///< the derived targets, as server/lesson encodes them
  int64_t created_ns = 0;
};

/// One scored trial of a lesson run (or a single oscillation's scores live as events).
struct TrialRecord {
  uint64_t session_id = 0;
  int index = 0;           ///< 1-based, in the order they ran
  std::string phase;       ///< guided, attempt
  double authority = 0.0;  ///< the guide's authority during it
  uint64_t first_seq = 0, last_seq = 0;
  double overall = 0.0;  ///< 0..100
  std::string figures;   ///< the scores, as server/lesson encodes them
};

/// A server of a pool sharing one record (docs/pool.md), as the record sees it.
struct PoolMember {
  std::string server;
  uint64_t sessions = 0;       ///< sessions it owns that are active or suspended
  int64_t lease_until_ns = 0;  ///< the record's clock
};

/// The outcome of a claim on a session (SessionStore::poolClaim).
struct PoolClaim {
  bool won = false;
  std::string previous;                 ///< its owner before ('' : none)
  int64_t previous_lease_until_ns = 0;  ///< when that owner's lease ran out (0: no lease)
  /// false: that owner's lease still ran, but its connection to the record had closed (its
  /// process is gone; PostgreSQL only, PgStore::poolHeartbeat)
  bool previous_connected = true;
  int64_t now_ns = 0;  ///< the record's clock at the claim
};

/// The last saved state of a session's hand (the server's checkpoint).
struct Checkpoint {
  uint64_t seq = 0;  ///< the last sample it had taken
  int64_t time_ns = 0;
  std::string data;
};

class SessionStore {
 public:
  /// Read-write: the record's schema is created (or brought up to date) on opening.
  /// Read-only: nothing is written, not even the schema; a record that is not there, or not
  /// a telehand record, is refused.
  enum class Mode { kReadWrite, kReadOnly };

  virtual ~SessionStore() = default;
  /// New session with a fresh id, larger than any the store has held.
  virtual uint64_t createSession(const SessionInfo& info) = 0;
  /// Store samples; a sequence number already stored is ignored. `valid` false marks a
  /// sample whose non-finite fields must not be trusted. Returns how many were new.
  virtual uint64_t appendSamples(uint64_t session_id, std::span<const Sample> samples,
                                 std::span<const uint8_t> valid) = 0;
  /// One session's samples in a write of several sessions' (appendSampleBatches).
  struct SampleBatch {
    uint64_t session_id = 0;
    std::span<const Sample> samples;
    std::span<const uint8_t> valid;
  };
  /// What became of one batch: how many samples were new, or why none was stored.
  struct BatchResult {
    bool stored = false;
    uint64_t added = 0;
    std::string error;  ///< when not stored (the store's message)
  };
  /// appendSamples for several sessions at once, a result per batch: a server's serve loop
  /// writes what one round took of all its sessions together. By default one write per
  /// batch, each failing on its own; a store may send them as one (PostgreSQL: one COPY).
  virtual std::vector<BatchResult> appendSampleBatches(std::span<const SampleBatch> batches);
  /// Another connection to the same record, for a thread that writes samples beside the one
  /// using this (BatchWriter); nullptr where the store has no use for one (SQLite: one
  /// writer at a time, so a second connection would only wait for the first).
  virtual std::unique_ptr<SessionStore> openWriter() { return nullptr; }
  /// Gives back what the connection keeps in memory for speed (SQLite: its page cache),
  /// once the server has no session left: pages cached while sessions came and went sit
  /// among the blocks those sessions freed and keep them resident. Nothing stored changes.
  virtual void releaseMemory() {}
  virtual void appendEvent(uint64_t session_id, const EventRecord& e) = 0;
  /// Exploration result: the angle reached in one direction of one axis and the force there.
  struct Reach {
    std::string phase;      ///< baseline, reassessment
    std::string direction;  ///< flexion, extension, abduction, adduction, supination, pronation
    double angle_deg = 0.0;
    double force_n = 0.0;  ///< force holding the joint at that moment (N at the lever arm)
  };
  virtual void appendReach(uint64_t session_id, const Reach& r) = 0;
  virtual std::vector<Reach> reaches(uint64_t session_id) = 0;
  virtual void closeSession(uint64_t session_id, int64_t ended_ns, uint64_t samples_expected,
                            const std::string& state) = 0;
  virtual std::vector<SessionInfo> listSessions() = 0;
  virtual std::optional<SessionInfo> session(uint64_t session_id) = 0;
  /// Samples in sequence order.
  virtual void forEachSample(uint64_t session_id,
                             const std::function<void(const Sample&, bool valid)>& fn) = 0;
  virtual std::vector<EventRecord> events(uint64_t session_id) = 0;
  /// Keep a file with the session (same name again: replaced).
  virtual void appendFile(uint64_t session_id, const SessionFile& f) = 0;
  virtual std::vector<SessionFile> files(uint64_t session_id) = 0;
  /// Samples with first_seq <= seq <= last_seq, in sequence order.
  virtual void forEachSampleIn(uint64_t session_id, uint64_t first_seq, uint64_t last_seq,
                               const std::function<void(const Sample&, bool valid)>& fn) = 0;
  /// How many samples with first_seq <= seq <= last_seq the record holds (an index look-up).
  virtual uint64_t countSamples(uint64_t session_id, uint64_t first_seq, uint64_t last_seq) = 0;
  /// The lowest sequence number stored at or after first_seq (an index look-up), nullopt
  /// without one: a reader steps over a gap in the record at once.
  virtual std::optional<uint64_t> nextStoredSeq(uint64_t session_id, uint64_t first_seq) = 0;
  /// The stored prefix: every seq below it is in the record, and that seq is not (what a
  /// resumed session acknowledges at once). By default a binary search of countSamples; a
  /// store may answer in one query (PostgreSQL: one scan up to the first gap).
  virtual uint64_t storedPrefix(uint64_t session_id);
  /// The first and last sample of a session's record (by sequence number), nullopt without
  /// any: where a replay starts and ends, without reading what lies between.
  struct Extent {
    uint64_t first_seq = 0, last_seq = 0;
    int64_t first_time_ns = 0, last_time_ns = 0;
  };
  virtual std::optional<Extent> extent(uint64_t session_id) = 0;
  /// Lessons: a new one gets a fresh id.
  virtual uint64_t createLesson(const LessonInfo& lesson) = 0;
  virtual std::vector<LessonInfo> listLessons() = 0;
  virtual std::optional<LessonInfo> lesson(uint64_t lesson_id) = 0;
  /// A lesson run: the session that ran `lesson_id` (its trials are kept with it).
  virtual void setSessionLesson(uint64_t session_id, uint64_t lesson_id) = 0;
  /// The lesson a session ran, 0 if none.
  virtual uint64_t sessionLesson(uint64_t session_id) = 0;
  virtual void appendTrial(const TrialRecord& t) = 0;
  virtual std::vector<TrialRecord> trials(uint64_t session_id) = 0;

  // ---- A pool of servers on one record (docs/pool.md) -------------------------------------
  // A server's lease is a row with a time on the record's own clock (PostgreSQL's for a
  // shared database, the host's for an SQLite file several servers of one machine share);
  // the sessions it owns live as long as it renews it. Every change is one transaction, so
  // two servers never both win a session.

  /// Renew `server`'s lease until the record's now + `lease_ns`, with its load; returns the
  /// ids of the sessions the record says it owns (a server that was too slow to renew learns
  /// here which of its sessions another one took over).
  virtual std::vector<uint64_t> poolHeartbeat(const std::string& server, uint64_t sessions,
                                              int64_t lease_ns) = 0;
  /// A server that stops: its lease ends now (its sessions are suspended by then).
  virtual void poolLeave(const std::string& server) = 0;
  /// The servers whose lease runs, least loaded first (load: sessions owned that are active or
  /// suspended, plus OPENs assigned to it in the last 60 s that made no session yet).
  virtual std::vector<PoolMember> poolMembers() = 0;
  /// Assign the OPEN `open_key` to the least-loaded server whose lease runs (ties: by name),
  /// once: the first caller decides, later ones read the answer. Returns the server.
  virtual std::string poolAssign(const std::string& open_key) = 0;
  /// Make `server` the owner of `session_id` when nobody owns it, it does already, or its
  /// owner's lease has run out; `open_key` (if any) is the OPEN that made the session.
  virtual PoolClaim poolClaim(uint64_t session_id, const std::string& server,
                              const std::string& open_key = {}) = 0;
  /// Sessions active or suspended whose owner's lease has run out, or that have no owner.
  virtual std::vector<uint64_t> poolOrphans() = 0;
  /// The owner of a session ('' : none).
  virtual std::string poolOwner(uint64_t session_id) = 0;
  /// The hand's state of a session, replacing the one kept before.
  virtual void putCheckpoint(uint64_t session_id, const Checkpoint& c) = 0;
  virtual std::optional<Checkpoint> checkpoint(uint64_t session_id) = 0;

  /// Where the record lives, for people (a path, or a URI without its password).
  virtual std::string location() const = 0;
};

/// The sample columns, in record and CSV order (README "Records").
const std::vector<std::string>& sampleColumns();
/// One sample as CSV fields in sampleColumns() order.
std::string sampleCsvRow(const Sample& s, bool valid);

}  // namespace telehand::server::store
