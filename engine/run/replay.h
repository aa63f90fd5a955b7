// Replaying one pass instance of a job in isolation, to profile it without the
// pipeline around it: its inputs are made once (by running only the passes
// they need) or loaded from buffer files, then the pass alone runs several
// times on them, each time as a fresh Pass with a fresh PassContext and fresh
// outputs, timed as the scheduler times passes. Every repetition's outputs are
// encoded with their codec and compared byte for byte, so a pass whose result
// depends on anything but its inputs, parameters and seed shows up.
//
// Streamed inputs are recorded batch by batch as the pipeline streams them to
// the pass (which then runs once inside the pipeline, as in a render) and
// every repetition consumes the same batches in the same order, so its
// outputs equal a render's byte for byte. With --save-inputs or --inputs a
// streamed input is made whole instead and handed to Pass::consumeBatch as one
// batch, as the scheduler does with a stored streamable input.
#pragma once

#include "engine/core/job.h"
#include "engine/core/pass.h"
#include "engine/core/scheduler.h"

#include <cstdint>
#include <map>
#include <string>
#include <vector>

namespace fg {

struct ReplayOptions {
    std::string instance;             // pass instance, e.g. "gather" or "progressive[3].pt"
    int repeat = 5;                   // repetitions, >= 1
    std::string inputsDirectory;      // non-empty: read inputs from DIR/<buffer>.fgbuf instead of making them
    std::string saveInputsDirectory;  // non-empty: write the inputs there as DIR/<buffer>.fgbuf
    std::string profilePath;          // Chrome trace of the repetitions, empty = none
};

struct ReplayInput {
    std::string slot;
    std::string version;  // the buffer version the slot reads in the plan
    std::string type;
    std::size_t bytes = 0;
    std::size_t batches = 0;  // > 0: a streamed input, recorded as the pipeline emitted it
};

struct ReplayRepetition {
    double wallSeconds = 0.0;
    double cpuSeconds = 0.0;  // summed over all threads that worked for the pass
    std::int64_t items = 0;
    double itemsPerSecond() const { return wallSeconds > 0 ? static_cast<double>(items) / wallSeconds : 0.0; }
};

struct ReplayResult {
    std::string instance;
    std::string pass;
    int threads = 0;
    std::vector<ReplayInput> inputs;  // bound inputs and in-out slots
    bool inputsLoaded = false;        // from files rather than made by running the pipeline
    int passesRunForInputs = 0;
    double inputsSeconds = 0.0;       // making or loading them
    std::vector<ReplayRepetition> repetitions;
    // The first repetition's outputs (outputs and in-out slots), by slot, and
    // the buffer version each is in the plan.
    std::map<std::string, BufferHandle> outputs;
    std::map<std::string, std::string> outputVersions;
    // "slot (repetition r)" for every output that differs from the first repetition's.
    std::vector<std::string> differences;
    std::vector<std::string> files;  // written: saved inputs, the profile
    bool identical() const { return differences.empty(); }
};

// The buffer file name an input version is saved under: its buffer's name
// without repeat-block prefix and version suffix ("progressive[2].image@2" ->
// "image"), plus ".fgbuf".
std::string replayInputFileName(const std::string& version);

// Throws InputError (one line) for an unknown instance (naming the instances),
// repeat < 1, missing or mismatched input files and everything a render
// would reject.
ReplayResult replayPass(const Job& job, const ReplayOptions& options, const Registry& registry = installedRegistry());

// The report `fluxgraph replay` prints: one line per repetition (wall, CPU,
// items, items/s), the medians, and whether the outputs were identical.
std::string formatReplayReport(const ReplayResult& result);

// A buffer as its codec encodes it (type, columns, item count and payload;
// no job text): equal strings mean byte-identical buffer files.
std::string encodeBuffer(const BufferHandle& buffer);
// As encodeBuffer, but with every Film AOV whose name ends in "time_ns"
// zeroed: those channels record how long pixels took (pt's time_ns,
// beam_query's query_time_ns), which no two runs repeat. The replay compares
// outputs in this form.
std::string comparableEncoding(const BufferHandle& buffer);

}  // namespace fg
