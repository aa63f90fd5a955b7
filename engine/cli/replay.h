// `fluxgraph replay JOB --pass NAME`: one pass instance of a job run several
// times on the same inputs, timed, with its outputs checked for determinism.
#pragma once

#include <string>
#include <vector>

namespace CLI {
class App;
}

namespace fg::cli {

struct ReplayCommandOptions {
    std::string jobPath;
    std::string instance;
    int repeat = 5;
    std::string inputsDirectory;
    std::string saveInputsDirectory;
    std::string profilePath;
    int threads = -1;  // -1: the job's
    std::vector<std::string> sets;
    std::vector<std::string> defines;
    std::vector<std::string> imports;
};

// Registers the subcommand on `app`; the parsed values land in `options`.
CLI::App* addReplaySubcommand(CLI::App& app, ReplayCommandOptions& options);
// Prints the replay report and returns the exit code: 0; 2 (one line on
// stderr) for bad input; 3 when the repetitions' outputs differ.
int runReplay(const ReplayCommandOptions& options);

}  // namespace fg::cli
