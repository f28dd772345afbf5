#include "telehand/app/dds_cli.h"

#include <cstdio>
#include <cstdlib>

#include "telehand/core/error.h"

namespace telehand::app {

void addDdsOptions(CLI::App& app, dds::Options& o, bool& insecure, const std::string& role) {
  app.add_option("--domain", o.domain, "DDS domain id")->check(CLI::Range(0, 230));
  app.add_option("--partition", o.partition, "DDS partition")->capture_default_str();
  app.add_option("--dds-config", o.config,
                 "Cyclone DDS XML config file (e.g. deploy/cyclonedds/loopback.xml)")
      ->check(CLI::ExistingFile);
  app.add_option("--pki", o.pki,
                 "DDS Security: the PKI directory deploy/pki/make-pki.sh made (default: "
                 "$TELEHAND_PKI)")
      ->check(CLI::ExistingDirectory);
  app.add_option("--identity", o.identity,
                 "DDS Security: the identity in the PKI to authenticate as (default: "
                 "$TELEHAND_IDENTITY, else '" +
                     role + "')");
  app.add_flag("--insecure", insecure,
               "run without DDS Security: anyone on the network can read and forge sessions; "
               "for loopback tests only (without --dds-config it keeps to loopback)");
}

void resolveDdsSecurity(dds::Options& o, bool insecure, const std::string& role,
                        const char* program) {
  const char* env_pki = std::getenv("TELEHAND_PKI");
  const char* env_identity = std::getenv("TELEHAND_IDENTITY");
  if (insecure) {
    if (!o.pki.empty()) throw ConfigError("--insecure and --pki contradict each other");
    o.identity.clear();
    if (o.config.empty()) o.config = TELEHAND_LOOPBACK_XML;
    std::fprintf(stderr,
                 "%s: DDS Security is off (--insecure): any participant on this network can "
                 "read and forge sessions; use it on loopback or a closed test network only\n",
                 program);
    return;
  }
  if (o.pki.empty() && env_pki && *env_pki) o.pki = env_pki;
  if (o.pki.empty()) {
    throw ConfigError(
        "no DDS Security identity: give --pki DIR (deploy/pki/make-pki.sh DIR makes one) and "
        "--identity NAME, or --insecure for a loopback test");
  }
  if (o.identity.empty()) o.identity = env_identity && *env_identity ? env_identity : role;
}

}  // namespace telehand::app
