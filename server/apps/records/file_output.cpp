#include "file_output.h"

#include <cerrno>
#include <cstring>
#include <fstream>
#include <string>
#include <system_error>

#include "telehand/core/error.h"

namespace telehand::records {

void writeFileAtomically(const std::filesystem::path& path, std::string_view text) {
  namespace fs = std::filesystem;
  std::error_code ec;
  if (path.has_parent_path()) {
    fs::create_directories(path.parent_path(), ec);
    if (ec) {
      throw Error("cannot write '" + path.string() +
                  "': cannot make its directory: " + ec.message());
    }
  }
  const fs::path tmp = path.string() + ".partial";
  const auto failed = [&](const std::string& why) {
    std::error_code ignored;
    fs::remove(tmp, ignored);
    return Error("cannot write '" + path.string() + "': " + why + "; nothing was written");
  };
  {
    std::ofstream f(tmp, std::ios::binary | std::ios::trunc);
    if (!f)
      throw failed(std::string("cannot open '") + tmp.string() + "': " + std::strerror(errno));
    f.write(text.data(), static_cast<std::streamsize>(text.size()));
    f.flush();
    if (!f)
      throw failed(std::string("writing '") + tmp.string() + "' failed: " + std::strerror(errno));
    f.close();
    if (f.fail()) throw failed("closing '" + tmp.string() + "' failed");
  }
  fs::rename(tmp, path, ec);
  if (ec) throw failed("cannot rename '" + tmp.string() + "' to it: " + ec.message());
}

}  // namespace telehand::records
