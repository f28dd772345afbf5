#include "sample_fields.h"

#include <sstream>

#include "telehand/server/store/store.h"

namespace telehand::server::store {

namespace detail {

const std::vector<std::string>& fieldNames() {
  static const std::vector<std::string> names = [] {
    std::vector<std::string> n = {"seq", "t_ns", "model_version", "flags"};
    const char* axes[3] = {"alpha", "beta", "gamma"};
    for (const char* a : axes) n.push_back(std::string(a) + "_rad");
    for (const char* a : axes) n.push_back("tau_" + std::string(a) + "_nm");
    const char* xyz[3] = {"x", "y", "z"};
    const char* wxyz[4] = {"w", "x", "y", "z"};
    for (const std::string f : {"thumb", "index"}) {
      for (const char* c : xyz) n.push_back(f + "_p" + c + "_m");
      for (const char* c : wxyz) n.push_back(f + "_q" + c);
      for (int i = 1; i <= 4; ++i) n.push_back(f + "_fsr" + std::to_string(i) + "_n");
      n.push_back(f + "_tangential_n");
      n.push_back(f + "_normal_n");
      for (const char* c : xyz) n.push_back(f + "_cmd" + c + "_n");
    }
    n.push_back("passivity_energy_j");
    n.push_back("passivity_damping_ns_per_m");
    for (const std::string f : {"thumb", "index"}) {  // record schema 7: the massage's web
      n.push_back(f + "_depth_m");
      for (const char* c : xyz) n.push_back(f + "_tissue" + c + "_n");
    }
    return n;
  }();
  return names;
}

}  // namespace detail

const std::vector<std::string>& sampleColumns() {
  static const std::vector<std::string> names = [] {
    std::vector<std::string> n = detail::fieldNames();
    n.push_back("valid");
    return n;
  }();
  return names;
}

std::string sampleCsvRow(const Sample& s, bool valid) {
  std::ostringstream o;
  o.precision(9);
  detail::visitFields(s, [&](const auto& v) { o << v << ','; });
  o << (valid ? 1 : 0);
  return o.str();
}

}  // namespace telehand::server::store
