#!/usr/bin/env bash
# Installs what is missing, builds (warnings are errors) and runs the whole test suite.
# Extra arguments go to ctest (e.g. -L unit, -R watch).
set -euo pipefail
cd "$(dirname "$0")/.."
./deploy/setup.sh
./deploy/build.sh release
ctest --preset release -j 2 "$@"
