#pragma once
/// Files telehand-records writes (reports, score tables, fitted patient cases): whole or not at
/// all.
#include <filesystem>
#include <string_view>

namespace telehand::records {

/// Writes `text` to `path`: to PATH.partial first, flushed and closed (each checked), then
/// renamed over `path`, so that a reader never sees half a file and an earlier file of that
/// name stays whole until the new one is. Creates the directory when missing. On any failure
/// nothing is left at PATH.partial and telehand::Error names the file and the reason.
void writeFileAtomically(const std::filesystem::path& path, std::string_view text);

}  // namespace telehand::records
