// telehand-records synth and fit as processes: a synthetic capture stored in a record, fitted
// into a patient-case file that loads, with one plot per axis.
#include <gtest/gtest.h>
#include <unistd.h>

#include <cstdlib>
#include <filesystem>

#include "process.h"
#include "telehand/config/config.h"

namespace telehand::test {
namespace {

namespace fs = std::filesystem;
using namespace std::chrono_literals;

TEST(RecordsFit, SynthThenFitWritesACaseAndPlots) {
  // A directory of its own: a kept one from an earlier failed run (same pid) must not lend
  // its record.
  std::string tmpl = (fs::temp_directory_path() / "telehand-records-fit-XXXXXX").string();
  ASSERT_NE(mkdtemp(tmpl.data()), nullptr);
  const fs::path dir = tmpl;
  const std::string db = (dir / "r.db").string();
  Process synth({TELEHAND_RECORDS_BIN, "--db", db, "synth", "--case", "stiff", "--seconds-per-axis",
                 "6", "--device", TELEHAND_DEPLOY_DIR "/devices/mf2.toml", "-q"},
                (dir / "synth.log").string());
  ASSERT_EQ(synth.wait(60s), 0) << synth.output();
  EXPECT_NE(synth.output().find("session 1: synthetic capture of case 'stiff'"), std::string::npos)
      << synth.output();

  Process fit({TELEHAND_RECORDS_BIN, "--db", db, "fit", "1", "--name", "stiff-fit", "-o",
               (dir / "cases" / "stiff-fit.toml").string(), "--plots", (dir / "plots").string()},
              (dir / "fit.log").string());
  ASSERT_EQ(fit.wait(60s), 0) << fit.output();
  const std::string out = fit.output();
  EXPECT_NE(out.find("RMS residual"), std::string::npos) << out;
  const PatientCase pc = loadPatientCaseByName((dir / "cases").string(), "stiff-fit");
  const PatientCase truth = loadPatientCase(TELEHAND_DEPLOY_DIR "/cases/stiff.toml");
  const JointModel fitted(pc.model), m(truth.model);
  for (int i = 0; i < kAxes; ++i) {
    const auto& c = pc.model.axes[static_cast<std::size_t>(i)];
    // 0.5 N over the range reached; the stiff case's axial wall, at the steep end of its
    // cubic, lands about half a degree off (docs/capture.md, "Known limits"): 0.7 N there.
    const double tolerance = i == kAxial ? 0.7 : 0.5;
    for (double d = c.min_deg; d <= c.max_deg; d += 1.0) {
      EXPECT_NEAR(fitted.holdingForceN(i, degToRad(d)), m.holdingForceN(i, degToRad(d)), tolerance)
          << kAxisNames[static_cast<std::size_t>(i)] << " at " << d << " deg";
    }
    const fs::path plot =
        dir / "plots" /
        ("stiff-fit-" + std::string(kAxisNames[static_cast<std::size_t>(i)]) + ".png");
    ASSERT_TRUE(fs::exists(plot)) << plot;
    EXPECT_GT(fs::file_size(plot), 10'000u);
  }

  // Not a capture session, no such session: clear errors, exit code 2.
  Process none({TELEHAND_RECORDS_BIN, "--db", db, "fit", "7"}, (dir / "none.log").string());
  EXPECT_EQ(none.wait(20s), 2);
  EXPECT_NE(none.output().find("no session 7"), std::string::npos) << none.output();
  if (!HasFailure()) fs::remove_all(dir);
}

}  // namespace
}  // namespace telehand::test
