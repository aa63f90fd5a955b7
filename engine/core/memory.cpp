#include "engine/core/memory.h"

#include <sys/resource.h>

#include <cstdio>
#include <fstream>
#include <iomanip>
#include <limits>
#include <sstream>

namespace fg {

namespace {

constexpr std::uint64_t kMaxBytes = std::numeric_limits<std::uint64_t>::max();

std::string readSmallFile(const std::string& path) {
    std::ifstream in(path);
    std::ostringstream text;
    text << in.rdbuf();
    return text.str();
}

// The process's cgroup (v2) directory, from the "0::/path" line of /proc/self/cgroup.
std::string cgroupDirectory() {
    std::istringstream lines(readSmallFile("/proc/self/cgroup"));
    for (std::string line; std::getline(lines, line);)
        if (line.rfind("0::", 0) == 0) return "/sys/fs/cgroup" + line.substr(3);
    return {};
}

std::optional<std::uint64_t> readNumber(const std::string& path) {
    std::ifstream in(path);
    std::uint64_t value = 0;
    if (in >> value) return value;
    return std::nullopt;  // missing, or "max"
}

}  // namespace

std::uint64_t addBytes(std::uint64_t a, std::uint64_t b) { return a > kMaxBytes - b ? kMaxBytes : a + b; }

std::uint64_t multiplyBytes(std::uint64_t count, std::uint64_t bytesEach) {
    if (bytesEach != 0 && count > kMaxBytes / bytesEach) return kMaxBytes;
    return count * bytesEach;
}

std::uint64_t filmBytes(const FilmSettings& film, int aovChannels) {
    const std::uint64_t pixels = static_cast<std::uint64_t>(film.width) * static_cast<std::uint64_t>(film.height);
    return multiplyBytes(pixels, sizeof(Rgb) + sizeof(float) + static_cast<std::uint64_t>(aovChannels) * sizeof(float));
}

std::string describeBytes(std::uint64_t bytes) {
    static constexpr const char* kUnits[] = {"B", "KiB", "MiB", "GiB", "TiB", "PiB", "EiB"};
    double value = static_cast<double>(bytes);
    std::size_t unit = 0;
    while (value >= 1024.0 && unit + 1 < std::size(kUnits)) {
        value /= 1024.0;
        ++unit;
    }
    std::ostringstream out;
    out << std::fixed << std::setprecision(unit == 0 ? 0 : 1) << value << " " << kUnits[unit];
    return out.str();
}

std::optional<std::uint64_t> procKilobytes(std::string_view text, std::string_view key) {
    std::size_t at = 0;
    while (at < text.size()) {
        const std::size_t end = std::min(text.find('\n', at), text.size());
        const std::string_view line = text.substr(at, end - at);
        at = end + 1;
        if (line.size() <= key.size() || line.substr(0, key.size()) != key || line[key.size()] != ':') continue;
        unsigned long long kilobytes = 0;
        if (std::sscanf(std::string(line.substr(key.size() + 1)).c_str(), "%llu", &kilobytes) != 1) return std::nullopt;
        return multiplyBytes(kilobytes, 1024);
    }
    return std::nullopt;
}

std::optional<AvailableMemory> availableMemory() {
    std::optional<AvailableMemory> best;
    const auto consider = [&](std::uint64_t bytes, const char* source) {
        if (!best || bytes < best->bytes) best = AvailableMemory{bytes, source};
    };
    if (const auto available = procKilobytes(readSmallFile("/proc/meminfo"), "MemAvailable"))
        consider(*available, "MemAvailable");
    const std::string status = readSmallFile("/proc/self/status");
    const auto limitLess = [&](int resource, const char* statusKey, const char* name) {
        rlimit limit{};
        if (::getrlimit(resource, &limit) != 0 || limit.rlim_cur == RLIM_INFINITY) return;
        const std::uint64_t used = procKilobytes(status, statusKey).value_or(0);
        const auto cap = static_cast<std::uint64_t>(limit.rlim_cur);
        consider(cap > used ? cap - used : 0, name);
    };
    limitLess(RLIMIT_AS, "VmSize", "RLIMIT_AS");
    limitLess(RLIMIT_DATA, "VmData", "RLIMIT_DATA");
    if (const std::string cgroup = cgroupDirectory(); !cgroup.empty()) {
        if (const auto max = readNumber(cgroup + "/memory.max")) {
            const std::uint64_t current = readNumber(cgroup + "/memory.current").value_or(0);
            consider(*max > current ? *max - current : 0, "cgroup memory.max");
        }
    }
    return best;
}

}  // namespace fg
