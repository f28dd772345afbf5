#pragma once
/// What a client asks a server for when it opens a session, and the SessionCommand OPENs
/// that carry it: the first one, and those that ask a server to resume the session after
/// its server went away (docs/recovery.md).
#include <cstdint>
#include <string>

#include "telehand/protocol/wire.h"

namespace telehand::client::link {

struct OpenRequest {
  telehand_msg_SessionMode mode = telehand_msg_MODE_MOBILIZATION;
  std::string case_name = "healthy";
  std::string user = "student";
  uint64_t follow_session = 0;  ///< render this capture session's live fit
  telehand_msg_StiffnessKind stiffness = telehand_msg_STIFFNESS_CUBIC;
  bool direct_force = false;  ///< baseline: the server computes the force
  uint64_t lesson_id = 0;     ///< MODE_LESSON: the lesson to run
  /// MODE_CAPTURE: what is captured (a massage session is MODE_MASSAGE).
  telehand_msg_Technique technique = telehand_msg_TECHNIQUE_MOBILIZATION;
};

/// Fills `cmd` (an OPEN from sessionCommand) with the session `req` asks for.
void describeOpen(const OpenRequest& req, telehand_msg_SessionCommand& cmd);

/// Fills `cmd` (an OPEN from sessionCommand naming the session) as a request to resume the
/// session that `req` opened: the server takes mode, case and user from its record, and
/// renders as the first OPEN asked (a direct-mode session gets its DirectForce from the
/// server that resumes it). `opened_case` is the case the first server opened the session on,
/// `last_seq` the last sample sent.
void describeResume(const OpenRequest& req, const std::string& opened_case, uint64_t last_seq,
                    telehand_msg_SessionCommand& cmd);

}  // namespace telehand::client::link
