// The `replay` subcommand: parses its options into a Job and ReplayOptions and
// prints engine/run/replay.h's report. Input errors cost one stderr line and
// exit code 2, before any work where they can be found before it.
#include "engine/cli/replay.h"

#include "engine/core/error.h"
#include "engine/core/job.h"
#include "engine/run/replay.h"

#include <CLI/CLI.hpp>

#include <iostream>

namespace fg::cli {

namespace {

constexpr int kInputErrorExit = 2;
constexpr int kOutputsDifferExit = 3;

std::string oneLine(std::string message) {
    for (char& c : message)
        if (c == '\n' || c == '\r') c = ' ';
    return printableMessage(message);
}

}  // namespace

CLI::App* addReplaySubcommand(CLI::App& app, ReplayCommandOptions& options) {
    CLI::App* replay = app.add_subcommand(
        "replay", "run one pass instance of a job repeatedly on the same inputs, timed (for profilers)");
    replay->add_option("job", options.jobPath, "job file (TOML)")->required();
    replay->add_option("--pass", options.instance, "pass instance to replay, e.g. gather or progressive[3].pt")
        ->required();
    replay->add_option("--repeat", options.repeat, "repetitions (default 5)");
    replay->add_option("--inputs", options.inputsDirectory,
                       "read the pass's inputs from DIR/<buffer>.fgbuf instead of running the pipeline up to it");
    replay->add_option("--save-inputs", options.saveInputsDirectory, "write the pass's inputs to DIR/<buffer>.fgbuf");
    replay->add_option("--threads", options.threads, "worker threads (0 = all)")->check(CLI::NonNegativeNumber);
    replay->add_option("--profile", options.profilePath,
                       "write a Chrome trace-event JSON of the repetitions (open in ui.perfetto.dev)");
    replay->add_option("--set", options.sets, "override a job value, e.g. passes.pt.spp=64 (repeatable)");
    replay->add_option("--define", options.defines,
                       "set a parameter of a Mitsuba XML scene ($name), e.g. spp=64 (repeatable)");
    replay->add_option("--import", options.imports,
                       "read buffer NAME from a file saved with --save instead of producing it, NAME=path (repeatable)");
    return replay;
}

int runReplay(const ReplayCommandOptions& options) {
    try {
        if (options.repeat < 1) throw InputError("--repeat " + std::to_string(options.repeat) + ": must be at least 1");
        JobOverrides overrides;
        overrides.sets = options.sets;
        overrides.defines = options.defines;
        overrides.imports = options.imports;
        if (options.threads >= 0) overrides.threads = options.threads;
        const Job job = loadJob(options.jobPath, overrides);
        ReplayOptions replay;
        replay.instance = options.instance;
        replay.repeat = options.repeat;
        replay.inputsDirectory = options.inputsDirectory;
        replay.saveInputsDirectory = options.saveInputsDirectory;
        replay.profilePath = options.profilePath;
        const ReplayResult result = replayPass(job, replay);
        std::cout << formatReplayReport(result);
        for (const std::string& file : result.files) std::cout << "wrote " << file << '\n';
        return result.identical() ? 0 : kOutputsDifferExit;
    } catch (const InputError& e) {
        std::cerr << oneLine(e.what()) << '\n';
        return kInputErrorExit;
    } catch (const std::exception& e) {
        std::cerr << "fluxgraph: internal error: " << oneLine(e.what()) << '\n';
        return 1;
    }
}

}  // namespace fg::cli
