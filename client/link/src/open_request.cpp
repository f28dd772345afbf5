#include "telehand/client/link/open_request.h"

namespace telehand::client::link {

void describeOpen(const OpenRequest& req, telehand_msg_SessionCommand& cmd) {
  cmd.mode = req.mode;
  cmd.direct_force = req.direct_force;
  copyString(cmd.case_name, req.case_name);
  copyString(cmd.user, req.user);
  copyString(cmd.text, "");
  cmd.follow_session = req.follow_session;
  cmd.stiffness = req.stiffness;
  cmd.lesson_id = req.lesson_id;
  cmd.technique = req.technique;
}

void describeResume(const OpenRequest& req, const std::string& opened_case, uint64_t last_seq,
                    telehand_msg_SessionCommand& cmd) {
  cmd.last_seq = last_seq;
  cmd.direct_force = req.direct_force;
  copyString(cmd.case_name, opened_case);
  copyString(cmd.user, "");
  copyString(cmd.text, "");
}

}  // namespace telehand::client::link
