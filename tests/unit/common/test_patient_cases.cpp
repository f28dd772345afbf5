// Patient cases (deploy/cases): every case loads, stays within its published ranges and changes
// what the student feels in the expected direction; malformed case files are named; the two
// new JointModel fields survive the wire.
#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <unistd.h>

#include <atomic>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <limits>
#include <optional>
#include <string>
#include <vector>

#include "telehand/config/config.h"
#include "telehand/core/error.h"
#include "telehand/core/joint_model.h"
#include "telehand/core/tissue_model.h"
#include "telehand/protocol/wire.h"

namespace telehand {
namespace {

namespace fs = std::filesystem;
using ::testing::AllOf;
using ::testing::ElementsAre;
using ::testing::HasSubstr;

const std::string kCasesDir = std::string(TELEHAND_DEPLOY_DIR) + "/cases";

PatientCase load(const std::string& name) { return loadPatientCaseByName(kCasesDir, name); }

/// Stiffness of one axis at `deg`, N·m/rad, from the passive torque (central difference).
double stiffnessNmPerRad(const JointModel& m, int axis, double deg) {
  const double h = 1e-4;  // rad
  Vec3 lo = Vec3::Zero(), hi = Vec3::Zero();
  lo[axis] = degToRad(deg) - h;
  hi[axis] = degToRad(deg) + h;
  const Vec3 zero = Vec3::Zero();
  return -(m.passiveTorqueNm(hi, zero)[axis] - m.passiveTorqueNm(lo, zero)[axis]) / (2.0 * h);
}

/// Restoring torque magnitude on one axis at `deg`, the joint at rest (no speed).
double torqueAt(const JointModel& m, int axis, double deg, double rate_rad_s = 0.0) {
  Vec3 a = Vec3::Zero(), r = Vec3::Zero();
  a[axis] = degToRad(deg);
  r[axis] = rate_rad_s;
  return m.passiveTorqueNm(a, r)[axis];
}

double restDeg(const JointModel& m, int axis) { return radToDeg(m.restAngleRad(axis)); }

// --- The shipped cases ----------------------------------------------------------------------

TEST(PatientCases, EveryFileInTheDeployDirectoryLoadsUnderItsOwnName) {
  const auto names = listPatientCases(kCasesDir);
  EXPECT_THAT(names, ElementsAre("healthy", "hypertonic", "lax", "oedema", "recovery", "scar",
                                 "spasm", "stiff"));
  for (const auto& name : names) {
    SCOPED_TRACE(name);
    PatientCase pc;
    ASSERT_NO_THROW(pc = load(name));
    EXPECT_EQ(pc.name, name);
    EXPECT_EQ(std::string(pc.model.case_name.data()), name);
    EXPECT_FALSE(pc.description.empty());
    EXPECT_FALSE(pc.source.empty());
    EXPECT_EQ(pc.recovers, name == "recovery");
    // Same file through the path loader.
    EXPECT_EQ(loadPatientCase(kCasesDir + "/" + name + ".toml").model, pc.model);
  }
}

TEST(PatientCases, EveryCaseStaysWithinItsRangesAndResistsEverywhereInThem) {
  for (const auto& name : listPatientCases(kCasesDir)) {
    const PatientCase pc = load(name);
    const JointModel m(pc.model);
    for (int axis = 0; axis < kAxes; ++axis) {
      SCOPED_TRACE(name + " " + std::string(kAxisNames[static_cast<std::size_t>(axis)]));
      const CubicCurve& c = pc.model.axes[static_cast<std::size_t>(axis)];
      ASSERT_LT(c.min_deg, c.max_deg);
      // The joint returns toward its rest angle from everywhere in its range (a range that
      // stops short of the curve's zero, as recovery's flexion does, rests on its end).
      const double rest = restDeg(m, axis);
      EXPECT_GE(rest, c.min_deg);
      EXPECT_LE(rest, c.max_deg);
      if (rest > c.min_deg && rest < c.max_deg) {
        EXPECT_NEAR(m.holdingForceN(axis, degToRad(rest)), 0.0, 1e-9);
      }
      for (double a = c.min_deg; a <= c.max_deg; a += 0.5) {
        if (std::abs(a - rest) <= pc.model.neutral_zone_deg[static_cast<std::size_t>(axis)] + 0.1) {
          continue;
        }
        EXPECT_LT(torqueAt(m, axis, a) * (a - rest), 0.0) << a;
      }
      // The holding force never falls with the angle, and restores toward rest on both sides.
      double prev = -1e300;
      for (double a = c.min_deg; a <= c.max_deg; a += 0.25) {
        const double f = m.holdingForceN(axis, degToRad(a));
        EXPECT_GE(f, prev - 1e-12) << a;
        prev = f;
      }
      // Beyond the range, the wall pushes back in.
      EXPECT_LT(torqueAt(m, axis, c.max_deg + 1.0), -0.005);
      EXPECT_GT(torqueAt(m, axis, c.min_deg - 1.0), 0.0);
    }
    // Anatomical ranges (docs/facts.md): flexion within −80..95 deg, abduction ±25, axial small.
    EXPECT_GE(pc.model.axes[kFlexion].min_deg, -80.0) << name;
    EXPECT_LE(pc.model.axes[kFlexion].max_deg, 95.0) << name;
    EXPECT_GE(pc.model.axes[kAbduction].min_deg, -25.0) << name;
    EXPECT_LE(pc.model.axes[kAbduction].max_deg, 25.0) << name;
    EXPECT_GE(pc.model.axes[kAxial].min_deg, -15.0) << name;
    EXPECT_LE(pc.model.axes[kAxial].max_deg, 20.0) << name;
  }
}

TEST(PatientCases, HealthyIsThePaperJoint) {
  const PatientCase pc = load("healthy");
  JointModelParams expected = healthyIndexMcp();
  EXPECT_EQ(pc.model, expected);
}

TEST(PatientCases, StiffnessesAreInThePublishedRanges) {
  const JointModel healthy(load("healthy").model);
  const JointModel stiff(load("stiff").model);
  // Post-stroke (docs/facts.md): resting at 40-58 deg flexion, 0.085-0.64 N·m/rad near rest.
  const double stiff_rest = restDeg(stiff, kFlexion);
  EXPECT_GE(stiff_rest, 40.0);
  EXPECT_LE(stiff_rest, 58.0);
  for (double d : {-2.0, 0.0, 2.0}) {
    const double k = stiffnessNmPerRad(stiff, kFlexion, stiff_rest + d);
    EXPECT_GE(k, 0.085) << d;
    EXPECT_LE(k, 0.64) << d;
  }
  EXPECT_NEAR(stiffnessNmPerRad(stiff, kFlexion, stiff_rest), 0.30, 0.01);  // as the file says
  // Healthy: 0.033-0.047 N·m/rad "near neutral"; the paper's curve gives 0.027 at 0 deg.
  for (double d : {0.0, 2.0, 5.0}) {
    const double k = stiffnessNmPerRad(healthy, kFlexion, d);
    EXPECT_GE(k, 0.026) << d;
    EXPECT_LE(k, 0.05) << d;
  }
  // Either way the stiff joint is several times stiffer near its own rest.
  EXPECT_GT(stiffnessNmPerRad(stiff, kFlexion, stiff_rest),
            3.0 * stiffnessNmPerRad(healthy, kFlexion, 0.0));
}

TEST(PatientCases, StiffResistsMoreThanHealthyAndHasASmallerRange) {
  const PatientCase healthy_case = load("healthy"), stiff_case = load("stiff");
  const JointModel healthy(healthy_case.model), stiff(stiff_case.model);
  for (int axis = 0; axis < kAxes; ++axis) {
    SCOPED_TRACE(kAxisNames[static_cast<std::size_t>(axis)]);
    const auto i = static_cast<std::size_t>(axis);
    const CubicCurve& hc = healthy_case.model.axes[i];
    const CubicCurve& sc = stiff_case.model.axes[i];
    EXPECT_LT(sc.max_deg - sc.min_deg, hc.max_deg - hc.min_deg);
    const double hr = restDeg(healthy, axis), sr = restDeg(stiff, axis);
    // Every displacement from rest that both ranges allow, both directions.
    const double lo = std::max(hc.min_deg - hr, sc.min_deg - sr);
    const double hi = std::min(hc.max_deg - hr, sc.max_deg - sr);
    ASSERT_LT(lo, -2.0);
    ASSERT_GT(hi, 2.0);
    for (double d = lo; d <= hi; d += 0.5) {
      if (std::abs(d) < 0.25) continue;
      const double th = std::abs(torqueAt(healthy, axis, hr + d));
      const double ts = std::abs(torqueAt(stiff, axis, sr + d));
      EXPECT_GT(ts, th) << "displacement " << d << " deg";
    }
  }
}

TEST(PatientCases, LaxIsFreeInItsNeutralZoneAndHealthyBeyondIt) {
  const PatientCase lax_case = load("lax"), healthy_case = load("healthy");
  const JointModel lax(lax_case.model), healthy(healthy_case.model);
  for (int axis = 0; axis < kAxes; ++axis) {
    SCOPED_TRACE(kAxisNames[static_cast<std::size_t>(axis)]);
    const auto i = static_cast<std::size_t>(axis);
    const double zone = lax_case.model.neutral_zone_deg[i];
    ASSERT_GT(zone, 0.0);
    EXPECT_EQ(healthy_case.model.neutral_zone_deg[i], 0.0);
    const double lr = restDeg(lax, axis), hr = restDeg(healthy, axis);
    EXPECT_NEAR(lr, hr, 1e-9);  // same curve: the zone centres on the healthy rest angle
    // Nothing resists inside the zone (no speed, so not even damping).
    for (int k = -20; k <= 20; ++k) {
      const double d = zone * k / 20.0;
      if (std::abs(k) < 20) {
        EXPECT_EQ(lax.holdingForceN(axis, degToRad(lr + d)), lax.holdingForceN(axis, degToRad(lr)))
            << d;
      }
      EXPECT_NEAR(lax.holdingForceN(axis, degToRad(lr + d)), 0.0, 1e-9) << d;
      EXPECT_NEAR(torqueAt(lax, axis, lr + d), 0.0, 1e-11) << d;
    }
    // While the healthy joint already resists there.
    EXPECT_GT(std::abs(healthy.holdingForceN(axis, degToRad(hr + zone))), 0.1);
    // Beyond the zone: the healthy curve, shifted out by the zone width.
    const CubicCurve& hc = healthy_case.model.axes[i];
    const CubicCurve& lc = lax_case.model.axes[i];
    for (double d = 0.5; d <= std::min(hc.max_deg - hr, lc.max_deg - lr - zone); d += 0.5) {
      EXPECT_NEAR(lax.holdingForceN(axis, degToRad(lr + zone + d)),
                  healthy.holdingForceN(axis, degToRad(hr + d)), 1e-9)
          << "+" << d;
    }
    for (double d = 0.5; d <= std::min(hr - hc.min_deg, lr - zone - lc.min_deg); d += 0.5) {
      EXPECT_NEAR(lax.holdingForceN(axis, degToRad(lr - zone - d)),
                  healthy.holdingForceN(axis, degToRad(hr - d)), 1e-9)
          << "-" << d;
    }
    // And the lax range is wider on both sides.
    EXPECT_LT(lc.min_deg, hc.min_deg);
    EXPECT_GT(lc.max_deg, hc.max_deg);
  }
}

TEST(PatientCases, LaxEndOfRangeWallIsWhereItsRangeEnds) {
  // The server's hand stops the joint at min_deg/max_deg (Bullet limits); the proxy the student
  // feels must put its wall there too, not a zone width further out.
  const PatientCase lax_case = load("lax");
  const JointModel lax(lax_case.model);
  for (int axis = 0; axis < kAxes; ++axis) {
    SCOPED_TRACE(kAxisNames[static_cast<std::size_t>(axis)]);
    const CubicCurve& c = lax_case.model.axes[static_cast<std::size_t>(axis)];
    auto f = [&](double deg) { return lax.holdingForceN(axis, degToRad(deg)); };
    // Continuous at the range ends.
    EXPECT_NEAR(f(c.max_deg + 1e-7), f(c.max_deg), 1e-5);
    EXPECT_NEAR(f(c.min_deg - 1e-7), f(c.min_deg), 1e-5);
    // Past them, at least the wall's 1 N/deg more per degree; inside, the curve's own slope.
    EXPECT_GE(f(c.max_deg + 1.0) - f(c.max_deg), kWallNPerDeg);
    EXPECT_GE(f(c.min_deg) - f(c.min_deg - 1.0), kWallNPerDeg);
    EXPECT_LT(f(c.max_deg) - f(c.max_deg - 1.0), f(c.max_deg + 1.0) - f(c.max_deg));
    EXPECT_LT(f(c.min_deg + 1.0) - f(c.min_deg), f(c.min_deg) - f(c.min_deg - 1.0));
  }
  // A zone that reaches past a range end: free up to the end, then the wall.
  JointModelParams wide = healthyIndexMcp();
  wide.neutral_zone_deg[kAbduction] = 25.0;  // rest near 3.6 deg, range ±20
  const JointModel m(wide);
  EXPECT_NEAR(m.holdingForceN(kAbduction, degToRad(-20.0)), 0.0, 1e-9);
  EXPECT_NEAR(m.holdingForceN(kAbduction, degToRad(20.0)), 0.0, 1e-9);
  EXPECT_GE(m.holdingForceN(kAbduction, degToRad(21.0)), kWallNPerDeg);
  EXPECT_LE(m.holdingForceN(kAbduction, degToRad(-21.0)), -kWallNPerDeg);
}

TEST(PatientCases, SpasmResistsFastMovementMoreAndEqualsHealthyAtRest) {
  const PatientCase spasm_case = load("spasm"), healthy_case = load("healthy");
  const JointModel spasm(spasm_case.model), healthy(healthy_case.model);
  const double g = spasm_case.model.speed_gain_s_per_rad;
  ASSERT_GT(g, 0.0);
  EXPECT_EQ(healthy_case.model.speed_gain_s_per_rad, 0.0);
  for (int axis = 0; axis < kAxes; ++axis) {
    SCOPED_TRACE(kAxisNames[static_cast<std::size_t>(axis)]);
    const CubicCurve& c = spasm_case.model.axes[static_cast<std::size_t>(axis)];
    const double rest = restDeg(spasm, axis);
    for (double deg :
         {c.min_deg + 1.0, 0.5 * (c.min_deg + rest), 0.5 * (rest + c.max_deg), c.max_deg - 1.0}) {
      // At zero speed the spasm joint is the healthy one, torque for torque.
      EXPECT_DOUBLE_EQ(torqueAt(spasm, axis, deg), torqueAt(healthy, axis, deg)) << deg;
      // The holding force itself does not depend on speed.
      EXPECT_EQ(spasm.holdingForceN(axis, degToRad(deg)),
                healthy.holdingForceN(axis, degToRad(deg)));
      // The speed-dependent part only ever resists the motion (dissipative), within the
      // damping cap; stretching (away from rest), it grows with speed and resists more than
      // the healthy joint's damping does.
      const double stretch = deg > rest ? 1.0 : -1.0;
      for (double rate : {0.05, 0.5, 1.6, 5.0}) {
        for (double dir : {1.0, -1.0}) {
          const double extra = torqueAt(spasm, axis, deg, dir * rate) - torqueAt(spasm, axis, deg);
          EXPECT_LE(extra * dir * rate, 0.0) << deg << " moving " << dir * rate;
          EXPECT_LE(std::abs(extra), spasm.maxDampingNmsPerRad() * rate * (1.0 + 1e-12));
        }
        const double slow = torqueAt(spasm, axis, deg, stretch * 0.05) - torqueAt(spasm, axis, deg);
        const double fast = torqueAt(spasm, axis, deg, stretch * rate) - torqueAt(spasm, axis, deg);
        if (rate > 0.05) {
          EXPECT_GT(std::abs(fast), std::abs(slow) * rate / 0.05 * 0.999) << deg;
        }
        const double healthy_extra =
            torqueAt(healthy, axis, deg, stretch * rate) - torqueAt(healthy, axis, deg);
        EXPECT_GT(std::abs(fast), std::abs(healthy_extra)) << deg;
      }
    }
  }
}

TEST(PatientCases, RecoveryInterpolatesFromTheStartingToTheFinalRanges) {
  const PatientCase pc = load("recovery");
  ASSERT_TRUE(pc.recovers);
  ASSERT_GT(pc.recovery_treatment_s, 0.0);
  const JointModelParams start = pc.at(0.0), end = pc.at(pc.recovery_treatment_s);
  EXPECT_EQ(start, pc.model);
  for (std::size_t i = 0; i < kAxes; ++i) {
    SCOPED_TRACE(kAxisNames[i]);
    EXPECT_EQ(end.axes[i].min_deg, pc.final_min_deg[i]);
    EXPECT_EQ(end.axes[i].max_deg, pc.final_max_deg[i]);
    EXPECT_EQ(end.axes[i].coeffs, pc.model.axes[i].coeffs);  // only the range recovers
    // It starts short of the final range and never shrinks on the way.
    EXPECT_GT(pc.model.axes[i].min_deg, pc.final_min_deg[i]);
    EXPECT_LT(pc.model.axes[i].max_deg, pc.final_max_deg[i]);
    double prev_min = start.axes[i].min_deg, prev_max = start.axes[i].max_deg;
    for (double t = 0.0; t <= pc.recovery_treatment_s; t += pc.recovery_treatment_s / 64.0) {
      const JointModelParams p = pc.at(t);
      EXPECT_LE(p.axes[i].min_deg, prev_min) << t;
      EXPECT_GE(p.axes[i].max_deg, prev_max) << t;
      EXPECT_GE(p.axes[i].min_deg, pc.final_min_deg[i]) << t;
      EXPECT_LE(p.axes[i].max_deg, pc.final_max_deg[i]) << t;
      prev_min = p.axes[i].min_deg;
      prev_max = p.axes[i].max_deg;
    }
    // Halfway in time is halfway in range; before 0 and after the end it is clamped.
    EXPECT_NEAR(pc.at(0.5 * pc.recovery_treatment_s).axes[i].max_deg,
                0.5 * (pc.model.axes[i].max_deg + pc.final_max_deg[i]), 1e-9);
    EXPECT_EQ(pc.at(-10.0).axes[i].max_deg, start.axes[i].max_deg);
    EXPECT_EQ(pc.at(10.0 * pc.recovery_treatment_s).axes[i].max_deg, pc.final_max_deg[i]);
  }
  // The recovered joint is still a valid joint on the wire.
  telehand_msg_JointModel w{};
  toWire(end, 7, w);
  std::string why;
  EXPECT_TRUE(fromWire(w, &why).has_value()) << why;
}

TEST(PatientCases, ACaseThatDoesNotRecoverIsTheSameAtAnyTime) {
  const PatientCase pc = load("stiff");
  EXPECT_FALSE(pc.recovers);
  EXPECT_EQ(pc.at(0.0), pc.model);
  EXPECT_EQ(pc.at(1e6), pc.model);
}

// --- Malformed case files -------------------------------------------------------------------

/// A valid case file (the healthy one, by value) that the malformed ones start from.
std::string validCase(const std::string& name = "test") {
  return "[case]\n"
         "name = \"" +
         name +
         "\"\n"
         "description = \"d\"\n"
         "source = \"s\"\n"
         "damping_nms_per_rad = 0.002\n"
         "speed_gain_s_per_rad = 0.0\n"
         "[flexion]\n"
         "coeffs = [1.834e-5, 0.0010338, 0.046382, 0.59057]\n"
         "min_deg = -45.0\n"
         "max_deg = 90.0\n"
         "neutral_zone_deg = 0.0\n"
         "[abduction]\n"
         "coeffs = [0.00017, 0.0012, 0.13, -0.49]\n"
         "min_deg = -20.0\n"
         "max_deg = 20.0\n"
         "neutral_zone_deg = 0.0\n"
         "[axial]\n"
         "coeffs = [0.0014, -0.014, 0.65, 0.09]\n"
         "min_deg = -10.0\n"
         "max_deg = 15.0\n"
         "neutral_zone_deg = 0.0\n";
}

std::string replaced(std::string text, const std::string& from, const std::string& to) {
  const auto at = text.find(from);
  EXPECT_NE(at, std::string::npos) << from;
  if (at != std::string::npos) text.replace(at, from.size(), to);
  return text;
}

/// The message of the ConfigError that parsing `text` as "bad.toml" throws ("" if none).
std::string caseError(const std::string& text) {
  try {
    parsePatientCase(text, "bad.toml");
  } catch (const ConfigError& e) {
    return e.what();
  }
  return "";
}

TEST(PatientCaseFile, TheValidStartingPointParses) {
  const PatientCase pc = parsePatientCase(validCase(), "good.toml");
  EXPECT_EQ(pc.name, "test");
  EXPECT_FALSE(pc.recovers);
  EXPECT_EQ(pc.model.axes, healthyIndexMcp().axes);
}

TEST(PatientCaseFile, MissingCaseTableIsNamed) {
  const std::string text = validCase().substr(validCase().find("[flexion]"));
  EXPECT_THAT(caseError(text), AllOf(HasSubstr("bad.toml"), HasSubstr("[case]")));
  EXPECT_THAT(caseError(replaced(validCase(), "name = \"test\"\n", "")),
              AllOf(HasSubstr("bad.toml"), HasSubstr("case.name")));
}

TEST(PatientCaseFile, MissingAxisTableIsNamed) {
  std::string text = validCase();
  text.erase(text.find("[axial]"));
  EXPECT_THAT(caseError(text), AllOf(HasSubstr("bad.toml"), HasSubstr("[axial]")));
}

TEST(PatientCaseFile, UnknownKeysAndTablesAreNamed) {
  EXPECT_THAT(
      caseError(replaced(validCase(), "max_deg = 20.0\n", "max_deg = 20.0\nstiffness = 3\n")),
      AllOf(HasSubstr("bad.toml"), HasSubstr("abduction.stiffness"), HasSubstr("line 16")));
  EXPECT_THAT(
      caseError(replaced(validCase(), "source = \"s\"\n", "source = \"s\"\nspeed_gain = 1\n")),
      AllOf(HasSubstr("bad.toml"), HasSubstr("case.speed_gain")));
  EXPECT_THAT(caseError(validCase() + "[wrist]\nx = 1\n"),
              AllOf(HasSubstr("bad.toml"), HasSubstr("unknown table 'wrist'")));
  EXPECT_THAT(caseError(validCase() + "[recovery]\nfinal_min_deg = [-45.0, -20.0, -10.0]\n"
                                      "final_max_deg = [90.0, 20.0, 15.0]\ntreatment_s = 60.0\n"
                                      "rate = 2.0\n"),
              AllOf(HasSubstr("bad.toml"), HasSubstr("recovery.rate")));
}

TEST(PatientCaseFile, WrongTypesAndOutOfRangeValuesAreNamed) {
  EXPECT_THAT(caseError(replaced(validCase(), "coeffs = [0.00017, 0.0012, 0.13, -0.49]",
                                 "coeffs = [0.00017, 0.0012, 0.13]")),
              AllOf(HasSubstr("bad.toml"), HasSubstr("abduction.coeffs"), HasSubstr("4 numbers")));
  EXPECT_THAT(caseError(replaced(validCase(), "coeffs = [0.00017, 0.0012, 0.13, -0.49]",
                                 "coeffs = [0.00017, 0.0012, 0.13, \"x\"]")),
              AllOf(HasSubstr("bad.toml"), HasSubstr("abduction.coeffs"), HasSubstr("element 3")));
  EXPECT_THAT(
      caseError(replaced(validCase(), "speed_gain_s_per_rad = 0.0", "speed_gain_s_per_rad = -1.0")),
      AllOf(HasSubstr("bad.toml"), HasSubstr("case.speed_gain_s_per_rad")));
  EXPECT_THAT(
      caseError(
          replaced(validCase(), "speed_gain_s_per_rad = 0.0", "speed_gain_s_per_rad = \"fast\"")),
      AllOf(HasSubstr("bad.toml"), HasSubstr("case.speed_gain_s_per_rad"), HasSubstr("number")));
  // The first neutral_zone_deg is flexion's.
  EXPECT_THAT(caseError(replaced(validCase(), "neutral_zone_deg = 0.0", "neutral_zone_deg = -1.0")),
              AllOf(HasSubstr("bad.toml"), HasSubstr("flexion.neutral_zone_deg")));
  EXPECT_THAT(caseError(replaced(validCase(), "neutral_zone_deg = 0.0", "neutral_zone_deg = 45.0")),
              AllOf(HasSubstr("bad.toml"), HasSubstr("flexion.neutral_zone_deg")));
  EXPECT_THAT(caseError(replaced(validCase(), "min_deg = -10.0\nmax_deg = 15.0",
                                 "min_deg = 15.0\nmax_deg = 15.0")),
              AllOf(HasSubstr("bad.toml"), HasSubstr("axial"), HasSubstr("empty")));
}

TEST(PatientCaseFile, ForceThatFallsWithTheAngleIsRejected) {
  // A negative linear term: the abduction force falls around 0 deg.
  EXPECT_THAT(caseError(replaced(validCase(), "coeffs = [0.00017, 0.0012, 0.13, -0.49]",
                                 "coeffs = [0.00017, 0.0012, -0.13, -0.49]")),
              AllOf(HasSubstr("bad.toml"), HasSubstr("abduction.coeffs"), HasSubstr("fall")));
  // A flat curve resists nothing.
  EXPECT_THAT(caseError(replaced(validCase(), "coeffs = [0.0014, -0.014, 0.65, 0.09]",
                                 "coeffs = [0.0, 0.0, 0.0, 0.5]")),
              AllOf(HasSubstr("bad.toml"), HasSubstr("axial.coeffs")));
  // Falling only in the last fraction of a degree below max (the slope 0.3 - 0.002 a^2 turns
  // negative at 12.25 deg, the range ends at 12.4) still counts.
  EXPECT_THAT(caseError(replaced(validCase(),
                                 "coeffs = [0.0014, -0.014, 0.65, 0.09]\n"
                                 "min_deg = -10.0\nmax_deg = 15.0",
                                 "coeffs = [-0.000666666666667, 0.0, 0.3, 0.0]\n"
                                 "min_deg = -10.0\nmax_deg = 12.4")),
              AllOf(HasSubstr("bad.toml"), HasSubstr("axial.coeffs")));
  // Falling only between two of the checked half degrees: the slope's minimum at the
  // vertex -c2/(3 c3) = 0.25 deg, where 3e-2 a^2 - 0.015 a + 0.0018 = -0.000075 < 0.
  EXPECT_THAT(caseError(replaced(validCase(), "coeffs = [0.00017, 0.0012, 0.13, -0.49]",
                                 "coeffs = [0.01, -0.0075, 0.0018, 0.0]")),
              AllOf(HasSubstr("bad.toml"), HasSubstr("abduction.coeffs")));
}

TEST(PatientCaseFile, ForceNoJointHoldsIsRejected) {
  // Rising everywhere, and 1e306 N/deg³: the holding force overflows.
  EXPECT_THAT(caseError(replaced(validCase(), "coeffs = [1.834e-5, 0.0010338, 0.046382, 0.59057]",
                                 "coeffs = [1e306, 0.0010338, 0.046382, 0.59057]")),
              AllOf(HasSubstr("bad.toml"), HasSubstr("flexion.coeffs"), HasSubstr("1000 N")));
  // 1200 N at 90 deg flexion: the stiffest joint a case holds takes about a tenth of it.
  EXPECT_THAT(caseError(replaced(validCase(), "coeffs = [1.834e-5, 0.0010338, 0.046382, 0.59057]",
                                 "coeffs = [0.0, 0.0, 10.0, 300.0]")),
              AllOf(HasSubstr("bad.toml"), HasSubstr("flexion.coeffs"), HasSubstr("1200 N")));
  // The shipped cases and random ones are far inside the bound.
  for (const auto& name : listPatientCases(kCasesDir)) {
    const PatientCase pc = load(name);
    for (const CubicCurve& c : pc.model.axes) EXPECT_EQ(passiveCurveProblem(c), std::nullopt);
  }
  for (uint64_t seed = 1; seed <= 200; ++seed) {
    const PatientCase pc = randomPatientCase(seed);
    for (const CubicCurve& c : pc.model.axes) {
      EXPECT_LT(std::max(std::abs(c.eval(c.min_deg)), std::abs(c.eval(c.max_deg))),
                0.2 * kMaxHoldingForceN)
          << seed;
    }
  }
}

// --- The web ([tissue]) ---------------------------------------------------------------------

TEST(PatientCases, MassageCasesCarryTheirWebOnTheHealthyJoint) {
  for (const char* name : {"healthy", "oedema", "scar", "hypertonic"}) {
    SCOPED_TRACE(name);
    const PatientCase pc = load(name);
    EXPECT_TRUE(pc.tissue_given);
    EXPECT_EQ(pc.tissue, tissueCase(name));
    EXPECT_EQ(invalidTissueParam(pc.tissue), nullptr);
    EXPECT_EQ(pc.model.axes, healthyIndexMcp().axes);
  }
  // The joint cases have no web of their own: the healthy one.
  for (const char* name : {"stiff", "lax", "spasm", "recovery"}) {
    const PatientCase pc = load(name);
    EXPECT_FALSE(pc.tissue_given) << name;
    EXPECT_EQ(pc.tissue, tissueCase("healthy")) << name;
  }
}

TEST(PatientCaseFile, TissueSectionIsOptionalAndItsKeysOverrideTheNamedCase) {
  EXPECT_EQ(parsePatientCase(validCase("scar"), "good.toml").tissue, tissueCase("scar"));
  const PatientCase some = parsePatientCase(validCase("scar") +
                                                "[tissue]\nmu_static = 0.7\n"
                                                "origin_m = [0.01, -0.02, 0.03]\n"
                                                "orientation = [0.0, 1.0, 0.0, 0.0]\n",
                                            "good.toml");
  TissueParams want = tissueCase("scar");
  want.mu_static = 0.7;
  want.origin_m = Vec3(0.01, -0.02, 0.03);
  want.orientation = Quat(0.0, 1.0, 0.0, 0.0);
  EXPECT_TRUE(some.tissue_given);
  EXPECT_EQ(some.tissue, want);
}

TEST(PatientCaseFile, BadTissueValuesAreNamed) {
  auto with = [](const std::string& lines) { return validCase() + "[tissue]\n" + lines; };
  EXPECT_THAT(caseError(with("exponent = 3.5\n")),
              AllOf(HasSubstr("bad.toml"), HasSubstr("tissue.exponent"), HasSubstr("outside")));
  EXPECT_THAT(caseError(with("stiffness_n_per_m_pow = -1.0\n")),
              AllOf(HasSubstr("bad.toml"), HasSubstr("tissue.stiffness_n_per_m_pow")));
  EXPECT_THAT(caseError(with("lateral_stiffness_n_per_m = 9000.0\n")),
              HasSubstr("tissue.lateral_stiffness_n_per_m"));
  EXPECT_THAT(caseError(with("patch_stiffness_factor = 0.0\n")),
              HasSubstr("tissue.patch_stiffness_factor"));
  EXPECT_THAT(caseError(with("damping_s_per_m = \"high\"\n")),
              AllOf(HasSubstr("tissue.damping_s_per_m"), HasSubstr("number")));
  EXPECT_THAT(
      caseError(with("mu_static = 0.3\nmu_kinetic = 0.4\n")),
      AllOf(HasSubstr("bad.toml"), HasSubstr("tissue.mu_kinetic"), HasSubstr("tissue.mu_static")));
  EXPECT_THAT(caseError(with("orientation = [1.0, 0.5, 0.0, 0.0]\n")),
              AllOf(HasSubstr("tissue.orientation"), HasSubstr("unit quaternion")));
  EXPECT_THAT(caseError(with("origin_m = [0.0, 0.0]\n")),
              AllOf(HasSubstr("tissue.origin_m"), HasSubstr("3 numbers")));
  EXPECT_THAT(caseError(with("origin_m = [0.0, 2.0, 0.0]\n")), HasSubstr("tissue.origin_m[1]"));
  EXPECT_THAT(caseError(with("stiffness = 2.0\n")),
              AllOf(HasSubstr("bad.toml"), HasSubstr("tissue.stiffness")));
  EXPECT_THAT(caseError(with("thickness_m = 0.5\n")), HasSubstr("tissue.thickness_m"));
  // A patch that changes the web with no rim to blend over (a step: nothing pushes the finger
  // out of it, and the web would give back more energy than it took).
  EXPECT_THAT(caseError(with("patch_radius_m = 0.006\npatch_stiffness_factor = 10.0\n"
                             "patch_rim_m = 0.0\n")),
              AllOf(HasSubstr("bad.toml"), HasSubstr("tissue.patch_rim_m"), HasSubstr("rim")));
  // With the rim, or with no patch, the same values are taken.
  EXPECT_EQ(caseError(with("patch_radius_m = 0.006\npatch_stiffness_factor = 10.0\n"
                           "patch_rim_m = 0.004\n")),
            "");
  EXPECT_EQ(caseError(with("patch_radius_m = 0.0\npatch_rim_m = 0.0\n")), "");
}

const char* kRecovery =
    "[recovery]\n"
    "final_min_deg = [-45.0, -20.0, -10.0]\n"
    "final_max_deg = [90.0, 20.0, 15.0]\n"
    "treatment_s = 600.0\n";

TEST(PatientCaseFile, RecoveryMustContainTheStartingRanges) {
  const std::string narrow =
      replaced(validCase(), "min_deg = -45.0\nmax_deg = 90.0", "min_deg = -10.0\nmax_deg = 50.0");
  const PatientCase ok = parsePatientCase(narrow + kRecovery, "good.toml");
  EXPECT_TRUE(ok.recovers);
  EXPECT_EQ(ok.recovery_treatment_s, 600.0);
  // Final flexion max below the starting one: the joint would lose range as it recovers.
  EXPECT_THAT(caseError(narrow + replaced(kRecovery, "[90.0,", "[40.0,")),
              AllOf(HasSubstr("bad.toml"), HasSubstr("recovery"), HasSubstr("flexion")));
  // Final axial min above the starting one.
  EXPECT_THAT(caseError(narrow + replaced(kRecovery, "-10.0]", "-5.0]")),
              AllOf(HasSubstr("bad.toml"), HasSubstr("recovery"), HasSubstr("axial")));
  EXPECT_THAT(caseError(narrow + replaced(kRecovery, "[-45.0, -20.0, -10.0]", "[-45.0, -20.0]")),
              AllOf(HasSubstr("bad.toml"), HasSubstr("recovery.final_min_deg")));
  EXPECT_THAT(caseError(narrow + replaced(kRecovery, "600.0", "0.0")),
              AllOf(HasSubstr("bad.toml"), HasSubstr("recovery.treatment_s")));
  // The final ranges are held to a case's bounds, as the starting ones: the model on the
  // way to them goes to the client.
  EXPECT_THAT(caseError(narrow + replaced(kRecovery, "[90.0,", "[130.0,")),
              AllOf(HasSubstr("bad.toml"), HasSubstr("recovery.final_max_deg (flexion)")));
  EXPECT_THAT(caseError(narrow + replaced(kRecovery, "[-45.0,", "[-95.0,")),
              AllOf(HasSubstr("bad.toml"), HasSubstr("recovery.final_min_deg (flexion)")));
  // The curve goes to the client over every range on the way to the final ones: it must rise
  // over the widest. Axial 0.3 a - a³/1500 rises over -10..12 and falls past 12.25 deg.
  const std::string turning = replaced(narrow,
                                       "coeffs = [0.0014, -0.014, 0.65, 0.09]\n"
                                       "min_deg = -10.0\nmax_deg = 15.0",
                                       "coeffs = [-0.000666666666667, 0.0, 0.3, 0.0]\n"
                                       "min_deg = -10.0\nmax_deg = 12.0");
  EXPECT_NO_THROW(parsePatientCase(turning, "good.toml"));
  EXPECT_THAT(caseError(turning + kRecovery),
              AllOf(HasSubstr("bad.toml"), HasSubstr("axial.coeffs"), HasSubstr("recovery"),
                    HasSubstr("falls at 15 deg")));
}

/// A fresh directory of case files per test, removed afterwards.
class CaseDirectory : public ::testing::Test {
 protected:
  void SetUp() override {
    static std::atomic<int> counter{0};
    dir_ = fs::temp_directory_path() /
           ("telehand-cases-" + std::to_string(::getpid()) + "-" + std::to_string(counter++));
    fs::remove_all(dir_);
    ASSERT_TRUE(fs::create_directories(dir_));
  }
  void TearDown() override {
    std::error_code ec;
    fs::remove_all(dir_, ec);
  }
  void write(const std::string& file, const std::string& text) {
    std::ofstream(dir_ / file) << text;
  }
  std::string error(const std::string& name) {
    try {
      loadPatientCaseByName(dir_.string(), name);
    } catch (const ConfigError& e) {
      return e.what();
    }
    return "";
  }
  fs::path dir_;
};

TEST_F(CaseDirectory, ListsOnlyTomlFilesSorted) {
  write("zeta.toml", validCase("zeta"));
  write("alpha.toml", validCase("alpha"));
  write("notes.txt", "not a case");
  EXPECT_THAT(listPatientCases(dir_.string()), ElementsAre("alpha", "zeta"));
  EXPECT_TRUE(listPatientCases((dir_ / "missing").string()).empty());
}

TEST_F(CaseDirectory, UnknownNameListsTheKnownCases) {
  write("alpha.toml", validCase("alpha"));
  write("beta.toml", validCase("beta"));
  EXPECT_THAT(error("gamma"), AllOf(HasSubstr("'gamma'"), HasSubstr("alpha, beta")));
  EXPECT_EQ(loadPatientCaseByName(dir_.string(), "beta").name, "beta");
  // The shipped directory names its cases.
  try {
    loadPatientCaseByName(kCasesDir, "floppy");
    ADD_FAILURE() << "no error";
  } catch (const ConfigError& e) {
    EXPECT_THAT(e.what(),
                AllOf(HasSubstr("'floppy'"),
                      HasSubstr("healthy, hypertonic, lax, oedema, recovery, scar, spasm, stiff")));
  }
  EXPECT_THAT(error("nothing"), AllOf(HasSubstr("'nothing'"), HasSubstr("alpha")));
  fs::remove_all(dir_ / "alpha.toml");
  fs::remove_all(dir_ / "beta.toml");
  EXPECT_THAT(error("nothing"), HasSubstr("none"));
}

TEST_F(CaseDirectory, BadNamesAreRejectedBeforeAnyFileIsOpened) {
  // A file that a path escape would reach must not be loaded.
  write("x.toml", validCase("x"));
  fs::create_directories(dir_ / "sub");
  const std::vector<std::string> bad = {"../x", "Healthy",           "", "a/b", "x.toml",
                                        "x y",  std::string(64, 'a')};
  for (const std::string& name : bad) {
    const std::string sub = (dir_ / "sub").string();
    try {
      loadPatientCaseByName(sub, name);
      ADD_FAILURE() << "no error for '" << name << "'";
    } catch (const ConfigError& e) {
      EXPECT_THAT(e.what(), AllOf(HasSubstr("'" + name + "'"), HasSubstr("[a-z0-9_-]"))) << name;
    }
  }
}

TEST_F(CaseDirectory, FileWhoseCaseNameDisagreesWithItsFileNameIsNamed) {
  write("alpha.toml", validCase("beta"));
  EXPECT_THAT(error("alpha"),
              AllOf(HasSubstr("alpha.toml"), HasSubstr("case.name"), HasSubstr("'beta'")));
}

TEST_F(CaseDirectory, ErrorsInAFileNameTheFile) {
  write("broken.toml",
        replaced(validCase("broken"), "max_deg = 20.0\n", "max_deg = 20.0\nk = 1\n"));
  EXPECT_THAT(error("broken"),
              AllOf(HasSubstr((dir_ / "broken.toml").string()), HasSubstr("abduction.k")));
  write("syntax.toml", "[case\nname = 1\n");
  EXPECT_THAT(error("syntax"), AllOf(HasSubstr("syntax.toml"), HasSubstr("line 1")));
  EXPECT_THAT(
      [&] {
        try {
          loadPatientCase((dir_ / "absent.toml").string());
        } catch (const ConfigError& e) {
          return std::string(e.what());
        }
        return std::string();
      }(),
      HasSubstr("absent.toml"));
}

// --- The wire ---------------------------------------------------------------------------------

TEST(PatientCaseWire, NeutralZonesAndSpeedGainSurviveTheRoundTrip) {
  for (const char* name : {"lax", "spasm", "stiff", "recovery"}) {
    SCOPED_TRACE(name);
    JointModelParams p = load(name).model;
    p.version = 5;
    telehand_msg_JointModel w{};
    toWire(p, 42, w);
    EXPECT_EQ(w.session_id, 42u);
    std::string why;
    const auto back = fromWire(w, &why);
    ASSERT_TRUE(back.has_value()) << why;
    EXPECT_EQ(back->neutral_zone_deg, p.neutral_zone_deg);
    EXPECT_EQ(back->speed_gain_s_per_rad, p.speed_gain_s_per_rad);
    EXPECT_EQ(*back, p);
  }
  JointModelParams lax = load("lax").model;
  telehand_msg_JointModel w{};
  toWire(lax, 1, w);
  EXPECT_EQ(w.neutral_zone_deg[0], 10.0);
  EXPECT_EQ(w.neutral_zone_deg[1], 5.0);
  EXPECT_EQ(w.neutral_zone_deg[2], 4.0);
}

TEST(PatientCaseWire, TheGripOffsetSurvivesTheWireAndBadOnesAreNamed) {
  JointModelParams p = load("lax").model;
  p.grip_offset_rad = Vec3(degToRad(-4.5), degToRad(0.25), degToRad(12.0));
  telehand_msg_JointModel w{};
  toWire(p, 3, w);
  std::string why;
  const auto back = fromWire(w, &why);
  ASSERT_TRUE(back.has_value()) << why;
  EXPECT_EQ(back->grip_offset_rad, p.grip_offset_rad);
  for (int axis = 0; axis < kAxes; ++axis) {
    for (double bad :
         {degToRad(31.0), -degToRad(31.0), std::nan(""), std::numeric_limits<double>::infinity()}) {
      telehand_msg_JointModel b = w;
      b.grip_offset_rad[axis] = bad;
      why.clear();
      EXPECT_FALSE(fromWire(b, &why).has_value()) << axis << " " << bad;
      EXPECT_THAT(why, AllOf(HasSubstr(std::string(kAxisNames[static_cast<std::size_t>(axis)])),
                             HasSubstr("grip_offset_rad")));
    }
  }
}

TEST(PatientCaseWire, FromWireRejectsBadNeutralZonesAndSpeedGains) {
  telehand_msg_JointModel good{};
  toWire(load("lax").model, 1, good);
  std::string why;
  ASSERT_TRUE(fromWire(good, &why).has_value()) << why;
  for (int axis = 0; axis < kAxes; ++axis) {
    telehand_msg_JointModel w = good;
    w.neutral_zone_deg[axis] = -0.5;
    why.clear();
    EXPECT_FALSE(fromWire(w, &why).has_value());
    EXPECT_THAT(why, AllOf(HasSubstr(std::string(kAxisNames[static_cast<std::size_t>(axis)])),
                           HasSubstr("neutral zone")));
    w.neutral_zone_deg[axis] = std::nan("");
    EXPECT_FALSE(fromWire(w, &why).has_value());
    w.neutral_zone_deg[axis] = 31.0;
    EXPECT_FALSE(fromWire(w, &why).has_value());
  }
  for (double gain : {-0.1, 21.0, std::nan(""), std::numeric_limits<double>::infinity()}) {
    telehand_msg_JointModel w = good;
    w.speed_gain_s_per_rad = gain;
    why.clear();
    EXPECT_FALSE(fromWire(w, &why).has_value()) << gain;
    EXPECT_THAT(why, HasSubstr("speed_gain")) << gain;
  }
}

TEST(PatientCaseWire, FromWireRefusesCurvesNoPassiveJointHas) {
  telehand_msg_JointModel good{};
  toWire(load("lax").model, 1, good);
  std::string why;
  ASSERT_TRUE(fromWire(good, &why).has_value()) << why;
  for (int axis = 0; axis < kAxes; ++axis) {
    const std::string name(kAxisNames[static_cast<std::size_t>(axis)]);
    SCOPED_TRACE(name);
    // A force that falls as the angle grows: the case file refuses it, and so does the wire.
    telehand_msg_JointModel w = good;
    const double falling[4] = {0.0, 0.0, -0.05, 0.0};
    for (int c = 0; c < 4; ++c) w.axes[axis].coeffs[c] = falling[c];
    why.clear();
    EXPECT_FALSE(fromWire(w, &why).has_value());
    EXPECT_THAT(why, AllOf(HasSubstr(name), HasSubstr("falls"), HasSubstr("rise with the angle")));
    // A flat one resists nothing.
    const double flat[4] = {0.0, 0.0, 0.0, 0.5};
    for (int c = 0; c < 4; ++c) w.axes[axis].coeffs[c] = flat[c];
    why.clear();
    EXPECT_FALSE(fromWire(w, &why).has_value());
    EXPECT_THAT(why, AllOf(HasSubstr(name), HasSubstr("falls")));
    // Finite, rising where its slope is least, and holding no force a joint has: refused
    // before a device renders it.
    w = good;
    w.axes[axis].coeffs[0] = 1e306;
    why.clear();
    EXPECT_FALSE(fromWire(w, &why).has_value());
    EXPECT_THAT(why, AllOf(HasSubstr(name), HasSubstr("beyond the 1000 N")));
    // The bound is kMaxHoldingForceN at either end of the range (lax: ±25 deg abduction...):
    // a line of 1 N/deg through the range's middle, shifted to just under and just over it.
    const double lo = w.axes[axis].min_deg, hi = w.axes[axis].max_deg;
    const double half = 0.5 * (hi - lo), mid = 0.5 * (hi + lo);
    for (double sign : {1.0, -1.0}) {
      for (double past : {-0.5, 0.5}) {
        telehand_msg_JointModel b = good;
        const double offset = sign * (kMaxHoldingForceN - half + past);
        const double line[4] = {0.0, 0.0, 1.0, offset - mid};
        for (int c = 0; c < 4; ++c) b.axes[axis].coeffs[c] = line[c];
        why.clear();
        EXPECT_EQ(fromWire(b, &why).has_value(), past < 0.0) << sign << " " << past << ": " << why;
        if (past > 0.0) {
          EXPECT_THAT(why, AllOf(HasSubstr(name), HasSubstr("N at")));
        }
      }
    }
  }
}

TEST(PatientCaseWire, FromWireRefusesRangesNoPatientCaseMayHave) {
  telehand_msg_JointModel good{};
  toWire(load("stiff").model, 1, good);
  std::string why;
  ASSERT_TRUE(fromWire(good, &why).has_value()) << why;
  const double inf = std::numeric_limits<double>::infinity();
  for (int axis = 0; axis < kAxes; ++axis) {
    const std::string name(kAxisNames[static_cast<std::size_t>(axis)]);
    for (double bad : {-inf, inf, std::nan(""), -1e6, 1e6, kRangeMinDegBounds.lo - 0.5,
                       kRangeMinDegBounds.hi + 0.5}) {
      telehand_msg_JointModel w = good;
      w.axes[axis].min_deg = bad;
      if (!(bad < w.axes[axis].max_deg)) w.axes[axis].max_deg = kRangeMaxDegBounds.hi;
      why.clear();
      EXPECT_FALSE(fromWire(w, &why).has_value()) << name << " min_deg " << bad;
      EXPECT_THAT(why, AllOf(HasSubstr(name), HasSubstr("min_deg"))) << bad;
    }
    for (double bad : {-inf, inf, std::nan(""), -1e6, 1e6, kRangeMaxDegBounds.lo - 0.5,
                       kRangeMaxDegBounds.hi + 0.5}) {
      telehand_msg_JointModel w = good;
      w.axes[axis].max_deg = bad;
      if (!(w.axes[axis].min_deg < bad)) w.axes[axis].min_deg = kRangeMinDegBounds.lo;
      why.clear();
      EXPECT_FALSE(fromWire(w, &why).has_value()) << name << " max_deg " << bad;
      EXPECT_THAT(why, AllOf(HasSubstr(name), HasSubstr("max_deg"))) << bad;
    }
    // The bounds themselves are a patient case's, and pass. The curve is made a gentle line
    // (±60 N at the bounds) so that only the range is at stake: stiff's axial cubic carried
    // out to -90 deg would hold over 2000 N, past kMaxHoldingForceN.
    telehand_msg_JointModel edge = good;
    edge.axes[axis].min_deg = kRangeMinDegBounds.lo;
    edge.axes[axis].max_deg = kRangeMaxDegBounds.hi;
    const double gentle[4] = {0.0, 0.0, 0.5, 0.0};
    for (int c = 0; c < 4; ++c) edge.axes[axis].coeffs[c] = gentle[c];
    why.clear();
    EXPECT_TRUE(fromWire(edge, &why).has_value()) << name << ": " << why;
  }
  // The same bounds as a case file: a case at them parses, one past them is refused.
  EXPECT_NO_THROW(parsePatientCase(
      replaced(validCase(), "min_deg = -45.0\nmax_deg = 90.0", "min_deg = -90.0\nmax_deg = 120.0"),
      "edge.toml"));
  EXPECT_THAT(caseError(replaced(validCase(), "min_deg = -45.0", "min_deg = -90.5")),
              HasSubstr("flexion.min_deg"));
}

TEST(GuideWire, RoundTripsAndRefusesWhatIsOutOfRange) {
  JointModelParams p = healthyIndexMcp();
  p.guide.authority = 0.5;
  p.guide.period_s = 0.33;
  for (int k = 0; k < GuideParams::kPoints; ++k)
    p.guide.path_rad[static_cast<std::size_t>(k)] = Vec3(0.01 * k, -0.002 * k, 0.0);
  telehand_msg_JointModel w{};
  toWire(p, 5, w);
  std::string why;
  const auto back = fromWire(w, &why);
  ASSERT_TRUE(back.has_value()) << why;
  EXPECT_EQ(back->guide, p.guide);
  auto refused = [&](auto mutate, const char* named) {
    telehand_msg_JointModel b = w;
    mutate(b);
    std::string reason;
    EXPECT_FALSE(fromWire(b, &reason).has_value()) << named;
    EXPECT_NE(reason.find(named), std::string::npos) << reason;
  };
  refused([](auto& b) { b.guide_authority = 1.5; }, "guide_authority");
  refused([](auto& b) { b.guide_authority = std::nan(""); }, "guide_authority");
  refused([](auto& b) { b.guide_period_s = 0.01; }, "guide_period_s");
  refused([](auto& b) { b.guide_stiffness_n_per_deg = 50.0; }, "guide_stiffness");
  refused([](auto& b) { b.guide_max_force_n = 1e9; }, "guide_max_force_n");
  refused([](auto& b) { b.guide_path_rad[10][1] = std::numeric_limits<double>::infinity(); },
          "guide_path_rad point 10");
  refused([](auto& b) { b.guide_path_rad[3][0] = 7.0; }, "guide_path_rad point 3");
}

}  // namespace
}  // namespace telehand
