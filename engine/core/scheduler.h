// The pass scheduler: unrolls a pipeline's repeat blocks, validates it against
// the pass registry and the job's parameters before any work is done, culls
// passes whose outputs nobody needs, runs the rest as one task graph
// (independent passes concurrently), frees every buffer after its last reader
// and times every pass instance. A buffer whose producer can emit it in
// batches and whose readers can all consume batches is streamed: the readers
// run inside the producer's task and see each batch as it is made, so the
// buffer is never held whole.
//
// Buffers are versioned (as FrameGraph's writes are): every write makes a new
// version with exactly one producer. Outside repeat blocks a version is named
// after its buffer ("image"), a later in-place write adds "@2", "@3"; inside
// iteration i of block B a version is "B[i].name". A reader binds to the
// version current at its place in the pipeline's declaration order. An in-out
// slot's write shares the old version's storage, so the writer waits for every
// reader of the old version declared before it.
#pragma once

#include "engine/core/pass.h"
#include "jobs/work_context.h"

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
    PipelineNode node;  // instance: the unrolled name; bindings: buffer versions for every slot ("" = absent)
    const PassRegistration* registration = nullptr;
    std::string paramsKey;  // the instance name as written: [passes.<paramsKey>] sets its parameters
    std::string source;     // "file:line" of its definition, for messages
    int block = -1;         // index into ExecutionPlan::blocks(), -1 outside blocks
    int iteration = -1;
    // When its iteration is skipped (early exit), each output slot takes this
    // version: the one its buffer had after the previous iteration.
    std::map<std::string, std::string> skipAliases;
    PassParams params;
    std::vector<int> dependencies;  // indices of producer passes
    bool culled = false;
    // Output slots handed to their readers batch by batch instead of stored.
    std::vector<std::string> streamedOutputs;
    // A reader of streamed buffers runs inside the task of their producer (this
    // index): it consumes each batch as it is emitted, then runs; -1 otherwise.
    int streamHost = -1;
};

// Buffers read from files instead of being produced, and buffers written to
// files when their producer finishes; by buffer name (its final version).
struct BufferFiles {
    std::map<std::string, std::string> imports;  // name -> path
    std::map<std::string, std::string> saves;    // name -> path
    std::map<std::string, std::string> sources;  // name -> where it was asked for ("job.toml:7", "--save ...")
};

struct PlannedBlock {
    std::string name;
    int count = 1;
    std::string untilInstance, untilSignal;  // empty: no condition
    double seconds = 0.0;
    std::vector<std::vector<int>> iterationPasses;  // pass indices of each iteration
    // Every block may end before its count: besides `until` and `seconds`, an
    // interrupt (engine/core/interrupt.h) ends it after the running iteration.
    // So iteration i + 1 always waits for all of iteration i.
    bool canExitEarly() const { return true; }
};

class ExecutionPlan {
public:
    // Throws InputError (naming `origin`, the job file, where no better line is known).
    // `registry` defaults to the installed one; tests pass their own passes.
    static ExecutionPlan build(const Pipeline& pipeline, const JobParams& params, const std::string& origin);
    static ExecutionPlan build(const Pipeline& pipeline, const JobParams& params, const std::string& origin,
                               const std::vector<PassRegistration>& registry, const BufferFiles& files = {});

