// Device and thimble calibration files (TOML). Strict: unknown tables and keys, wrong types,
// non-finite or out-of-range values are ConfigErrors naming the file, line and key.
#include <toml++/toml.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <limits>
#include <set>
#include <sstream>
#include <utility>

#include "telehand/config/toml_reader.h"
#include "telehand/core/error.h"
#include "telehand/devices/mf2_device.h"
#include "telehand/devices/mf2_protocol.h"

namespace telehand::mf2 {

namespace {

using config::parseToml;
using config::rejectUnknownTables;
using Table = config::TomlTable;

std::string readText(const std::string& path, const char* what) {
  return config::readTextFile(path, what);
}

Quat quatFromRpyDeg(const std::array<double, 3>& rpy) {
  return Quat(Eigen::AngleAxisd(degToRad(rpy[2]), Vec3::UnitZ()) *
              Eigen::AngleAxisd(degToRad(rpy[1]), Vec3::UnitY()) *
              Eigen::AngleAxisd(degToRad(rpy[0]), Vec3::UnitX()));
}

constexpr double kMaxCountsPerRad = 1e7;

/// `keys`: where the file gives the values, for the messages ("'thumb.min_deg' etc. element
/// 2"; empty for the built-in description).
EncoderCalibration encoder(double counts_per_rad, double zero, double min_deg, double max_deg,
                           const std::string& origin, const std::string& what,
                           const std::string& keys = "") {
  const std::string at = keys.empty() ? "" : " (" + keys + ")";
  if (std::abs(counts_per_rad) < 1.0) {
    throw ConfigError(origin + ": " + what + " counts_per_rad must be at least 1 in magnitude" +
                      at);
  }
  if (!(min_deg < max_deg)) {
    throw ConfigError(origin + ": " + what + " range is empty: min_deg " +
                      config::formatNumber(min_deg) + " is not below max_deg " +
                      config::formatNumber(max_deg) + at);
  }
  // The wire carries counts as 32-bit integers: a zero and range whose counts do not fit
  // would make every packet a pose the linkage cannot take.
  const double reach =
      std::abs(zero) +
      std::abs(counts_per_rad) * std::max(std::abs(degToRad(min_deg)), std::abs(degToRad(max_deg)));
  if (reach > static_cast<double>(std::numeric_limits<int32_t>::max())) {
    throw ConfigError(origin + ": " + what + " zero_counts " + config::formatNumber(zero) +
                      " with its counts_per_rad and range reaches " + config::formatNumber(reach) +
                      " counts, past the 32-bit counts the device sends" + at);
  }
  EncoderCalibration e;
  e.counts_per_rad = counts_per_rad;
  e.zero_counts = static_cast<int64_t>(std::llround(zero));
  e.min_rad = degToRad(min_deg);
  e.max_rad = degToRad(max_deg);
  return e;
}

}  // namespace

Mf2Description defaultMf2() {
  Mf2Description d;
  d.name = "mf2";
  d.source =
      "built-in: link lengths chosen (the MF-2's are not public); see deploy/devices/mf2.toml";
  d.base_pivot_m = Vec3(-0.13, 0.0, -0.06);
  // 4096-line encoders in quadrature (16384 counts/rev) behind a 10:1 capstan: 26076 counts/rad.
  constexpr double kActuatorCpr = 16384.0 * 10.0 / (2.0 * kPi);
  // 1024-line encoders in quadrature on the gimbal axes: 651.9 counts/rad.
  constexpr double kGimbalCpr = 4096.0 / (2.0 * kPi);
  d.actuator_encoders[0] = encoder(kActuatorCpr, 0, -45, 45, "built-in", "base");
  d.max_torque_nm[0] = 1.2;
  for (int f = 0; f < 2; ++f) {
    FingerLinkage& l = d.fingers[f];
    l.yaw_pivot_m = Vec3(0.0, f == kThumb ? 0.03 : -0.03, 0.0);
    l.crank_half_spacing_m = 0.015;
    l.crank_m = {0.10, 0.10};
    l.distal_m = {0.12, 0.12};
    // Zero gimbal angles hold the thimble in its working orientation at the home pose
    // (the grip of a neutral MCP): thumb pad facing down, index pad facing up.
    l.gimbal_mount = f == kThumb ? quatFromRpyDeg({180.0, 0.0, 0.0}) : Quat::Identity();
    d.actuator_encoders[actuatorIndex(f, 0)] = encoder(kActuatorCpr, 0, -60, 60, "built-in", "yaw");
    d.actuator_encoders[actuatorIndex(f, 1)] =
        encoder(kActuatorCpr, 0, -90, 200, "built-in", "crank 1");
    d.actuator_encoders[actuatorIndex(f, 2)] =
        encoder(kActuatorCpr, 0, -90, 200, "built-in", "crank 2");
    for (int j = 0; j < 3; ++j) d.max_torque_nm[actuatorIndex(f, j)] = 0.6;
    d.gimbal_encoders[f][0] = encoder(kGimbalCpr, 0, -170, 170, "built-in", "gimbal 1");
    d.gimbal_encoders[f][1] = encoder(kGimbalCpr, 0, -80, 80, "built-in", "gimbal 2");
    d.gimbal_encoders[f][2] = encoder(kGimbalCpr, 0, -170, 170, "built-in", "gimbal 3");
    ThimbleCalibration& t = d.thimbles[f];
    t.serial = f == kThumb ? "built-in-thumb" : "built-in-index";
    t.source = "nominal: 12-bit ADC, 40 counts offset, 180 counts/N (22 N at saturation)";
    for (auto& s : t.fsr) s = FsrCalibration{40.0, 180.0, 4000.0, 10.0};
  }
  return d;
}

ThimbleCalibration parseThimbleCalibration(const std::string& text, const std::string& origin) {
  const toml::table root = parseToml(text, origin);
  rejectUnknownTables(root, {"thimble", "fsr1", "fsr2", "fsr3", "fsr4"}, origin);
  ThimbleCalibration c;
  Table th(root, "thimble", origin, true);
  c.serial = th.text("serial", "");
  c.source = th.text("source", "");
  c.stuck_samples =
      static_cast<uint32_t>(th.integer("stuck_samples", c.stuck_samples, 0, 1'000'000));
  th.rejectUnknown();
  if (c.serial.empty()) throw ConfigError(origin + ": 'thimble.serial' must be set");
  for (int i = 0; i < kFsrPerThimble; ++i) {
    const std::string name = "fsr" + std::to_string(i + 1);
    Table s(root, name, origin, true);
    FsrCalibration& f = c.fsr[i];
    // A 12-bit ADC reads 0..kFsrMaxRaw; the zero and the slope are the sensor's own (no
    // default stands for a calibration).
    constexpr double kMaxRaw = devices::proto::kFsrMaxRaw;
    constexpr double kUnset = std::numeric_limits<double>::quiet_NaN();
    f.zero_counts = s.number("zero_counts", kUnset, 0.0, kMaxRaw);
    f.counts_per_n = s.number("counts_per_n", kUnset, 1e-3, 1e6);
    f.saturation_counts = s.number("saturation_counts", f.saturation_counts, 0.0, kMaxRaw);
    f.floor_counts = s.number("floor_counts", f.floor_counts, -1.0, kMaxRaw);
    s.rejectUnknown();
    for (const auto& [key, v] :
         {std::pair{"zero_counts", f.zero_counts}, std::pair{"counts_per_n", f.counts_per_n}}) {
      if (std::isnan(v)) {
        throw ConfigError(origin + ": '" + name + "." + key +
                          "' must be set (the sensor's own calibration)");
      }
    }
    if (!(f.saturation_counts > f.zero_counts)) {
      throw ConfigError(origin + ": '" + name + ".saturation_counts' must exceed zero_counts");
    }
    if (!(f.floor_counts < f.zero_counts)) {
      throw ConfigError(origin + ": '" + name + ".floor_counts' must be below zero_counts");
    }
  }
  return c;
}

ThimbleCalibration loadThimbleCalibration(const std::string& path) {
  return parseThimbleCalibration(readText(path, "thimble calibration file"), path);
}

Mf2Description parseMf2Description(const std::string& text, const std::string& origin,
                                   const std::string& base_dir) {
  const toml::table root = parseToml(text, origin);
  rejectUnknownTables(root, {"device", "thumb", "index"}, origin);
  Mf2Description d = defaultMf2();
  d.path = origin;
  Table dev(root, "device", origin, true);
  d.name = dev.text("name", "");
  d.source = dev.text("source", "");
  const auto pivot = dev.numbers<3>(
      "base_pivot_m", {d.base_pivot_m.x(), d.base_pivot_m.y(), d.base_pivot_m.z()}, -1.0, 1.0);
  d.base_pivot_m = Vec3(pivot[0], pivot[1], pivot[2]);
  const double base_cpr = dev.number("base_counts_per_rad", d.actuator_encoders[0].counts_per_rad,
                                     -kMaxCountsPerRad, kMaxCountsPerRad);
  const double base_zero = dev.number("base_zero_counts", 0.0, -1e12, 1e12);
  const auto base_range = dev.numbers<2>("base_range_deg", {-45.0, 45.0}, -180.0, 180.0);
  d.actuator_encoders[0] =
      encoder(base_cpr, base_zero, base_range[0], base_range[1], origin, "device.base",
              "'device.base_counts_per_rad', 'base_zero_counts', 'base_range_deg'");
  d.max_torque_nm[0] = dev.number("base_max_torque_nm", d.max_torque_nm[0], 0.0, 10.0);
  dev.rejectUnknown();
  if (d.name.empty()) throw ConfigError(origin + ": 'device.name' must be set");

  for (int f = 0; f < 2; ++f) {
    const std::string name = f == kThumb ? "thumb" : "index";
    Table t(root, name, origin, true);
    FingerLinkage& l = d.fingers[f];
    const auto yaw = t.numbers<3>(
        "yaw_pivot_m", {l.yaw_pivot_m.x(), l.yaw_pivot_m.y(), l.yaw_pivot_m.z()}, -1.0, 1.0);
    l.yaw_pivot_m = Vec3(yaw[0], yaw[1], yaw[2]);
    l.crank_half_spacing_m = t.number("crank_half_spacing_m", l.crank_half_spacing_m, 0.0, 0.5);
    const auto crank = t.numbers<2>("crank_m", l.crank_m, 0.005, 1.0);
    const auto distal = t.numbers<2>("distal_m", l.distal_m, 0.005, 1.0);
    l.crank_m = crank;
    l.distal_m = distal;
    l.gimbal_mount = quatFromRpyDeg(
        t.numbers<3>("gimbal_mount_rpy_deg", {f == kThumb ? 180.0 : 0.0, 0.0, 0.0}, -360.0, 360.0));
    const auto cpr = t.numbers<3>("counts_per_rad", {26076.0, 26076.0, 26076.0}, -kMaxCountsPerRad,
                                  kMaxCountsPerRad);
    const auto zero = t.numbers<3>("zero_counts", {0.0, 0.0, 0.0}, -1e12, 1e12);
    const auto lo = t.numbers<3>("min_deg", {-60.0, -90.0, -90.0}, -360.0, 360.0);
    const auto hi = t.numbers<3>("max_deg", {60.0, 200.0, 200.0}, -360.0, 360.0);
    const auto torque = t.numbers<3>("max_torque_nm", {0.6, 0.6, 0.6}, 0.0, 10.0);
    const char* joint_names[3] = {"yaw", "crank 1", "crank 2"};
    for (int j = 0; j < 3; ++j) {
      d.actuator_encoders[actuatorIndex(f, j)] =
          encoder(cpr[j], zero[j], lo[j], hi[j], origin, name + " " + joint_names[j],
                  "'" + name + ".counts_per_rad', 'zero_counts', 'min_deg', 'max_deg' element " +
                      std::to_string(j + 1));
      d.max_torque_nm[actuatorIndex(f, j)] = torque[j];
    }
    const auto gcpr = t.numbers<3>("gimbal_counts_per_rad", {651.9, 651.9, 651.9},
                                   -kMaxCountsPerRad, kMaxCountsPerRad);
    const auto gzero = t.numbers<3>("gimbal_zero_counts", {0.0, 0.0, 0.0}, -1e12, 1e12);
    const auto glo = t.numbers<3>("gimbal_min_deg", {-170.0, -80.0, -170.0}, -360.0, 360.0);
    const auto ghi = t.numbers<3>("gimbal_max_deg", {170.0, 80.0, 170.0}, -360.0, 360.0);
    for (int j = 0; j < 3; ++j) {
      d.gimbal_encoders[f][j] = encoder(
          gcpr[j], gzero[j], glo[j], ghi[j], origin, name + " gimbal " + std::to_string(j + 1),
          "'" + name +
              ".gimbal_counts_per_rad', 'gimbal_zero_counts', 'gimbal_min_deg', "
              "'gimbal_max_deg' element " +
              std::to_string(j + 1));
    }
    const std::string thimble = t.text("thimble", "");
    t.rejectUnknown();
    if (thimble.empty())
      throw ConfigError(origin + ": '" + name + ".thimble' (calibration file) must be set");
    std::filesystem::path p(thimble);
    if (p.is_relative() && !base_dir.empty()) p = std::filesystem::path(base_dir) / p;
    d.thimble_files[f] = p.string();
    d.thimbles[f] = loadThimbleCalibration(p.string());
  }
  // The home pose must be reachable: a device file whose linkage cannot reach the joint is
  // caught here, not at the first sample.
  Mf2Kinematics k(d);
  PerFinger<ThimblePose> home;
  home[kThumb].position_m = Vec3(0.01, 0.0, 0.008);
  home[kThumb].orientation = Quat(Eigen::AngleAxisd(kPi, Vec3::UnitX()));
  home[kIndex].position_m = Vec3(0.01, 0.0, -0.008);
  JointAngles q;
  if (!k.inverse(home, 0.0, q) || !k.withinLimits(q)) {
    throw ConfigError(origin +
                      ": the linkage cannot reach the home grip (thimbles 8 mm either "
                      "side of a point 1 cm from the device origin)");
  }
  return d;
}

std::vector<NamedFile> descriptionFiles(const Mf2Description& d) {
  std::vector<NamedFile> files;
  if (d.path.empty()) {
    files.push_back({"device/built-in.toml",
                     "# built-in MF-2 description (mf2::defaultMf2): " + d.source + "\n"});
    return files;
  }
  files.push_back({"device/" + std::filesystem::path(d.path).filename().string(),
                   readText(d.path, "device file")});
  for (const auto& t : d.thimble_files) {
    files.push_back({"thimble/" + std::filesystem::path(t).filename().string(),
                     readText(t, "thimble calibration file")});
  }
  return files;
}

Mf2Description loadMf2Description(const std::string& path) {
  const std::string text = readText(path, "device file");
  return parseMf2Description(text, path, std::filesystem::path(path).parent_path().string());
}

}  // namespace telehand::mf2
