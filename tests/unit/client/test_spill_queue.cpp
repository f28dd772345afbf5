// The client's unacknowledged record chunks (client/link/spill_queue.h): first in, first out
// across memory and the spill file, forgotten once acknowledged, bounded on disk.
#include <gtest/gtest.h>

#include <filesystem>

#include "telehand/client/link/spill_queue.h"
#include "telehand/core/error.h"

namespace telehand::client::link {
namespace {

SpillQueue::Chunk chunkOf(uint64_t first, std::size_t n) {
  SpillQueue::Chunk c(n);
  for (std::size_t i = 0; i < n; ++i) {
    c[i].seq = first + i;
    c[i].mcp_angles_rad[0] = 0.001 * static_cast<double>(first + i);
  }
  return c;
}

class SpillQueueTest : public ::testing::Test {
 protected:
  std::string dir_ = ::testing::TempDir() + "/telehand-spill";
};

TEST_F(SpillQueueTest, KeepsOrderAcrossMemoryAndDisk) {
  SpillQueue q(3, 1 << 20, dir_);
  for (uint64_t k = 0; k < 10; ++k) q.push(chunkOf(100 * k, 100));
  EXPECT_EQ(q.size(), 10u);
  EXPECT_EQ(q.chunksOnDisk(), 7u);
  EXPECT_EQ(q.samples(), 1000u);
  EXPECT_GT(q.bytesOnDisk(), 7u * 100u * sizeof(telehand_msg_DeviceState));
  SpillQueue::Chunk c;
  for (uint64_t k = 0; k < 10; ++k) {
    ASSERT_TRUE(q.pop(c));
    ASSERT_EQ(c.size(), 100u);
    EXPECT_EQ(c.front().seq, 100 * k);
    EXPECT_EQ(c.back().seq, 100 * k + 99);
    EXPECT_DOUBLE_EQ(c[42].mcp_angles_rad[0], 0.001 * static_cast<double>(100 * k + 42));
  }
  EXPECT_FALSE(q.pop(c));
  EXPECT_TRUE(q.empty());
  EXPECT_EQ(q.droppedSamples(), 0u);
}

TEST_F(SpillQueueTest, ForgetsWhatTheServerAcknowledged) {
  SpillQueue q(2, 1 << 20, dir_);
  for (uint64_t k = 0; k < 6; ++k) q.push(chunkOf(100 * k, 100));
  q.forgetBelow(250);  // chunks 0 and 1 are stored; chunk 2 only in part: kept whole
  EXPECT_EQ(q.size(), 4u);
  q.forgetBelow(100);  // an older acknowledgement changes nothing
  EXPECT_EQ(q.size(), 4u);
  SpillQueue::Chunk c;
  ASSERT_TRUE(q.pop(c));
  EXPECT_EQ(c.front().seq, 200u);
  q.forgetBelow(600);
  EXPECT_TRUE(q.empty());
  EXPECT_EQ(q.samples(), 0u);
  // Used again after it emptied: the file starts over.
  q.push(chunkOf(600, 10));
  q.push(chunkOf(610, 10));
  q.push(chunkOf(620, 10));
  EXPECT_EQ(q.chunksOnDisk(), 1u);
  ASSERT_TRUE(q.pop(c));
  EXPECT_EQ(c.front().seq, 600u);
}

TEST_F(SpillQueueTest, AFullFileDropsTheOldestAndCountsThem) {
  const uint64_t one = 8 + 100 * sizeof(telehand_msg_DeviceState);
  SpillQueue q(1, 3 * one, dir_);
  for (uint64_t k = 0; k < 8; ++k) q.push(chunkOf(100 * k, 100));
  EXPECT_EQ(q.chunksOnDisk(), 3u);
  EXPECT_EQ(q.size(), 4u);
  EXPECT_EQ(q.droppedSamples(), 400u);
  SpillQueue::Chunk c;
  ASSERT_TRUE(q.pop(c));
  EXPECT_EQ(c.front().seq, 400u);  // 0..399 were dropped, the rest kept in order
}

TEST_F(SpillQueueTest, ADirectoryThatCannotHoldTheFileIsNamed) {
  SpillQueue q(1, 1 << 20, "/proc/telehand-no-such-dir");
  q.push(chunkOf(0, 10));
  try {
    q.push(chunkOf(10, 10));
    FAIL() << "no error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("/proc/telehand-no-such-dir"), std::string::npos)
        << e.what();
  }
}

}  // namespace
}  // namespace telehand::client::link
