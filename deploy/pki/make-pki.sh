#!/usr/bin/env bash
# Make a DDS Security PKI for telehand: one CA (it signs the identities and, as the
# permissions CA, the governance and permissions documents), one identity per role, the
# governance document and each identity's permissions document, all signed (S/MIME) the
# way Cyclone DDS's access control plugin reads them. docs/security.md explains the roles.
#
#   deploy/pki/make-pki.sh OUT_DIR [NAME:ROLE ...]
#
# ROLE is server, device, supervisor or engineer. Without NAME:ROLE arguments it makes one
# identity per role, named after the role (server, device, supervisor, engineer): what the
# demo and the tests use. OUT_DIR must not exist yet, or hold a PKI made by this script
# (new identities are added to it with its CA). Keys are written readable by the owner only.
set -euo pipefail

usage() {
  sed -n '2,12p' "$0" | sed 's/^# \{0,1\}//'
}
if [ $# -lt 1 ] || [ "$1" = "-h" ] || [ "$1" = "--help" ]; then
  usage
  [ $# -ge 1 ] && exit 0 || exit 2
fi
command -v openssl >/dev/null || { echo "make-pki: openssl is not installed (deploy/setup.sh installs it)" >&2; exit 2; }

here=$(cd "$(dirname "$0")" && pwd)
out=$1
shift
ids=("$@")
[ ${#ids[@]} -eq 0 ] && ids=(server:server device:device supervisor:supervisor engineer:engineer)
days=${TELEHAND_PKI_DAYS:-3650}
org="telehand"

umask 077
mkdir -p "$out"
out=$(cd "$out" && pwd)

# The CA: made once, reused when identities are added later.
if [ ! -f "$out/ca/ca.pem" ]; then
  mkdir -p "$out/ca"
  openssl req -x509 -newkey ec -pkeyopt ec_paramgen_curve:prime256v1 -nodes -days "$days" \
    -subj "/O=$org/CN=telehand CA" -keyout "$out/ca/ca.key" -out "$out/ca/ca.pem" 2>/dev/null
  chmod 644 "$out/ca/ca.pem"
fi
ca="$out/ca/ca.pem"
ca_key="$out/ca/ca.key"

sign() {  # sign IN.xml -> OUT.p7s with the permissions CA (here the same CA)
  openssl smime -sign -in "$1" -text -out "$2" -signer "$ca" -inkey "$ca_key" 2>/dev/null
  chmod 644 "$2"
}

# Governance: who may join and how everything is protected (the same for every identity).
sign "$here/governance.xml" "$out/governance.p7s"
cp "$here/governance.xml" "$out/governance.xml"

not_before=$(date -u +%Y-%m-%dT%H:%M:%S)
not_after=$(date -u -d "+$days days" +%Y-%m-%dT%H:%M:%S)

for spec in "${ids[@]}"; do
  name=${spec%%:*}
  role=${spec#*:}
  if [ "$name" = "$spec" ] || [ -z "$name" ] || [ -z "$role" ]; then
    echo "make-pki: '$spec' is not NAME:ROLE" >&2
    exit 2
  fi
  case "$name" in *[!A-Za-z0-9_.-]*) echo "make-pki: identity name '$name' may hold only letters, digits, '.', '_' and '-'" >&2; exit 2 ;; esac
  rules="$here/roles/$role.xml"
  if [ ! -f "$rules" ]; then
    echo "make-pki: unknown role '$role' (server, device, supervisor, engineer)" >&2
    exit 2
  fi
  dir="$out/$name"
  mkdir -p "$dir"
  subject="/O=$org/OU=$role/CN=$name"
  openssl req -newkey ec -pkeyopt ec_paramgen_curve:prime256v1 -nodes -subj "$subject" \
    -keyout "$dir/identity.key" -out "$dir/identity.csr" 2>/dev/null
  openssl x509 -req -in "$dir/identity.csr" -CA "$ca" -CAkey "$ca_key" -CAcreateserial \
    -days "$days" -out "$dir/identity.pem" 2>/dev/null
  rm -f "$dir/identity.csr"
  chmod 644 "$dir/identity.pem"
  # The subject as the access control plugin compares it (RFC 4514 order: CN first).
  dn="CN=$name,OU=$role,O=$org"
  {
    echo '<?xml version="1.0" encoding="UTF-8"?>'
    echo '<dds xmlns:xsi="http://www.w3.org/2001/XMLSchema-instance"'
    echo '     xsi:noNamespaceSchemaLocation="http://www.omg.org/spec/DDS-Security/20170801/omg_shared_ca_permissions.xsd">'
    echo '  <permissions>'
    echo "    <grant name=\"$name\">"
    echo "      <subject_name>$dn</subject_name>"
    echo "      <validity><not_before>$not_before</not_before><not_after>$not_after</not_after></validity>"
    cat "$rules"
    echo '      <default>DENY</default>'
    echo '    </grant>'
    echo '  </permissions>'
    echo '</dds>'
  } >"$dir/permissions.xml"
  sign "$dir/permissions.xml" "$dir/permissions.p7s"
  echo "$role" >"$dir/role"
  chmod 644 "$dir/permissions.xml" "$dir/role"
  echo "make-pki: $name ($role) in $dir"
done
rm -f "$out/ca/ca.srl"
