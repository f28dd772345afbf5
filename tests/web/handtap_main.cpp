// telehand-test-handtap: prints every HandState it takes, one line each, for the browser
// test to compare the page against: "hand SESSION SEQ ALPHA_RAD INDEX_MCP_FLEXION_JOINT_RAD".
#include <cstdio>

#include "telehand/app/dds_cli.h"
#include "telehand/app/signals.h"
#include "telehand/protocol/dds.h"

int main(int argc, char** argv) {
  using namespace telehand;
  CLI::App app{"telehand-test-handtap: HandState lines for the web console's browser test"};
  dds::Options o;
  bool insecure = false;
  double seconds = 60.0;
  app::addDdsOptions(app, o, insecure, "supervisor");
  app.add_option("--seconds", seconds, "run this long");
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return app.exit(e) == 0 ? 0 : 2;
  }
  app::resolveDdsSecurity(o, insecure, "supervisor", "telehand-test-handtap");
  installStopSignals();
  dds::Participant p(o);
  dds::Topics t(p);
  dds::Reader<telehand_msg_HandState> r(p, t.hand_state, dds::qos::handStateReader(64));
  dds::WaitSet ws(p);
  ws.attach(r.handle(), 1);
  const auto end = std::chrono::steady_clock::now() + std::chrono::duration<double>(seconds);
  while (!g_stop_requested.load() && std::chrono::steady_clock::now() < end) {
    ws.wait(std::chrono::milliseconds(100));
    r.take([](const telehand_msg_HandState& h, const dds_sample_info_t&) {
      std::printf("hand %llu %llu %.9g %.9g\n", static_cast<unsigned long long>(h.session_id),
                  static_cast<unsigned long long>(h.seq), h.mcp_angles_rad[0],
                  h.dof_count > 1 ? h.joint_angles_rad[1] : h.mcp_angles_rad[0]);
    });
    std::fflush(stdout);
  }
  return 0;
}
