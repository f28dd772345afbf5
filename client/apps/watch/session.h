#pragma once
// Finding the session to watch and watching it until Ctrl-C, --seconds or its close.
#include "model.h"

namespace telehand::client::watch {

/// Watches as `o` asks; returns the exit code.
int run(const Options& o);

}  // namespace telehand::client::watch
