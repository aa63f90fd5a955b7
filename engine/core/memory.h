// Memory checked before work: what a job's passes will allocate, estimated
// from their parameters during preflight, against what the process may use.
#pragma once

#include "engine/image/film.h"

#include <cstdint>
#include <optional>
#include <string>
#include <string_view>

namespace fg {

// What one pass expects to allocate (PassRegistration::memory).
struct MemoryEstimate {
    std::uint64_t bytes = 0;
    std::string what;  // the buffers counted, e.g. "film 16384 x 16384"
    std::string hint;  // how to need less, when there is a better way than smaller numbers
};

// Bytes of a Film's sums for `film` with `aovChannels` float AOVs.
std::uint64_t filmBytes(const FilmSettings& film, int aovChannels = 0);
// a + b, saturating (estimates of absurd jobs must not wrap around).
std::uint64_t addBytes(std::uint64_t a, std::uint64_t b);
// count * bytesEach, saturating.
std::uint64_t multiplyBytes(std::uint64_t count, std::uint64_t bytesEach);
// "6.0 GiB"
std::string describeBytes(std::uint64_t bytes);

struct AvailableMemory {
    std::uint64_t bytes = 0;
    std::string limitedBy;  // "MemAvailable", "RLIMIT_AS", "RLIMIT_DATA" or "cgroup memory.max"
};
// What this process may still allocate: MemAvailable of /proc/meminfo, lowered
// by RLIMIT_AS and RLIMIT_DATA (less what the process already maps) and by the
// cgroup's memory.max (less its memory.current). Empty when nothing is known.
std::optional<AvailableMemory> availableMemory();

// The value of a "Key:  123 kB" line of /proc/meminfo or /proc/self/status, in bytes.
std::optional<std::uint64_t> procKilobytes(std::string_view text, std::string_view key);

}  // namespace fg
