#pragma once
/// SessionStore on SQLite in WAL mode: the embedded default. One writer (the server), any
/// number of readers (telehand-records) at the same time.
///
/// Schema 5: one row per sample, one column per field (the CSV names of sampleColumns()),
/// marked in the SQLite header by application_id 0x54484e44 ("THND") and user_version 5.
/// Opening read-write creates the schema in an empty file and migrates an older one (schema 1:
/// one blob per sample; 2: no owners; 3: no lessons; 4: no take-over) in place, in one
/// transaction; a file of a newer schema, or an SQLite file that is not a telehand record, is
/// refused unmodified.
#include <sqlite3.h>

#include <memory>

#include "telehand/server/store/store.h"

namespace telehand::server::store {

class SqliteStore : public SessionStore {
 public:
  /// Creates the file and its directory (read-write) or opens an existing one (read-only);
  /// StoreError naming the path on failure or refusal.
  explicit SqliteStore(const std::string& path, Mode mode = Mode::kReadWrite);
  ~SqliteStore() override;
  void releaseMemory() override;
  /// Bytes the connection's page cache holds now (what releaseMemory gives back).
  std::size_t cacheBytes() const;

  uint64_t createSession(const SessionInfo& info) override;
  uint64_t appendSamples(uint64_t session_id, std::span<const Sample> samples,
                         std::span<const uint8_t> valid) override;
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
  std::optional<Extent> extent(uint64_t session_id) override;
  uint64_t createLesson(const LessonInfo& lesson) override;
  std::vector<LessonInfo> listLessons() override;
  std::optional<LessonInfo> lesson(uint64_t lesson_id) override;
  void setSessionLesson(uint64_t session_id, uint64_t lesson_id) override;
  uint64_t sessionLesson(uint64_t session_id) override;
  void appendTrial(const TrialRecord& t) override;
  std::vector<TrialRecord> trials(uint64_t session_id) override;
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
  std::string location() const override { return path_; }

 private:
  enum class Layout { kEmpty, kBlob, kColumns, kOwner, kLessons, kTakeover, kPool, kCurrent };
  void addPoolTables();
  void addWebColumns();
  bool hasWebColumns();
  bool web_columns_ = true;  // the samples table has schema 7's web columns
  /// BEGIN IMMEDIATE ... COMMIT around fn (ROLLBACK when it throws).
  template <class F>
  auto transaction(F&& fn);
  Layout inspect();
  void migrateFromBlobs();
  void addOwnerColumn();
  bool hasOwnerColumn();
  bool hasTable(const char* name);
  void addLessonTables();
  void addTakeoverColumn();
  bool hasTakeoverColumn();
  void exec(const char* sql);
  sqlite3_stmt* prepare(const char* sql);

  std::string path_;
  sqlite3* db_ = nullptr;
  sqlite3_stmt* insert_sample_ = nullptr;
};

}  // namespace telehand::server::store