    const Pipeline& pipeline() const { return pipeline_; }
    const std::vector<PlannedPass>& passes() const { return passes_; }
    const std::vector<PlannedBlock>& blocks() const { return blocks_; }
    std::vector<int> topologicalOrder() const { return order_; }
    // Whether `buffer` (a version) is handed over batch by batch (never stored whole).
    bool streamed(const std::string& buffer) const;
    // The version a buffer name has at the end of the pipeline (results, saves).
    std::string finalVersion(const std::string& name) const;
    // Imported versions -> (type, path); saved versions -> path.
    const std::map<std::string, std::pair<std::string, std::string>>& imports() const { return imports_; }
    const std::map<std::string, std::string>& saves() const { return saves_; }
    // The plan that makes only the given buffer versions (and what they need):
    // every other pass is culled, the versions are stored whole (never
    // streamed), kept to the end and handed to RunOptions::save with an empty
    // path as soon as they are made. Throws InputError for a version that no
    // pass of the plan makes or imports.
    ExecutionPlan producing(const std::vector<std::string>& versions) const;
    // Graphviz DOT; repeat blocks drawn once with their count unless `unroll`.
    std::string toDot(bool unroll = false) const;
    // The type of a buffer version ("Film", ...), empty if unknown.
    std::string bufferTypeOf(const std::string& version) const;

private:
    // Culls every pass that none of `roots` (pass indices) needs.
    void cullAllBut(std::vector<int> roots);
    void chooseStreams();
    bool fusedTasksAcyclic() const;
    Pipeline pipeline_;
    std::vector<PlannedPass> passes_;
    std::vector<PlannedBlock> blocks_;
    std::vector<int> order_;
    std::map<std::string, int> producer_;  // buffer version -> pass index
    std::map<std::string, std::string> finalVersion_;
    std::map<std::string, std::pair<std::string, std::string>> imports_;
    std::map<std::string, std::string> saves_;
};

struct PassStats {
    std::string instance;
    std::string pass;
    std::string block;   // repeat block, empty outside blocks
    std::string blockPass;  // the instance name inside its block (summed rows)
    double startSeconds = 0.0;  // since the run began
    double wallSeconds = 0.0;
    double cpuSeconds = 0.0;    // summed over all threads that worked for the pass
    std::int64_t items = 0;
    std::size_t outputBytes = 0;  // of streamed outputs: the largest batch
    std::int64_t batchesEmitted = 0;
    std::map<std::string, std::int64_t> counters;
    std::string partial;  // what the pass kept when an interrupt stopped it early; empty otherwise
};

// Time booked to one pass instance, possibly in several pieces (the batches it
// consumed, then its run): wall time, and the CPU time of every thread that
// worked for it (its own thread's, less nested timed bodies, plus the parallel
// chunks booked to `work`).
struct PassTiming {
    jobs::WorkContext work;
    std::int64_t firstStartNs = -1;  // jobs::wallNanos() when the first piece began
    std::int64_t wallNs = 0;
    std::int64_t serialCpuNs = 0;
    double cpuSeconds() const { return 1e-9 * static_cast<double>(serialCpuNs + work.chunkCpuNs.load()); }
};
// Runs body() booked to `timing`, and records a "pass" trace slice named `label`.
void timePass(PassTiming& timing, const std::string& label, const std::function<void()>& body);

struct RunOptions {
    std::uint64_t seed = 1;
    FilmSettings film;
    std::function<void(const std::string&, double)> progress;  // instance, fraction
    std::map<std::string, BufferHandle> imported;  // imported version -> buffer (loaded before the run)
    // Called with each saved version as soon as its producer finishes.
    std::function<void(const std::string& version, const std::string& path, const BufferHandle&)> save;
    // Called with every batch of a streamed version, in emission order, before
    // its readers see it (to record a stream and replay it later).
    std::function<void(const std::string& version, const std::shared_ptr<void>& batch, std::size_t bytes)> batchTap;
};

struct RunResult {
    std::map<std::string, BufferHandle> results;  // the pipeline's result buffers, by name
    std::vector<PassStats> stats;                 // in topological order; skipped iterations left out
    std::map<std::string, int> iterations;        // repeat block -> iterations run
    // What was kept of work an interrupt cut short, one entry per pass or block
    // ("pt: 37 of 256 samples per pixel", "refine: 3 of 10 iterations"); empty
    // when everything ran to its end.
    std::vector<std::string> partial;
    double wallSeconds = 0.0;
};

RunResult execute(const ExecutionPlan& plan, const Scene& scene, const RayQuery& rays, const RunOptions& options);
// As above; `rays` may be null when no pass of the plan traces rays.
RunResult execute(const ExecutionPlan& plan, const Scene& scene, const RayQuery* rays, const RunOptions& options);

}  // namespace fg
