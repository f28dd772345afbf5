#include "telehand/common/config.h"

#include <fstream>
#include <sstream>
#include <toml++/toml.h>
#include <utility>

#include "telehand/common/error.h"

namespace telehand {
namespace {

[[noreturn]] void fail(const std::string& origin, const std::string& what) {
  throw ConfigError(origin + ": " + what);
}

/// Reads keys of one table, rejecting keys it was not asked about.
class TableReader {
 public:
  TableReader(const toml::table& root, const std::string& name, const std::string& origin)
      : origin_(origin), name_(name) {
    if (const toml::node* n = root.get(name)) {
      table_ = n->as_table();
      if (!table_) fail(origin, "'" + name + "' must be a table");
    }
  }
  template <typename T>
  void read(const std::string& key, T& out) {
    known_.push_back(key);
    if (!table_) return;
    const toml::node* n = table_->get(key);
    if (!n) return;
    if constexpr (std::is_same_v<T, std::string>) {
      if (auto v = n->value<std::string>()) {
        out = *v;
        return;
      }
    } else if constexpr (std::is_floating_point_v<T>) {
      if (auto v = n->value<double>()) {
        out = *v;
        return;
      }
    } else {
      // toml++ would convert a boolean: only a TOML integer counts, and it must fit T.
      if (auto v = n->value<int64_t>(); v && n->is_integer() && *v >= 0) {
        if (!std::in_range<T>(*v)) {
          fail(origin_, "line " + std::to_string(n->source().begin.line) + ": '" + name_ + "." +
                            key + "' = " + std::to_string(*v) + " is too large");
        }
        out = static_cast<T>(*v);
        return;
      }
    }
    std::string want = std::is_same_v<T, std::string> ? "a string"
                       : std::is_floating_point_v<T>   ? "a number"
                                                       : "a non-negative integer";
    fail(origin_, "line " + std::to_string(n->source().begin.line) + ": '" + name_ + "." + key +
                      "' must be " + want + " (found " + std::string(toml::impl::node_type_friendly_names[static_cast<int>(n->type())]) + ")");
  }
  void rejectUnknown() const {
    if (!table_) return;
    for (const auto& [k, v] : *table_) {
      if (std::find(known_.begin(), known_.end(), std::string(k.str())) == known_.end()) {
        fail(origin_, "line " + std::to_string(v.source().begin.line) + ": unknown key '" +
                          name_ + "." + std::string(k.str()) + "'");
      }
    }
  }

 private:
  std::string origin_;
  std::string name_;
  const toml::table* table_ = nullptr;
  std::vector<std::string> known_;
};

toml::table parse(const std::string& text, const std::string& origin) {
  try {
    return toml::parse(text, origin);
  } catch (const toml::parse_error& e) {
    fail(origin, "line " + std::to_string(e.source().begin.line) + ", column " +
                     std::to_string(e.source().begin.column) + ": " +
                     std::string(e.description()));
  }
}

void rejectUnknownTables(const toml::table& root, std::initializer_list<const char*> known,
                         const std::string& origin) {
  for (const auto& [k, v] : root) {
    bool ok = false;
    for (const char* n : known) ok = ok || k.str() == n;
    if (!ok) {
      fail(origin, "line " + std::to_string(v.source().begin.line) + ": unknown table '" +
                       std::string(k.str()) + "'");
    }
  }
}

std::string readFile(const std::string& path) {
  std::ifstream in(path);
  if (!in) throw ConfigError("config file '" + path + "' cannot be read");
  std::ostringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

void requireRange(const std::string& origin, const char* key, double v, double lo, double hi) {
  if (!(v >= lo && v <= hi)) {
    fail(origin, std::string("'") + key + "' = " + std::to_string(v) + " is outside [" +
                     std::to_string(lo) + ", " + std::to_string(hi) + "]");
  }
}

}  // namespace

void validate(const OperatorConfig& c, const std::string& origin) {
  requireRange(origin, "operator.frequency_hz", c.frequency_hz, 0.1, 10.0);
  requireRange(origin, "operator.band_min_n", c.band_min_n, 0.0, 40.0);
  requireRange(origin, "operator.band_max_n", c.band_max_n, c.band_min_n, 40.0);
  requireRange(origin, "operator.ramp_s", c.ramp_s, 0.0, 60.0);
  requireRange(origin, "operator.sensor_noise_n", c.sensor_noise_n, 0.0, 5.0);
}

void validate(const SafetyLimits& c, const std::string& origin) {
  requireRange(origin, "safety.max_force_n", c.max_force_n, 0.0, 4.0);
  requireRange(origin, "safety.max_rate_n_per_s", c.max_rate_n_per_s, 1.0, 10000.0);
  requireRange(origin, "safety.watchdog_ms", static_cast<double>(c.watchdog_ns) / 1e6, 1.0, 1000.0);
}

ClientConfig parseClientConfig(const std::string& text, const std::string& origin) {
  const toml::table root = parse(text, origin);
  rejectUnknownTables(root, {"operator", "safety", "loop"}, origin);
  ClientConfig c;
  TableReader op(root, "operator", origin);
  op.read("frequency_hz", c.op.frequency_hz);
  op.read("band_min_n", c.op.band_min_n);
  op.read("band_max_n", c.op.band_max_n);
  op.read("ramp_s", c.op.ramp_s);
  op.read("sensor_noise_n", c.op.sensor_noise_n);
  op.read("seed", c.op.seed);
  op.rejectUnknown();
  TableReader sf(root, "safety", origin);
  sf.read("max_force_n", c.safety.max_force_n);
  sf.read("max_rate_n_per_s", c.safety.max_rate_n_per_s);
  double watchdog_ms = static_cast<double>(c.safety.watchdog_ns) / 1e6;
  sf.read("watchdog_ms", watchdog_ms);
  // Before the conversion: inf or 1e300 ms do not fit an int64 (undefined behaviour).
  requireRange(origin, "safety.watchdog_ms", watchdog_ms, 1.0, 1000.0);
  c.safety.watchdog_ns = static_cast<int64_t>(watchdog_ms * 1e6);
  sf.rejectUnknown();
  TableReader lp(root, "loop", origin);
  lp.read("rate_hz", c.loop.rate_hz);
  lp.read("rt_priority", c.loop.rt_priority);
  lp.rejectUnknown();
  validate(c.op, origin);
  validate(c.safety, origin);
  requireRange(origin, "loop.rate_hz", c.loop.rate_hz, 100.0, 4000.0);
  requireRange(origin, "loop.rt_priority", c.loop.rt_priority, 0, 99);
  return c;
}

ServerConfig parseServerConfig(const std::string& text, const std::string& origin) {
  const toml::table root = parse(text, origin);
  rejectUnknownTables(root, {"server"}, origin);
  ServerConfig c;
  TableReader sv(root, "server", origin);
  sv.read("db", c.db_path);
  sv.read("hand_state_hz", c.hand_state_hz);
  sv.read("close_grace_s", c.close_grace_s);
  sv.rejectUnknown();
  if (c.db_path.empty()) fail(origin, "'server.db' must not be empty");
  requireRange(origin, "server.hand_state_hz", c.hand_state_hz, 1.0, 1000.0);
  requireRange(origin, "server.close_grace_s", c.close_grace_s, 0.0, 600.0);
  return c;
}

ClientConfig loadClientConfig(const std::string& path) {
  return parseClientConfig(readFile(path), path);
}
ServerConfig loadServerConfig(const std::string& path) {
  return parseServerConfig(readFile(path), path);
}

}  // namespace telehand
