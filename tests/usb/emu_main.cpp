// telehand-mf2-emu: runs a command against an emulated MF-2 (no hardware). The emulated USB
// bus is visible to the command and its children. Run under umockdev-wrapper:
//   umockdev-wrapper build/release/tests/usb/telehand-mf2-emu build/release/client/telehand-probe
//   --live 3
#include <sys/prctl.h>

#include <algorithm>
#include <cstdio>
#include <optional>
#include <string>
#include <vector>

#include "mf2_emulator.h"
#include "telehand/app/cli.h"
#include "telehand/app/process.h"

int main(int argc, char** argv) {
  using namespace telehand;
  CLI::App app{
      "telehand-mf2-emu: run a command against an emulated MF-2 (run this under "
      "umockdev-wrapper)"};
  int64_t pace_us = 1000;
  double push_nm = 0.05, push_hz = 1.0;
  std::string fsr_text;
  std::vector<double> fsr;
  std::vector<std::string> command;
  app.add_option("--pace-us", pace_us, "state packet period, us (0: as fast as asked)")
      ->capture_default_str();
  app.add_option("--push", push_nm, "operator torque on the thumb's first crank, N m amplitude")
      ->capture_default_str();
  app.add_option("--push-hz", push_hz, "operator push frequency")->capture_default_str();
  app.add_option("--fsr", fsr_text, "the 8 FSR forces, N, comma-separated (thumb 1-4, index 1-4)");
  app.prefix_command();  // everything from the first non-option on is the command
  app.footer("Usage: telehand-mf2-emu [OPTIONS] COMMAND [ARGS...]");
  TELEHAND_CLI_PARSE(app, argc, argv)
  for (std::size_t pos = 0; !fsr_text.empty() && pos <= fsr_text.size();) {
    const std::size_t comma = std::min(fsr_text.find(',', pos), fsr_text.size());
    try {
      fsr.push_back(std::stod(fsr_text.substr(pos, comma - pos)));
    } catch (const std::exception&) {
      std::fprintf(stderr, "telehand-mf2-emu: --fsr: '%s' is not a list of numbers\n",
                   fsr_text.c_str());
      return 2;
    }
    pos = comma + 1;
  }
  if (!fsr.empty() && fsr.size() != 8) {
    std::fprintf(stderr, "telehand-mf2-emu: --fsr needs 8 values, got %zu\n", fsr.size());
    return 2;
  }
  command = app.remaining();
  if (!command.empty() && command.front() == "--") command.erase(command.begin());
  if (command.empty()) {
    std::fprintf(stderr, "telehand-mf2-emu: no command to run (see --help)\n");
    return 2;
  }

  prctl(PR_SET_TIMERSLACK, 1UL, 0UL, 0UL, 0UL);
  try {
    test::usb::EmulatorOptions opt;
    opt.pace_ns = pace_us * 1000;
    opt.firmware.operator_actuator = 2;
    opt.firmware.operator_amplitude_nm = push_nm;
    opt.firmware.operator_hz = push_hz;
    test::usb::Mf2Emulator emu(opt);
    emu.withFirmware([&](test::usb::Mf2Firmware& fw) {
      fw.keepHistory(false);
      if (fsr.size() == 8) {
        std::array<double, 8> f{};
        std::copy(fsr.begin(), fsr.end(), f.begin());
        fw.setFsrForces(f);
      }
      return 0;
    });
    std::optional<app::Process> child;
    try {
      child.emplace(app::ProcessOptions{.argv = command, .search_path = true});
    } catch (const std::exception&) {
      std::fprintf(stderr, "telehand-mf2-emu: cannot run %s\n", command.front().c_str());
      return 2;
    }
    const int exit_code = child->wait();
    const auto c = emu.counters();
    std::fprintf(stderr,
                 "telehand-mf2-emu: %llu state packets, %llu commands, %llu unhandled ioctls\n",
                 static_cast<unsigned long long>(c.states_sent),
                 static_cast<unsigned long long>(c.commands_received),
                 static_cast<unsigned long long>(c.unhandled_ioctls));
    return exit_code;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "telehand-mf2-emu: %s\n", e.what());
    return 2;
  }
}
