#pragma once
/// The hand of a replay in the console: a recorded session's samples run through the server's
/// own replay (server/session `Replay`: every sample steps a Bullet hand through
/// HandRunner::advance on device time, as the live samples did), as fast as the machine goes,
/// with the HandState it publishes taken every 1/hz s of record. The same record gives the
/// same states as the session showed live (docs/lessons.md "Watch: the replay").
#include <cstdint>
#include <functional>
#include <string>

#include "telehand/protocol/dds.h"
#include "telehand/server/sim/hand_model.h"

namespace telehand::web {

struct ReplayHandOptions {
  std::string cases_dir;          ///< patient cases (*.toml); '' = the built-in healthy case only
  double hz = 50.0;               ///< hand frames per second of record, at most
  double min_hz = 10.0;           ///< a long record lowers the rate to fit max_frames, down to this
  std::size_t max_frames = 9000;  ///< frames in all, at most
  double max_s = 600.0;           ///< seconds of record simulated, at most
};

struct ReplayHandResult {
  bool ok = false;    ///< the hand ran (to the end, to a bound, or until cancelled)
  std::string error;  ///< why there is no hand, when !ok
  std::string case_name;
  double hz = 0.0;           ///< frames per second of record
  std::size_t frames = 0;    ///< HandStates passed on
  uint64_t samples = 0;      ///< samples that stepped the hand
  double duration_s = 0.0;   ///< the record's, first sample to last
  double simulated_s = 0.0;  ///< the part of it the hand covers, from its start
  bool cut = false;          ///< stopped at a bound (max_s, max_frames) before the record's end
  bool cancelled = false;    ///< `keep_going` said stop
  double compute_s = 0.0;    ///< wall time it took
};

/// Runs session `session` of the store `db` (opened read-only) on `hand`, with the patient
/// case its session row names and the model the server's replay starts on (openingModel,
/// unguided). `on_frame` gets each HandState (source time = the device time of the sample it
/// reflects); `keep_going(done_s)` is asked between frames, false stops. Never throws: a
/// missing session, case or record and a store that cannot be read come back as `error`.
ReplayHandResult replayHand(const std::string& db, uint64_t session,
                            const server::sim::HandModel& hand, const ReplayHandOptions& options,
                            const std::function<void(const telehand_msg_HandState&)>& on_frame,
                            const std::function<bool(double done_s)>& keep_going);

}  // namespace telehand::web
