#include "telehand/config/toml_reader.h"

#include <fstream>
#include <iomanip>
#include <locale>
#include <sstream>

#include "telehand/core/error.h"

namespace telehand::config {

std::string formatNumber(double v) {
  std::ostringstream o;
  o.imbue(std::locale::classic());
  o << std::setprecision(15) << v;
  return o.str();
}

std::string readTextFile(const std::string& path, const std::string& what) {
  std::ifstream in(path);
  if (!in) throw ConfigError(what + " '" + path + "' cannot be read");
  std::ostringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

void fail(const std::string& origin, const std::string& what) {
  throw ConfigError(origin + ": " + what);
}

toml::table parseToml(const std::string& text, const std::string& origin) {
  try {
    return toml::parse(text, origin);
  } catch (const toml::parse_error& e) {
    fail(origin, "line " + std::to_string(e.source().begin.line) + ", column " +
                     std::to_string(e.source().begin.column) + ": " + std::string(e.description()));
  }
}

void rejectUnknownTables(const toml::table& root, const std::set<std::string>& known,
                         const std::string& origin) {
  for (const auto& [k, v] : root) {
    if (!known.count(std::string(k.str()))) {
      fail(origin, "line " + std::to_string(v.source().begin.line) + ": unknown table '" +
                       std::string(k.str()) + "'");
    }
  }
}

TomlTable::TomlTable(const toml::table& root, const std::string& name, const std::string& origin,
                     bool required)
    : origin_(origin), name_(name) {
  const toml::node* n = root.get(name);
  if (!n) {
    if (required) config::fail(origin, "missing table [" + name + "]");
    return;
  }
  t_ = n->as_table();
  if (!t_) config::fail(origin, "'" + name + "' must be a table");
}

double TomlTable::number(const std::string& key, double fallback, double lo, double hi) {
  const toml::node* n = get(key);
  if (!n) return fallback;
  auto v = n->value<double>();
  if (!v || n->is_boolean()) fail(n, key, "must be a number");
  if (!std::isfinite(*v)) fail(n, key, "must be a finite number");
  if (!(*v >= lo && *v <= hi)) {
    fail(n, key,
         "= " + formatNumber(*v) + " is outside [" + formatNumber(lo) + ", " + formatNumber(hi) +
             "]");
  }
  return *v;
}

int64_t TomlTable::integer(const std::string& key, int64_t fallback, int64_t lo, int64_t hi) {
  const toml::node* n = get(key);
  if (!n) return fallback;
  if (!n->is_integer()) fail(n, key, "must be an integer");
  const int64_t v = *n->value<int64_t>();
  if (v < lo || v > hi) fail(n, key, "= " + std::to_string(v) + " is outside its range");
  return v;
}

std::string TomlTable::text(const std::string& key, const std::string& fallback) {
  const toml::node* n = get(key);
  if (!n) return fallback;
  auto v = n->value<std::string>();
  if (!v || !n->is_string()) fail(n, key, "must be a string");
  return *v;
}

void TomlTable::rejectUnknown() const {
  if (!t_) return;
  for (const auto& [k, v] : *t_) {
    if (!known_.count(std::string(k.str()))) {
      config::fail(origin_, "line " + std::to_string(v.source().begin.line) + ": unknown key '" +
                                name_ + "." + std::string(k.str()) + "'");
    }
  }
}

const toml::node* TomlTable::get(const std::string& key) {
  known_.insert(key);
  return t_ ? t_->get(key) : nullptr;
}

void TomlTable::fail(const toml::node* n, const std::string& key, const std::string& what) const {
  config::fail(origin_, "line " + std::to_string(n->source().begin.line) + ": '" + name_ + "." +
                            key + "' " + what);
}

std::string TomlTable::typeName(const toml::node& n) {
  return std::string(toml::impl::node_type_friendly_names[static_cast<int>(n.type())]);
}

}  // namespace telehand::config
