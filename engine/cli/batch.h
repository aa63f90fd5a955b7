// `fluxgraph batch PLAN.toml`: renders every run of a batch plan
// (engine/run/batch_plan.h), resumably, into one results table, here or as a
// SLURM job array (--slurm writes its script, --task runs one array task,
// --collect merges the tasks' tables; engine/run/batch_slurm.h).
#pragma once

#include <climits>
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
    // Cluster batches.
    bool slurm = false;      // write the sbatch script of a job array
    bool submit = false;     // and submit it with sbatch
    bool collect = false;    // merge the tasks' tables into results.csv / .jsonl
    int task = kNoTask;      // render only this array task's runs
    int runsPerTask = 1;
    std::string partition;
    std::string timeLimit;
    static constexpr int kNoTask = INT_MIN;
};

CLI::App* addBatchSubcommand(CLI::App& app, BatchCliOptions& options);
// Exit code: 0 every run ok or skipped, 1 some run failed (--collect: some run
// missing; --submit: sbatch failed), 2 malformed plan (one line naming
// plan-file:line) or options, 130 interrupted by SIGINT.
int runBatch(const BatchCliOptions& options);

}  // namespace fg::cli
