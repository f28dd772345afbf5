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

}  // namespace telehand::server::store::detail
