#include "telehand/server/session/session.h"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>

#include "telehand/core/clock.h"
#include "telehand/core/error.h"
#include "telehand/core/thimble.h"
#include "telehand/protocol/wire.h"
#include "telehand/server/lesson/lesson.h"
#include "telehand/server/session/session_manager.h"

namespace telehand::server::session {

JointModelParams openingModel(const PatientCase& patient) {
  JointModelParams p = patient.at(0.0);
  p.version = 1;
  p.knn = nullptr;
  return p;
}

Session::Session(SessionContext& context, const store::SessionInfo& session_info,
                 const telehand_msg_SessionCommand& cmd, const PatientCase& patient_case,
                 const sim::HandModel* hand_model, const sim::HandSimConfig& hand_config,
                 int64_t now_ns)
    : ctx(context),
      info(session_info),
      client_id(cmd.client_id),
      request_seq(cmd.request_seq),
      mode(cmd.mode),
      patient(patient_case),
      params(openingModel(patient_case)),
      model(params),
      opened_ns(now_ns),
      live(now_ns),
      recorder(session_info.id),
      hand(session_info.id, hand_model, params, hand_config, context.config.hand_deadband_weber,
           now_ns),
      hand_model_(hand_model),
      hand_config_(hand_config),
      next_recovery_check_ns_(now_ns + kNsPerS) {
  if (cmd.mode == telehand_msg_MODE_EXPLORATION) beginExploration("baseline");
  if (cmd.direct_force) direct_ = std::make_unique<JointProxy>(params);
}

void Session::beginExploration(const std::string& phase) {
  exploration_skipped_from_ = hand_skipped_;
  hand.beginExploration(phase);
}

void Session::endExploration(uint64_t client, int64_t now_ns) {
  hand.endExploration(ctx, client, now_ns, hand_skipped_ - exploration_skipped_from_);
}

void Session::publishModel() {
  telehand_msg_JointModel m{};
  toWire(params, info.id, m);
  m.source_time_ns = wallNs();
  ctx.out.publish(m);
}

void Session::adoptModel(JointModelParams next, std::shared_ptr<const KnnTorqueModel> knn) {
  next.version = params.version + 1;
  next.grip_offset_rad = hand.drift().offset();
  params = next;
  model = JointModel(params);
  hand.setModel(params);
  if (direct_) direct_->setModel(params);
  if (knn) knn_held_.push_back(std::move(knn));
  releaseKnn();
  publishModel();
}

void Session::releaseKnn() {
  // The direct renderer's waiting version, if any, is the newest: params.
  std::erase_if(knn_held_, [&](const std::shared_ptr<const KnnTorqueModel>& k) {
    const KnnTorqueModel* m = k.get();
    return m != params.knn && m != direct_knn_ && m != direct_knn_prev_;
  });
}

telehand_msg_SessionStatus statusOf(const store::SessionInfo& info, telehand_msg_SessionState state,
                                    uint64_t client_id, uint32_t request_seq,
                                    const std::string& location) {
  telehand_msg_SessionStatus st{};
  st.session_id = info.id;
  st.client_id = client_id;
  st.request_seq = request_seq;
  st.source_time_ns = wallNs();
  st.state = state;
  st.mode = parseMode(info.mode).value_or(telehand_msg_MODE_MOBILIZATION);
  st.started_ns = info.started_ns;
  st.ended_ns = info.ended_ns;
  st.samples_recorded = info.samples;
  st.samples_missing = info.missing();
  copyString(st.case_name, info.case_name);
  copyString(st.user, info.user);
  copyString(st.record, location + " session " + std::to_string(info.id));
  return st;
}

void Session::publishStatus(telehand_msg_SessionState state) {
  telehand_msg_SessionStatus st =
      statusOf(info, state, client_id, request_seq, ctx.store.location());
  st.mode = mode;
  st.ended_ns = state == telehand_msg_SESSION_CLOSED ? wallNs() : 0;
  st.samples_recorded = recorder.recorded();
  st.stored_below = recorder.storedBelow();
  st.samples_missing = state == telehand_msg_SESSION_CLOSED && expected > storedOfExpected()
                           ? expected - storedOfExpected()
                           : 0;
  if (lesson) copyString(st.lesson, encodePlan(lesson->plan));
  ctx.out.publish(st);
}

void Session::onLive(const Sample& d, int64_t now_ns) {
  live.touch(now_ns);
  if (auto bad = firstInvalid(d)) {
    recorder.invalidSample(ctx, client_id, d, *bad, now_ns);
    return;
  }
  ++ctx.stats.live_samples;
  const PerFinger<Vec3> grip = thimblePositions(d);
  const bool coded = (d.flags & sample_flags::kDeadband) != 0;
  if (direct_ && live.isNew(d)) {
    // The baseline design: the server renders the force with the same proxy the client
    // would run, on device time, and sends it back.
    const ProxyOutput out = direct_->render(grip, d.source_time_ns);
    // What the direct renderer may still use: its current model and, while it fades, the
    // one before.
    const KnnTorqueModel* current = direct_->model().params().knn;
    if (current != direct_knn_) {
      direct_knn_prev_ = direct_knn_;
      direct_knn_ = current;
    }
    if (!direct_->blending() && direct_knn_prev_) {
      direct_knn_prev_ = nullptr;
      releaseKnn();
    }
    telehand_msg_DirectForce f{};
    toWire(info.id, d.seq, wallNs(), out.force_device_n, f);
    ctx.out.publish(f);
    ++direct_sent_;
  }
  const bool is_new = live.isNew(d);
  const uint64_t steps =
      is_new ? std::min<uint64_t>(live.ticksTo(d), coded ? SessionManager::kMaxHeldSteps
                                                         : SessionManager::kMaxCatchUpSteps)
             : 0;
  if (is_new) hand.stepWeb(d, grip, steps, coded, model);
  if (hand.simulated() && is_new) {
    if (!hand_deferred) {
      stepTo(d, grip, steps, coded, now_ns);
    } else {
      if (hand_queue_.size() >= SessionManager::kMaxHandQueue) {
        // The hand is this far behind the live stream: every other sample waiting goes (the
        // newest stays), and the hand steps in 2 ms strides over them rather than lag
        // further. The record has every sample all the same.
        std::size_t kept = 0;
        const std::size_t n = hand_queue_.size();
        for (std::size_t i = 0; i < n; ++i) {
          if ((n - 1 - i) % 2 == 0) hand_queue_[kept++] = hand_queue_[i];
        }
        hand_skipped_ += n - kept;
        ctx.stats.hand_samples_skipped += n - kept;
        hand_queue_.resize(kept);
      }
      hand_queue_.push_back({d, grip, steps, coded});
    }
  } else if (!hand.simulated()) {
    hand.observeGrip(grip, model);
  }
  live.accept(d, coded);
}

void Session::stepTo(const Sample& d, const PerFinger<Vec3>& grip, uint64_t steps, bool coded,
                     int64_t now_ns) {
  Vec3 before = Vec3::Zero();
  if (hand.advance(ctx, d, grip, steps, coded, model, mode, &before)) {
    ++ctx.stats.drift_corrections;
    adoptModel(params, nullptr);
    hand.reportDrift(ctx, before, params.version, now_ns);
  }
}

bool Session::stepHand(int64_t deadline_ns, int64_t now_ns) {
  // At least one sample per turn: a hand whose steps outlast the slice still moves.
  SteadyClock clock;
  while (!hand_queue_.empty()) {
    const PendingStep p = hand_queue_.front();
    hand_queue_.pop_front();
    stepTo(p.d, p.grip, p.steps, p.coded, now_ns);
    if (!hand_queue_.empty() && deadline_ns != INT64_MAX && clock.nowNs() >= deadline_ns) {
      return false;
    }
  }
  return true;
}

void Session::onRecord(std::vector<Sample>&& samples, std::vector<uint8_t>&& valid,
                       int64_t now_ns) {
  live.touch(now_ns);
  if (closing && !samples.empty()) close_wait.samplesCame(now_ns);
  capture.add(samples, valid, now_ns);
  recorder.add(std::move(samples), std::move(valid));  // stored at the round's tick
}

void Session::tick(int64_t now_ns) {
  // What the round took, in one write: the acknowledgement below counts it.
  recorder.flush(ctx);
  live.updateRate(now_ns);
  // The record's acknowledgement (what the client may forget) when it has grown, and at
  // least every kHeartbeatNs: a client that hears nothing for longer knows its server went
  // away (docs/recovery.md), even while its chunks are held up on the way.
  // A closing session goes on acknowledging (as CLOSING) while it waits for what its record
  // lacks: its client, with a backlog still on the way, must neither think its server went
  // away nor give up on a close that progresses.
  if (now_ns >= next_ack_ns_ && (recorder.storedBelow() != acked_below_ ||
                                 now_ns >= std::max(last_status_ns_, opened_ns) + kHeartbeatNs)) {
    acked_below_ = recorder.storedBelow();
    last_status_ns_ = now_ns;
    next_ack_ns_ = now_ns + kAckPeriodNs;
    publishStatus(closing ? telehand_msg_SESSION_CLOSING : telehand_msg_SESSION_ACTIVE);
  }
  if (replay) {
    // A replay is this session's HandState while it lasts (a lesson's watch phase ends
    // with it; a replay session stays open, at its end, until its viewer closes it).
    replay->tick(now_ns);
    live.touch(now_ns);
    if (replay->finished() && mode == telehand_msg_MODE_LESSON) {
      ctx.event(info.id, client_id, telehand_msg_EVENT_INFO, "watch: the demonstration ended",
                now_ns);
      endReplay();
    } else if (replay->finished() && !closing) {
      // A replay session ends with its record: closed now (it records nothing of its own).
      ctx.event(info.id, client_id, telehand_msg_EVENT_INFO,
                "replay: the end of the record (" + std::to_string(replay->stepped()) +
                    " samples replayed)",
                now_ns);
      closing = true;
      expected = 0;
      close_wait = {.deadline_ns = now_ns};
    }
  } else {
    hand.publishDue(ctx, live, model, now_ns);
  }
  if (lesson) lesson->scoreDue(ctx, info.id, client_id, params.force_scale, now_ns, false);
  followTakeover(now_ns);
}

void Session::startReplay(uint64_t source, const JointModelParams& m, double speed,
                          int64_t now_ns) {
  JointModelParams start = m;
  start.guide = GuideParams{};
  replay = std::make_unique<Replay>(ctx, info.id, source, start, hand_model_, hand_config_, now_ns);
  replay->continueSeq(hand.published());  // viewers see one sequence of HandStates
  replay->setSpeed(speed > 0.0 ? speed : 1.0, now_ns);
  replay->play(now_ns);
}

void Session::endReplay() {
  if (!replay) return;
  hand.continueSeq(replay->published());
  replay.reset();
}

void Session::cutReplay(const std::string& why, int64_t now_ns) {
  if (replay && !replay->finished() && mode == telehand_msg_MODE_LESSON) {
    // The record says how much of the demonstration was seen rather than that it was
    // watched.
    char buf[120];
    std::snprintf(buf, sizeof buf,
                  "watch: the demonstration was cut short at %.1f of %.1f s (%llu samples "
                  "replayed): ",
                  replay->positionS(), replay->durationS(),
                  static_cast<unsigned long long>(replay->stepped()));
    ctx.event(info.id, client_id, telehand_msg_EVENT_INFO, buf + why, now_ns);
  }
  endReplay();
}

void Session::setGuide(double authority, int64_t now_ns) {
  guide_authority_ = lesson ? authority : 0.0;
  JointModelParams next = params;
  next.guide = GuideParams{};
  std::optional<technique::Targets> taken;
  if (guide_authority_ > 0.0) {
    if (takeover_source_ != 0) taken = takeoverTargets(now_ns);
    next.guide = lesson->massage ? lesson::guideFor(*lesson->massage, authority)
                                 : lesson::guideFor(taken ? *taken : lesson->targets, authority);
    next_takeover_ns_ = now_ns + kTakeoverRefreshNs;
  }
  if (next.guide == params.guide) return;
  adoptModel(next, nullptr);
  if (taken) announceTakeover(*taken, now_ns);
}

void Session::announceTakeover(const technique::Targets& t, int64_t now_ns) {
  char text[160];
  std::snprintf(text, sizeof text,
                "take-over: the guide follows session %llu: %.2f Hz, flexion amplitude %.1f deg",
                static_cast<unsigned long long>(takeover_source_), t.frequency_hz, t.amplitude_deg);
  ctx.event(info.id, client_id, telehand_msg_EVENT_INFO, text, now_ns);
}

std::optional<technique::Targets> Session::takeoverTargets(int64_t now_ns) {
  auto problem = [&](const std::string& why) -> std::optional<technique::Targets> {
    if (why != takeover_problem_) {
      takeover_problem_ = why;
      ctx.event(info.id, client_id, telehand_msg_EVENT_INFO,
                "take-over: " + why + "; the guide keeps its path", now_ns);
    }
    return std::nullopt;
  };
  std::optional<store::SessionStore::Extent> extent;
  try {
    extent = ctx.store.extent(takeover_source_);
  } catch (const Error& e) {
    return problem(std::string("session ") + std::to_string(takeover_source_) +
                   "'s record cannot be read (" + e.what() + ")");
  }
  if (!extent || extent->last_seq - extent->first_seq + 1 < 3000) {
    return problem("session " + std::to_string(takeover_source_) +
                   " has recorded less than 3 s of movement yet");
  }
  const uint64_t first =
      extent->last_seq >= kTakeoverWindow ? extent->last_seq - kTakeoverWindow + 1 : 0;
  try {
    technique::Targets t =
        lesson::targetsFromRecord(ctx.store, takeover_source_, std::max(first, extent->first_seq),
                                  extent->last_seq, params.force_scale, 0.0);
    takeover_last_seq_ = extent->last_seq;
    takeover_problem_.clear();
    return t;
  } catch (const Error& e) {
    return problem(e.what());
  }
}

void Session::followTakeover(int64_t now_ns) {
  if (takeover_source_ == 0 || guide_authority_ <= 0.0 || now_ns < next_takeover_ns_) return;
  next_takeover_ns_ = now_ns + kTakeoverRefreshNs;
  const auto t = takeoverTargets(now_ns);
  if (!t) return;
  const GuideParams next = lesson::guideFor(*t, guide_authority_);
  // A new path restarts the guide's period on the student's device (with a fade): only a
  // change the student would feel is worth it.
  double moved_deg = 0.0;
  for (std::size_t k = 0; k < next.path_rad.size(); ++k) {
    moved_deg = std::max(moved_deg, radToDeg((next.path_rad[k] - params.guide.path_rad[k]).norm()));
  }
  const double period_change =
      params.guide.period_s > 0.0 ? std::abs(next.period_s / params.guide.period_s - 1.0) : 1.0;
  if (moved_deg < kTakeoverPathDeg && period_change < kTakeoverPeriodChange) return;
  JointModelParams p = params;
  p.guide = next;
  adoptModel(p, nullptr);
  announceTakeover(*t, now_ns);
}

void Session::onTakeover(const telehand_msg_SessionCommand& cmd, const Session* source,
                         const std::string& who, int64_t now_ns) {
  auto refuse = [&](const std::string& why) {
    ++ctx.stats.bad_commands;
    if (++takeover_refusals_ > kMaxTakeoverRefusals) return;
    ctx.event(info.id, cmd.client_id, telehand_msg_EVENT_ERROR,
              "take-over by " + who + " refused: " + why +
                  (takeover_refusals_ == kMaxTakeoverRefusals
                       ? " (further refused take-overs of this session are counted, not recorded)"
                       : ""),
              now_ns);
  };
  if (mode != telehand_msg_MODE_LESSON || !lesson) return refuse("the session runs no lesson");
  if (!lesson->plan.takeover) {
    return refuse("lesson " + std::to_string(lesson->info.id) +
                  " does not allow one (telehand-records lesson create --takeover)");
  }
  if (closing) return refuse("the session is closing");
  if (takeovers_ >= kMaxTakeovers) {
    return refuse("the run has taken " + std::to_string(kMaxTakeovers) + " take-overs already");
  }
  if (cmd.follow_session != 0) {
    if (!source) return refuse("session " + std::to_string(cmd.follow_session) + " is not open");
    if (source == this) return refuse("a session cannot lead itself");
    if (source->mode != telehand_msg_MODE_MOBILIZATION || source->closing) {
      return refuse("session " + std::to_string(source->info.id) +
                    " is not an open mobilization at an MF-2");
    }
  }
  ++takeovers_;
  takeover_source_ = cmd.follow_session;
  takeover_problem_.clear();
  if (takeover_source_ != 0) {
    ctx.event(info.id, cmd.client_id, telehand_msg_EVENT_INFO,
              "take-over: " + who + " leads the guided trials from session " +
                  std::to_string(takeover_source_) + " (user " + source->info.user + ")",
              now_ns);
  } else {
    ctx.event(info.id, cmd.client_id, telehand_msg_EVENT_INFO,
              "take-over ended by " + who + ": the guided trials follow the demonstration", now_ns);
  }
  if (guide_authority_ > 0.0) setGuide(guide_authority_, now_ns);
}

void Session::onPhase(const telehand_msg_SessionCommand& cmd, int64_t now_ns) {
  const std::string phase(cmd.text, strnlen(cmd.text, sizeof cmd.text));
  auto refuse = [&](const std::string& why) {
    ++ctx.stats.bad_commands;
    ctx.event(info.id, cmd.client_id, telehand_msg_EVENT_ERROR,
              "phase '" + phase.substr(0, 32) + "' refused: " + why, now_ns);
  };
  if (mode == telehand_msg_MODE_REPLAY) {
    if (!replay) return refuse("the replay is not running");
    if (phase == "pause") {
      replay->pause(now_ns);
    } else if (phase == "play") {
      replay->play(now_ns);
    } else if (phase == "speed") {
      if (!std::isfinite(cmd.value)) return refuse("the speed is not a number");
      replay->setSpeed(cmd.value, now_ns);
    } else if (phase == "loop") {
      replay->setLoop(cmd.value != 0.0);
    } else {
      return refuse("a replay knows pause, play, speed and loop");
    }
    return;
  }
  if (mode != telehand_msg_MODE_LESSON || !lesson) return refuse("the session runs no lesson");
  const bool known = phase == "baseline" || phase == "watch" || phase == "guided" ||
                     phase == "attempt" || phase == "rest" || phase == "reassessment";
  if (!known) {
    return refuse("a lesson knows baseline, watch, guided, attempt, rest and reassessment");
  }
  if (lesson->massage && (phase == "baseline" || phase == "reassessment")) {
    return refuse("a massage lesson has no exploration (it measures the joint's range)");
  }
  if (phase == "guided" && !(cmd.value > 0.0 && cmd.value <= 1.0)) {
    return refuse("a guided trial's authority must be in (0, 1]");
  }
  if (lesson->trialsBegun() >= lesson->plan.guided + lesson->plan.attempts &&
      (phase == "guided" || phase == "attempt")) {
    return refuse("the lesson's " + std::to_string(lesson->trialsBegun()) + " trials are done");
  }
  // The stream may lag the command (it travels on its own topics), by seconds at most.
  if (cmd.last_seq >= sample_bounds::kMaxSeq ||
      cmd.last_seq > (have_seq ? seq_high : 0) + SessionManager::kSeqWindow) {
    return refuse("its last sample " + std::to_string(cmd.last_seq) +
                  " is beyond the session's stream");
  }
  // Whatever ran ends here: the trial (it waits for its record to be scored), the
  // exploration phase (scored now), the demonstration.
  lesson->end(cmd.last_seq, now_ns);
  endExploration(client_id, now_ns);
  // The student moved on before the demonstration's end (their client's watch time ran out
  // while this server replayed it slower than real time, or they chose to).
  cutReplay("the " + phase + " phase began before it ended", now_ns);
  const uint64_t next_seq = cmd.last_seq + 1;
  if (phase == "baseline" || phase == "reassessment") {
    setGuide(0.0, now_ns);
    beginExploration(phase);
  } else if (phase == "watch") {
    setGuide(0.0, now_ns);
    try {
      startReplay(lesson->info.demo_session, openingModel(patient),
                  cmd.value > 0.0 ? cmd.value : 1.0, now_ns);
    } catch (const Error& e) {
      return refuse(std::string("the demonstration cannot be replayed: ") + e.what());
    }
  } else if (phase == "guided") {
    lesson->begin("guided", cmd.value, next_seq);
    setGuide(cmd.value, now_ns);
  } else if (phase == "attempt") {
    lesson->begin("attempt", 0.0, next_seq);
    setGuide(0.0, now_ns);
  } else {  // rest
    setGuide(0.0, now_ns);
  }
  std::string text = "phase: " + phase;
  if (phase == "guided") {
    text += " (guide authority " + std::to_string(std::lround(100 * cmd.value)) + " %)";
  }
  ctx.event(info.id, cmd.client_id, telehand_msg_EVENT_INFO, text, now_ns);
}

void Session::recoverIfDue(int64_t now_ns) {
  if (!patient.recovers || now_ns < next_recovery_check_ns_) return;
  next_recovery_check_ns_ = now_ns + kNsPerS;
  recover(now_ns);
}

void Session::recover(int64_t now_ns) {
  JointModelParams next = patient.at(hand.treatmentS());
  double grown = 0.0;
  for (std::size_t i = 0; i < kAxes; ++i) {
    grown = std::max({grown, params.axes[i].min_deg - next.axes[i].min_deg,
                      next.axes[i].max_deg - params.axes[i].max_deg});
  }
  if (grown < SessionManager::kRecoveryStepDeg) return;  // not a change anyone would feel
  adoptModel(next, nullptr);
  char text[160];
  std::snprintf(text, sizeof text,
                "recovery: after %.0f s of treatment, flexion range %.1f..%.1f deg (model v%u)",
                hand.treatmentS(), params.axes[kFlexion].min_deg, params.axes[kFlexion].max_deg,
                params.version);
  ctx.event(info.id, 0, telehand_msg_EVENT_INFO, text, now_ns);
}

bool Session::close(const std::string& state, int64_t now_ns) {
  // A client that closes mid-watch (or a session ended for it) ends the demonstration too.
  cutReplay("the session ended (" + state + ") before it did", now_ns);
  if (lesson) {
    // The last trial ends with the record; everything waiting is scored on what arrived.
    lesson->end(seq_high, now_ns);
    lesson->scoreDue(ctx, info.id, client_id, params.force_scale, now_ns, true);
    ctx.event(info.id, client_id, telehand_msg_EVENT_SCORE, lesson->summary(), now_ns);
  }
  {
    // The link's packet rates, into the record.
    const double secs = std::max(static_cast<double>(now_ns - opened_ns) * 1e-9, 1e-3);
    char text[240];
    std::snprintf(text, sizeof text,
                  "link: DeviceState %.1f packets/s received live (%s), HandState %.1f/s "
                  "published (%llu withheld by the deadband)%s",
                  static_cast<double>(live.count()) / secs,
                  live.deadbandCoded() ? "deadband-coded" : "every sample",
                  static_cast<double>(hand.published()) / secs,
                  static_cast<unsigned long long>(hand.withheld()),
                  direct_ ? (", DirectForce " +
                             std::to_string(static_cast<long long>(
                                 std::llround(static_cast<double>(direct_sent_) / secs))) +
                             "/s sent")
                                .c_str()
                          : "");
    std::string link = text;
    if (hand_skipped_ > 0) {
      // The server had less CPU for the hands than they needed: the record is whole, the hand
      // stepped over some of the live stream.
      link += "; the hand stepped over " + std::to_string(hand_skipped_) +
              " live samples (the server's hands were short of CPU)";
    }
    ctx.event(info.id, client_id, telehand_msg_EVENT_INFO, link, now_ns);
  }
  closed_ns = wallNs();
  try {
    ctx.store.closeSession(info.id, closed_ns, expected, state);
  } catch (const StoreError& e) {
    // The record still says active: CLOSED would tell the client a close the record does not
    // hold. The server closes it again until the record takes it (SessionManager::tick).
    ++ctx.stats.store_errors;
    spdlog::error("session {}: the record would not close it ({}); trying again", info.id,
                  e.what());
    ctx.event(info.id, client_id, telehand_msg_EVENT_ERROR,
              "the record would not take the session's close (" + std::string(e.what()) +
                  "); the server tries again",
              now_ns);
    return false;
  }
  const uint64_t recorded = recorder.recorded();
  const uint64_t stored = storedOfExpected();
  const uint64_t missing = expected > stored ? expected - stored : 0;
  ctx.event(info.id, client_id, missing ? telehand_msg_EVENT_ERROR : telehand_msg_EVENT_INFO,
            state + ": " + std::to_string(recorded) + " samples recorded" +
                (missing ? ", " + std::to_string(missing) + " missing" : "") +
                (recorder.nonfinite() ? ", " + std::to_string(recorder.nonfinite()) +
                                            " non-finite live samples ignored"
                                      : ""),
            now_ns);
  publishStatus(telehand_msg_SESSION_CLOSED);
  return true;
}

}  // namespace telehand::server::session
