#!/usr/bin/env bash
# The tree's dependency rules, read from the #include lines (docs/design.md "Layout"):
# every library may include only the libraries below it; the client and the server never
# include each other; the libraries the 1 kHz loop and the Bullet hand are built from
# include no DDS. Prints every violation with its file and line; exit 1 if any.
set -uo pipefail
root=${1:-$(cd "$(dirname "$0")/../.." && pwd)}
cd "$root" || exit 2
status=0

# rule DIR ALLOWED-REGEX: every project include in DIR must match ALLOWED-REGEX.
rule() {
  local dir=$1 allowed=$2
  local hits
  hits=$(grep -rnE '^\s*#\s*include\s*["<](telehand(/|\.h)|dds/|ddsc?/)' "$dir" --include='*.h' --include='*.cpp' \
           | grep -vE "#\s*include\s*[\"<]($allowed)" || true)
  if [ -n "$hits" ]; then
    echo "layout: $dir may include only ($allowed):"
    echo "$hits" | sed 's/^/  /'
    status=1
  fi
}

rule common/core            'telehand/core/'
rule common/app             'telehand/(app|protocol|core)/|telehand\.h|dds/'
rule common/config          'telehand/(core|config)/'
rule common/devices         'telehand/(core|config|devices)/'
rule common/protocol        'telehand/(core|protocol)/|telehand\.h|dds/'
rule client/loop            'telehand/(core|config|devices|client/loop)/'
rule client/usb             'telehand/(core|devices|client/usb)/'
rule client/link            'telehand/(core|config|devices|protocol|client/(loop|link))/|telehand\.h|dds/'
rule client/apps            'telehand/(core|config|devices|protocol|app|client/)|telehand\.h|dds/'
rule server/sim             'telehand/(core|server/sim)/'
rule server/store           'telehand/(core|server/store)/'
rule server/estimate        'telehand/(core|config|devices|server/(store|estimate))/'
rule server/lesson          'telehand/(core|config|protocol|server/(store|lesson))/'
rule server/session         'telehand/(core|config|protocol|server/(sim|store|estimate|lesson|session))/|telehand\.h'
rule server/link            'telehand/(core|config|protocol|server/(sim|store|estimate|lesson|session|link))/|telehand\.h|dds/'
rule server/apps            'telehand/(core|config|devices|protocol|app|server/)|telehand\.h|dds/'

# No relative includes that climb out of a library.
climb=$(grep -rnE '^\s*#\s*include\s*"\.\./' common client server tools --include='*.h' --include='*.cpp' || true)
if [ -n "$climb" ]; then
  echo "layout: relative includes out of a library:"
  echo "$climb" | sed 's/^/  /'
  status=1
fi

# Nothing points outside the repository: the design and the facts live in docs/.
outside=$(git -C "$root" grep -nE '(^|[^/])(FACTS|DESIGN)\.md|shared/reference' -- ':!tests/layout/check_layout.sh' 2>/dev/null || true)
if [ -n "$outside" ]; then
  echo "layout: references outside the repository (use docs/design.md or docs/facts.md):"
  echo "$outside" | sed 's/^/  /'
  status=1
fi

[ $status -eq 0 ] && echo "layout: include directions hold, nothing cited outside the repository"
exit $status
