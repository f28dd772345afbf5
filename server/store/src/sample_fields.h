#pragma once
// The sample's fields as the record keeps them, one column each: the order and names the
// SQLite and PostgreSQL tables, their inserts and reads, and the CSV export all follow.
#include <string>
#include <utility>
#include <vector>

#include "telehand/core/sample.h"

namespace telehand::server::store::detail {

/// The sample's fields in record order (core's visitSampleFields()).
template <class S, class F>
void visitFields(S& s, F&& f) {
  visitSampleFields(s, std::forward<F>(f));
}

/// The names visitFields() goes through, in its order (sampleColumns() without "valid").
const std::vector<std::string>& fieldNames();

/// The last fields, which record schema 7 added (the massage's web per finger: depth and
/// force). A record from before them reads them as 0.
constexpr std::size_t kWebFieldCount = 8;
inline bool isWebField(std::size_t i) { return i + kWebFieldCount >= fieldNames().size(); }

}  // namespace telehand::server::store::detail
