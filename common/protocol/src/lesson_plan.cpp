#include "telehand/protocol/lesson_plan.h"

#include <cstdio>
#include <map>

#include "telehand/core/parse.h"

namespace telehand {

bool validSchedule(const std::string& s) noexcept {
  return s == "concurrent" || s == "terminal" || s == "faded" || s == "self";
}

std::string encodePlan(const LessonPlan& p) {
  char buf[256];
  std::snprintf(buf, sizeof buf,
                "lesson=%llu;schedule=%s;guided=%d;attempts=%d;trial_s=%.3f;assessment=%d;"
                "demo_s=%.3f;band_min_n=%.3f;band_max_n=%.3f;frequency_hz=%.4f;takeover=%d;"
                "technique=%s",
                static_cast<unsigned long long>(p.lesson_id), p.schedule.c_str(), p.guided,
                p.attempts, p.trial_s, p.assessment ? 1 : 0, p.demo_s, p.band_min_n, p.band_max_n,
                p.frequency_hz, p.takeover ? 1 : 0,
                p.technique == "massage" ? "massage" : "mobilization");
  return buf;
}

std::optional<LessonPlan> decodePlan(const std::string& text, std::string* why) {
  auto bad = [why](const std::string& w) -> std::optional<LessonPlan> {
    if (why) *why = w;
    return std::nullopt;
  };
  std::map<std::string, std::string> kv;
  std::size_t pos = 0;
  while (pos < text.size()) {
    const std::size_t end = std::min(text.find(';', pos), text.size());
    const std::string item = text.substr(pos, end - pos);
    const std::size_t eq = item.find('=');
    if (eq == std::string::npos) return bad("lesson plan item '" + item + "' has no '='");
    if (!kv.emplace(item.substr(0, eq), item.substr(eq + 1)).second) {
      return bad("lesson plan: '" + item.substr(0, eq) + "' is given twice");
    }
    pos = end + 1;
  }
  auto num = [&](const char* key, double lo, double hi, double& out) -> bool {
    const auto it = kv.find(key);
    if (it == kv.end()) return false;
    double d = 0.0;
    if (!parseFiniteNumber(it->second, d) || d < lo || d > hi) return false;
    out = d;
    return true;
  };
  LessonPlan p;
  double v = 0.0;
  if (!num("lesson", 1, 9e15, v)) return bad("lesson plan: 'lesson' missing or not an id");
  p.lesson_id = static_cast<uint64_t>(v);
  const auto sch = kv.find("schedule");
  if (sch == kv.end() || !validSchedule(sch->second)) {
    return bad("lesson plan: 'schedule' missing or not concurrent, terminal, faded or self");
  }
  p.schedule = sch->second;
  if (!num("guided", 0, 10, v)) return bad("lesson plan: 'guided' missing or out of 0..10");
  p.guided = static_cast<int>(v);
  if (!num("attempts", 1, 20, v)) return bad("lesson plan: 'attempts' missing or out of 1..20");
  p.attempts = static_cast<int>(v);
  if (!num("trial_s", 2, 120, p.trial_s)) return bad("lesson plan: 'trial_s' out of 2..120 s");
  if (!num("assessment", 0, 1, v)) return bad("lesson plan: 'assessment' missing or not 0/1");
  p.assessment = v != 0.0;
  if (!num("demo_s", 0, 600, p.demo_s)) return bad("lesson plan: 'demo_s' out of 0..600 s");
  if (!num("band_min_n", 0, 100, p.band_min_n) || !num("band_max_n", 0, 100, p.band_max_n) ||
      p.band_min_n > p.band_max_n || !(p.band_max_n > 0.0)) {
    return bad(
        "lesson plan: 'band_min_n'/'band_max_n' missing, out of 0..100 N, reversed or a band "
        "ending at 0 N");
  }
  if (!num("frequency_hz", 0.1, 10, p.frequency_hz)) {
    return bad("lesson plan: 'frequency_hz' out of 0.1..10 Hz");
  }
  if (kv.count("takeover")) {  // optional: a plan without it allows none
    if (!num("takeover", 0, 1, v)) return bad("lesson plan: 'takeover' not 0/1");
    p.takeover = v != 0.0;
  }
  if (const auto t = kv.find("technique"); t != kv.end()) {  // optional: a mobilization
    if (t->second != "mobilization" && t->second != "massage") {
      return bad("lesson plan: 'technique' not mobilization or massage");
    }
    p.technique = t->second;
  }
  return p;
}

double guidedAuthority(int i, int n) noexcept {
  if (n <= 0 || i < 0 || i >= n) return 0.0;
  return 1.0 - static_cast<double>(i) / static_cast<double>(n);
}

bool feedbackAfter(const std::string& schedule, int i, int trials, bool requested) noexcept {
  if (schedule == "terminal") return true;
  if (schedule == "self") return requested;
  if (schedule == "concurrent") return i == trials - 1;
  if (schedule == "faded") {
    // Every trial of the first third, every other one of the second, none after (the
    // last trial's summary still shows: the student sees where they ended).
    if (i == trials - 1) return true;
    if (3 * i < trials) return true;
    if (3 * i < 2 * trials) return i % 2 == 0;
    return false;
  }
  return false;
}

}  // namespace telehand
