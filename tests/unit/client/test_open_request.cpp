// The OPENs a client sends: the first one carries the request, and the one that asks a server
// to resume the session after a failover asks for the same rendering.
#include <gtest/gtest.h>

#include <cstring>

#include "telehand/client/link/open_request.h"

namespace telehand::client::link {
namespace {

TEST(OpenRequest, TheFirstOpenCarriesTheRequest) {
  OpenRequest req;
  req.mode = telehand_msg_MODE_CAPTURE;
  req.case_name = "stiff";
  req.user = "ana";
  req.follow_session = 17;
  req.stiffness = telehand_msg_STIFFNESS_KNN;
  req.direct_force = true;
  req.technique = telehand_msg_TECHNIQUE_MASSAGE;
  telehand_msg_SessionCommand cmd = sessionCommand(telehand_msg_CMD_OPEN, 99, 1, 0);
  describeOpen(req, cmd);
  EXPECT_EQ(cmd.kind, telehand_msg_CMD_OPEN);
  EXPECT_EQ(cmd.mode, telehand_msg_MODE_CAPTURE);
  EXPECT_STREQ(cmd.case_name, "stiff");
  EXPECT_STREQ(cmd.user, "ana");
  EXPECT_EQ(cmd.follow_session, 17u);
  EXPECT_EQ(cmd.stiffness, telehand_msg_STIFFNESS_KNN);
  EXPECT_TRUE(cmd.direct_force);
  EXPECT_EQ(cmd.technique, telehand_msg_TECHNIQUE_MASSAGE);
}

TEST(OpenRequest, AResumeAsksTheNewServerForTheSameRendering) {
  for (const bool direct : {true, false}) {
    SCOPED_TRACE(direct ? "direct" : "model");
    OpenRequest req;
    req.direct_force = direct;
    telehand_msg_SessionCommand first = sessionCommand(telehand_msg_CMD_OPEN, 99, 1, 0);
    describeOpen(req, first);
    telehand_msg_SessionCommand resume = sessionCommand(telehand_msg_CMD_OPEN, 99, 7, 4242);
    describeResume(req, "healthy", 12345, resume);
    EXPECT_EQ(resume.direct_force, first.direct_force)
        << "the server that resumes a direct-mode session must send DirectForce";
    EXPECT_EQ(resume.direct_force, direct);
    EXPECT_EQ(resume.session_id, 4242u) << "a resume names its session";
    EXPECT_EQ(resume.request_seq, 7u);
    EXPECT_EQ(resume.last_seq, 12345u);
    EXPECT_STREQ(resume.case_name, "healthy");
    EXPECT_STREQ(resume.user, "") << "the server takes the user from its record";
  }
}

}  // namespace
}  // namespace telehand::client::link
