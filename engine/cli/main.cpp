// The fluxgraph command line: render, validate, graph, passes, pipelines.
// Input errors print one line "file:line: message" and exit with code 2,
// leaving no output file behind; internal errors exit with code 1.
#include "engine/cli/batch.h"
#include "engine/cli/compare.h"
#include "engine/cli/scale.h"
#include "engine/cli/replay.h"
#include "engine/core/error.h"
#include "engine/core/interrupt.h"
#include "engine/core/job.h"
#include "engine/core/pass.h"
#include "engine/core/render.h"
#include "passes/passes.h"

#include <CLI/CLI.hpp>

#include <csignal>
#include <cstdio>
#include <iostream>
#include <new>
#include <unistd.h>

namespace {

constexpr int kInputErrorExit = 2;
constexpr int kInterruptedExit = 128 + SIGINT;

// Ctrl-C on a render (README, "Interrupts"): the first SIGINT, once a unit of
// work is done, asks the passes to stop at their next unit boundary and the
// render writes what it has; before that, or the second time, the process
// quits at once. SIGTERM and SIGHUP always quit. Quitting removes the output
// temporaries and the directories made for them, and writes nothing.
extern "C" void onInterruptSignal(int signal) {
    if (!fg::stopRequested() && fg::completedUnits() > 0) {
        fg::requestStop();
        return;
    }
    const char* message = fg::stopRequested() ? "fluxgraph: interrupted again: quit, nothing more written\n"
                                              : "fluxgraph: interrupted before any unit of work was done: nothing written\n";
    if (!fg::deferQuitIfCommitting(signal, message)) fg::quitAfterSignal(signal, message);
}

extern "C" void onQuitSignal(int signal) {
    const char* message = signal == SIGTERM ? "fluxgraph: terminated (SIGTERM): nothing written\n"
                                            : "fluxgraph: hung up (SIGHUP): nothing written\n";
    if (!fg::deferQuitIfCommitting(signal, message)) fg::quitAfterSignal(signal, message);
}

void installRenderSignalHandlers() {
    struct sigaction action {};
    sigemptyset(&action.sa_mask);
    // One handler at a time: a second signal waits for the first to finish.
    sigaddset(&action.sa_mask, SIGINT);
    sigaddset(&action.sa_mask, SIGTERM);
    sigaddset(&action.sa_mask, SIGHUP);
    action.sa_flags = SA_RESTART;
    action.sa_handler = onInterruptSignal;
    ::sigaction(SIGINT, &action, nullptr);
    action.sa_handler = onQuitSignal;
    ::sigaction(SIGTERM, &action, nullptr);
    ::sigaction(SIGHUP, &action, nullptr);
}

void printPasses() {
    for (const fg::PassRegistration& r : fg::installedRegistry().passes) {
        const fg::PassSpec& s = r.spec;
        std::cout << s.name << " — " << s.doc << "\n";
        for (const auto& in : s.inputs)
            std::cout << "  in   " << in.name << " : " << in.type << (in.streamable ? " (batches)" : "")
                      << (in.optional ? " (optional)" : "") << "  " << in.doc << "\n";
        for (const auto& io : s.inouts)
            std::cout << "  inout " << io.name << " : " << io.type << "  " << io.doc << "\n";
        for (const auto& out : s.outputs)
            std::cout << "  out  " << out.name << " : " << out.type << (out.streamable ? " (batches)" : "") << "  "
                      << out.doc << "\n";
        for (const auto& p : s.params) {
            std::cout << "  param " << p.name << " : " << fg::toString(p.type) << " = " << fg::toString(p.defaultValue);
            if (p.type == fg::ParamType::Int || p.type == fg::ParamType::Float) std::cout << "  " << fg::describeRange(p);
            if (!p.choices.empty()) {
                std::cout << "  {";
                for (std::size_t i = 0; i < p.choices.size(); ++i) std::cout << (i ? "|" : "") << p.choices[i];
                std::cout << "}";
            }
            if (!p.sceneHint.empty()) std::cout << "  (scene hint: " << p.sceneHint << ")";
            std::cout << "\n      " << p.doc << "\n";
        }
        for (const auto& signal : s.signals) std::cout << "  signal " << signal << "\n";
        std::cout << "\n";
    }
}

void printPipelines() {
    for (const fg::Pipeline& p : fg::installedRegistry().pipelines) {
        std::cout << p.name << " — " << p.doc << "\n  file: " << p.file << "\n  passes:";
        for (const auto& n : p.nodes) std::cout << " " << n.instance;
        for (const auto& b : p.blocks) {
            std::cout << " repeat " << b.name << " x " << b.count << " {";
            for (const auto& n : b.nodes) std::cout << " " << n.instance;
            std::cout << " }";
        }
        std::cout << "\n  results:";
        for (const auto& r : p.results) std::cout << " " << r;
        std::cout << "\n";
    }
}

// The arguments as one line a POSIX shell would split back into the same words.
std::string shellCommandLine(int argc, char** argv) {
    static constexpr const char* kPlain = "abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789-_./=:,+@%";
    std::string line;
    for (int i = 0; i < argc; ++i) {
        const std::string arg = argv[i];
        if (i > 0) line += ' ';
        if (!arg.empty() && arg.find_first_not_of(kPlain) == std::string::npos) {
            line += arg;
            continue;
        }
        line += '\'';
        for (char c : arg) line += c == '\'' ? std::string("'\\''") : std::string(1, c);
        line += '\'';
    }
    return line;
}

}  // namespace

