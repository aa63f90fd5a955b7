// `fluxgraph batch PLAN.toml`: renders every run of a batch plan
// (engine/run/batch_plan.h), resumably, into one results table.
#pragma once

#include <string>

namespace CLI {
class App;
}

namespace fg::cli {

struct BatchCliOptions {
    std::string planPath;
    bool force = false;
    bool failFast = false;
    int jobs = 1;
    int threads = -1;       // -1: the jobs' own (or hardware / jobs with --jobs > 1)
    std::string worker;     // "K/N": render only runs i with i % N == K (set by --jobs for its processes)
    std::string startedAt;  // batch_started of the parent, for its worker processes
    std::string commandLine;
};

CLI::App* addBatchSubcommand(CLI::App& app, BatchCliOptions& options);
// Exit code: 0 every run ok or skipped, 1 some run failed, 2 malformed plan
// (one line naming plan-file:line), 130 interrupted by SIGINT.
int runBatch(const BatchCliOptions& options);

}  // namespace fg::cli
