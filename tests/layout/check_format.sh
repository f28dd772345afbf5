#!/usr/bin/env bash
# Every C++ file the repository tracks is formatted as .clang-format says (clang-format 14,
# Debian's clang-format). Lists the files that are not; exit 1 if any.
set -uo pipefail
root=${1:-$(cd "$(dirname "$0")/../.." && pwd)}
cd "$root" || exit 2
command -v clang-format >/dev/null || { echo "format: clang-format not found (deploy/setup.sh installs it)"; exit 1; }
# The list first: a checkout git cannot read must fail here, not pass having checked nothing.
files=$(git ls-files '*.h' '*.cpp') || { echo "format: cannot list the tracked files (git ls-files failed in $root)"; exit 1; }
[ -n "$files" ] || { echo "format: no tracked C++ files in $root"; exit 1; }
# One clang-format over all the files (a process a file took most of the check's time): it
# names each file that differs in a "FILE:LINE:COL: error: code should be clang-formatted".
out=$(printf '%s\n' "$files" | xargs -d '\n' clang-format --dry-run --Werror 2>&1)
rc=$?
mapfile -t bad < <(grep -oE '^[^:]+:[0-9]+:[0-9]+: error: code should be clang-formatted' <<< "$out" |
                   cut -d: -f1 | sort -u)
if [ ${#bad[@]} -gt 0 ]; then
  echo "format: ${#bad[@]} files differ from .clang-format (clang-format -i FILE to fix):"
  printf '  %s\n' "${bad[@]}"
  exit 1
fi
if [ $rc -ne 0 ]; then
  echo "format: clang-format failed (exit $rc) without naming a file that differs:"
  printf '%s\n' "$out" | head -20
  exit 1
fi
echo "format: every tracked C++ file matches .clang-format"
