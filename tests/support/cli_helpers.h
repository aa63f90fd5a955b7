// Helpers for tests that run the fluxgraph binary: a scratch directory per
// test, the command run there with its output captured, and the source tree.
#pragma once

#include <filesystem>
#include <string>
#include <vector>

namespace fg::test {

struct CommandResult {
    int exitCode = -1;  // 128 + signal number when a signal ended it
    std::string out;
    std::string err;
};

std::string readText(const std::filesystem::path& path);
// Writes `text` to `path`, making its directory if needed (a failed write fails
// the calling test).
void writeText(const std::filesystem::path& path, const std::string& text);
// A fresh, empty directory FLUXGRAPH_TEST_TMP/<group>/<test name> (ctest runs
// tests as separate processes, in parallel).
std::filesystem::path scratchDirectory(const std::string& group);
// Runs the binary with `dir` as working directory, so that anything written to
// a relative path lands in the scratch directory; stdout and stderr are
// captured in dir/logs, away from the output directories the tests inspect.
CommandResult runFluxgraph(const std::filesystem::path& dir, const std::vector<std::string>& args);
// A path in the source tree.
std::string sourcePath(const std::string& relative);

}  // namespace fg::test
