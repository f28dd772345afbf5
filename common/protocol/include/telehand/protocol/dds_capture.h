#pragma once
/// Topics of capture sessions and data-driven models: a capture's device and calibration
/// files (client -> server) and the samples behind a k-nearest-neighbour JointModel
/// (server -> clients). Kept apart from dds.h's core set; same RAII types.
#include "telehand/protocol/dds.h"

namespace telehand::dds {

template <>
struct TopicTraits<telehand_msg_SessionFile> {
  static const dds_topic_descriptor_t* descriptor() { return &telehand_msg_SessionFile_desc; }
};
template <>
struct TopicTraits<telehand_msg_KnnModel> {
  static const dds_topic_descriptor_t* descriptor() { return &telehand_msg_KnnModel_desc; }
};

namespace topic {
inline constexpr const char* kSessionFile = "telehand_SessionFile";
inline constexpr const char* kKnnModel = "telehand_KnnModel";
}  // namespace topic

namespace qos {
/// Reliable, keep-all, volatile: every file reaches the record once.
inline Qos sessionFile() {
  Qos q;
  q.reliable().keepAll().volatileDurability();
  return q;
}
/// As JointModel: reliable, transient-local, keep-last 1 per session (a late follower gets
/// the current samples).
inline Qos knnModel() { return jointModel(); }
}  // namespace qos

struct CaptureTopics {
  explicit CaptureTopics(const Participant& p)
      : session_file(p, topic::kSessionFile), knn_model(p, topic::kKnnModel) {}
  Topic<telehand_msg_SessionFile> session_file;
  Topic<telehand_msg_KnnModel> knn_model;
};

}  // namespace telehand::dds
