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
//
// On a cluster, --slurm writes (and with --submit submits) an sbatch job array
// whose tasks run this binary with --task I; --collect merges their tables.
#include "engine/cli/batch.h"

#include "engine/core/error.h"
#include "engine/run/batch.h"
#include "engine/run/batch_slurm.h"
#include "jobs/parallel.h"

#include <CLI/CLI.hpp>

#include <signal.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cctype>
#include <chrono>
#include <cstdio>
#include <cstdlib>
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
    return printableMessage(message);
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

// Arguments that make a worker or an array task render like this invocation.
void addTaskArguments(const BatchCliOptions& options, std::vector<std::string>& args) {
    if (options.task != BatchCliOptions::kNoTask) {
        args.insert(args.end(), {"--task", std::to_string(options.task)});
        args.insert(args.end(), {"--runs-per-task", std::to_string(options.runsPerTask)});
    }
}

int runWorkers(const BatchCliOptions& options, const BatchPlan& plan, const BatchOptions& batchOptions) {
    const std::string& startedAt = batchOptions.startedAt;
    const std::size_t total = std::min(batchOptions.runCount, plan.runs.size() - std::min(batchOptions.firstRun, plan.runs.size()));
    const int threads = options.threads >= 0 ? options.threads : std::max(1, jobs::hardwareThreads() / options.jobs);
    const std::string self = std::filesystem::read_symlink("/proc/self/exe").string();
    std::vector<pid_t> children;
    for (int k = 0; k < options.jobs; ++k) {
        std::vector<std::string> args = {self, "batch", options.planPath, "--worker",
                                         std::to_string(k) + "/" + std::to_string(options.jobs), "--started", startedAt,
                                         "--threads", std::to_string(threads)};
        if (options.force) args.emplace_back("--force");
        if (options.failFast) args.emplace_back("--fail-fast");
        addTaskArguments(options, args);
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
    RowCounter rows(batchTableBase(plan, batchOptions) + ".csv");
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
            const double left =
                done > 0 ? elapsed / static_cast<double>(done) * static_cast<double>(total - std::min(done, total)) : 0.0;
            std::fprintf(stderr, "\rbatch: %zu/%zu runs, %.1f s elapsed, ~%.1f s left   ", done, total, elapsed, left);
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
    batch->add_flag("--slurm", options.slurm,
                    "write <output>/batch.sbatch, a SLURM job array of this plan (one task per --runs-per-task runs)");
    batch->add_flag("--submit", options.submit, "with --slurm: submit the script with sbatch and print the job id");
    batch->add_option("--runs-per-task", options.runsPerTask, "runs per array task (default 1)");
    batch->add_option("--partition", options.partition, "with --slurm: the SLURM partition");
    batch->add_option("--time", options.timeLimit, "with --slurm: time limit per task (HH:MM:SS, D-HH:MM:SS)");
    batch->add_option("--task", options.task,
                      "render only array task I's runs [I*K, I*K+K), into <output>/tasks/task-I.csv/.jsonl");
    batch->add_flag("--collect", options.collect,
                    "merge every task's rows into results.csv/.jsonl; exit 1 while runs are missing");
    batch->add_option("--worker", options.worker)->group("");
    batch->add_option("--started", options.startedAt)->group("");
    return batch;
}

namespace {

// Option combinations that make no sense; empty when they are fine.
std::string clusterOptionsProblem(const BatchCliOptions& options) {
    const bool task = options.task != BatchCliOptions::kNoTask;
    if (options.runsPerTask < 1) return "batch: --runs-per-task must be at least 1";
    if (task && options.slurm) return "batch: --task runs one array task of a written script; it does not go with --slurm";
    if (options.collect && (options.slurm || task)) return "batch: --collect goes alone, without --slurm or --task";
    if (!options.slurm && (options.submit || !options.partition.empty() || !options.timeLimit.empty()))
        return "batch: --submit, --partition and --time go with --slurm";
    // They are written into the script: nothing a shell or sbatch could read as more.
    if (options.timeLimit.find_first_not_of("0123456789:-") != std::string::npos)
        return "batch: --time " + options.timeLimit + ": expected minutes, HH:MM:SS or D-HH:MM:SS";
    for (char c : options.partition)
        if (!std::isalnum(static_cast<unsigned char>(c)) && c != '_' && c != '-' && c != '.' && c != ',')
            return "batch: --partition " + options.partition + ": not a partition name";
    return {};
}

std::string shellQuote(const std::string& word) {
    std::string quoted = "'";
    for (char c : word) quoted += c == '\'' ? std::string("'\\''") : std::string(1, c);
    return quoted + "'";
}

std::string absolutePath(const std::string& path) {
    return std::filesystem::absolute(path).lexically_normal().string();
}

int collect(const BatchPlan& plan) {
    const BatchCollection collection = collectBatchTasks(plan);
    std::cout << "batch: collected " << collection.finished << " of " << collection.runs << " runs into "
              << (std::filesystem::path(plan.outputDirectory) / kBatchCsvName).string() << " and " << kBatchJsonlName
              << "; " << collection.missing.size() << " missing";
    if (!collection.missing.empty()) {
        std::cout << " (" << collection.failed << " failed, the rest not finished yet):";
        constexpr std::size_t kNamesShown = 5;
        for (std::size_t i = 0; i < std::min(kNamesShown, collection.missing.size()); ++i)
            std::cout << " " << collection.missing[i];
        if (collection.missing.size() > kNamesShown) std::cout << " ...";
    }
    std::cout << "\n";
    return collection.missing.empty() ? 0 : kFailedRunExit;
}

// sbatch --parsable prints "jobid" or "jobid;cluster".
int submit(const std::string& script, std::size_t tasks, const std::string& collectCommand) {
    const std::string command = "sbatch --parsable " + shellQuote(script) + " 2>&1";
    FILE* pipe = ::popen(command.c_str(), "r");
    if (!pipe) {
        std::cerr << "batch: cannot run sbatch\n";
        return kFailedRunExit;
    }
    std::string output;
    char buffer[256];
    while (std::fgets(buffer, sizeof buffer, pipe)) output += buffer;
    const int status = ::pclose(pipe);
    while (!output.empty() && (output.back() == '\n' || output.back() == ' ')) output.pop_back();
    // Warnings may come first; the id is the last line.
    const std::string last = output.substr(output.find_last_of('\n') == std::string::npos ? 0 : output.find_last_of('\n') + 1);
    const std::string jobId = last.substr(0, last.find(';'));
    if (status != 0 || jobId.empty() || jobId.find_first_not_of("0123456789") != std::string::npos) {
        std::cerr << "batch: sbatch failed: " << oneLine(output.empty() ? "no output" : output) << "\n";
        return kFailedRunExit;
    }
    std::cout << "batch: submitted job " << jobId << " (" << tasks << " array task"
              << (tasks == 1 ? "" : "s") << "); when it has finished: " << collectCommand << "\n";
    return 0;
}

int writeScript(const BatchCliOptions& options, const BatchPlan& plan, const BatchOptions& batchOptions) {
    // Every run is checked before anything is queued.
    validateBatchPlan(plan, batchOptions.threads);
    SlurmScriptOptions script;
    script.binary = std::filesystem::read_symlink("/proc/self/exe").string();
    script.planPath = absolutePath(options.planPath);
    script.workingDirectory = std::filesystem::current_path().string();
    script.runsPerTask = static_cast<std::size_t>(options.runsPerTask);
    script.partition = options.partition;
    script.timeLimit = options.timeLimit;
    if (options.force) script.taskArguments.emplace_back("--force");
    if (options.failFast) script.taskArguments.emplace_back("--fail-fast");
    if (options.threads >= 0) script.taskArguments.insert(script.taskArguments.end(), {"--threads", std::to_string(options.threads)});
    const std::string path = writeSlurmArrayScript(plan, script);
    const std::size_t tasks = batchTaskCount(plan.runs.size(), script.runsPerTask);
    const std::string collectCommand = "fluxgraph batch " + options.planPath + " --collect";
    std::cout << "batch: wrote " << path << " (" << plan.runs.size() << " runs in " << tasks << " array task"
              << (tasks == 1 ? "" : "s") << ")\n";
    if (options.submit) return submit(path, tasks, collectCommand);
    std::cout << "submit it with: sbatch " << path << "\nthen, when it has finished: " << collectCommand << "\n";
    return 0;
}

}  // namespace

int runBatch(const BatchCliOptions& options) {
    try {
        if (const std::string problem = clusterOptionsProblem(options); !problem.empty()) throw InputError(problem);
        const BatchPlan plan = loadBatchPlan(options.planPath);
        BatchOptions batchOptions;
        batchOptions.force = options.force;
        batchOptions.failFast = options.failFast;
        if (options.threads >= 0) batchOptions.threads = options.threads;
        batchOptions.commandLine = options.commandLine;
        batchOptions.startedAt = options.startedAt.empty() ? batchTimestamp() : options.startedAt;
        batchOptions.stopRequested = &stopRequested;
        if (options.collect) return collect(plan);
        if (options.slurm) return writeScript(options, plan, batchOptions);
        if (options.task != BatchCliOptions::kNoTask) {
            const auto runsPerTask = static_cast<std::size_t>(options.runsPerTask);
            const std::size_t tasks = batchTaskCount(plan.runs.size(), runsPerTask);
            if (options.task < 0 || static_cast<std::size_t>(options.task) >= tasks)
                throw InputError("batch: --task " + std::to_string(options.task) + " is out of range: " +
                                 std::to_string(plan.runs.size()) + " runs in tasks of " +
                                 std::to_string(runsPerTask) + " make tasks 0 to " +
                                 std::to_string(static_cast<long long>(tasks) - 1));
            const auto task = static_cast<std::size_t>(options.task);
            batchOptions.firstRun = task * runsPerTask;
            batchOptions.runCount = runsPerTask;
            batchOptions.tableBase = batchTaskTableBase(plan, task);
        }
        installSigintHandler();

        if (!options.worker.empty()) {
            const auto slash = options.worker.find('/');
            batchOptions.workerIndex = std::stoi(options.worker.substr(0, slash));
            batchOptions.workerCount = std::stoi(options.worker.substr(slash + 1));
            batchOptions.writeHeader = false;
        } else if (options.jobs > 1) {
            // Every run is checked before any process starts rendering.
            validateBatchPlan(plan, batchOptions.threads);
            prepareBatchOutput(plan, batchOptions.tableBase);
            return runWorkers(options, plan, batchOptions);
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
                      << " failed; results in " << batchTableBase(plan, batchOptions) << ".csv\n";
        return summary.failed > 0 ? kFailedRunExit : 0;
    } catch (const InputError& e) {
        std::cerr << oneLine(e.what()) << "\n";
        return kInputErrorExit;
    }
}

}  // namespace fg::cli
