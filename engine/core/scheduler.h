// The pass scheduler: validates a pipeline against the pass registry and the
// job's parameters before any work is done, culls passes whose outputs nobody
// needs, runs the rest as one task graph (independent passes concurrently),
// frees every buffer after its last reader and times every pass. A buffer
// whose producer can emit it in batches and whose readers can all consume
// batches is streamed: the readers run inside the producer's task and see
// each batch as it is made, so the buffer is never held whole.
#pragma once

#include "engine/core/pass.h"

#include <map>
#include <string>
#include <vector>

namespace fg {

// A parameter value as written in a job file (or on the command line).
struct ParamSetting {
    ParamValue value;
    std::string source;  // "file:line" or "--set ..."
};
// instance -> parameter -> setting, plus where each [passes.<instance>] table was written.
struct JobParams {
    std::map<std::string, std::map<std::string, ParamSetting>> values;
    std::map<std::string, std::string> tableSource;
};

struct PlannedPass {
    PipelineNode node;
    const PassRegistration* registration = nullptr;
    PassParams params;
    std::vector<int> dependencies;  // indices of producer passes
    bool culled = false;
    // Output slots handed to their readers batch by batch instead of stored.
    std::vector<std::string> streamedOutputs;
    // A reader of streamed buffers runs inside the task of their producer (this
    // index): it consumes each batch as it is emitted, then runs; -1 otherwise.
    int streamHost = -1;
};

class ExecutionPlan {
public:
    // Throws InputError (naming `origin`, the job file, where no better line is known).
    // `registry` defaults to the built-in table; tests pass their own passes.
    static ExecutionPlan build(const Pipeline& pipeline, const JobParams& params, const std::string& origin,
                               const std::vector<PassRegistration>& registry = passRegistry());

    const Pipeline& pipeline() const { return pipeline_; }
    const std::vector<PlannedPass>& passes() const { return passes_; }
    std::vector<int> topologicalOrder() const { return order_; }
    // Whether `buffer` is handed over batch by batch (never stored whole).
    bool streamed(const std::string& buffer) const;
    std::string toDot() const;

private:
    void chooseStreams();
    bool fusedTasksAcyclic() const;
    Pipeline pipeline_;
    std::vector<PlannedPass> passes_;
    std::vector<int> order_;
    std::map<std::string, int> producer_;  // buffer -> pass index
};

struct PassStats {
    std::string instance;
    std::string pass;
    double startSeconds = 0.0;  // since the run began
    double wallSeconds = 0.0;
    double cpuSeconds = 0.0;    // summed over all threads that worked for the pass
    std::int64_t items = 0;
    std::size_t outputBytes = 0;  // of streamed outputs: the largest batch
    std::int64_t batchesEmitted = 0;
    std::map<std::string, std::int64_t> counters;
};

struct RunOptions {
    std::uint64_t seed = 1;
    FilmSettings film;
    std::function<void(const std::string&, double)> progress;  // instance, fraction
};

struct RunResult {
    std::map<std::string, BufferHandle> results;  // the pipeline's result buffers
    std::vector<PassStats> stats;                 // in topological order
    double wallSeconds = 0.0;
};

RunResult execute(const ExecutionPlan& plan, const Scene& scene, const RayQuery& rays, const RunOptions& options);
// As above; `rays` may be null when no pass of the plan traces rays.
RunResult execute(const ExecutionPlan& plan, const Scene& scene, const RayQuery* rays, const RunOptions& options);

}  // namespace fg
