// Thread scaling of a job: renders it at several thread counts, several times
// each, and reduces the per-pass wall times to medians, speed-ups, parallel
// efficiencies and an Amdahl serial fraction. It also checks the engine's
// promise that images do not depend on the thread count, byte for byte.
// `fluxgraph scale` (engine/cli/scale.cpp) is the command-line face of this.
#pragma once

#include "engine/core/job.h"

#include <functional>
#include <string>
#include <vector>

namespace fg::run {

// "1,2,4,8" -> {1, 2, 4, 8}, sorted, duplicates dropped. Throws InputError
// naming the list for empty items, non-numbers, and counts below 1 or above
// kMaxScaleThreads.
inline constexpr int kMaxScaleThreads = 4096;
std::vector<int> parseThreadList(const std::string& text);

// Serial fraction f of Amdahl's law T(N) = T1 * (f + (1 - f) / N), fitted by
// least squares over all points, with T1 given (the measured one-thread time).
// Rewritten as T(N) - T1/N = f * T1 * (1 - 1/N) it is a line through the origin,
// so f = sum(x*y) / sum(x*x). Clamped to [0, 1]; NaN when no point has N > 1
// or T1 is not positive (nothing to fit).
double fitSerialFraction(const std::vector<int>& threads, const std::vector<double>& seconds, double oneThreadSeconds);

// Median of a non-empty sample (mean of the middle two for even sizes).
double median(std::vector<double> values);

struct ScaleSettings {
    std::vector<int> threads;  // as parsed; 1 is added when missing (the baseline of S(N))
    int repeat = 3;
    // Called before each render with (threads, repetition from 1, repetitions); may be empty.
    std::function<void(int, int, int)> progress;
};

struct ThreadTiming {
    int threads = 0;
    std::vector<double> seconds;  // one per repetition, in run order
    double median = 0.0, min = 0.0, max = 0.0;
    double speedup = 0.0;     // T(1) / T(N), medians
    double efficiency = 0.0;  // speedup / N
    bool oversubscribed = false;  // N above the machine's hardware threads
};

struct ScaleSeries {
    std::string name;  // pass instance, "block[*].pass" for a repeat block's summed rows, or "pipeline"
    std::vector<ThreadTiming> timings;  // ascending thread counts
    double serialFraction = 0.0;        // NaN when only N = 1 was run
};

struct ImageMismatch {
    int threads = 0;
    int repetition = 0;   // from 1
    std::string result;   // the result buffer that differs, or "" when the set of results differs
};

struct ScaleReport {
    std::string jobPath;
    std::vector<int> threads;    // what was run, ascending, 1 first
    bool baselineAdded = false;  // 1 was not asked for but run for T(1)
    int repeat = 0;
    int hardwareThreads = 0;
    std::vector<ScaleSeries> passes;  // in pipeline order
    ScaleSeries pipeline;             // all passes' wall time (RunResult::wallSeconds)
    int imagesCompared = 0;           // Film results, per run
    std::vector<ImageMismatch> mismatches;  // against the first run (1 thread, repetition 1)
    std::vector<std::string> files;         // images written by the last run
};

// Loads the job once per thread count (overrides.threads replaced), renders it
// settings.repeat times at each count, repetitions interleaved so that a drift
// of the machine (another load, thermal) spreads over all counts instead of
// biasing one. Images go to the job's output directory (overrides.outputDirectory),
// overwritten by every run. Throws InputError for a bad job or settings.
ScaleReport measureScaling(const std::string& jobPath, const JobOverrides& overrides, const ScaleSettings& settings);

// Fills median/min/max, speed-up, efficiency and the serial fraction from the
// raw seconds; `timings` ascending with threads == 1 first.
void summarize(ScaleSeries& series, int hardwareThreads);

// The table `fluxgraph scale` prints: one row per (pass, threads) with median
// wall seconds, speed-up, efficiency and, on each pass's first row, the serial
// fraction; then one line on the image check.
std::string formatScaleTable(const ScaleReport& report);
// One CSV row per (pass, threads), the pipeline rows last:
// pass,threads,median_s,min_s,max_s,speedup,efficiency,serial_fraction,oversubscribed
std::string scaleCsv(const ScaleReport& report);

}  // namespace fg::run
