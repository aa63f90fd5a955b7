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
// A fresh, empty directory FLUXGRAPH_TEST_TMP/<group>/<suite>.<test name> (ctest
// runs tests as separate processes, in parallel).
std::filesystem::path scratchDirectory(const std::string& group);
// Runs the binary with `dir` as working directory, so that anything written to
// a relative path lands in the scratch directory; stdout and stderr are
// captured in dir/logs, away from the output directories the tests inspect.
CommandResult runFluxgraph(const std::filesystem::path& dir, const std::vector<std::string>& args);
// A fluxgraph process running in the background, to send signals to.
struct RunningFluxgraph {
    int pid = -1;
    std::filesystem::path dir;
};
struct StartOptions {
    std::vector<std::pair<std::string, std::string>> environment;  // added to the test's own
    long long addressSpaceLimit = 0;  // > 0: RLIMIT_AS of the child, in bytes
};
// Starts the binary as runFluxgraph would (working directory `dir`, output in
// dir/logs) without waiting for it.
RunningFluxgraph startFluxgraph(const std::filesystem::path& dir, const std::vector<std::string>& args,
                                const StartOptions& options = {});
// Waits (polling, at most `seconds`) until the process's stderr holds `text`;
// false if it did not, or the process ended first.
bool waitForStderr(const RunningFluxgraph& process, const std::string& text, double seconds = 60.0);
// Waits for the process to end and collects its exit code and output.
CommandResult finishFluxgraph(const RunningFluxgraph& process);
// runFluxgraph with StartOptions.
CommandResult runFluxgraphWith(const std::filesystem::path& dir, const std::vector<std::string>& args,
                               const StartOptions& options);
// A path in the source tree.
std::string sourcePath(const std::string& relative);

}  // namespace fg::test
