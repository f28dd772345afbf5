#pragma once
/// SessionStore on PostgreSQL (libpq): one record that several servers write and anyone reads
/// at the same time, beside the embedded SqliteStore. The same tables and columns as SQLite's
/// schema 5 (docs/design.md "Records"), in the schema the connection's search_path names
/// first (`public` unless the URI says otherwise), marked by a table of its own:
/// telehand_schema holds one row, application_id 0x54484e44 ("THND") and the schema version.
///
/// Opening read-write creates the tables in an empty schema, in one transaction, under an
/// advisory lock (two programs opening it at once create them once); a schema of a newer
/// version, one with the marker but not the tables, and one holding tables that are not a
/// telehand record are refused unmodified, the message naming the database. Read-only opens
/// write nothing, not even the schema (the session is set default_transaction_read_only).
///
/// appendSamples sends a batch as one binary COPY, a statement of its own (all of it stored, or
/// none). When some of its sequence numbers are stored already (a client's resend after an
/// outage: rare), the COPY fails whole and the batch goes again as INSERTs of binary arrays
/// (unnest, 8192 samples per statement, one transaction) ON CONFLICT DO NOTHING. Either way a
/// sequence number already stored, or repeated in the batch, is ignored (the first copy kept),
/// as SQLite does. Reads page through
/// the (session_id, seq) key, 8192 samples per round trip, so a long record never sits in
/// memory whole and the callback may use the store.
///
/// One connection, used by one thread at a time (calls are serialised). A connection that
/// broke is re-established on the next call, and after a failed attempt calls fail at once
/// for 5 s before the next; the failed calls threw StoreError and the server's recorder
/// retries what it could not store. Unless the URI says otherwise, an attempt to connect gives
/// up after 5 s and a connection whose server stopped answering after about 10 s.
#include <chrono>
#include <cstdint>
#include <mutex>
#include <set>
#include <string>

#include "telehand/server/store/store.h"

struct pg_conn;

namespace telehand::server::store {

class PgStore final : public SessionStore {
 public:
  /// The schema version this program writes and reads (SQLite's user_version, the same).
  static constexpr int kSchemaVersion = 7;

  /// `uri`: libpq's connection URI, postgresql://[user[:password]@][host][:port][/dbname]
  /// [?param=value&...] (postgres:// too). StoreError naming the URI, without its password,
  /// when it is malformed, the server cannot be reached or the database is refused.
  explicit PgStore(const std::string& uri, Mode mode = Mode::kReadWrite);
  ~PgStore() override;
  PgStore(const PgStore&) = delete;
  PgStore& operator=(const PgStore&) = delete;

