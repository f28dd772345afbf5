#pragma once
/// The DDS options every networked program takes, and the rule that a program runs under
/// DDS Security unless told otherwise (docs/security.md):
///   --domain, --partition, --dds-config   which DDS world to join
///   --pki DIR, --identity NAME            authenticate as NAME of the PKI in DIR
///                                         (environment: TELEHAND_PKI, TELEHAND_IDENTITY)
///   --insecure                            no DDS Security: loopback tests only
#include <CLI/CLI.hpp>
#include <string>

#include "telehand/protocol/dds.h"

namespace telehand::app {

/// Adds the options above to `app`; `role` is the identity used when neither --identity nor
/// TELEHAND_IDENTITY names one (server, device, supervisor, engineer).
void addDdsOptions(CLI::App& app, dds::Options& options, bool& insecure, const std::string& role);

/// After parsing: fills --pki/--identity from the environment (else `role`) where not given,
/// then applies the rule: secured with a PKI, or --insecure (which, without --dds-config,
/// keeps to deploy/cyclonedds/loopback.xml, and says so on stderr as `program`). Throws
/// ConfigError when neither or both are given.
void resolveDdsSecurity(dds::Options& options, bool insecure, const std::string& role,
                        const char* program);

}  // namespace telehand::app
