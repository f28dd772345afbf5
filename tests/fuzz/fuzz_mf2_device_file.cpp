// libFuzzer target: MF-2 device file text into parseMf2Description (thimble calibration
// files resolved against deploy/devices, as for deploy/devices/mf2.toml), and thimble
// calibration text into parseThimbleCalibration; the first byte picks which.
// Properties: a refusal is a ConfigError naming the file; nothing else escapes.
// A device file names other files to read: inputs that could name one outside
// deploy/devices (an absolute path, "..", a \u escape) are skipped, so that the fuzzer
// never opens a device node or a FIFO.
#include <string>
#include <string_view>

#include "telehand/devices/mf2_device.h"
#include "toml_input.h"

using namespace telehand;

#ifndef TELEHAND_FUZZ_DEVICES_DIR
#error "TELEHAND_FUZZ_DEVICES_DIR: the directory of deploy/devices/mf2.toml"
#endif

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, std::size_t size) {
  if (size < 1) return 0;
  const bool thimble = (data[0] & 1u) != 0;
  ++data;
  --size;
  if (thimble) {
    fuzz::parsesOrRefuses(data, size, "thimble.toml",
                          [](const std::string& t, const std::string& o) {
                            (void)mf2::parseThimbleCalibration(t, o);
                          });
    return 0;
  }
  const std::string_view text(reinterpret_cast<const char*>(data), size);
  for (std::string_view risky : {"\"/", "'/", "..", "\\u", "\\U"}) {
    if (text.find(risky) != std::string_view::npos) return 0;
  }
  fuzz::parsesOrRefuses(
      data, size, "mf2.toml",
      [](const std::string& t, const std::string& o) {
        (void)mf2::parseMf2Description(t, o, TELEHAND_FUZZ_DEVICES_DIR);
      },
      /*names_origin=*/false);
  return 0;
}
