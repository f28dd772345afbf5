#pragma once
// The results as text on stdout and as JSON.
#include <cstddef>
#include <cstdint>
#include <ostream>

#include "ddsperf.h"
#include "echo.h"

namespace telehand::latency {

/// Serialized payload size of a DeviceState as Cyclone writes it (without the 4-byte
/// encapsulation header), to show that "DeviceState-sized" means the same on the wire.
uint32_t serializedSize(const Sample& s, uint32_t* xcdr_version);

void printPing(const Settings& s, const PingResult& r, std::size_t size_of, uint32_t ser,
               uint32_t xcdr);
void printCompare(const Settings& s, const PingResult& r, const DdsperfResult& d,
                  const std::string& path, uint32_t size);
/// `d`: the ddsperf comparison, if it ran.
void writeJson(std::ostream& o, const Settings& s, const PingResult& r, std::size_t size_of,
               uint32_t ser, const DdsperfResult* d, uint32_t ddsperf_size);

}  // namespace telehand::latency
