#pragma once
/// The session record: every sample a client sent and every event, per session.
#include <cstdint>
#include <functional>
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
  uint64_t rejected = 0;          ///< samples stored flagged invalid (non-finite fields)
  /// Who opened it: the DDS participant's GUID (under DDS Security, derived from its
  /// authenticated certificate), and the identity's name where known. '' before schema 3.
  std::string owner;
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

class SessionStore {
 public:
  virtual ~SessionStore() = default;
  /// New session with a fresh id, larger than any the store has held.
  virtual uint64_t createSession(const SessionInfo& info) = 0;
  /// Store samples; a sequence number already stored is ignored. `valid` false marks a
  /// sample whose non-finite fields must not be trusted. Returns how many were new.
  virtual uint64_t appendSamples(uint64_t session_id, std::span<const Sample> samples,
                                 std::span<const uint8_t> valid) = 0;
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
  /// Where the record lives, for people.
  virtual std::string location() const = 0;
};

}  // namespace telehand::server::store
