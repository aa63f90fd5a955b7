// Running a batch plan (batch_plan.h) in this process: every run is rendered
// with renderJob, each scene loaded and its Embree scene built once and shared
// by the runs that use it, and one row per run appended to the results table
// as soon as the run ends.
//
// Outputs in the plan's output directory:
//   <run>.exr / <run>.png   the images (as `fluxgraph render` writes them)
//   results.csv             one row per run per invocation; header written once
//   results.jsonl           the same rows as JSON objects, with per-pass statistics nested
// Each row is appended with a single write() of a whole line, so a table cut
// short by Ctrl-C or a crash holds only whole rows.
//
// Resuming: a run whose EXR files exist and carry the same job text and
// overrides in their metadata is skipped (row status "skipped", with metrics
// against the reference recomputed from the existing image); `force` reruns.
#pragma once

#include "engine/run/batch_plan.h"

#include <atomic>
#include <cstddef>
#include <limits>
#include <optional>
#include <string>
#include <vector>

namespace fg {

struct BatchOptions {
    bool force = false;         // rerun runs whose images are up to date
    bool failFast = false;      // stop at the first failed run
    bool showProgress = false;  // one "runs done / total, elapsed, remaining" line on stderr
    std::optional<int> threads; // per run; default the job's own
    // This process renders only the runs i with i % workerCount == workerIndex
    // (--jobs N starts N such processes, which share the table files).
    int workerIndex = 0;
    int workerCount = 1;
    // Only runs [firstRun, firstRun + runCount) of the plan are this invocation's
    // (one array task of a cluster batch, batch_slurm.h); workers split that range.
    std::size_t firstRun = 0;
    std::size_t runCount = std::numeric_limits<std::size_t>::max();
    // Rows go to <tableBase>.csv and <tableBase>.jsonl; empty: the plan's
    // results.csv / results.jsonl. Cluster tasks write their own tables so that
    // tasks running at once on different machines never append to one file.
    std::string tableBase;
    bool writeHeader = true;    // false in workers: the parent wrote it
    std::string commandLine;    // for the EXR metadata
    std::string startedAt;      // the table's batch_started value; empty: now (UTC)
    // Set (e.g. from a SIGINT handler) to stop after the current run.
    const std::atomic<bool>* stopRequested = nullptr;
};

struct BatchSummary {
    int ok = 0;
    int failed = 0;
    int skipped = 0;
    bool interrupted = false;  // stopped by stopRequested or failFast before the end
};

inline constexpr const char* kBatchCsvName = "results.csv";
inline constexpr const char* kBatchJsonlName = "results.jsonl";

// Now as "2024-05-01T12:00:00Z", the batch_started value of a table row.
std::string batchTimestamp();

// The CSV columns, in order (per-pass details are only in the JSON lines).
const std::vector<std::string>& batchCsvColumns();
// <output>/results, or options.tableBase when set (without .csv / .jsonl).
std::string batchTableBase(const BatchPlan& plan, const BatchOptions& options);
// Creates the output directory (and the table's) and writes the CSV header if
// the table is new or empty.
void prepareBatchOutput(const BatchPlan& plan, const std::string& tableBase = {});

// Validates the whole plan first (throws InputError naming the plan line), then
// renders. A failed run (any exception) is recorded with its one-line error.
BatchSummary runBatch(const BatchPlan& plan, const BatchOptions& options);

}  // namespace fg