  uint64_t createSession(const SessionInfo& info) override;
  uint64_t appendSamples(uint64_t session_id, std::span<const Sample> samples,
                         std::span<const uint8_t> valid) override;
  /// Every batch in one COPY (one statement: all stored or none). When some sample was
  /// stored before (a unique violation) or a batch repeats a sequence number, batch by batch.
  std::vector<BatchResult> appendSampleBatches(std::span<const SampleBatch> batches) override;
  /// A connection of its own to the same database (the schema is already there).
  std::unique_ptr<SessionStore> openWriter() override;
  void appendEvent(uint64_t session_id, const EventRecord& e) override;
  void appendReach(uint64_t session_id, const Reach& r) override;
  std::vector<Reach> reaches(uint64_t session_id) override;
  void closeSession(uint64_t session_id, int64_t ended_ns, uint64_t samples_expected,
                    const std::string& state) override;
  std::vector<SessionInfo> listSessions() override;
  std::optional<SessionInfo> session(uint64_t session_id) override;
  void forEachSample(uint64_t session_id,
                     const std::function<void(const Sample&, bool)>& fn) override;
  std::vector<EventRecord> events(uint64_t session_id) override;
  void appendFile(uint64_t session_id, const SessionFile& f) override;
  std::vector<SessionFile> files(uint64_t session_id) override;
  void forEachSampleIn(uint64_t session_id, uint64_t first_seq, uint64_t last_seq,
                       const std::function<void(const Sample&, bool)>& fn) override;
  uint64_t countSamples(uint64_t session_id, uint64_t first_seq, uint64_t last_seq) override;
  std::optional<uint64_t> nextStoredSeq(uint64_t session_id, uint64_t first_seq) override;
  uint64_t storedPrefix(uint64_t session_id) override;
  std::optional<Extent> extent(uint64_t session_id) override;
  uint64_t createLesson(const LessonInfo& lesson) override;
  std::vector<LessonInfo> listLessons() override;
  std::optional<LessonInfo> lesson(uint64_t lesson_id) override;
  void setSessionLesson(uint64_t session_id, uint64_t lesson_id) override;
  uint64_t sessionLesson(uint64_t session_id) override;
  void appendTrial(const TrialRecord& t) override;
  std::vector<TrialRecord> trials(uint64_t session_id) override;
  /// Also holds, on this connection, the pool member's advisory lock (its name's): the
  /// record sees at once that a server whose process died is gone (its connection closed),
  /// without waiting for its lease to run out (docs/pool.md, "A member's connection").
  std::vector<uint64_t> poolHeartbeat(const std::string& server, uint64_t sessions,
                                      int64_t lease_ns) override;
  void poolLeave(const std::string& server) override;
  std::vector<PoolMember> poolMembers() override;
  std::string poolAssign(const std::string& open_key) override;
  PoolClaim poolClaim(uint64_t session_id, const std::string& server,
                      const std::string& open_key = {}) override;
  std::vector<uint64_t> poolOrphans() override;
  std::string poolOwner(uint64_t session_id) override;
  void putCheckpoint(uint64_t session_id, const Checkpoint& c) override;
  std::optional<Checkpoint> checkpoint(uint64_t session_id) override;
  /// The URI with its password replaced by ***.
  std::string location() const override { return location_; }

 private:
  enum class Layout { kEmpty, kTakeover, kPool, kCurrent };
  void connect();
  void prepare();
  Layout inspect();
  void createSchema();
  void readSamples(uint64_t session_id, int64_t first, int64_t last,
                   const std::function<void(const Sample&, bool)>& fn);
  std::optional<uint64_t> copySamples(std::span<const SampleBatch> batches);
  uint64_t insertSamples(uint64_t session_id, std::span<const Sample> samples,
                         std::span<const uint8_t> valid);

  /// The condition "the pool member named by the SQL expression `server` holds its lock on a
  /// connection of its own": "true" until this store's connection has lasted a lease after
  /// its first heartbeat, so that after the database restarted, the servers reconnecting one
  /// after another do not take each other's sessions.
  std::string connectedSql(const std::string& server) const;

  std::string uri_;  ///< as given, password and all: never shown
  std::string location_;
  Mode mode_;
  std::recursive_mutex mutex_;
  pg_conn* conn_ = nullptr;
  /// After a failed attempt to connect again, calls fail at once until retry_at_.
  static constexpr std::chrono::seconds kRetryPause{5};
  std::chrono::steady_clock::time_point retry_at_{};
  std::string last_error_;
  /// The members whose lock this connection holds (reset with the connection), when to try
  /// again for one another connection held, and from when the others' connections count (a
  /// lease after this connection's first heartbeat).
  std::set<std::string> member_locks_;
  std::chrono::steady_clock::time_point member_lock_retry_at_{};
  std::chrono::steady_clock::time_point trust_connections_at_ =
      std::chrono::steady_clock::time_point::max();
  bool prepared_ = false;
  bool web_columns_ = true;  ///< false: a read-only record of schema 5 or 6 (web reads 0)
  bool pool_tables_ = true;  ///< false: a read-only record of schema 5 (no pool tables)  ///< the
                             ///< sample statements are prepared on this connection
};

/// `uri` with the password of its user part and any password parameter replaced by ***: what
/// messages and logs may show of a connection URI.
std::string redactUri(const std::string& uri);

}  // namespace telehand::server::store
