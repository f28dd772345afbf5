#pragma once
/// Lessons (docs/lessons.md): what a demonstration sets as targets, how they are kept in the
/// record (text: one `key=value` per `;`), the plan a student's client receives, the guide
/// that leads the student, and which trials the feedback schedule shows feedback after.
#include <cstdint>
#include <map>
#include <optional>
#include <string>

#include "telehand/core/joint_model.h"
#include "telehand/core/massage_score.h"
#include "telehand/core/technique_score.h"
#include "telehand/protocol/lesson_plan.h"
#include "telehand/server/store/store.h"

namespace telehand::server::lesson {

/// What a trial's build-up takes before it is judged, seconds: the push rises over 1.5 s
/// (the simulated operator's ramp, a clinician's is similar), and the first oscillations on
/// the way up are no part of the technique. Used for the demonstration and every trial.
inline constexpr double kSettleS = 2.0;

/// A massage trial's build-up: the press and the circling come up over 0.5 s (the simulated
/// clinician's ramp); the first second is not judged.
inline constexpr double kMassageSettleS = 1.0;

/// The targets as the record keeps them; decode throws Error naming the key that is missing,
/// malformed or out of range (a record may be damaged or hostile).
std::string encodeTargets(const technique::Targets& t);
technique::Targets decodeTargets(const std::string& text);

/// A massage lesson's targets as the record keeps them (`technique=massage;` first); decode
/// throws Error naming the key that is missing, malformed or out of range.
std::string encodeMassageTargets(const technique::MassageTargets& t);
technique::MassageTargets decodeMassageTargets(const std::string& text);
/// A massage trial's scores as the record keeps them.
std::string encodeMassageScore(const technique::MassageScore& s);

/// A trial's scores as the record keeps them (key=value; oscillations are not listed).
std::string encodeScore(const technique::TrialScore& s);
/// Any key=value text as numbers (keys whose value is not a finite number are left out).
std::map<std::string, double> decodeFigures(const std::string& text);

/// The targets a demonstration record sets: its samples (valid ones, in order) as a series at
/// `force_scale`. Throws Error when the record is missing, too short or not an oscillation.
technique::Targets targetsFromRecord(store::SessionStore& store, uint64_t demo_session,
                                     double force_scale, double settle_s = kSettleS);
/// The same over the samples `first_seq`..`last_seq` of the record (a live session's latest
/// seconds: a supervisor's take-over).
technique::Targets targetsFromRecord(store::SessionStore& store, uint64_t demo_session,
                                     uint64_t first_seq, uint64_t last_seq, double force_scale,
                                     double settle_s);

/// A massage demonstration's targets: its valid samples at `force_scale` on the web `web`.
/// Throws Error when the record is missing, shorter than 3 s or draws no whole circle.
technique::MassageTargets massageTargetsFromRecord(store::SessionStore& store,
                                                   uint64_t demo_session, double force_scale,
                                                   const TissueParams& web,
                                                   double settle_s = kMassageSettleS);

/// How a trial is named in events and reports: "trial 2 (guided 50 %)", "trial 3 (attempt)".
std::string trialLabel(int index, const std::string& phase, double authority);

/// The guide of a guided trial: the targets' path and period at `authority` (0..1).
GuideParams guideFor(const technique::Targets& t, double authority);

/// The guide of a massage's guided trial (common/core/web_guide.h): the contact point round
/// the demonstration's circle (its centre and radius, one lap per 1/|frequency|, the way it
/// turned), starting at the circle's +x point, at `authority` (0..1).
GuideParams guideFor(const technique::MassageTargets& t, double authority);

/// The plan a student's client receives for `l` (common/protocol/lesson_plan.h).
LessonPlan planOf(const store::LessonInfo& l, const technique::Targets& t, double demo_s);
/// The plan of a massage lesson: its band is the pads' normal force, its frequency the
/// circle's laps per second; no exploration (it is the joint's) and no take-over.
LessonPlan planOf(const store::LessonInfo& l, const technique::MassageTargets& t, double demo_s);

}  // namespace telehand::server::lesson
