// The `scale` subcommand: measures a job's thread scaling with
// engine/run/scale.h, prints the table, writes the CSV and, if asked, has
// tools/plot_scaling.py draw the speed-up curves. A missing plot script or
// matplotlib costs one line and no exit code: the CSV holds the measurements.
// Images that differ between runs are a defect of the engine (it promises
// bit-identical images at any thread count), so they are reported loudly and
// end with exit code 3.
#include "engine/cli/scale.h"

#include "engine/core/error.h"
#include "engine/core/job.h"
#include "engine/core/output_files.h"
#include "engine/run/scale.h"

#include <CLI/CLI.hpp>

#include <cstdio>
#include <filesystem>
#include <iostream>
#include <thread>
#include <unistd.h>

namespace fg::cli {

namespace {

namespace fs = std::filesystem;

constexpr int kInputErrorExit = 2;
constexpr int kImagesDifferExit = 3;

std::string oneLine(std::string message) {
    for (char& c : message)
        if (c == '\n' || c == '\r') c = ' ';
    while (!message.empty() && message.back() == ' ') message.pop_back();
    return printableMessage(message);
}

std::string shellQuote(const std::string& word) {
    std::string quoted = "'";
    for (char c : word) quoted += c == '\'' ? std::string("'\\''") : std::string(1, c);
    return quoted + "'";
}

// 1, 2, 4, ... up to the hardware threads, which are included even when not a power of two.
std::vector<int> defaultThreadCounts() {
    const int hardware = std::max(1, static_cast<int>(std::thread::hardware_concurrency()));
    std::vector<int> counts;
    for (int n = 1; n < hardware; n *= 2) counts.push_back(n);
    counts.push_back(hardware);
    return counts;
}

// The script lives in the source tree; an installed binary may have it beside itself.
std::string findPlotScript() {
    std::vector<fs::path> candidates = {fs::path(FLUXGRAPH_SOURCE_DIR) / "tools" / "plot_scaling.py"};
    std::error_code ec;
    const fs::path binary = fs::read_symlink("/proc/self/exe", ec);
    if (!ec) {
        candidates.push_back(binary.parent_path() / "plot_scaling.py");
        candidates.push_back(binary.parent_path().parent_path() / "tools" / "plot_scaling.py");
    }
    for (const fs::path& candidate : candidates)
        if (fs::is_regular_file(candidate, ec)) return candidate.string();
    return {};
}

// Debian's interpreter is the one python3-matplotlib installs into; a python3
// earlier on PATH (pyenv, a virtualenv) may lack it.
std::string pythonInterpreter() {
    std::error_code ec;
    return fs::exists("/usr/bin/python3", ec) ? "/usr/bin/python3" : "python3";
}

// Runs the plot script; returns "" on success, else why it failed (one line).
std::string drawPlot(const std::string& csvPath, const std::string& plotPath) {
    const std::string script = findPlotScript();
    if (script.empty()) return "tools/plot_scaling.py not found";
    const std::string command = shellQuote(pythonInterpreter()) + " " + shellQuote(script) + " " +
                                shellQuote(csvPath) + " " + shellQuote(plotPath) + " 2>&1";
    FILE* pipe = ::popen(command.c_str(), "r");
    if (!pipe) return "cannot start " + pythonInterpreter();
    std::string output;
    char buffer[512];
    while (std::fgets(buffer, sizeof buffer, pipe)) output += buffer;
    const int status = ::pclose(pipe);
    if (status == 0) return {};
    // The script's last line says why (e.g. matplotlib missing); tracebacks end with the error.
    while (!output.empty() && (output.back() == '\n' || output.back() == ' ')) output.pop_back();
    const std::size_t lastLine = output.rfind('\n');
    const std::string reason = lastLine == std::string::npos ? output : output.substr(lastLine + 1);
    return reason.empty() ? script + " failed" : reason;
}

void writeCsv(const std::string& path, const std::string& text) {
    writeAtomically(path, [&](const std::string& temporary) { writeFileChecked(path, temporary, text); });
}

}  // namespace

CLI::App* addScaleSubcommand(CLI::App& app, ScaleOptions& options) {
    CLI::App* scale = app.add_subcommand("scale", "render a job at several thread counts: speed-up, efficiency, Amdahl fit");
    scale->add_option("job", options.jobPath, "job file (TOML)")->required();
    scale->add_option("--set", options.sets, "override a job value, e.g. passes.pt.spp=64 (repeatable)");
    scale->add_option("--define", options.defines, "set a parameter of a Mitsuba XML scene ($name) (repeatable)");
    scale->add_option("--threads", options.threads,
                      "thread counts, e.g. 1,2,4,8 (default: powers of two up to the hardware threads; 1 is always run)");
    scale->add_option("--repeat", options.repeat, "renders per thread count; the median is reported (default 3)");
    scale->add_option("--out", options.outDir, "output directory for the images (default: the job's)");
    scale->add_option("--csv", options.csvPath, "CSV of the measurements (default: scale.csv in the output directory)");
    scale->add_option("--plot", options.plotPath, "draw speed-up against threads as PNG (tools/plot_scaling.py)");
    scale->add_flag("--quiet,-q", options.quiet, "no progress lines");
    return scale;
}

int runScale(const ScaleOptions& options) {
    try {
        run::ScaleSettings settings;
        settings.threads = options.threads.empty() ? defaultThreadCounts() : run::parseThreadList(options.threads);
        if (options.repeat < 1)
            throw InputError("--repeat " + std::to_string(options.repeat) + ": must be at least 1");
        settings.repeat = options.repeat;
        JobOverrides overrides;
        overrides.sets = options.sets;
        overrides.defines = options.defines;
        if (!options.outDir.empty()) overrides.outputDirectory = options.outDir;

        // The destination of the CSV is checked before minutes of rendering.
        const Job job = loadJob(options.jobPath, overrides);
        const std::string csvPath =
            options.csvPath.empty() ? (fs::path(job.output.directory) / "scale.csv").string() : options.csvPath;
        std::error_code ec;
        fs::create_directories(job.output.directory, ec);
        const fs::path csvParent = fs::path(csvPath).has_parent_path() ? fs::path(csvPath).parent_path() : ".";
        if (!fs::is_directory(csvParent, ec)) throw InputError(csvPath + ": cannot write the CSV: no directory " + csvParent.string());
        if (fs::is_directory(csvPath, ec)) throw InputError(csvPath + ": cannot write the CSV: is a directory");
        if (!options.plotPath.empty()) {
            const fs::path plotParent =
                fs::path(options.plotPath).has_parent_path() ? fs::path(options.plotPath).parent_path() : ".";
            if (!fs::is_directory(plotParent, ec))
                throw InputError(options.plotPath + ": cannot write the plot: no directory " + plotParent.string());
        }

        if (!options.quiet && ::isatty(STDERR_FILENO))
            settings.progress = [](int threads, int repetition, int repeat) {
                std::cerr << "scale: " << threads << " thread" << (threads == 1 ? "" : "s") << ", run " << repetition
                          << "/" << repeat << "\n";
            };
        const run::ScaleReport report = run::measureScaling(options.jobPath, overrides, settings);
        std::cout << run::formatScaleTable(report);
        writeCsv(csvPath, run::scaleCsv(report));
        std::cout << "wrote " << csvPath << "\n";
        if (!options.plotPath.empty()) {
            const std::string failure = drawPlot(csvPath, options.plotPath);
            if (failure.empty()) std::cout << "wrote " << options.plotPath << "\n";
            else std::cout << "plot not drawn: " << oneLine(failure) << " (the CSV has the measurements)\n";
        }
        if (!report.mismatches.empty()) {
            std::cerr << "fluxgraph scale: IMAGES DIFFER BETWEEN THREAD COUNTS: the renders are not deterministic "
                         "(see the table above)\n";
            return kImagesDifferExit;
        }
        return 0;
    } catch (const InputError& e) {
        std::cerr << oneLine(e.what()) << '\n';
        return kInputErrorExit;
    }
}

}  // namespace fg::cli
