// libFuzzer target: a KnnModel from the network (CDR through Cyclone's deserializer, with
// a sequence of fuzzed length) into fromWire, as the client's link thread builds the
// data-driven model before the loop may render it.
// Properties: a refusal names a reason; an accepted model holds every wire sample (at most
// kMaxKnnSamples), each finite with its angles within ±π, with k in [1, 64], and answers
// queries near its samples with finite torques.
#include <cmath>
#include <cstdlib>
#include <numbers>
#include <string>

#include "cdr_input.h"
#include "telehand/core/knn_model.h"
#include "telehand/protocol/wire.h"

using namespace telehand;

using fuzz::check;

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, std::size_t size) {
  fuzz::CdrSample<telehand_msg_KnnModel> in(telehand_msg_KnnModel_desc);
  if (!in.read(data, size)) return 0;
  const telehand_msg_KnnModel& k = in.get();
  std::string why;
  const auto model = fromWire(k, &why);
  if (!model) {
    check(!why.empty());
    return 0;
  }
  check(model->size() == k.samples._length && model->size() <= kMaxKnnSamples);
  check(model->options().k >= 1 && model->options().k <= 64);
  for (const auto& p : model->samples()) {
    check(allFinite(p.angles_rad) && allFinite(p.torque_nm));
    check(p.angles_rad.cwiseAbs().maxCoeff() <= static_cast<double>(std::numbers::pi_v<float>));
  }
  // Query at (up to) the first few samples and at the origin. Every sample torque is a
  // finite float, so their mean is finite too.
  check(allFinite(model->torqueNm(Vec3::Zero())));
  for (std::size_t i = 0; i < model->size() && i < 4; ++i) {
    const Vec3 t = model->torqueNm(model->samples()[i].angles_rad);
    check(allFinite(t));
  }
  return 0;
}
