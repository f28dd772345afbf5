// QoS profiles against docs/design.md's "Data over DDS" table.
#include <gtest/gtest.h>

#include "telehand/protocol/dds.h"

namespace telehand::dds {
namespace {

void expectHistory(const Qos& q, dds_history_kind_t kind, int32_t depth) {
  const auto [k, d] = q.history();
  EXPECT_EQ(k, kind);
  if (kind == DDS_HISTORY_KEEP_LAST) {
    EXPECT_EQ(d, depth);
  }
}

dds_duration_t deadlineOf(const Qos& q) {
  dds_duration_t d = 0;
  if (!dds_qget_deadline(q.get(), &d)) return -1;
  return d;
}

TEST(Qos, DeviceStateIsBestEffortKeepLast1VolatileWithDeadline) {
  const Qos q = qos::deviceState();
  EXPECT_EQ(q.reliabilityKind(), DDS_RELIABILITY_BEST_EFFORT);
  EXPECT_EQ(q.durabilityKind(), DDS_DURABILITY_VOLATILE);
  expectHistory(q, DDS_HISTORY_KEEP_LAST, 1);
  EXPECT_EQ(deadlineOf(q), DDS_MSECS(100));
}

TEST(Qos, DeviceStateReaderOnlyDeepensTheHistory) {
  const Qos q = qos::deviceStateReader(256);
  EXPECT_EQ(q.reliabilityKind(), DDS_RELIABILITY_BEST_EFFORT);
  EXPECT_EQ(q.durabilityKind(), DDS_DURABILITY_VOLATILE);
  expectHistory(q, DDS_HISTORY_KEEP_LAST, 256);
  EXPECT_EQ(deadlineOf(q), DDS_MSECS(100));
}

TEST(Qos, JointModelIsReliableTransientLocalKeepLast1) {
  const Qos q = qos::jointModel();
  EXPECT_EQ(q.reliabilityKind(), DDS_RELIABILITY_RELIABLE);
  EXPECT_EQ(q.durabilityKind(), DDS_DURABILITY_TRANSIENT_LOCAL);
  expectHistory(q, DDS_HISTORY_KEEP_LAST, 1);
}

TEST(Qos, HandStateIsBestEffortKeepLast1) {
  const Qos q = qos::handState();
  EXPECT_EQ(q.reliabilityKind(), DDS_RELIABILITY_BEST_EFFORT);
  EXPECT_EQ(q.durabilityKind(), DDS_DURABILITY_VOLATILE);
  expectHistory(q, DDS_HISTORY_KEEP_LAST, 1);
}

TEST(Qos, SessionCommandIsReliable) {
  const Qos q = qos::sessionCommand();
  EXPECT_EQ(q.reliabilityKind(), DDS_RELIABILITY_RELIABLE);
  EXPECT_EQ(q.durabilityKind(), DDS_DURABILITY_VOLATILE);
  expectHistory(q, DDS_HISTORY_KEEP_ALL, 0);
}

TEST(Qos, SessionStatusIsReliableTransientLocal) {
  const Qos q = qos::sessionStatus();
  EXPECT_EQ(q.reliabilityKind(), DDS_RELIABILITY_RELIABLE);
  EXPECT_EQ(q.durabilityKind(), DDS_DURABILITY_TRANSIENT_LOCAL);
  expectHistory(q, DDS_HISTORY_KEEP_LAST, 1);
}

TEST(Qos, SessionEventIsReliableTransientLocalKeepLastN) {
  const Qos q = qos::sessionEvent(32);
  EXPECT_EQ(q.reliabilityKind(), DDS_RELIABILITY_RELIABLE);
  EXPECT_EQ(q.durabilityKind(), DDS_DURABILITY_TRANSIENT_LOCAL);
  expectHistory(q, DDS_HISTORY_KEEP_LAST, 32);
  expectHistory(qos::sessionEvent(), DDS_HISTORY_KEEP_LAST, 64);
}

TEST(Qos, RecordChunkIsReliableKeepAllUnlimited) {
  const Qos q = qos::recordChunk();
  EXPECT_EQ(q.reliabilityKind(), DDS_RELIABILITY_RELIABLE);
  EXPECT_EQ(q.durabilityKind(), DDS_DURABILITY_VOLATILE);
  expectHistory(q, DDS_HISTORY_KEEP_ALL, 0);
  int32_t samples = 0, instances = 0, per_instance = 0;
  ASSERT_TRUE(dds_qget_resource_limits(q.get(), &samples, &instances, &per_instance));
  EXPECT_EQ(samples, DDS_LENGTH_UNLIMITED);
  EXPECT_EQ(per_instance, DDS_LENGTH_UNLIMITED);
  // Reliable writes may block while the server catches up, rather than drop records.
  dds_reliability_kind_t kind{};
  dds_duration_t max_blocking = 0;
  ASSERT_TRUE(dds_qget_reliability(q.get(), &kind, &max_blocking));
  EXPECT_GT(max_blocking, 0);
}

TEST(Qos, LatencyProbeTravelsLikeDeviceState) {
  const Qos probe = qos::latencyProbe();
  const Qos state = qos::deviceState();
  EXPECT_EQ(probe.reliabilityKind(), state.reliabilityKind());
  EXPECT_EQ(probe.durabilityKind(), state.durabilityKind());
  EXPECT_EQ(probe.history(), state.history());
  EXPECT_EQ(deadlineOf(probe), deadlineOf(state));
}

TEST(Qos, CopiesAreIndependent) {
  Qos a = qos::jointModel();
  Qos b = a;
  b.bestEffort().keepLast(5);
  EXPECT_EQ(a.reliabilityKind(), DDS_RELIABILITY_RELIABLE);
  expectHistory(a, DDS_HISTORY_KEEP_LAST, 1);
  EXPECT_EQ(b.reliabilityKind(), DDS_RELIABILITY_BEST_EFFORT);
  expectHistory(b, DDS_HISTORY_KEEP_LAST, 5);
  Qos c;
  c = b;
  expectHistory(c, DDS_HISTORY_KEEP_LAST, 5);
}

TEST(Qos, UnsetPolicyIsAnError) {
  const Qos empty;
  EXPECT_THROW(empty.reliabilityKind(), DdsError);
  EXPECT_THROW(empty.durabilityKind(), DdsError);
  EXPECT_THROW(empty.history(), DdsError);
}

}  // namespace
}  // namespace telehand::dds