int main(int argc, char** argv) {
    fg::installRegistry(&fg::builtinRegistry());
    CLI::App app{"fluxgraph — a pass-based renderer for photon density estimation research"};
    app.require_subcommand(1);

    std::string jobPath;
    fg::JobOverrides overrides;
    int threads = -1;
    long long seed = -1;
    std::string outDir, profilePath, statsPath;
    bool quiet = false;

    const auto addJobOptions = [&](CLI::App* cmd) {
        cmd->add_option("job", jobPath, "job file (TOML)")->required();
        cmd->add_option("--import", overrides.imports,
                        "read buffer NAME from a file saved with --save instead of producing it, NAME=path (repeatable)");
        cmd->add_option("--set", overrides.sets, "override a job value, e.g. passes.pt.spp=64 (repeatable)");
        cmd->add_option("--define", overrides.defines,
                        "set a parameter of a Mitsuba XML scene ($name), e.g. spp=64 (repeatable; wins over scene_defines)");
    };
    CLI::App* render = app.add_subcommand("render", "render a job");
    addJobOptions(render);
    render->add_option("--threads", threads, "worker threads (0 = all)");
    render->add_option("--seed", seed, "random seed");
    render->add_option("--out", outDir, "output directory");
    render->add_option("--profile", profilePath, "write a Chrome trace-event JSON (open in ui.perfetto.dev)");
    render->add_option("--stats", statsPath, "write per-pass statistics and counters as JSON");
    render->add_flag("--quiet,-q", quiet, "no progress bar and no pass table");
    render->add_option("--save", overrides.saves,
                       "write buffer NAME (its final version) to a file when its producer finishes, NAME=path (repeatable)");
    CLI::App* validate = app.add_subcommand("validate", "check a job, its pipeline and its scene without rendering");
    addJobOptions(validate);
    CLI::App* graph = app.add_subcommand("graph", "print a job's pipeline as Graphviz DOT");
    addJobOptions(graph);
    bool unroll = false;
    graph->add_flag("--unroll", unroll, "draw every iteration of repeat blocks");
    app.add_subcommand("passes", "list every registered pass with its inputs, outputs and parameters");
    app.add_subcommand("pipelines", "list the built-in pipelines");
    fg::cli::CompareOptions compareOptions;
    CLI::App* compare = fg::cli::addCompareSubcommand(app, compareOptions);
    fg::cli::ScaleOptions scaleOptions;
    CLI::App* scale = fg::cli::addScaleSubcommand(app, scaleOptions);
    fg::cli::ReplayCommandOptions replayOptions;
    CLI::App* replay = fg::cli::addReplaySubcommand(app, replayOptions);
    fg::cli::BatchCliOptions batchOptions;
    CLI::App* batch = fg::cli::addBatchSubcommand(app, batchOptions);

    try {
        app.parse(argc, argv);
    } catch (const CLI::CallForHelp& e) {
        return app.exit(e);
    } catch (const CLI::CallForAllHelp& e) {
        return app.exit(e);
    } catch (const CLI::ParseError& e) {
        std::cerr << "fluxgraph: " << fg::printableMessage(e.what()) << "\n";
        return kInputErrorExit;
    }

    try {
        if (app.got_subcommand("passes")) {
            printPasses();
            return 0;
        }
        if (app.got_subcommand("pipelines")) {
            printPipelines();
            return 0;
        }
        if (compare->parsed()) return fg::cli::runCompare(compareOptions);
        if (scale->parsed()) return fg::cli::runScale(scaleOptions);
        if (replay->parsed()) return fg::cli::runReplay(replayOptions);
        if (batch->parsed()) {
            batchOptions.commandLine = shellCommandLine(argc, argv);
            return fg::cli::runBatch(batchOptions);
        }
        if (threads >= 0) overrides.threads = threads;
        if (seed >= 0) overrides.seed = static_cast<std::uint64_t>(seed);
        if (render->parsed() && render->count("--seed") && seed < 0) throw fg::InputError("--seed: must be non-negative");
        if (render->parsed() && render->count("--threads") && (threads < 0 || threads > fg::kMaxThreads))
            throw fg::InputError("--threads: must be 0 (all) or a count up to " + std::to_string(fg::kMaxThreads));
        if (!outDir.empty()) overrides.outputDirectory = outDir;
        const fg::Job job = fg::loadJob(jobPath, overrides);

        if (graph->parsed()) {
            std::cout << fg::ExecutionPlan::build(job.pipeline, job.params, job.path, fg::installedRegistry().passes,
                                                  job.bufferFiles)
                             .toDot(unroll);
            return 0;
        }
        if (validate->parsed()) {
            const fg::ExecutionPlan plan = fg::validateJob(job);
            std::size_t live = 0;
            for (const auto& p : plan.passes()) live += p.culled ? 0 : 1;
            std::cout << job.path << ": ok (pipeline '" << job.pipeline.name << "', " << live << " passes, scene "
                      << job.scenePath << ")\n";
            return 0;
        }
        fg::RenderOptions options;
        options.showProgress = !quiet && ::isatty(STDERR_FILENO);
        options.profilePath = profilePath;
        options.statsPath = statsPath;
        options.commandLine = shellCommandLine(argc, argv);
        installRenderSignalHandlers();
        const fg::RenderOutcome outcome = fg::renderJob(job, options);
        if (!quiet) {
            std::cout << fg::formatPassTable(outcome);
            for (const std::string& f : outcome.files) std::cout << "wrote " << f << "\n";
        }
        if (!fg::stopRequested()) return 0;
        std::string kept;
        for (const std::string& part : outcome.run.partial) kept += (kept.empty() ? "" : "; ") + part;
        if (kept.empty())
            std::cerr << "fluxgraph: interrupted after the work was done: the outputs are complete\n";
        else
            std::cerr << "fluxgraph: interrupted: kept " << kept << " (written with fluxgraph:partial = true)\n";
        return kInterruptedExit;
    } catch (const fg::InputError& e) {
        // Messages quote keys, values and paths from the input, which may hold any bytes.
        if (e.problems().empty()) std::cerr << fg::printableMessage(e.what()) << "\n";
        for (const std::string& problem : e.problems()) std::cerr << fg::printableMessage(problem) << "\n";
        return kInputErrorExit;
    } catch (const std::bad_alloc&) {
        // Passes name themselves (the scheduler); this is loading, building or writing.
        std::cerr << "fluxgraph: ran out of memory outside the passes (scene, acceleration structure or outputs)\n";
        return kInputErrorExit;
    } catch (const std::exception& e) {
        std::cerr << "fluxgraph: internal error: " << fg::printableMessage(e.what()) << "\n";
        return 1;
    }
}
