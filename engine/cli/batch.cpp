// The `batch` subcommand. With --jobs 1 (the default) every run is rendered in
// this process, sharing loaded scenes. jobs::ThreadLimit is process-wide, so
// --jobs N > 1 starts N worker processes of this same binary instead
// (`batch PLAN --worker K/N`), each with its own scene cache and its share of
// the threads, rendering every N-th run; they append whole rows to the same
// table files. Images do not depend on the thread count, so --jobs changes
// only the row order, never a pixel.
//
// Ctrl-C: the first SIGINT lets the current run finish and write its row, then
// the batch stops with exit code 130; a second SIGINT abandons the current run
// at once (its images are written atomically, so none is left half-written).
#include "engine/cli/batch.h"

#include "engine/core/error.h"
#include "engine/run/batch.h"
#include "jobs/parallel.h"

#include <CLI/CLI.hpp>

#include <signal.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <thread>
#include <vector>

extern char** environ;

namespace fg::cli {

namespace {

constexpr int kInputErrorExit = 2;
constexpr int kFailedRunExit = 1;
constexpr int kInterruptedExit = 130;

std::atomic<bool> stopRequested{false};

void onSigint(int) {
    if (stopRequested.exchange(true)) {
        // Second Ctrl-C: abandon the current run now.
        ::signal(SIGINT, SIG_DFL);
        ::raise(SIGINT);
    }
}

void installSigintHandler() {
    struct sigaction action {};
    action.sa_handler = onSigint;
    sigemptyset(&action.sa_mask);
    action.sa_flags = SA_RESTART;
    ::sigaction(SIGINT, &action, nullptr);
}

std::string oneLine(std::string message) {
    for (char& c : message)
        if (c == '\n' || c == '\r') c = ' ';
    return message;
}

// Counts the rows appended to the CSV since construction, for the parent's progress line.
class RowCounter {
public:
    explicit RowCounter(std::string path) : path_(std::move(path)) {
        std::error_code ec;
        offset_ = std::filesystem::file_size(path_, ec);
        if (ec) offset_ = 0;
    }
    std::size_t poll() {
        std::ifstream in(path_, std::ios::binary);
        in.seekg(static_cast<std::streamoff>(offset_));
        char buffer[4096];
        while (in.read(buffer, sizeof buffer) || in.gcount() > 0) {
            const auto n = static_cast<std::size_t>(in.gcount());
            for (std::size_t i = 0; i < n; ++i) rows_ += buffer[i] == '\n' ? 1 : 0;
            offset_ += n;
        }
        return rows_;
    }

private:
    std::string path_;
    std::uintmax_t offset_ = 0;
    std::size_t rows_ = 0;
};

int runWorkers(const BatchCliOptions& options, const BatchPlan& plan, const std::string& startedAt) {
    const int threads = options.threads >= 0 ? options.threads : std::max(1, jobs::hardwareThreads() / options.jobs);
    const std::string self = std::filesystem::read_symlink("/proc/self/exe").string();
    std::vector<pid_t> children;
    for (int k = 0; k < options.jobs; ++k) {
        std::vector<std::string> args = {self, "batch", options.planPath, "--worker",
                                         std::to_string(k) + "/" + std::to_string(options.jobs), "--started", startedAt,
                                         "--threads", std::to_string(threads)};
        if (options.force) args.emplace_back("--force");
        if (options.failFast) args.emplace_back("--fail-fast");
        std::vector<char*> argv;
        for (std::string& a : args) argv.push_back(a.data());
        argv.push_back(nullptr);
        // Own process groups: a terminal's Ctrl-C reaches only this process, which
        // forwards it once; a second one here is then a second one for them too.
        posix_spawnattr_t attributes;
        posix_spawnattr_init(&attributes);
        posix_spawnattr_setflags(&attributes, POSIX_SPAWN_SETPGROUP);
        posix_spawnattr_setpgroup(&attributes, 0);
        pid_t pid = 0;
        const int status = ::posix_spawn(&pid, self.c_str(), nullptr, &attributes, argv.data(), environ);
        posix_spawnattr_destroy(&attributes);
        if (status != 0) {
            for (pid_t child : children) ::kill(child, SIGINT);
            stopRequested = true;
            std::cerr << "fluxgraph: internal error: cannot start a batch worker process\n";
            break;
        }
        children.push_back(pid);
    }

    const bool showProgress = ::isatty(STDERR_FILENO);
    RowCounter rows((std::filesystem::path(plan.outputDirectory) / kBatchCsvName).string());
    const auto start = std::chrono::steady_clock::now();
    std::vector<int> exitCodes(children.size(), -1);
    std::size_t running = children.size();
    int interruptsForwarded = 0;
    bool anyFailed = false;
    while (running > 0) {
        for (std::size_t i = 0; i < children.size(); ++i) {
            if (exitCodes[i] >= 0) continue;
            int status = 0;
            const pid_t done = ::waitpid(children[i], &status, WNOHANG);
            if (done != children[i]) continue;
            exitCodes[i] = WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
            --running;
            if (exitCodes[i] == kFailedRunExit) anyFailed = true;
        }
        const int wanted = stopRequested ? 1 : 0;
        // Fail-fast: one worker's failure stops the others after their current run.
        if ((wanted > interruptsForwarded || (options.failFast && anyFailed && interruptsForwarded == 0)) && running > 0) {
            for (std::size_t i = 0; i < children.size(); ++i)
                if (exitCodes[i] < 0) ::kill(children[i], SIGINT);
            ++interruptsForwarded;
        }
        if (showProgress) {
            const std::size_t done = rows.poll();
            const double elapsed = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
            const double left = done > 0 ? elapsed / static_cast<double>(done) *
                                               static_cast<double>(plan.runs.size() - std::min(done, plan.runs.size()))
                                         : 0.0;
            std::fprintf(stderr, "\rbatch: %zu/%zu runs, %.1f s elapsed, ~%.1f s left   ", done, plan.runs.size(),
                         elapsed, left);
            std::fflush(stderr);
        }
        if (running > 0) std::this_thread::sleep_for(std::chrono::milliseconds(50));
    }
    if (showProgress) std::fputc('\n', stderr);

    int exitCode = 0;
    for (int code : exitCodes) {
        if (code == kInterruptedExit || stopRequested) exitCode = kInterruptedExit;
        else if (code != 0 && exitCode == 0) exitCode = code;
    }
    if (exitCode == kInterruptedExit && !(options.failFast && anyFailed && !stopRequested))
        std::cerr << "batch: interrupted; finished runs are in " << plan.outputDirectory << ", rerun to resume\n";
    else if (options.failFast && anyFailed) exitCode = kFailedRunExit;
    return exitCode;
}

}  // namespace

CLI::App* addBatchSubcommand(CLI::App& app, BatchCliOptions& options) {
    CLI::App* batch = app.add_subcommand("batch", "render every run of a batch plan (jobs and parameter sweeps)");
    batch->add_option("plan", options.planPath, "batch plan (TOML)")->required();
    batch->add_flag("--force", options.force, "rerun runs whose images are up to date");
    batch->add_flag("--fail-fast", options.failFast, "stop at the first failed run");
    batch->add_option("--jobs,-j", options.jobs, "runs at once, in separate processes (threads split between them)")
        ->check(CLI::Range(1, 4096));
    batch->add_option("--threads", options.threads, "worker threads per run (0 = all)")->check(CLI::Range(0, 4096));
    batch->add_option("--worker", options.worker)->group("");
    batch->add_option("--started", options.startedAt)->group("");
    return batch;
}

int runBatch(const BatchCliOptions& options) {
    try {
        const BatchPlan plan = loadBatchPlan(options.planPath);
        BatchOptions batchOptions;
        batchOptions.force = options.force;
        batchOptions.failFast = options.failFast;
        if (options.threads >= 0) batchOptions.threads = options.threads;
        batchOptions.commandLine = options.commandLine;
        batchOptions.startedAt = options.startedAt.empty() ? batchTimestamp() : options.startedAt;
        batchOptions.stopRequested = &stopRequested;
        installSigintHandler();

        if (!options.worker.empty()) {
            const auto slash = options.worker.find('/');
            batchOptions.workerIndex = std::stoi(options.worker.substr(0, slash));
            batchOptions.workerCount = std::stoi(options.worker.substr(slash + 1));
            batchOptions.writeHeader = false;
        } else if (options.jobs > 1) {
            // Every run is checked before any process starts rendering.
            validateBatchPlan(plan, batchOptions.threads);
            prepareBatchOutput(plan);
            return runWorkers(options, plan, batchOptions.startedAt);
        } else {
            batchOptions.showProgress = ::isatty(STDERR_FILENO);
        }

        const BatchSummary summary = fg::runBatch(plan, batchOptions);
        const bool worker = !options.worker.empty();
        if (summary.interrupted && stopRequested) {
            if (!worker)
                std::cerr << "batch: interrupted; finished runs are in " << plan.outputDirectory << ", rerun to resume\n";
            return kInterruptedExit;
        }
        if (!worker)
            std::cout << "batch: " << summary.ok << " ok, " << summary.skipped << " skipped, " << summary.failed
                      << " failed; results in " << plan.outputDirectory << "/" << kBatchCsvName << "\n";
        return summary.failed > 0 ? kFailedRunExit : 0;
    } catch (const InputError& e) {
        std::cerr << oneLine(e.what()) << "\n";
        return kInputErrorExit;
    }
}

}  // namespace fg::cli
