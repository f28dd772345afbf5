// telehand-web: the supervisor's web console. Joins the DDS domain as the supervisor role
// (under DDS Security unless --insecure), serves the page (web/, vendored into the build
// tree) and one WebSocket (/ws) per browser: the live sessions, each session's hand at up to
// --hand-hz, its events, marks the supervisor adds, and replays of recorded sessions read
// from the store (docs/web.md).
#include <spdlog/fmt/fmt.h>

#include <filesystem>
#include <iostream>

#include "gateway.h"
#include "telehand/app/cli.h"
#include "telehand/app/dds_cli.h"
#include "telehand/app/signals.h"
#include "telehand/core/error.h"
#include "telehand/core/log.h"
#include "telehand/server/store/open_store.h"

int main(int argc, char** argv) {
  using namespace telehand;
  CLI::App app{
      "telehand-web: the supervisor's web console. Serves one page and a WebSocket stream: "
      "live sessions (the 3D hand, forces against the band, MCP angles, link health, "
      "events), marks and comments, and replays of recorded sessions. Ctrl-C quits."};
  web::Options o;
  o.root = TELEHAND_WEB_ROOT;
  std::string log_level = "info";
  std::string bind;
  app.add_option("--bind", bind,
                 "address:port to serve on (default 127.0.0.1:8080, this machine only; e.g. "
                 "0.0.0.0:8080 to open it to the network; port 0: one the system chooses, "
                 "printed at start)");
  app.add_option("--allow-host", o.allow_hosts,
                 "a host name the console is opened by (repeatable); IP addresses and localhost "
                 "always are. A request naming another host is refused (a page of another site "
                 "whose name was made to point here)");
  app.add_option("--db", o.db,
                 "the record store to replay sessions from (telehand-server --db): an SQLite "
                 "file path or a PostgreSQL URI postgresql://[user@]host[:port]/dbname");
  o.hand = std::string(TELEHAND_DEPLOY_DIR) + "/hand/hand24.urdf";
  app.add_option("--hand", o.hand, "the hand model (URDF) the server's HandState follows")
      ->check(CLI::ExistingFile)
      ->capture_default_str();
  o.cases = std::string(TELEHAND_DEPLOY_DIR) + "/cases";
  app.add_option("--cases", o.cases,
                 "the patient cases the server reads (telehand-server --cases): a replay's hand "
                 "runs on the case its session ran on")
      ->capture_default_str();
  app.add_option("--replay-hand-hz", o.replay_hand_hz,
                 "a replay's hand frames per second of record, at most")
      ->check(CLI::Range(1.0, 100.0))
      ->capture_default_str();
  app.add_option("--replay-hand-s", o.replay_hand_s,
                 "seconds of a record the replay's hand is simulated for, at most")
      ->check(CLI::Range(1.0, 3600.0))
      ->capture_default_str();
  app.add_option("--root", o.root, "the page's files")
      ->check(CLI::ExistingDirectory)
      ->capture_default_str();
  app.add_option("--hand-hz", o.hand_hz, "hand frames per second per browser, at most")
      ->check(CLI::Range(1.0, 60.0))
      ->capture_default_str();
  app.add_option("--band-min", o.band_min_n, "reference force band low end, N")
      ->check(CLI::NonNegativeNumber)
      ->capture_default_str();
  app.add_option("--band-max", o.band_max_n, "reference force band high end, N")
      ->check(CLI::PositiveNumber)
      ->capture_default_str();
  app.add_option("--max-clients", o.max_clients, "browsers served at once")
      ->check(CLI::Range(1, 256))
      ->capture_default_str();
  app.add_option("--max-message", o.max_message, "largest message a browser may send, bytes")
      ->check(CLI::Range(256, 65536))
      ->capture_default_str();
  app.add_option("--queue-bytes", o.queue_bytes,
                 "bytes of replies waiting for one browser before it is dropped as too slow")
      ->check(CLI::Range(std::size_t{1} << 16, std::size_t{1} << 30))
      ->capture_default_str();
  app.add_option("--ping-s", o.ping_s,
                 "seconds a browser may be silent before it is pinged; 6 pings unanswered "
                 "close it")
      ->check(CLI::Range(0.2, 600.0))
      ->capture_default_str();
  app.add_option("--seconds", o.seconds, "serve this long (0 = until Ctrl-C)")
      ->check(CLI::NonNegativeNumber)
      ->capture_default_str();
  bool insecure = false;
  app::addDdsOptions(app, o.dds, insecure, "supervisor");
  app.add_option("--log-level", log_level, "trace, debug, info, warn, error, off")
      ->capture_default_str();
  TELEHAND_CLI_PARSE(app, argc, argv);
  if (!bind.empty()) o.bind = bind;
  try {
    setupLogging("telehand-web", log_level);
    app::resolveDdsSecurity(o.dds, insecure, "supervisor", "telehand-web");
    // civetweb would take a bare port for every interface: the address is always said.
    if (o.bind.find(':') == std::string::npos || o.bind.front() == ':') {
      throw ConfigError("--bind '" + o.bind + "': give ADDRESS:PORT (e.g. 127.0.0.1:8080)");
    }
    if (!(o.band_min_n < o.band_max_n)) {
      throw ConfigError(fmt::format("--band-min ({:g} N) must be below --band-max ({:g} N)",
                                    o.band_min_n, o.band_max_n));
    }
    if (!std::filesystem::exists(std::filesystem::path(o.root) / "index.html")) {
      throw ConfigError("no index.html in '" + o.root + "' (--root)");
    }
    // The server may make the file later (a PostgreSQL store is reached when first asked).
    if (!o.db.empty() && !server::store::isPostgresUri(o.db) && !std::filesystem::exists(o.db)) {
      std::cerr << "telehand-web: no record store '" << o.db << "' yet (--db)\n";
    }
    installStopSignals();
    web::Gateway gateway(o);
    std::cout << "telehand-web: serving http://" << o.bind.substr(0, o.bind.rfind(':')) << ":"
              << gateway.port() << "/ (domain " << o.dds.domain << ", partition " << o.dds.partition
              << ")" << std::endl;
    return gateway.run(g_stop_requested);
  } catch (const telehand::Error& e) {
    std::cerr << "telehand-web: " << e.what() << "\n";
    return 2;
  } catch (const std::exception& e) {
    std::cerr << "telehand-web: unexpected error: " << e.what() << "\n";
    return 1;
  }
}
