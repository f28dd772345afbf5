#!/usr/bin/env bash
# Installs, with apt, exactly the Debian 12 packages telehand needs to build, test and run.
# Idempotent: packages already present are left alone and apt is not called at all
# when nothing is missing.
set -euo pipefail

packages=(
  # toolchain
  g++ cmake ninja-build pkg-config
  # DDS (C API, idlc, ddsperf; the security plugins come with libddsc0debian) and the
  # DDS Security PKI (deploy/pki/make-pki.sh)
  cyclonedds-dev cyclonedds-tools openssl libssl-dev
  # maths, physics, USB, nearest neighbours
  libeigen3-dev libbullet-dev libusb-1.0-0-dev libflann-dev liblz4-dev
  # hand model (URDF parser, check_urdf)
  liburdfdom-dev liburdfdom-tools
  # records (SQLite; PostgreSQL's client library, and its server for the tests and benchmark
  # of the PostgreSQL store), CLI, logs, config
  libsqlite3-dev libpq-dev postgresql libcli11-dev libspdlog-dev libtomlplusplus-dev
  # tests and benchmarks
  libgtest-dev libgmock-dev libbenchmark-dev
  # the emulated MF-2 (USB tests) and the fuzz targets (clang's libFuzzer)
  umockdev libumockdev-dev clang libclang-rt-14-dev
  # formatting and layout checks (tests/layout/: they read the tracked files with git)
  git
  clang-format
  # plots of fitted captures (telehand-records fit)
  gnuplot-nox
  # network namespaces for system tests
  iproute2
  # the web console (telehand-web): HTTP/WebSocket server, JSON, the page's JavaScript
  # dependencies from web/package-lock.json (npm), and the browser its test drives
  libcivetweb-dev nlohmann-json3-dev nodejs chromium
)

missing=()
for p in "${packages[@]}"; do
  if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed"; then
    missing+=("$p")
  fi
done

# The web console's JavaScript (three.js, uPlot; playwright-core for its browser test),
# exactly as web/package-lock.json pins it, into web/node_modules; the build vendors it from
# there. Skipped when what is installed already matches the lockfile.
web_dependencies() {
  local web
  web="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)/web"
  command -v npm >/dev/null || { echo "setup: npm missing (package nodejs)" >&2; return 1; }
  if cmp -s "$web/package-lock.json" "$web/node_modules/.telehand-lock" 2>/dev/null; then
    return 0
  fi
  echo "setup: installing the web console's JavaScript (npm ci in web/)"
  (cd "$web" && npm ci --no-audit --no-fund --loglevel=error)
  cp "$web/package-lock.json" "$web/node_modules/.telehand-lock"
}

# npm comes with some builds of nodejs and is a package of its own in Debian's.
command -v npm >/dev/null || missing+=(npm)

if [ ${#missing[@]} -eq 0 ]; then
  echo "setup: all ${#packages[@]} packages present"
  web_dependencies
  exit 0
fi

echo "setup: installing ${missing[*]}"
sudo_cmd=()
if [ "$(id -u)" -ne 0 ]; then
  command -v sudo >/dev/null || { echo "setup: need root or sudo to install: ${missing[*]}" >&2; exit 1; }
  sudo_cmd=(sudo)
fi
export DEBIAN_FRONTEND=noninteractive
"${sudo_cmd[@]}" apt-get update -qq
"${sudo_cmd[@]}" apt-get install -y -qq --no-install-recommends "${missing[@]}"
web_dependencies
