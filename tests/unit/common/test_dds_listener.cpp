// dds::DataListener: samples reach the callback without a waitset or a thread of ours, and
// after detach() (or destruction) the callback is never called again.
#include <gtest/gtest.h>
#include <unistd.h>

#include <atomic>
#include <string>
#include <vector>

#include "telehand/protocol/dds.h"

namespace telehand::dds {
namespace {

using Sample = telehand_msg_DeviceState;

/// One participant with a latency-probe writer and reader on a partition of this process's own,
/// in a domain of its own (ids 100..199 by PID), on loopback.
struct Loop {
  explicit Loop(const std::string& name) : participant(options(name)) {}
  static Options options(const std::string& name) {
    Options o;
    o.domain = 100 + static_cast<uint32_t>(getpid() % 100);
    o.config = TELEHAND_DEPLOY_DIR "/cyclonedds/loopback.xml";
    o.partition = "listener-" + std::to_string(getpid()) + "-" + name;
    return o;
  }
  Participant participant;
  Topic<Sample> topic{participant, topic::kLatencyPing};
  Reader<Sample> reader{participant, topic, qos::latencyProbe()};
  Writer<Sample> writer{participant, topic, qos::latencyProbe()};
};

Sample sample(uint64_t seq) {
  Sample x{};
  x.session_id = 7;
  x.seq = seq;
  x.source_time_ns = static_cast<int64_t>(seq) * 1000;
  return x;
}

TEST(DataListener, EverySampleWrittenReachesTheCallbackWithItsContents) {
  Loop loop("contents");
  std::vector<uint64_t> seqs;
  seqs.reserve(100);
  uint64_t calls = 0, mismatched = 0;
  DataListener listener(loop.reader.handle(), [&]() noexcept {
    ++calls;
    loop.reader.take([&](const Sample& x, const dds_sample_info_t&) {
      seqs.push_back(x.seq);
      if (x.session_id != 7 || x.source_time_ns != static_cast<int64_t>(x.seq) * 1000) {
        ++mismatched;
      }
    });
  });
  for (uint64_t i = 0; i < 100; ++i) ASSERT_EQ(loop.writer.write(sample(i)), DDS_RETCODE_OK);
  listener.detach();  // the callback's writes are visible after it

  // A reader in this process gets a local writer's samples during the write: keep-last 1
  // loses none when each is taken before the next is written.
  ASSERT_EQ(seqs.size(), 100u);
  for (uint64_t i = 0; i < 100; ++i) EXPECT_EQ(seqs[i], i);
  EXPECT_EQ(mismatched, 0u);
  EXPECT_GE(calls, 100u);
}

TEST(DataListener, DetachEndsTheCallsAndLeavesTheSamplesInTheReader) {
  Loop loop("detach");
  std::atomic<uint64_t> taken{0};
  DataListener listener(loop.reader.handle(), [&]() noexcept {
    taken += loop.reader.take([](const Sample&, const dds_sample_info_t&) {});
  });
  ASSERT_EQ(loop.writer.write(sample(1)), DDS_RETCODE_OK);
  listener.detach();
  listener.detach();  // twice is harmless
  EXPECT_EQ(taken.load(), 1u);

  ASSERT_EQ(loop.writer.write(sample(2)), DDS_RETCODE_OK);
  EXPECT_EQ(taken.load(), 1u);
  // The sample written after detach() waits in the reader for whoever takes it next.
  uint64_t seq = 0;
  EXPECT_EQ(loop.reader.take([&](const Sample& x, const dds_sample_info_t&) { seq = x.seq; }), 1u);
  EXPECT_EQ(seq, 2u);
}

TEST(DataListener, DestructionDetaches) {
  Loop loop("destroy");
  uint64_t calls = 0;
  {
    DataListener listener(loop.reader.handle(), [&]() noexcept {
      ++calls;
      loop.reader.take([](const Sample&, const dds_sample_info_t&) {});
    });
    ASSERT_EQ(loop.writer.write(sample(1)), DDS_RETCODE_OK);
  }
  const uint64_t before = calls;
  EXPECT_GE(before, 1u);
  ASSERT_EQ(loop.writer.write(sample(2)), DDS_RETCODE_OK);
  EXPECT_EQ(calls, before);
}

TEST(DataListener, ABadReaderIsNamedInTheError) {
  try {
    DataListener listener(dds_entity_t{123456789}, []() noexcept {});
    FAIL() << "a listener on an entity that does not exist was accepted";
  } catch (const DdsError& e) {
    EXPECT_NE(std::string(e.what()).find("data-available listener"), std::string::npos) << e.what();
  }
}

}  // namespace
}  // namespace telehand::dds
