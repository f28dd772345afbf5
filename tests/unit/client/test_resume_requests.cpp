// The resume's requests: a late answer to any of them counts, nothing else does.
#include <gtest/gtest.h>

#include <cstdint>

#include "telehand/client/link/resume_requests.h"

namespace telehand::client::link {
namespace {

TEST(ResumeRequests, NothingAnswersBeforeARequestWasSent) {
  ResumeRequests r;
  EXPECT_FALSE(r.answers(0));
  EXPECT_FALSE(r.answers(1));
  r.begin();
  EXPECT_FALSE(r.answers(0));
}

TEST(ResumeRequests, ALateAnswerToAnEarlierRequestOfTheSameResumeCounts) {
  ResumeRequests r;
  r.begin();
  for (uint32_t seq = 17; seq <= 21; ++seq) r.sent(seq);  // five seconds unanswered
  for (uint32_t seq = 17; seq <= 21; ++seq) EXPECT_TRUE(r.answers(seq)) << seq;
  EXPECT_FALSE(r.answers(16)) << "sent before this resume began";
  EXPECT_FALSE(r.answers(22)) << "not sent yet";
}

TEST(ResumeRequests, ANewResumeForgetsTheRequestsOfTheOneBefore) {
  ResumeRequests r;
  r.begin();
  r.sent(5);
  r.sent(6);
  r.begin();
  EXPECT_FALSE(r.answers(5));
  EXPECT_FALSE(r.answers(6));
  r.sent(9);
  EXPECT_FALSE(r.answers(6));
  EXPECT_TRUE(r.answers(9));
}

TEST(ResumeRequests, SequenceNumbersThatWrapAreComparedFromTheFirst) {
  ResumeRequests r;
  r.begin();
  r.sent(UINT32_MAX - 1);
  r.sent(UINT32_MAX);
  r.sent(0);
  r.sent(1);
  EXPECT_TRUE(r.answers(UINT32_MAX - 1));
  EXPECT_TRUE(r.answers(0));
  EXPECT_TRUE(r.answers(1));
  EXPECT_FALSE(r.answers(2));
  EXPECT_FALSE(r.answers(UINT32_MAX - 2));
}

}  // namespace
}  // namespace telehand::client::link
