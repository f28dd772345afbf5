#pragma once
/// The one set of TOML readers every file format of telehand uses (client and server
/// configuration, patient cases, MF-2 device and thimble files, link profiles). Strict:
/// unknown tables and keys, wrong types and out-of-range values are ConfigErrors naming the
/// file (origin), the line and the key.
#include <toml++/toml.h>

#include <array>
#include <cmath>
#include <cstdint>
#include <set>
#include <string>
#include <utility>

namespace telehand::config {

/// The whole file; a missing or unreadable file is a ConfigError "<what> '<path>' cannot
/// be read".
std::string readTextFile(const std::string& path, const std::string& what);

/// Parse TOML text; a syntax error is a ConfigError with its line and column.
toml::table parseToml(const std::string& text, const std::string& origin);

/// Every top-level table must be one of `known`.
void rejectUnknownTables(const toml::table& root, const std::set<std::string>& known,
                         const std::string& origin);

[[noreturn]] void fail(const std::string& origin, const std::string& what);

/// A number in an error message as a user would write it: 800, 0.1, 67108865, 1e+300 (up to
/// 15 significant digits, so 799.9999999 is not shown as 800; the C locale).
std::string formatNumber(double v);

/// Reads the keys of one table; rejectUnknown() then refuses every key nobody asked for.
class TomlTable {
 public:
  /// An absent table reads as empty (every key keeps its default) unless `required`.
  TomlTable(const toml::table& root, const std::string& name, const std::string& origin,
            bool required = false);
  bool present() const noexcept { return t_ != nullptr; }

  /// Typed getters with a default and a range.
  double number(const std::string& key, double fallback, double lo, double hi);
  int64_t integer(const std::string& key, int64_t fallback, int64_t lo, int64_t hi);
  std::string text(const std::string& key, const std::string& fallback);
  template <std::size_t N>
  std::array<double, N> numbers(const std::string& key, const std::array<double, N>& fallback,
                                double lo, double hi) {
    const toml::node* n = get(key);
    if (!n) return fallback;
    const toml::array* a = n->as_array();
    if (!a || a->size() != N) fail(n, key, "must be an array of " + std::to_string(N) + " numbers");
    std::array<double, N> out{};
    for (std::size_t i = 0; i < N; ++i) {
      auto v = (*a)[i].value<double>();
      if (!v || !std::isfinite(*v) || *v < lo || *v > hi) {
        fail(n, key,
             "element " + std::to_string(i) + " is not a number in [" + formatNumber(lo) + ", " +
                 formatNumber(hi) + "]");
      }
      out[i] = *v;
    }
    return out;
  }

  /// Read into `out` when present (its type says what is accepted: a string, true/false, a
  /// number, or a non-negative integer that fits); ranges are checked by the caller.
  template <typename T>
  void read(const std::string& key, T& out) {
    const toml::node* n = get(key);
    if (!n) return;
    if constexpr (std::is_same_v<T, std::string>) {
      if (auto v = n->value<std::string>()) {
        out = *v;
        return;
      }
    } else if constexpr (std::is_same_v<T, bool>) {
      if (n->is_boolean()) {
        out = *n->value<bool>();
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
        if (!std::in_range<T>(*v)) fail(n, key, "= " + std::to_string(*v) + " is too large");
        out = static_cast<T>(*v);
        return;
      }
    }
    const char* want = std::is_same_v<T, std::string> ? "a string"
                       : std::is_same_v<T, bool>      ? "true or false"
                       : std::is_floating_point_v<T>  ? "a number"
                                                      : "a non-negative integer";
    fail(n, key, std::string("must be ") + want + " (found " + typeName(*n) + ")");
  }
  /// A TOML array of exactly N finite numbers, into `out` when present.
  template <std::size_t N>
  void readArray(const std::string& key, std::array<double, N>& out) {
    const toml::node* n = get(key);
    if (!n) return;
    const toml::array* a = n->as_array();
    if (!a || a->size() != N) fail(n, key, "must be an array of " + std::to_string(N) + " numbers");
    for (std::size_t i = 0; i < N; ++i) {
      auto v = (*a)[i].value<double>();
      if (!v || !std::isfinite(*v))
        fail(n, key, "element " + std::to_string(i) + " is not a finite number");
      out[i] = *v;
    }
  }

  void rejectUnknown() const;

 private:
  const toml::node* get(const std::string& key);
  [[noreturn]] void fail(const toml::node* n, const std::string& key,
                         const std::string& what) const;
  static std::string typeName(const toml::node& n);

  std::string origin_;
  std::string name_;
  const toml::table* t_ = nullptr;
  std::set<std::string> known_;
};

}  // namespace telehand::config
