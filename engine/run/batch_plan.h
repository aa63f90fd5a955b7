// Batch plans: many renders described in one TOML file, for parameter sweeps
// and test matrices (`fluxgraph batch PLAN.toml`). A plan is
//
//   output = "results/caustics"        # images and results.csv/.jsonl; relative to the working directory
//   jobs = ["data/*/pt.toml"]          # job files, globs allowed; relative to the plan file's directory
//   set = { "film.width" = 16 }        # optional: --set values applied to every run
//   [[sweep]]
//   job = "data/water-wave-sine/caustic-spm.toml"   # a job file or a glob
//   reference = "data/water-wave-sine/reference/caustic-reference.exr"  # optional: metrics against it
//   set = { "passes.gather.k_caustic" = [10, 20], "seed" = [1, 2] }     # the cartesian product (keys in alphabetical order)
//
// Every run is a job file plus --set overrides. Its output stem is derived
// from the job's path (relative to the plan, extension dropped, '/' -> '-')
// and its sweep values, e.g. "caustic-spm--gather.k_caustic=10--seed=2",
// so that rerunning the plan finds the images of earlier runs.
#pragma once

#include "engine/core/job.h"

#include <map>
#include <optional>
#include <string>
#include <vector>

namespace fg {

struct BatchRun {
    std::string jobPath;                // as the plan resolves it (plan directory + entry)
    std::vector<std::string> sets;      // "key=value", plan-level ones first
    std::string name;                   // output stem, unique in the plan
    std::string referencePath;          // empty: no reference, no metrics
    std::string origin;                 // "plan.toml:7": the entry the run comes from
    std::map<std::string, std::string> setOrigins;  // key -> "plan.toml:9", where its value was written
};

struct BatchPlan {
    std::string path;
    std::string outputDirectory;
    std::vector<BatchRun> runs;  // in plan order: jobs first, then each sweep's product
};

// Throws InputError naming plan-file:line: unknown keys, wrong types, a glob
// that matches nothing, an empty product, two runs with the same output stem.
BatchPlan parseBatchPlan(const std::string& text, const std::string& path);
BatchPlan loadBatchPlan(const std::string& path);

// The job of one run, its outputs redirected to the plan's output directory
// under the run's name (EXR always on: resuming and metrics read it).
// `threads` overrides the job's thread count when given.
// Errors name the plan line of the run (and of the offending --set value).
Job loadBatchJob(const BatchPlan& plan, const BatchRun& run, std::optional<int> threads = std::nullopt);

// Loads every run's job and builds its execution plan (unknown parameters,
// bad values, pipeline errors) and checks its imported buffer files as
// validate does, before anything is rendered. Throws the first problem as an
// InputError naming the plan line.
std::vector<Job> validateBatchPlan(const BatchPlan& plan, std::optional<int> threads = std::nullopt);

}  // namespace fg
