// Fixtures shared by the batch tests (in-process and through the binary):
// small job trees to glob over, and the settings that keep every run tiny.
#pragma once

#include "tests/support/cli_helpers.h"

#include <filesystem>
#include <string>
#include <vector>

namespace fg::test {

// The lines of a text file (a results table), without their newlines.
inline std::vector<std::string> fileLines(const std::filesystem::path& path) {
    std::vector<std::string> out;
    const std::string text = readText(path);
    std::size_t start = 0;
    while (start < text.size()) {
        const std::size_t end = text.find('\n', start);
        out.push_back(text.substr(start, end == std::string::npos ? std::string::npos : end - start));
        if (end == std::string::npos) break;
        start = end + 1;
    }
    return out;
}

// Two path-tracing jobs under jobs/*/pt.toml and one that cannot load its scene.
inline void writeBatchJobs(const std::filesystem::path& dir) {
    const std::string job = "scene = \"" + sourcePath("data/cornell-box/cornell-box.toml") + "\"\npipeline = \"pt\"\n";
    writeText(dir / "jobs/a/pt.toml", job);
    writeText(dir / "jobs/b/pt.toml", job);
    writeText(dir / "broken/pt.toml", "scene = \"no-such-scene.toml\"\npipeline = \"pt\"\n");
}

// A plan-level `set` that makes every run tiny: 16x16 pixels, 1 sample per pixel.
inline constexpr const char* kTinyBatchSet =
    "set = { \"film.width\" = 16, \"film.height\" = 16, \"passes.pt.spp\" = 1, \"passes.pt.max_depth\" = 3 }\n";

}  // namespace fg::test
