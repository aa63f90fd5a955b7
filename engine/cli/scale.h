// `fluxgraph scale JOB --threads 1,2,4`: thread scaling of a job's passes.
#pragma once

#include <string>
#include <vector>

namespace CLI {
class App;
}

namespace fg::cli {

struct ScaleOptions {
    std::string jobPath;
    std::vector<std::string> sets;     // --set, as for render
    std::vector<std::string> defines;  // --define, as for render
    std::string threads;               // comma-separated; empty = powers of two up to the hardware threads
    int repeat = 3;
    std::string outDir;    // images of the runs; empty = the job's output directory
    std::string csvPath;   // empty = scale.csv in the output directory
    std::string plotPath;  // empty = no plot
    bool quiet = false;
};

// Registers the subcommand on `app`; the parsed values land in `options`.
CLI::App* addScaleSubcommand(CLI::App& app, ScaleOptions& options);
// Prints the scaling table and returns the exit code: 0; 2 (one line on
// stderr) for bad input; 3 when the images differ between runs (a defect of
// the engine's determinism, reported after the table).
int runScale(const ScaleOptions& options);

}  // namespace fg::cli
