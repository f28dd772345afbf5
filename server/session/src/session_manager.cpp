#include "telehand/server/session/session_manager.h"

#include <fmt/format.h>
#include <spdlog/spdlog.h>
#if defined(__GLIBC__)
#include <malloc.h>
#endif

#include <algorithm>
#include <cstring>
#include <filesystem>
#include <string_view>

#include "telehand/core/clock.h"
#include "telehand/core/error.h"
#include "telehand/protocol/wire.h"
#include "telehand/server/lesson/lesson.h"
#include "telehand/server/session/session.h"

namespace telehand::server::session {

SessionManager::SessionManager(SessionStore& store, Outbox& out, const ServerConfig& config,
                               const sim::HandModel* hand)
    : store_(store),
      out_(out),
      config_(config),
      hand_(hand),
      ctx_{store_, out_, config_, stats_,
           [this](uint64_t session_id, uint64_t client_id, telehand_msg_EventKind kind,
                  const std::string& text,
                  int64_t now_ns) { event(session_id, client_id, kind, text, now_ns); }} {
  ended_owners_.reserve(kMaxEndedOwners);
  answered_opens_.reserve(kMaxAnsweredOpens);
}

SessionManager::~SessionManager() = default;

Session* SessionManager::find(uint64_t session_id) {
  auto it = sessions_.find(session_id);
  return it == sessions_.end() ? nullptr : &it->second;
}

void SessionManager::event(uint64_t session_id, uint64_t client_id, telehand_msg_EventKind kind,
                           const std::string& text, int64_t now_ns) {
  (void)now_ns;
  telehand_msg_SessionEvent e{};
  e.session_id = session_id;
  e.seq = ++event_seq_;
  e.source_time_ns = wallNs();
  e.kind = kind;
  e.client_id = client_id;
  copyString(e.text, text);
  out_.publish(e);
  if (session_id != 0 && sessions_.count(session_id)) {
    try {
      store_.appendEvent(session_id, {e.source_time_ns, std::string(eventKindName(kind)), text});
    } catch (const StoreError& err) {
      ++stats_.store_errors;
      spdlog::error("{}", err.what());
    }
  }
  if (kind == telehand_msg_EVENT_ERROR) {
    spdlog::warn("session {}: {}", session_id, text);
  } else {
    spdlog::info("session {}: {}", session_id, text);
  }
}

namespace {

/// Rate-limit keys of OPEN refusals: the sender's participant handle with the top bit set,
/// apart from session ids.
constexpr uint64_t kOpenKey = uint64_t{1} << 63;

/// Whether an event about `id` is due: at most one per 5 s per id. A flood of ids must not
/// grow memory: past `cap` ids, those not reported for 5 s are forgotten, and past the cap
/// new ones stay unreported (the stats still count them).
bool reportDue(std::map<uint64_t, int64_t>& reported, std::size_t cap, uint64_t id,
               int64_t now_ns) {
  if (reported.size() >= cap && !reported.count(id)) {
    std::erase_if(reported, [&](const auto& kv) { return now_ns - kv.second >= 5 * kNsPerS; });
    if (reported.size() >= cap) return false;
  }
  auto [it, fresh] = reported.try_emplace(id, now_ns);
  if (!fresh && now_ns - it->second < 5 * kNsPerS) return false;
  it->second = now_ns;
  return true;
}
}  // namespace

void SessionManager::unknownSession(uint64_t session_id, const std::string& what, int64_t now_ns) {
  if (!reportDue(unknown_reported_ns_, kMaxUnknownIds, session_id, now_ns)) return;
  event(0, 0, telehand_msg_EVENT_ERROR,
        what + " for unknown session " + std::to_string(session_id) + " dropped", now_ns);
}

void SessionManager::badCommand(uint64_t client_id, const Origin& from, const std::string& what,
                                int64_t now_ns) {
  ++stats_.bad_commands;
  // An honest client hears about its own bad command; a participant sending a flood of them
  // is heard kBadCommandEvents times per 5 s (each event is published and logged), the rest
  // counted. Callers without DDS (participant 0) are not limited.
  if (from.participant != 0) {
    if (bad_commands_by_.size() >= kMaxUnknownIds && !bad_commands_by_.count(from.participant)) {
      std::erase_if(bad_commands_by_,
                    [&](const auto& kv) { return now_ns - kv.second.first >= 5 * kNsPerS; });
      if (bad_commands_by_.size() >= kMaxUnknownIds) return;
    }
    auto& [since, count] = bad_commands_by_[from.participant];
    if (count == 0 || now_ns - since >= 5 * kNsPerS) {
      since = now_ns;
      count = 0;
    }
    if (++count > kBadCommandEvents) return;
  }
  event(0, client_id, telehand_msg_EVENT_ERROR, what, now_ns);
}

void SessionManager::refuse(uint64_t session_id, uint64_t client_id, const std::string& what,
                            uint64_t count, int64_t now_ns, std::optional<uint64_t> rate_key) {
  stats_.refused += count;
  if (!reportDue(refused_reported_ns_, kMaxUnknownIds, rate_key.value_or(session_id), now_ns))
    return;
  // Under the session's key only for a session this server runs or holds for its client: any
  // other id, made up by the sender, would be a new instance of the transient-local
  // SessionEvent topic that nothing retires, kept for good and replayed to every late joiner.
  // Those go under session 0, the id named in the text.
  const bool here = sessions_.count(session_id) > 0 || suspended_.count(session_id) > 0;
  event(here ? session_id : 0, client_id, telehand_msg_EVENT_ERROR,
        "security: refused " + what +
            (here || session_id == 0 ? "" : " (for session " + std::to_string(session_id) + ")") +
            " (" + std::to_string(stats_.refused) + " refused by this server so far)",
        now_ns);
}

namespace {
/// Who sent something, for an event.
std::string senderOf(const Origin& from) {
  if (from.unknown)
    return "a participant that had left before it was read (its sender cannot be told)";
  return "participant " + (from.guid.empty() ? std::string("?") : from.guid);
}
}  // namespace

bool SessionManager::owns(const Session& s, const Origin& from) {
  if (from.unknown) return false;
  return from.participant == 0 || s.owner == 0 || from.participant == s.owner;
}

bool SessionManager::owns(Session& s, const Origin& from, const char* what, uint64_t count,
                          int64_t now_ns) {
  if (owns(s, from)) return true;
  refuse(s.info.id, s.client_id,
         std::string(what) + " from " + senderOf(from) + ": session " + std::to_string(s.info.id) +
             " belongs to " + s.info.owner,
         count, now_ns);
  return false;
}

void SessionManager::rememberOwner(uint64_t session_id, const std::string& owner) {
  EndedOwner e;
  e.session_id = session_id;
  owner.copy(e.guid.data(), e.guid.size() - 1);
  for (EndedOwner& known : ended_owners_) {
    if (known.session_id == session_id) {
      known = e;
      return;
    }
  }
  if (ended_owners_.size() < kMaxEndedOwners) {
    ended_owners_.push_back(e);
  } else {
    ended_owners_[ended_next_] = e;
  }
  ended_next_ = (ended_next_ + 1) % kMaxEndedOwners;
}

const SessionManager::EndedOwner* SessionManager::rememberedOwner(uint64_t session_id) const {
  const auto it = std::find_if(ended_owners_.begin(), ended_owners_.end(),
                               [&](const EndedOwner& e) { return e.session_id == session_id; });
  return it == ended_owners_.end() ? nullptr : &*it;
}

void SessionManager::onCommand(const telehand_msg_SessionCommand& cmd, int64_t now_ns,
                               const Origin& from) {
  progress_.fetch_add(1, std::memory_order_relaxed);
  // In a pool every server hears every command: one for a session another server runs is
  // that server's (an OPEN goes through the record's assignment, a resume to the claimer).
  if (cmd.kind != telehand_msg_CMD_OPEN && cmd.session_id != 0 && elsewhere(cmd.session_id)) {
    return;
  }
  if (from.unknown) {
    // No OPEN (its session would belong to nobody, and so take anyone's CLOSE), no command on
    // a session, from a sender nobody can name.
    refuse(cmd.session_id, cmd.client_id,
           "a command (kind " + std::to_string(static_cast<int>(cmd.kind)) + ") from " +
               senderOf(from),
           1, now_ns, cmd.session_id == 0 ? std::optional<uint64_t>(kOpenKey) : std::nullopt);
    return;
  }
  if (cmd.kind == telehand_msg_CMD_MARK) {
    // Anyone the access control lets write commands (a device, a supervisor) may mark a
    // session; another participant's mark is kept attributed to it, never acts on the
    // session, and is bounded per session.
    if (Session* s = find(cmd.session_id); s && !owns(*s, from)) {
      if (s->foreign_marks >= kMaxForeignMarks) {
        refuse(s->info.id, s->client_id,
               "a MARK from " + senderOf(from) + ": session " + std::to_string(s->info.id) +
                   " holds " + std::to_string(kMaxForeignMarks) + " marks from other participants",
               1, now_ns);
        return;
      }
      ++s->foreign_marks;
      event(cmd.session_id, cmd.client_id, telehand_msg_EVENT_MARK,
            std::string(cmd.text) + " (from participant " +
                (from.identity.empty() ? from.guid : from.identity) + ")",
            now_ns);
      return;
    }
  } else if (cmd.kind != telehand_msg_CMD_OPEN && cmd.kind != telehand_msg_CMD_TAKEOVER) {
    // A TAKEOVER comes from a supervisor, not the session's owner: the session itself
    // decides (its lesson must allow it), and the record names who asked.
    if (Session* s = find(cmd.session_id)) {
      if (!owns(*s, from, cmd.kind == telehand_msg_CMD_PHASE ? "a PHASE" : "a CLOSE", 1, now_ns))
        return;
    }
  }
  // A command acts after the live samples that came before it: its session's hand steps to
  // them first.
  if (cmd.kind != telehand_msg_CMD_OPEN) {
    if (Session* s = find(cmd.session_id)) s->flushHand(now_ns);
  }
  switch (cmd.kind) {
    case telehand_msg_CMD_OPEN:
      open(cmd, now_ns, from);
      return;
    case telehand_msg_CMD_CLOSE:
      requestClose(cmd, now_ns, from);
      return;
    case telehand_msg_CMD_MARK: {
      if (!sessions_.count(cmd.session_id)) {
        badCommand(cmd.client_id, from,
                   "MARK for unknown session " + std::to_string(cmd.session_id), now_ns);
        return;
      }
      event(cmd.session_id, cmd.client_id, telehand_msg_EVENT_MARK, cmd.text, now_ns);
      Session& s = sessions_.at(cmd.session_id);
      if (std::string(cmd.text) == "reassessment") {
        s.endExploration(s.client_id, now_ns);
        s.beginExploration("reassessment");
      }
      return;
    }
    case telehand_msg_CMD_PHASE: {
      Session* s = find(cmd.session_id);
      if (!s) {
        badCommand(cmd.client_id, from,
                   "PHASE for unknown session " + std::to_string(cmd.session_id), now_ns);
        return;
      }
      s->onPhase(cmd, now_ns);
      return;
    }
    case telehand_msg_CMD_TAKEOVER: {
      Session* s = find(cmd.session_id);
      if (!s) {
        badCommand(cmd.client_id, from,
                   "TAKEOVER for unknown session " + std::to_string(cmd.session_id), now_ns);
        return;
      }
      const std::string who =
          "participant " +
          (from.identity.empty() ? (from.guid.empty() ? "?" : from.guid) : from.identity);
      s->onTakeover(cmd, cmd.follow_session ? find(cmd.follow_session) : nullptr, who, now_ns);
      return;
    }
  }
  badCommand(cmd.client_id, from,
             "unknown command kind " + std::to_string(static_cast<int>(cmd.kind)), now_ns);
}

void SessionManager::open(const telehand_msg_SessionCommand& cmd, int64_t now_ns,
                          const Origin& from, const SessionInfo* resumed) {
  if (cmd.session_id != 0 && !resumed) {
    resume(cmd, now_ns, from);
    return;
  }
  const std::string open_key = fmt::format("{}:{:x}:{}", from.guid.empty() ? "?" : from.guid,
                                           cmd.client_id, cmd.request_seq);
  AnsweredOpen answer;
  answer.client_id = cmd.client_id;
  answer.request_seq = cmd.request_seq;
  (from.guid.empty() ? std::string_view("?") : std::string_view(from.guid))
      .copy(answer.guid.data(), answer.guid.size() - 1);
  if (!resumed) {
    if (const auto it = std::find_if(answered_opens_.begin(), answered_opens_.end(),
                                     [&](const AnsweredOpen& a) {
                                       return a.client_id == answer.client_id &&
                                              a.request_seq == answer.request_seq &&
                                              a.guid == answer.guid;
                                     });
        it != answered_opens_.end()) {
      // The same request again (its answer was lost, or it came before the client saw it):
      // the session it made, announced again.
      if (Session* again = find(it->session_id)) {
        again->publishStatus(telehand_msg_SESSION_ACTIVE);
        again->publishModel();
      }
      return;
    }
  }
  if (pooled() && !resumed) {
    // The record assigns the OPEN to the least-loaded server of the pool, once: the others
    // stay silent.
    try {
      if (store_.poolAssign(open_key) != pool_id_) return;
    } catch (const StoreError& e) {
      ++stats_.store_errors;
      spdlog::error("an OPEN from participant {}: {}", from.guid, e.what());
      return;
    }
  }
  // Bounds: a flood of OPENs must not take the server's memory (each session holds a hand).
  if (sessions_.size() >= static_cast<std::size_t>(config_.max_sessions)) {
    refuse(0, cmd.client_id,
           "an OPEN from " + senderOf(from) + ": " + std::to_string(sessions_.size()) +
               " sessions open, the server's limit " + "(server.max_sessions)",
           1, now_ns, kOpenKey | from.participant);
    return;
  }
  if (from.participant != 0) {
    // Per identity under DDS Security (one certificate cannot take the server with many
    // participants), else per participant.
    const auto mine = std::count_if(sessions_.begin(), sessions_.end(), [&](const auto& kv) {
      return from.identity.empty() ? kv.second.owner == from.participant
                                   : kv.second.owner_identity == from.identity;
    });
    if (mine >= config_.max_sessions_per_participant) {
      refuse(0, cmd.client_id,
             "an OPEN from " + senderOf(from) + ": " +
                 (from.identity.empty() ? std::string("it has ")
                                        : "its identity " + from.identity + " has ") +
                 std::to_string(mine) +
                 " sessions open, the limit per participant (server.max_sessions_per_participant)",
             1, now_ns, kOpenKey | from.participant);
      return;
    }
  }
  if (cmd.mode != telehand_msg_MODE_MOBILIZATION && cmd.mode != telehand_msg_MODE_EXPLORATION &&
      cmd.mode != telehand_msg_MODE_CAPTURE && cmd.mode != telehand_msg_MODE_LESSON &&
      cmd.mode != telehand_msg_MODE_REPLAY && cmd.mode != telehand_msg_MODE_MASSAGE) {
    badCommand(cmd.client_id, from,
               "OPEN with unknown mode " + std::to_string(static_cast<int>(cmd.mode)), now_ns);
    return;
  }
  std::string case_name = cmd.case_name;
  // A lesson run renders the lesson's case; a replay shows a recorded session on its own.
  std::optional<store::LessonInfo> lesson_info;
  technique::Targets targets;
  std::optional<technique::MassageTargets> massage_targets;
  std::optional<store::SessionInfo> replayed;
  try {
    if (cmd.mode == telehand_msg_MODE_LESSON) {
      lesson_info = store_.lesson(cmd.lesson_id);
      if (!lesson_info)
        throw Error("no lesson " + std::to_string(cmd.lesson_id) + " in the record");
      const bool massage_lesson = lesson_info->technique == "massage";
      const bool massage_asked = cmd.technique == telehand_msg_TECHNIQUE_MASSAGE;
      if (massage_lesson != massage_asked) {
        throw Error("lesson " + std::to_string(cmd.lesson_id) + " teaches the " +
                    lesson_info->technique +
                    (massage_lesson ? " (open it with technique "
                                      "massage: telehand-client "
                                      "--technique massage --lesson " +
                                          std::to_string(cmd.lesson_id) + ")"
                                    : ", not the massage"));
      }
      if (massage_lesson) {
        massage_targets = lesson::decodeMassageTargets(lesson_info->targets);
      } else {
        targets = lesson::decodeTargets(lesson_info->targets);
      }
      // The lesson's settings come from the record, which may be damaged or hostile: the run
      // is refused here, naming the setting, rather than acknowledged with a plan the client
      // refuses (or trial counts and lengths the run cannot hold).
      const LessonPlan plan = massage_targets ? lesson::planOf(*lesson_info, *massage_targets, 0.0)
                                              : lesson::planOf(*lesson_info, targets, 0.0);
      std::string why;
      if (!validSchedule(lesson_info->schedule)) {
        throw Error("lesson " + std::to_string(cmd.lesson_id) + " in the record: schedule '" +
                    lesson_info->schedule.substr(0, 40) +
                    "' is not concurrent, terminal, faded or self");
      }
      if (!decodePlan(encodePlan(plan), &why)) {
        throw Error("lesson " + std::to_string(cmd.lesson_id) + " in the record: " + why);
      }
      case_name = lesson_info->case_name;
    } else if (cmd.mode == telehand_msg_MODE_REPLAY) {
      replayed = store_.session(cmd.follow_session);
      if (!replayed) {
        throw Error("no session " + std::to_string(cmd.follow_session) + " in the record");
      }
      if (replayed->mode == "replay") throw Error("a replay cannot be replayed");
      case_name = replayed->case_name;
    }
  } catch (const Error& e) {
    badCommand(
        cmd.client_id, from,
        std::string("cannot open the ") +
            (lesson_info || cmd.mode == telehand_msg_MODE_LESSON ? "lesson run: " : "replay: ") +
            e.what(),
        now_ns);
    return;
  }
  // The massage renders the web of the case (docs/massage.md): a massage session, a capture of
  // one, a lesson whose technique it is, or a resumed one.
  const bool massage =
      cmd.mode == telehand_msg_MODE_MASSAGE ||
      (cmd.mode == telehand_msg_MODE_CAPTURE && cmd.technique == telehand_msg_TECHNIQUE_MASSAGE) ||
      (lesson_info && lesson_info->technique == "massage") ||
      (resumed && techniqueOfMode(resumed->mode) == Technique::kMassage);
  const bool web_case = case_name == "oedema" || case_name == "scar" || case_name == "hypertonic";
  PatientCase patient;
  Session* capture = nullptr;
  if (cmd.follow_session != 0 && cmd.mode != telehand_msg_MODE_REPLAY) {
    // A follower renders the live fit of a running capture session.
    capture = find(cmd.follow_session);
    if (!capture || capture->mode != telehand_msg_MODE_CAPTURE || capture->closing) {
      badCommand(cmd.client_id, from,
                 "cannot follow session " + std::to_string(cmd.follow_session) +
                     ": no capture session of that id is running",
                 now_ns);
      return;
    }
    if (cmd.mode == telehand_msg_MODE_CAPTURE) {
      badCommand(cmd.client_id, from, "a capture session cannot follow another", now_ns);
      return;
    }
    case_name = "capture-" + std::to_string(cmd.follow_session);
    patient.name = case_name;
    patient.model = capture->params;
  } else if (config_.cases_dir.empty() ||
             (massage && web_case &&
              !std::filesystem::exists(std::filesystem::path(config_.cases_dir) /
                                       (case_name + ".toml")))) {
    // Without a case file: the healthy joint, and for a massage the built-in webs.
    if (case_name != "healthy" && !(massage && web_case)) {
      badCommand(cmd.client_id, from,
                 "unknown patient case '" + case_name + "' (known: healthy" +
                     (massage ? std::string(", and for a massage oedema, scar, hypertonic") : "") +
                     ")",
                 now_ns);
      return;
    }
    patient.name = case_name;
    patient.model = healthyIndexMcp();
  } else {
    try {
      patient = loadPatientCaseByName(config_.cases_dir, case_name);
    } catch (const ConfigError& e) {
      badCommand(cmd.client_id, from, e.what(), now_ns);
      return;
    }
  }
  if (massage) {
    patient.model.technique = Technique::kMassage;
    patient.model.tissue = patient.tissue_given ? patient.tissue : tissueCase(case_name.c_str());
  }
  SessionInfo info;
  uint64_t stored_below = 0;
  std::optional<store::SessionStore::Extent> extent;
  const int64_t open_t0 = SteadyClock{}.nowNs();
  try {
    if (resumed) {
      info = *resumed;
      info.state = "active";
      stored_below = store_.storedPrefix(info.id);
      extent = store_.extent(info.id);
      store_.closeSession(info.id, 0, 0, "active");
    } else {
      info.user = cmd.user;
      info.case_name = case_name;
      info.mode = std::string(modeName(cmd.mode));
      if (massage && cmd.mode == telehand_msg_MODE_CAPTURE) info.mode = "capture-massage";
      info.state = "active";
      info.started_ns = wallNs();
      info.owner = from.guid;
      info.id = store_.createSession(info);
      if (pooled()) store_.poolClaim(info.id, pool_id_, open_key);
    }
  } catch (const StoreError& e) {
    ++stats_.store_errors;
    event(0, cmd.client_id, telehand_msg_EVENT_ERROR,
          std::string(resumed ? "cannot resume the session's record: "
                              : "cannot open a session record: ") +
              e.what(),
          now_ns);
    return;
  }
  suspended_.erase(info.id);
  if (!resumed) {
    answer.session_id = info.id;
    if (answered_opens_.size() < kMaxAnsweredOpens) {
      answered_opens_.push_back(answer);
    } else {
      answered_opens_[answered_next_] = answer;
    }
    answered_next_ = (answered_next_ + 1) % kMaxAnsweredOpens;
  }
  const int64_t open_t1 = SteadyClock{}.nowNs();
  Session& s = sessions_.try_emplace(info.id, ctx_, info, cmd, patient, hand_, hand_config_, now_ns)
                   .first->second;
  s.owner = from.participant;
  s.owner_identity = from.identity;
  s.hand_deferred = hand_slice_ns_ > 0;
  const int64_t open_built = SteadyClock{}.nowNs();
  int64_t open_restored = open_built;
  std::string hand_from;
  if (resumed) {
    // What the record holds: acknowledged at once, so the client sends what it lacks.
    s.recorder.resumeFrom(resumed->samples, stored_below);
    if (extent) {
      s.seq_high = extent->last_seq;
      s.have_seq = true;
    }
    // The hand goes on from the last checkpoint its server kept, if any.
    try {
      if (const auto cp = store_.checkpoint(info.id); cp && s.hand.simulated()) {
        hand_from = s.hand.restore(cp->data)
                        ? fmt::format(
                              "; the hand goes on from its checkpoint at seq {} ({:.2f} s "
                              "old)",
                              cp->seq, static_cast<double>(wallNs() - cp->time_ns) * 1e-9)
                        : "; the hand's checkpoint does not fit this hand: it starts afresh";
      }
    } catch (const StoreError& e) {
      ++stats_.store_errors;
      hand_from = std::string("; the hand's checkpoint cannot be read: ") + e.what();
    }
    open_restored = SteadyClock{}.nowNs();
  }
  const bool wants_knn = cmd.stiffness == telehand_msg_STIFFNESS_KNN;
  if (capture) {
    s.capture.follow(cmd.follow_session, wants_knn);
    capture->capture.addFollower(info.id);
  }
  if (cmd.mode == telehand_msg_MODE_CAPTURE) s.capture.startRefit(s.params, refit_options_);
  if (lesson_info) {
    const auto demo = store_.session(lesson_info->demo_session);
    const double demo_s = demo ? static_cast<double>(demo->samples) * 1e-3 : 0.0;
    if (massage_targets) {
      const LessonPlan plan =
          lesson::planOf(*lesson_info, *massage_targets, std::min(demo_s, 600.0));
      s.lesson = std::make_unique<LessonRun>(*lesson_info, *massage_targets, s.params.tissue, plan);
    } else {
      const LessonPlan plan = lesson::planOf(*lesson_info, targets, std::min(demo_s, 600.0));
      s.lesson = std::make_unique<LessonRun>(*lesson_info, targets, plan);
    }
    try {
      store_.setSessionLesson(info.id, lesson_info->id);
    } catch (const StoreError& e) {
      ++stats_.store_errors;
      spdlog::error("session {}: {}", info.id, e.what());
    }
  }
  if (replayed) {
    try {
      s.startReplay(replayed->id, s.params, 1.0, now_ns);
    } catch (const Error& e) {
      event(s.info.id, cmd.client_id, telehand_msg_EVENT_ERROR,
            std::string("the replay cannot read its record: ") + e.what(), now_ns);
    }
  }

  s.publishStatus(telehand_msg_SESSION_ACTIVE);
  s.publishModel();
  if (resumed) {
    const int64_t open_t2 = SteadyClock{}.nowNs();
    event(s.info.id, cmd.client_id, telehand_msg_EVENT_INFO,
          "resumed: " + info.mode + " on case '" + case_name + "' for " + info.user +
              "; the record holds " + std::to_string(resumed->samples) +
              " samples, all below seq " + std::to_string(stored_below) +
              ", and the client sends what it lacks" + hand_from +
              fmt::format(" (record read in {:.0f} ms, hand made in {:.0f} ms, its checkpoint "
                          "read and restored in {:.0f} ms, status and model published in {:.0f} "
                          "ms; {:.0f} ms after the request was taken)",
                          static_cast<double>(open_t1 - open_t0) * 1e-6,
                          static_cast<double>(open_built - open_t1) * 1e-6,
                          static_cast<double>(open_restored - open_built) * 1e-6,
                          static_cast<double>(open_t2 - open_restored) * 1e-6,
                          static_cast<double>(open_t2 - now_ns) * 1e-6),
          now_ns);
    return;
  }
  if (pooled()) {
    event(s.info.id, cmd.client_id, telehand_msg_EVENT_INFO, "owner: server " + pool_id_, now_ns);
    // A first checkpoint at once: a server that dies before its next one still leaves the
    // hand's starting state to whoever takes the session over.
    if (s.hand.simulated()) {
      try {
        store_.putCheckpoint(s.info.id, {0, wallNs(), s.hand.checkpoint()});
      } catch (const StoreError& e) {
        ++stats_.store_errors;
        spdlog::error("session {}: checkpoint: {}", s.info.id, e.what());
      }
    }
  }
  event(s.info.id, cmd.client_id, telehand_msg_EVENT_INFO,
        "opened: " + info.mode + " on case '" + case_name + "' for " + info.user +
            (capture ? std::string(", following capture session ") +
                           std::to_string(cmd.follow_session) +
                           (wants_knn ? " (k-nearest-neighbour model)" : " (cubic model)")
                     : "") +
            (cmd.direct_force ? " (direct force: the server renders)" : "") +
            (lesson_info ? ", lesson " + std::to_string(lesson_info->id) + " (demonstration " +
                               std::to_string(lesson_info->demo_session) + ", " +
                               lesson_info->schedule + " feedback)"
                         : std::string()) +
            (replayed ? ", replaying session " + std::to_string(replayed->id) : std::string()),
        now_ns);
}

void SessionManager::resume(const telehand_msg_SessionCommand& cmd, int64_t now_ns,
                            const Origin& from) {
  const uint64_t id = cmd.session_id;
  if (Session* s = find(id)) {
    // Still running here: its client lost sight of this server (a partition), not the
    // reverse. Answered again, with the model, so that it goes on with this server.
    if (!owns(*s, from, "a resume", 1, now_ns)) return;
    if (!stillOurs(id)) return;  // the server that took it over answers
    s->client_id = cmd.client_id;
    s->request_seq = cmd.request_seq;
    s->publishStatus(telehand_msg_SESSION_ACTIVE);
    s->publishModel();
    event(id, cmd.client_id, telehand_msg_EVENT_INFO,
          "resumed by its client (it was running here all along)", now_ns);
    return;
  }
  if (elsewhere(id)) return;  // pool: the server that claimed it answers
  const auto cannot = [&](const std::string& why) {
    badCommand(cmd.client_id, from, "cannot resume session " + std::to_string(id) + ": " + why,
               now_ns);
  };
  if (closeOwed(id)) {
    cannot("it ended here; its close is not in the record yet and is tried again every second");
    return;
  }
  std::optional<SessionInfo> info;
  try {
    info = store_.session(id);
  } catch (const StoreError& e) {
    ++stats_.store_errors;
    cannot(e.what());
    return;
  }
  if (!info) {
    cannot("not in this server's record (" + store_.location() + ")");
    return;
  }
  if (from.participant != 0 && !info->owner.empty() && info->owner != from.guid) {
    refuse(id, cmd.client_id,
           "a resume of session " + std::to_string(id) + " from " + senderOf(from) +
               ": it belongs to " + info->owner,
           1, now_ns, kOpenKey | from.participant);
    return;
  }
  if (info->ended()) {
    cannot("the record has it " + info->state);
    return;
  }
  const auto mode = parseMode(info->mode);
  if (!mode || *mode == telehand_msg_MODE_REPLAY || *mode == telehand_msg_MODE_LESSON) {
    // A lesson run's trials and a replay's position lived with the server that stopped.
    cannot(std::string("a ") + (mode ? std::string(modeName(*mode)) : info->mode) +
           " session is not resumed; its record up to the outage is kept (closed as "
           "interrupted)");
    closeUnresumed(id, now_ns,
                   "not resumed: a " + info->mode + " session does not survive its server");
    return;
  }
  telehand_msg_SessionCommand c = cmd;
  c.mode = *mode;
  copyString(c.case_name, info->case_name);
  copyString(c.user, info->user);
  c.follow_session = 0;  // a follower renders the model it has
  c.lesson_id = 0;
  if (!stillOurs(id)) return;
  open(c, now_ns, from, &*info);
}

void SessionManager::publishRecordStatus(const SessionInfo& info, telehand_msg_SessionState state,
                                         uint64_t client_id, uint32_t request_seq) {
  out_.publish(statusOf(info, state, client_id, request_seq, store_.location()));
}

void SessionManager::closeUnresumed(uint64_t session_id, int64_t now_ns, const std::string& why) {
  suspended_.erase(session_id);
  try {
    // Its server may have closed it meanwhile (a pool server whose lease lapsed while it
    // finished the session): that close, and the client's count in it, stands.
    if (const auto before = store_.session(session_id); before && before->ended()) {
      spdlog::info("session {}: not closed as interrupted: the record has it {} already",
                   session_id, before->state);
      publishRecordStatus(*before, telehand_msg_SESSION_CLOSED, 0, 0);
      retiring_.emplace_back(now_ns + static_cast<int64_t>(config_.status_keep_s * 1e9),
                             session_id);
      return;
    }
    const auto extent = store_.extent(session_id);
    store_.closeSession(session_id, wallNs(), extent ? extent->last_seq + 1 : 0, "interrupted");
    store_.appendEvent(session_id, {wallNs(), "error", why});
    if (const auto info = store_.session(session_id)) {
      publishRecordStatus(*info, telehand_msg_SESSION_CLOSED, 0, 0);
    }
  } catch (const StoreError& e) {
    ++stats_.store_errors;
    spdlog::error("session {}: {}", session_id, e.what());
  }
  event(session_id, 0, telehand_msg_EVENT_ERROR, why, now_ns);
  retiring_.emplace_back(now_ns + static_cast<int64_t>(config_.status_keep_s * 1e9), session_id);
}

std::size_t SessionManager::recoverFromStore(int64_t now_ns, bool take_active) {
  std::vector<SessionInfo> all;
  try {
    all = store_.listSessions();
  } catch (const StoreError& e) {
    ++stats_.store_errors;
    spdlog::error("cannot look for sessions to recover: {}", e.what());
    return 0;
  }
  std::size_t found = 0;
  for (SessionInfo& info : all) {
    const bool takeable = info.state == "suspended" || (take_active && info.state == "active");
    if (!takeable || sessions_.count(info.id)) continue;
    ++found;
    const bool died = info.state == "active";  // a server that stopped suspends its sessions
    try {
      if (died) store_.closeSession(info.id, 0, 0, "suspended");
      store_.appendEvent(
          info.id,
          {wallNs(), "info",
           std::string(died ? "recovered: its server died" : "recovered: its server stopped") +
               "; the record holds " + std::to_string(info.samples) + " samples; waiting " +
               fmt::format("{:g}", config_.resume_wait_s) + " s for its client to resume it"});
    } catch (const StoreError& e) {
      ++stats_.store_errors;
      spdlog::error("session {}: {}", info.id, e.what());
    }
    info.state = "suspended";
    suspended_[info.id] = now_ns + static_cast<int64_t>(config_.resume_wait_s * 1e9);
    rememberOwner(info.id, info.owner);
    publishRecordStatus(info, telehand_msg_SESSION_SUSPENDED, 0, 0);
    spdlog::info("session {}: recovered from the record ({} samples), waiting for its client",
                 info.id, info.samples);
  }
  return found;
}

void SessionManager::requestClose(const telehand_msg_SessionCommand& cmd, int64_t now_ns,
                                  const Origin& from) {
  Session* s = find(cmd.session_id);
  if (!s) {
    // Ended here, its close not yet in the record: CLOSED follows when the record takes it.
    if (closeOwed(cmd.session_id)) return;
    badCommand(cmd.client_id, from, "CLOSE for unknown session " + std::to_string(cmd.session_id),
               now_ns);
    return;
  }
  s->close_wait.closeAsked(now_ns, static_cast<int64_t>(config_.close_grace_s * 1e9),
                           kMaxCloseGraces, !s->closing);
  s->closing = true;
  s->expected = cmd.samples_sent;
  s->publishStatus(telehand_msg_SESSION_CLOSING);
}

void SessionManager::onDeviceState(const telehand_msg_DeviceState& wire, int64_t now_ns,
                                   const Origin& from) {
  onSample(fromWire(wire), now_ns, from);
}

namespace {
/// Whether `seq` lies within the window of `high`, the session's highest sequence number
/// before the sample (or its chunk) came; without one (`have` false) any number does.
bool inWindowOf(uint64_t high, bool have, uint64_t seq) {
  if (seq >= sample_bounds::kMaxSeq) return false;
  if (!have) return true;
  const uint64_t lo = high > SessionManager::kSeqWindow ? high - SessionManager::kSeqWindow : 0;
  return seq >= lo && seq <= high + SessionManager::kSeqWindow;
}

void advanceSeq(Session& s, uint64_t seq) {
  if (!s.have_seq || seq > s.seq_high) s.seq_high = seq;
  s.have_seq = true;
}

/// Whether `seq` lies within the window of the session's highest sequence number so far
/// (and advances it); the first sample of a session sets it.
bool inSeqWindow(Session& s, uint64_t seq) {
  if (!inWindowOf(s.seq_high, s.have_seq, seq)) return false;
  advanceSeq(s, seq);
  return true;
}
}  // namespace

void SessionManager::onSample(const Sample& d, int64_t now_ns, const Origin& from) {
  Session* s = find(d.session_id);
  if (!s) {
    if (elsewhere(d.session_id)) return;  // another server's of the pool
    ++stats_.unknown_session_samples;
    unknownSession(d.session_id, "DeviceState", now_ns);
    return;
  }
  if (!owns(*s, from, "DeviceState", 1, now_ns)) return;
  if (!inSeqWindow(*s, d.seq)) {
    refuse(s->info.id, s->client_id,
           "DeviceState seq " + std::to_string(d.seq) + ", outside the sequence window (" +
               std::to_string(kSeqWindow) + " of " + std::to_string(s->seq_high) + ")",
           1, now_ns);
    return;
  }
  s->onLive(d, now_ns);
}

void SessionManager::onChunk(const telehand_msg_RecordChunk& c, int64_t now_ns,
                             const Origin& from) {
  progress_.fetch_add(1, std::memory_order_relaxed);
  Session* s = find(c.session_id);
  if (!s && elsewhere(c.session_id) && rememberedOwner(c.session_id) == nullptr) {
    return;  // another server's of the pool (a late chunk goes to the server that closed it)
  }
  if (s && !owns(*s, from, "a RecordChunk", c.samples._length, now_ns)) return;
  if (!s && from.unknown) {
    refuse(c.session_id, 0, "a late RecordChunk from " + senderOf(from), c.samples._length, now_ns);
    return;
  }
  std::vector<Sample> samples = samplesFromWire(c);
  // A sample no device could have sent is stored flagged invalid (the record keeps what
  // arrived); one outside the sequence window is not stored at all.
  std::vector<uint8_t> valid(samples.size(), 1);
  uint64_t outside = 0;
  std::size_t kept = 0;
  // A chunk's samples are judged against the window as it stood before the chunk (the first
  // chunk's, against its first sample): one chunk cannot walk the window along by itself.
  uint64_t anchor = s && s->have_seq ? s->seq_high : 0;
  if (s && !s->have_seq) {
    const auto first = std::find_if(samples.begin(), samples.end(),
                                    [](const Sample& x) { return x.seq < sample_bounds::kMaxSeq; });
    if (first != samples.end()) anchor = first->seq;
  }
  for (std::size_t i = 0; i < samples.size(); ++i) {
    if (s && !inWindowOf(anchor, true, samples[i].seq)) {
      ++outside;
      continue;
    }
    if (s) advanceSeq(*s, samples[i].seq);
    if (!s && samples[i].seq >= sample_bounds::kMaxSeq) {
      ++outside;
      continue;
    }
    valid[kept] = !firstInvalid(samples[i]).has_value() && samples[i].session_id == c.session_id;
    samples[kept++] = samples[i];
  }
  samples.resize(kept);
  valid.resize(kept);
  if (outside > 0) {
    refuse(c.session_id, s ? s->client_id : 0,
           std::to_string(outside) + " RecordChunk samples outside the sequence window", outside,
           now_ns);
  }
  if (!s) {
    // A late chunk for a session that is not running here (closed, or suspended awaiting its
    // client) still belongs in its record, if it comes from the session's owner: the owner
    // this server remembers (it ended or suspended the session, or looked it up before), else
    // the record's, remembered from then on (one look-up, on PostgreSQL two counts of its
    // rows, per session rather than per chunk).
    try {
      const bool waiting = suspended_.count(c.session_id) > 0;
      const EndedOwner* owner = rememberedOwner(c.session_id);
      // A session waiting for its client is looked up too when its owner is no longer
      // remembered (a stranger's chunks for kMaxEndedOwners other sessions push it out of
      // the ring): its chunks are taken from its owner only, as a running session's are.
      if (!owner) {
        if (const auto info = store_.session(c.session_id)) {
          rememberOwner(c.session_id, info->owner);
          owner = rememberedOwner(c.session_id);
        }
      }
      if (from.participant != 0 && owner != nullptr && owner->guid[0] != '\0' &&
          std::string_view(owner->guid.data()) != from.guid) {
        refuse(c.session_id, 0,
               "a late RecordChunk from " + senderOf(from) + ": session " +
                   std::to_string(c.session_id) + " belongs to " + owner->guid.data(),
               c.samples._length, now_ns);
        return;
      }
      if (owner != nullptr) {
        const int64_t t0 = SteadyClock{}.nowNs();
        const uint64_t added = store_.appendSamples(c.session_id, samples, valid);
        records_ns_ += SteadyClock{}.nowNs() - t0;
        stats_.recorded_samples += added;
        if (waiting) {
          spdlog::debug("session {}: {} samples stored while it waits for its client", c.session_id,
                        added);
        } else {
          spdlog::info("session {}: {} late samples stored after close", c.session_id, added);
        }
        return;
      }
    } catch (const StoreError& e) {
      ++stats_.store_errors;
      spdlog::error("{}", e.what());
    }
    ++stats_.unknown_session_samples;
    unknownSession(c.session_id, "RecordChunk", now_ns);
    return;
  }
  s->onRecord(std::move(samples), std::move(valid), now_ns);
}

void SessionManager::onFile(const telehand_msg_SessionFile& f, int64_t now_ns, const Origin& from) {
  progress_.fetch_add(1, std::memory_order_relaxed);
  Session* s = find(f.session_id);
  if (!s) {
    if (elsewhere(f.session_id)) return;
    unknownSession(f.session_id, "SessionFile", now_ns);
    return;
  }
  if (!owns(*s, from, "a SessionFile", 1, now_ns)) return;
  const std::string name = f.name;
  const std::size_t bytes = f.content ? std::strlen(f.content) : 0;
  // Files belong to captures (the device and calibration they were made with), a few kB.
  if (s->mode != telehand_msg_MODE_CAPTURE ||
      bytes > static_cast<std::size_t>(config_.max_file_bytes) ||
      s->files >= config_.max_files_per_session) {
    refuse(
        f.session_id, s->client_id,
        "SessionFile '" + name + "' (" + std::to_string(bytes) + " bytes): " +
            (s->mode != telehand_msg_MODE_CAPTURE ? std::string("only capture sessions keep files")
             : s->files >= config_.max_files_per_session
                 ? "the session already keeps " + std::to_string(s->files) +
                       " files (server.max_files_per_session)"
                 : "larger than server.max_file_bytes = " + std::to_string(config_.max_file_bytes)),
        1, now_ns);
    return;
  }
  ++s->files;
  const std::string content = f.content ? f.content : "";
  try {
    store_.appendFile(f.session_id, {name, content});
  } catch (const StoreError& e) {
    ++stats_.store_errors;
    event(f.session_id, s->client_id, telehand_msg_EVENT_ERROR,
          "file '" + name + "' not stored: " + e.what(), now_ns);
    return;
  }
  event(f.session_id, 0, telehand_msg_EVENT_INFO,
        "stored " + name + " (" + std::to_string(content.size()) + " bytes) with the record",
        now_ns);
}

bool SessionManager::writeSamplesOnThread() {
  if (writer_) return true;
  auto connection = store_.openWriter();
  if (!connection) return false;
  writer_ = std::make_unique<store::BatchWriter>(std::move(connection));
  ctx_.samples_on_writer = true;
  return true;
}

void SessionManager::landWrites() {
  if (!writer_->collect(jobs_)) return;
  for (auto& j : jobs_) {
    Session* s = find(j.session_id);
    // A session let go meanwhile (another server of the pool has it): its new owner's
    // record is the judge.
    if (s && s->recorder.writing()) s->recorder.written(ctx_, j.samples, j.valid, j.result);
  }
}

void SessionManager::flushRecords() {
  if (writer_) {
    // One write under way at a time: what comes meanwhile waits in the recorders and goes
    // in the next, so that a slow record makes the writes larger, not the loop slower.
    if (writer_->busy()) return;
    const int64_t t0 = SteadyClock{}.nowNs();
    landWrites();
    std::size_t n = 0;
    for (auto& [id, s] : sessions_) {
      if (!s.recorder.queued() || s.recorder.writing()) continue;
      if (n == jobs_.size()) jobs_.emplace_back();
      store::BatchWriter::Job& j = jobs_[n++];
      j.session_id = id;
      s.recorder.handOver(j.samples, j.valid);
    }
    if (n > 0) {
      jobs_.resize(n);
      writer_->submit(jobs_);
    }
    records_ns_ += SteadyClock{}.nowNs() - t0;
    return;
  }
  batches_.clear();
  batch_sessions_.clear();
  for (auto& [id, s] : sessions_) {
    if (s.recorder.drained()) continue;
    batches_.push_back(s.recorder.batch());
    batch_sessions_.push_back(&s);
  }
  if (batches_.empty()) return;
  const int64_t t0 = SteadyClock{}.nowNs();
  const auto results = store_.appendSampleBatches(batches_);
  records_ns_ += SteadyClock{}.nowNs() - t0;
  for (std::size_t i = 0; i < batch_sessions_.size(); ++i) {
    batch_sessions_[i]->recorder.stored(ctx_, results[i]);
  }
}

void SessionManager::tick(int64_t now_ns) {
  progress_.fetch_add(1, std::memory_order_relaxed);
  if (!owed_closes_.empty() && now_ns >= next_owed_close_ns_) closeOwed(now_ns, false);
  if (pooled() &&
      (now_ns >= next_pool_ns_ || claim_soon_.exchange(false, std::memory_order_relaxed))) {
    poolTick(now_ns);
  }
  // Ended sessions leave the transient-local topics once late joiners had their chance.
  std::size_t due = 0;
  while (due < retiring_.size() && retiring_[due].first <= now_ns) {
    out_.retire(retiring_[due].second);
    ++stats_.retired_sessions;
    ++due;
  }
  retiring_.erase(retiring_.begin(), retiring_.begin() + static_cast<std::ptrdiff_t>(due));
  for (auto it = suspended_.begin(); it != suspended_.end();) {
    const uint64_t id = it->first;
    if (now_ns < (it++)->second) continue;
    closeUnresumed(id, now_ns,
                   "not resumed within " + fmt::format("{:g}", config_.resume_wait_s) +
                       " s: closed as interrupted with what the record holds");
  }
  if (hand_slice_ns_ > 0) stepHands(now_ns);
  flushRecords();
  const auto lookup = [this](uint64_t id) { return find(id); };
  std::vector<uint64_t> done;
  for (auto& [id, s] : sessions_) {
    s.tick(now_ns);
    if (s.capture.capturing() && !s.closing)
      s.capture.refit(ctx_, s, lookup, refit_options_.knn, now_ns);
    s.recoverIfDue(now_ns);
    if (pooled() && s.closing && s.recorder.drained() && s.recorder.recorded() < s.expected &&
        s.expected > 0 && now_ns >= s.recount_ns) {
      // The record is the judge of what it holds: a server that had the session before may
      // have stored some of the samples this one is waiting for.
      s.recount_ns = now_ns + 500'000'000;
      try {
        s.recorder.recountFrom(store_.countSamples(id, 0, s.expected - 1));
      } catch (const StoreError& e) {
        ++stats_.store_errors;
        spdlog::error("session {}: {}", id, e.what());
      }
    }
    // A write of the session's samples under way (the writer thread) is waited for, past
    // the close's grace too: what it stores counts, and the record's state follows it.
    if (s.recorder.writing()) continue;
    if (s.closing && ((s.recorder.recorded() >= s.expected && s.recorder.drained()) ||
                      s.close_wait.due(now_ns))) {
      done.push_back(id);
    } else if (!s.closing && s.live.idleNs(now_ns) > kIdleTimeoutNs) {
      s.expected = s.live.sentOr(0);
      event(id, s.client_id, telehand_msg_EVENT_ERROR,
            "no data for " + std::to_string(kIdleTimeoutNs / kNsPerS) + " s: closed as abandoned",
            now_ns);
      finish(s, now_ns, "abandoned");
      done.push_back(id);
      continue;
    }
  }
  for (uint64_t id : done) {
    auto it = sessions_.find(id);
    if (it == sessions_.end()) continue;
    Session& s = it->second;
    if (s.closing) finish(s, now_ns, recordComplete(s) ? "closed" : "incomplete");
    sessions_.erase(it);
  }
#if defined(__GLIBC__)
  // A session's hand is megabytes of blocks (hand_heap.h): glibc keeps freed ones in its
  // arenas, so without this a burst of sessions (a flood of OPENs up to
  // server.max_sessions) would hold the server's RSS at its peak after they ended. Retired
  // sessions free their samples in Cyclone: trimmed too, and once none is left, the samples
  // Cyclone pooled for reuse (a burst fills its pool) are given back first.
  if (!done.empty() || due > 0) {
    if (sessions_.empty() && retiring_.empty()) {
      out_.idle();
      settle_ns_ = now_ns + kSettleNs;
    }
    malloc_trim(0);
  } else if (settle_ns_ != 0 && now_ns >= settle_ns_) {
    settle_ns_ = 0;
    if (sessions_.empty() && retiring_.empty()) {
      out_.settle();
      releaseRecordMemory();
      malloc_trim(0);
    }
  }
#endif
}

bool SessionManager::recordComplete(Session& s) {
  // The row count says no more than that enough rows arrived: rows of sequence numbers at or
  // past what the client says it sent would stand in for missing ones. So the record's rows
  // below `expected` are counted (one range count, at the end only).
  if (s.recorder.recorded() < s.expected) return false;
  // The client did not say what it sent (0: unknown): complete only as far as the server
  // can tell, with nothing it received still held back from the record (a write refused).
  if (s.expected == 0) return s.recorder.drained();
  try {
    s.stored_of_expected = store_.countSamples(s.info.id, 0, s.expected - 1);
  } catch (const StoreError& e) {
    ++stats_.store_errors;
    spdlog::error("session {}: {}", s.info.id, e.what());
    return false;  // not known to be complete: not said to be
  }
  return *s.stored_of_expected >= s.expected;
}

void SessionManager::releaseRecordMemory() {
  // With no session left, what the record's side kept for speed goes: the sample buffers
  // sized by the busiest write, the connections' page caches (SessionStore::releaseMemory).
  jobs_ = {};
  batches_ = {};
  batch_sessions_ = {};
  if (writer_) writer_->releaseMemory();
  store_.releaseMemory();
}

void SessionManager::setHandSlice(int64_t slice_ns) {
  hand_slice_ns_ = std::max<int64_t>(slice_ns, 0);
  for (auto& [id, s] : sessions_) {
    if (hand_slice_ns_ == 0) s.flushHand(SteadyClock{}.nowNs());
    s.hand_deferred = hand_slice_ns_ > 0;
  }
}

void SessionManager::setHandShare(double share) {
  if (!(share > 0.0 && share <= 1.0)) {
    throw ConfigError("the hands' share of the serving thread must be in (0, 1], not " +
                      fmt::format("{:g}", share));
  }
  hand_share_ = share;
}

int64_t SessionManager::handWaitNs(int64_t now_ns) const noexcept {
  if (hand_slice_ns_ <= 0 || !handPending()) return -1;
  if (hand_credit_at_ns_ == 0) return 0;  // a full slice before the first
  // The credit the budget will have by now_ns; the hands step once it is positive.
  const int64_t credit =
      hand_credit_ns_ +
      static_cast<int64_t>(hand_share_ * static_cast<double>(now_ns - hand_credit_at_ns_));
  if (credit > 0) return 0;
  return static_cast<int64_t>(static_cast<double>(-credit) / hand_share_) + 1;
}

bool SessionManager::handPending() const noexcept {
  return std::any_of(sessions_.begin(), sessions_.end(),
                     [](const auto& kv) { return kv.second.handPending() > 0; });
}

void SessionManager::stepHands(int64_t now_ns) {
  // Session after session from where the last slice stopped, so that every hand gets its
  // turn when they cannot all keep up.
  if (sessions_.empty()) return;
  SteadyClock clock;
  const int64_t start = clock.nowNs();
  // The budget: share x the wall time since it was last counted, at most one slice in hand
  // (a thread that slept long does not buy a long stall with it).
  if (hand_credit_at_ns_ == 0) {
    hand_credit_at_ns_ = start;
    hand_credit_ns_ = hand_slice_ns_;
  }
  hand_credit_ns_ = std::min(
      hand_slice_ns_,
      hand_credit_ns_ +
          static_cast<int64_t>(hand_share_ * static_cast<double>(start - hand_credit_at_ns_)));
  hand_credit_at_ns_ = start;
  if (hand_credit_ns_ <= 0) return;
  const int64_t deadline = start + std::min(hand_slice_ns_, hand_credit_ns_);
  struct Spend {
    SessionManager& m;
    SteadyClock& clock;
    int64_t start;
    ~Spend() {
      // The share of the time spent stepping is the budget's too.
      const int64_t end = clock.nowNs();
      m.hand_credit_ns_ -=
          end - start - static_cast<int64_t>(m.hand_share_ * static_cast<double>(end - start));
      m.hand_credit_at_ns_ = end;
    }
  } spend{*this, clock, start};
  auto it = sessions_.lower_bound(hand_cursor_);
  for (std::size_t n = 0; n < sessions_.size(); ++n, ++it) {
    if (it == sessions_.end()) it = sessions_.begin();
    if ((n > 0 && it->second.handPending() > 0 && clock.nowNs() >= deadline) ||
        !it->second.stepHand(deadline, now_ns)) {
      hand_cursor_ = it->first;
      return;
    }
  }
  hand_cursor_ = it == sessions_.end() ? 0 : it->first;
}

void SessionManager::finish(Session& s, int64_t now_ns, const std::string& state) {
  if (pooled()) {
    // Only the owner closes a session's record: one that another server took over while
    // this one was too slow to renew its lease is left to that server.
    try {
      if (!store_.poolClaim(s.info.id, pool_id_).won) {
        spdlog::warn("session {}: another server of the pool owns it now; not closed here",
                     s.info.id);
        return;
      }
    } catch (const StoreError& e) {
      ++stats_.store_errors;
      spdlog::error("session {}: {}", s.info.id, e.what());
    }
  }
  s.flushHand(now_ns);
  s.endExploration(s.client_id, now_ns);
  if (s.capture.follows()) {
    if (Session* capture = find(s.capture.follows())) capture->capture.removeFollower(s.info.id);
  }
  for (uint64_t id : s.capture.takeFollowers()) {
    if (Session* f = find(id)) f->capture.unfollow();  // keeps the last model it got
  }
  if (!s.close(state, now_ns)) {
    if (owed_closes_.size() >= kMaxOwedCloses) {
      spdlog::error("session {}: left active in the record: {} closes are owed already",
                    owed_closes_.front().session_id, kMaxOwedCloses);
      retiring_.emplace_back(now_ns + static_cast<int64_t>(config_.status_keep_s * 1e9),
                             owed_closes_.front().session_id);
      owed_closes_.erase(owed_closes_.begin());
    }
    if (owed_closes_.empty()) next_owed_close_ns_ = now_ns + kOwedCloseEveryNs;
    owed_closes_.push_back({s.info.id, s.closed_ns, s.expected, state, s.client_id});
  } else {
    retiring_.emplace_back(now_ns + static_cast<int64_t>(config_.status_keep_s * 1e9), s.info.id);
  }
  rememberOwner(s.info.id, s.info.owner);
  refused_reported_ns_.erase(s.info.id);
}

bool SessionManager::closeOwed(uint64_t session_id) const {
  return std::any_of(owed_closes_.begin(), owed_closes_.end(),
                     [&](const OwedClose& c) { return c.session_id == session_id; });
}

void SessionManager::closeOwed(int64_t now_ns, bool last_try) {
  next_owed_close_ns_ = now_ns + kOwedCloseEveryNs;
  const auto retire = [&](uint64_t id) {
    retiring_.emplace_back(now_ns + static_cast<int64_t>(config_.status_keep_s * 1e9), id);
  };
  for (auto it = owed_closes_.begin(); it != owed_closes_.end();) {
    const OwedClose& c = *it;
    try {
      if (pooled() && !store_.poolClaim(c.session_id, pool_id_).won) {
        spdlog::warn("session {}: another server of the pool owns it now; its close is left to it",
                     c.session_id);
        retire(c.session_id);
        it = owed_closes_.erase(it);
        continue;
      }
      // Another server may have taken the session over, had it resumed and closed it while
      // this one could not reach the record: that close stands.
      if (const auto now = store_.session(c.session_id); now && now->ended()) {
        spdlog::info("session {}: the record has it {} already; its owed close is dropped",
                     c.session_id, now->state);
        publishRecordStatus(*now, telehand_msg_SESSION_CLOSED, c.client_id, 0);
        retire(c.session_id);
        it = owed_closes_.erase(it);
        continue;
      }
      store_.closeSession(c.session_id, c.ended_ns, c.samples_expected, c.state);
    } catch (const StoreError& e) {
      ++stats_.store_errors;
      // The record is not taking writes: the rest wait for the next pass (a busy record
      // costs its timeout per statement, and the serve loop waits meanwhile). Stopping, the
      // server says which it leaves.
      if (last_try) {
        for (; it != owed_closes_.end(); ++it) {
          spdlog::error(
              "session {}: left active in the record, which would not take its close as {} "
              "({}); a server that recovers it closes it as interrupted",
              it->session_id, it->state, e.what());
        }
      }
      break;
    }
    spdlog::info("session {}: the record took its close as {}", c.session_id, c.state);
    try {
      if (const auto info = store_.session(c.session_id)) {
        publishRecordStatus(*info, telehand_msg_SESSION_CLOSED, c.client_id, 0);
      }
    } catch (const StoreError& e) {
      ++stats_.store_errors;
      spdlog::error("session {}: {}", c.session_id, e.what());
    }
    retire(c.session_id);
    it = owed_closes_.erase(it);
  }
}

void SessionManager::closeAll(int64_t now_ns) {
  if (writer_) {
    writer_->wait();
    landWrites();
  }
  if (pooled()) {
    // Pool: a session another server took over since the last heartbeat (this one's lease had
    // run out) is let go, not written over; the heartbeat renews the lease, so no one can take
    // the rest before they are written.
    try {
      letGoOfTakenSessions(
          store_.poolHeartbeat(pool_id_, sessions_.size() + suspended_.size(), kPoolLeaseNs));
    } catch (const StoreError& e) {
      ++stats_.store_errors;
      spdlog::error("pool: {}", e.what());
    }
  }
  for (auto& [id, s] : sessions_) {
    s.recorder.flushNow(ctx_);
    s.flushHand(now_ns);
    if (s.closing) {
      finish(s, now_ns, recordComplete(s) ? "closed" : "incomplete");
      continue;
    }
    // Not ended by its client: suspended, for its client to resume on the next server.
    try {
      store_.closeSession(id, 0, 0, "suspended");
    } catch (const StoreError& e) {
      ++stats_.store_errors;
      spdlog::error("session {}: {}", id, e.what());
    }
    event(id, s.client_id, telehand_msg_EVENT_INFO,
          "suspended: the server stopped with " + std::to_string(s.recorder.recorded()) +
              " samples recorded, all below seq " + std::to_string(s.recorder.storedBelow()) +
              "; its client may resume it on the next server",
          now_ns);
    s.publishStatus(telehand_msg_SESSION_SUSPENDED);
  }
  sessions_.clear();
  if (!owed_closes_.empty()) closeOwed(now_ns, true);
}

// ---- Pool (docs/pool.md) --------------------------------------------------------------------

void SessionManager::letGoOfTakenSessions(std::vector<uint64_t> mine) {
  std::sort(mine.begin(), mine.end());
  const auto owned = [&](uint64_t id) { return std::binary_search(mine.begin(), mine.end(), id); };
  // Writing nothing more of them: their clients follow the new owner.
  for (auto it = sessions_.begin(); it != sessions_.end();) {
    if (owned(it->first)) {
      ++it;
      continue;
    }
    spdlog::warn("session {}: taken over by another server of the pool; let go here", it->first);
    it = sessions_.erase(it);
  }
  std::erase_if(suspended_, [&](const auto& kv) { return !owned(kv.first); });
}

bool SessionManager::stillOurs(uint64_t session_id) {
  if (!pooled()) return true;
  try {
    if (store_.poolClaim(session_id, pool_id_).won) return true;
  } catch (const StoreError& e) {
    // Not known to be ours: not answered now (its client asks again within a second).
    ++stats_.store_errors;
    spdlog::error("pool: session {}: {}", session_id, e.what());
    return false;
  }
  spdlog::warn("session {}: taken over by another server of the pool; let go here", session_id);
  sessions_.erase(session_id);
  suspended_.erase(session_id);
  return false;
}

bool SessionManager::elsewhere(uint64_t session_id) const {
  return pooled() && !sessions_.count(session_id) && !suspended_.count(session_id);
}

void SessionManager::joinPool(const std::string& server) {
  pool_id_ = server;
  next_pool_ns_ = 0;
  // The first heartbeat now: the lease must run before any OPEN can be assigned here.
  store_.poolHeartbeat(pool_id_, 0, kPoolLeaseNs);
}

void SessionManager::leavePool() {
  if (!pooled()) return;
  try {
    store_.poolLeave(pool_id_);
  } catch (const StoreError& e) {
    ++stats_.store_errors;
    spdlog::error("cannot leave the pool: {}", e.what());
  }
}

void SessionManager::poolTick(int64_t now_ns) {
  next_pool_ns_ = now_ns + kPoolHeartbeatNs;
  std::vector<uint64_t> mine, orphans;
  const int64_t t0 = SteadyClock{}.nowNs();
  try {
    mine = store_.poolHeartbeat(pool_id_, sessions_.size() + suspended_.size(), kPoolLeaseNs);
    orphans = store_.poolOrphans();
  } catch (const StoreError& e) {
    ++stats_.store_errors;
    spdlog::error("pool: {}", e.what());
    return;
  }
  const int64_t t1 = SteadyClock{}.nowNs();
  const uint64_t progress = progress_.load(std::memory_order_relaxed);
  const double writer_ms = writer_ ? static_cast<double>(writer_->takeWriteNs()) * 1e-6 : 0.0;
  if (last_beat_ns_ != 0 && t1 - last_beat_ns_ > 1'000'000'000) {
    spdlog::warn(
        "pool: {:.0f} ms between two heartbeats of the serve loop ({:.0f} ms in the record's "
        "heartbeat, {:.0f} ms writing samples{}, {} rounds, commands and chunks); the lease "
        "({:.0f} ms) is renewed on a thread of its own while the loop is held up less than "
        "{:.0f} s",
        static_cast<double>(t1 - last_beat_ns_) * 1e-6, static_cast<double>(t1 - t0) * 1e-6,
        static_cast<double>(records_ns_) * 1e-6,
        writer_ ? fmt::format(" (and {:.0f} ms on the writer thread)", writer_ms) : "",
        progress - beat_progress_, static_cast<double>(kPoolLeaseNs) * 1e-6,
        static_cast<double>(kServeStallNs) * 1e-9);
  }
  last_beat_ns_ = t1;
  records_ns_ = 0;
  beat_progress_ = progress;
  letGoOfTakenSessions(mine);
  int claims = 0;
  for (uint64_t id : orphans) {
    if (claims >= kMaxClaimsPerBeat) break;
    if (sessions_.count(id) || suspended_.count(id)) continue;
    store::PoolClaim claim;
    try {
      claim = store_.poolClaim(id, pool_id_);
    } catch (const StoreError& e) {
      ++stats_.store_errors;
      spdlog::error("pool: session {}: {}", id, e.what());
      continue;
    }
    if (!claim.won) continue;
    ++claims;
    takeOver(id, claim, now_ns);
  }
  if (now_ns >= next_checkpoint_ns_) {
    next_checkpoint_ns_ = now_ns + kCheckpointNs;
    for (auto& [id, s] : sessions_) {
      if (!s.hand.simulated() || s.closing) continue;
      try {
        // The hand as it is: at the sample it stepped to last (behind seq_high while a
        // deferred hand waits for its turn).
        const Sample* at = s.hand.lastStepped();
        store_.putCheckpoint(id, {at ? at->seq : s.seq_high, wallNs(), s.hand.checkpoint()});
      } catch (const StoreError& e) {
        ++stats_.store_errors;
        spdlog::error("session {}: checkpoint: {}", id, e.what());
      }
    }
  }
}

void SessionManager::takeOver(uint64_t session_id, const store::PoolClaim& claim, int64_t now_ns) {
  // Why the session was free to take, said once for the record's event and the log: its
  // owner's process gone (its connection to the record closed, and with it every write it
  // could make) before its lease ran out, or its lease run out.
  const bool by_connection = !claim.previous.empty() &&
                             claim.previous_lease_until_ns >= claim.now_ns &&
                             !claim.previous_connected;
  std::optional<SessionInfo> info;
  try {
    info = store_.session(session_id);
    if (!info) return;
    if (info->ended()) {
      // Its server closed it after it was listed as an orphan: nothing to take over.
      spdlog::info("pool: session {}: claimed, but the record has it {}: left as it is", session_id,
                   info->state);
      return;
    }
    const std::string why =
        claim.previous.empty()
            ? "owner: server " + pool_id_ + " took the session on (it had no owner in the pool)"
        : by_connection
            ? fmt::format(
                  "owner: server {} took the session over from server {}, whose connection to "
                  "the record had closed (its lease would have run out at {}, {:.0f} ms later; "
                  "record clock {})",
                  pool_id_, claim.previous, claim.previous_lease_until_ns,
                  static_cast<double>(claim.previous_lease_until_ns - claim.now_ns) * 1e-6,
                  claim.now_ns)
            : fmt::format(
                  "owner: server {} took the session over from server {}, whose lease ran out "
                  "at {} ({:.0f} ms before; record clock {})",
                  pool_id_, claim.previous, claim.previous_lease_until_ns,
                  static_cast<double>(claim.now_ns - claim.previous_lease_until_ns) * 1e-6,
                  claim.now_ns);
    if (info->state == "active") store_.closeSession(session_id, 0, 0, "suspended");
    store_.appendEvent(session_id, {wallNs(), "info",
                                    why + "; the record holds " + std::to_string(info->samples) +
                                        " samples; waiting for its client to resume it"});
  } catch (const StoreError& e) {
    ++stats_.store_errors;
    spdlog::error("session {}: {}", session_id, e.what());
    return;
  }
  info->state = "suspended";
  suspended_[session_id] = now_ns + static_cast<int64_t>(config_.resume_wait_s * 1e9);
  rememberOwner(session_id, info->owner);
  // Its client hears SUSPENDED from a server that is not its own and asks to resume at once.
  publishRecordStatus(*info, telehand_msg_SESSION_SUSPENDED, 0, 0);
  spdlog::info("session {}: taken over from {} ({}; {} samples in the record)", session_id,
               claim.previous.empty() ? "nobody" : claim.previous,
               claim.previous.empty() ? "it had no owner"
               : by_connection        ? "its connection to the record had closed"
                                      : "its lease ran out",
               info->samples);
}

}  // namespace telehand::server::session
