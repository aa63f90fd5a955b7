// Batches on a SLURM cluster. A plan's runs are split, in plan order, into
// array tasks of K runs each (task I renders runs [I*K, I*K+K)); an sbatch
// script starts one array task per chunk, each running
// `fluxgraph batch PLAN --task I --runs-per-task K`. Tasks may run at once on
// different machines sharing the output directory, so each appends its rows
// to its own table, <output>/tasks/task-I.csv / .jsonl; collecting merges them
// into the one results.csv / results.jsonl a local batch writes.
#pragma once

#include "engine/run/batch_plan.h"

#include <cstddef>
#include <string>
#include <vector>

namespace fg {

inline constexpr const char* kBatchTaskDirectory = "tasks";
inline constexpr const char* kBatchScriptName = "batch.sbatch";

// Tasks of up to `runsPerTask` runs that cover `runCount` runs.
std::size_t batchTaskCount(std::size_t runCount, std::size_t runsPerTask);
// <output>/tasks/task-I, the table of task I without .csv / .jsonl.
std::string batchTaskTableBase(const BatchPlan& plan, std::size_t task);

struct SlurmScriptOptions {
    std::string binary;            // absolute path of the fluxgraph binary the tasks run
    std::string planPath;          // absolute
    std::string workingDirectory;  // absolute; the plan's output directory is relative to it
    std::size_t runsPerTask = 1;
    std::string partition;         // empty: the cluster's default partition
    std::string timeLimit;         // per task, as sbatch --time takes it; empty: the partition's
    std::vector<std::string> taskArguments;  // more arguments for every task (--force, --threads N)
};

// The text of an sbatch script for the plan's job array.
std::string slurmArrayScript(const BatchPlan& plan, const SlurmScriptOptions& options);
// Writes the script to <output>/batch.sbatch and creates <output>/tasks (the
// tasks' logs go there, and SLURM does not create directories); returns the
// script's absolute path.
std::string writeSlurmArrayScript(const BatchPlan& plan, const SlurmScriptOptions& options);

struct BatchCollection {
    std::size_t runs = 0;      // in the plan
    std::size_t finished = 0;  // whose latest row says ok or skipped
    std::size_t failed = 0;    // whose latest row says failed
    std::vector<std::string> missing;  // runs not finished (no row yet, or failed), in plan order
};

// Replaces <output>/results.csv and results.jsonl with the rows of every task
// table: one header, one row per run in plan order, the latest when a run has
// several (a rerun task, or a plan resubmitted with another --runs-per-task).
// Rows of runs the plan no longer has are left out.
BatchCollection collectBatchTasks(const BatchPlan& plan);

}  // namespace fg
