// `fluxgraph batch --slurm` on a real SLURM cluster: a private one-node cluster
// on localhost (tools/slurm_local.sh, its own munged, slurmctld and slurmd on
// free ports, every file under this test's scratch directory) runs a plan as
// a job array; the collected table and the images must equal those of a local
// batch of the same plan. Needs root and the packages slurm-wlm and munge
// (tools/install-deps.sh). A cluster that cannot start fails the test with the
// daemon's log; FLUXGRAPH_NO_SLURM_TEST=1 skips it on machines without SLURM.
#include "engine/image/image_io.h"

#include "tests/support/cli_helpers.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <set>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

namespace fg {
namespace {

namespace fs = std::filesystem;

using test::CommandResult;
using test::readText;
using test::runFluxgraph;
using test::writeText;

constexpr auto kJobTimeout = std::chrono::seconds(180);

std::string shellQuote(const std::string& word) {
    std::string quoted = "'";
    for (char c : word) quoted += c == '\'' ? std::string("'\\''") : std::string(1, c);
    return quoted + "'";
}

// Runs a shell command; its exit status and its stdout and stderr together.
std::pair<int, std::string> shell(const std::string& command) {
    FILE* pipe = ::popen((command + " 2>&1").c_str(), "r");
    if (!pipe) return {-1, "cannot run " + command};
    std::string output;
    char buffer[512];
    while (std::fgets(buffer, sizeof buffer, pipe)) output += buffer;
    return {::pclose(pipe), output};
}

// The cluster's daemons, stopped (and their directory removed) when the test
// ends however it ends. slurmd makes a Unix socket per job step in its spool
// directory, and a socket path may not exceed 108 bytes, so the cluster lives
// in a fresh directory under /tmp, not below the build tree, whose path
// depends on where the checkout is.
class LocalCluster {
public:
    LocalCluster() : directory_(freshDirectory()) {
        const auto [status, output] = shell(script() + " start " + shellQuote(directory_.string()));
        started_ = status == 0;
        output_ = output;
    }
    ~LocalCluster() {
        shell(script() + " stop " + shellQuote(directory_.string()));
        std::error_code ignored;
        fs::remove_all(directory_, ignored);
    }
    LocalCluster(const LocalCluster&) = delete;
    LocalCluster& operator=(const LocalCluster&) = delete;

    bool started() const { return started_; }
    const std::string& startOutput() const { return output_; }
    fs::path configuration() const { return directory_ / "slurm.conf"; }
    std::string logTails() const {
        std::string text;
        for (const char* log : {"slurmctld.log", "slurmd.log"})
            text += "--- tail of " + std::string(log) + ":\n" + shell("tail -n 15 " + shellQuote((directory_ / "log" / log).string())).second;
        return text;
    }

private:
    static std::string script() { return shellQuote(test::sourcePath("tools/slurm_local.sh")); }
    static fs::path freshDirectory() {
        char name[] = "/tmp/fluxgraph-slurm-XXXXXX";
        const char* made = ::mkdtemp(name);
        EXPECT_NE(made, nullptr) << "cannot create a directory under /tmp: " << std::strerror(errno);
        return made ? fs::path(made) : fs::temp_directory_path() / "fluxgraph-slurm";
    }
    fs::path directory_;
    bool started_ = false;
    std::string output_;
};

std::vector<std::string> split(const std::string& text, char separator) {
    std::vector<std::string> parts;
    std::string part;
    std::istringstream in(text);
    while (std::getline(in, part, separator)) parts.push_back(part);
    if (!text.empty() && text.back() == separator) parts.emplace_back();
    return parts;
}

void replaceAll(std::string& text, const std::string& from, const std::string& to) {
    for (std::size_t at = text.find(from); at != std::string::npos; at = text.find(from, at + to.size()))
        text.replace(at, from.size(), to);
}

// The table's rows without the columns that differ between any two runs of a
// plan (times, memory, the invocation's start) and with the plan's directory
// written as <plan>, so that the same plan in two directories compares equal.
std::vector<std::string> comparableRows(const fs::path& planDirectory) {
    static const std::set<std::string> varying = {"batch_started",       "wall_seconds",       "scene_seconds",
                                                  "accel_seconds",       "passes_seconds",     "passes_wall_seconds",
                                                  "passes_cpu_seconds",  "peak_rss_kib"};
    const std::vector<std::string> lines = split(readText(planDirectory / "out/results.csv"), '\n');
    std::vector<std::string> rows;
    if (lines.empty()) return rows;
    const std::vector<std::string> columns = split(lines.front(), ',');
    for (std::size_t i = 1; i < lines.size(); ++i) {
        if (lines[i].empty()) continue;
        EXPECT_EQ(lines[i].find('"'), std::string::npos) << "a quoted field: " << lines[i];
        const std::vector<std::string> fields = split(lines[i], ',');
        EXPECT_EQ(fields.size(), columns.size()) << lines[i];
        std::string row;
        for (std::size_t c = 0; c < std::min(fields.size(), columns.size()); ++c)
            if (!varying.count(columns[c])) row += columns[c] + "=" + fields[c] + ";";
        replaceAll(row, planDirectory.string(), "<plan>");
        rows.push_back(row);
    }
    return rows;
}

void writePlan(const fs::path& dir) {
    const std::string job = "scene = \"" + test::sourcePath("data/cornell-box/cornell-box.toml") + "\"\npipeline = \"pt\"\n";
    writeText(dir / "jobs/pt.toml", job);
    writeText(dir / "plan.toml",
              "output = \"out\"\n"
              "set = { \"film.width\" = 16, \"film.height\" = 16, \"passes.pt.spp\" = 1 }\n"
              "[[sweep]]\njob = \"jobs/pt.toml\"\nset = { \"passes.pt.max_depth\" = [2, 3], \"seed\" = [1, 2] }\n");
}

TEST(SlurmCluster, JobArrayMatchesALocalBatch) {
    if (const char* skip = std::getenv("FLUXGRAPH_NO_SLURM_TEST"); skip && std::string(skip) == "1")
        GTEST_SKIP() << "FLUXGRAPH_NO_SLURM_TEST=1";
    const auto testStart = std::chrono::steady_clock::now();
    const fs::path dir = test::scratchDirectory("cli-slurm");
    const fs::path localDir = dir / "local";
    const fs::path clusterDir = dir / "cluster";
    writePlan(localDir);
    writePlan(clusterDir);

    LocalCluster cluster;
    ASSERT_TRUE(cluster.started()) << "the local SLURM cluster did not start:\n" << cluster.startOutput();
    ::setenv("SLURM_CONF", cluster.configuration().c_str(), 1);

    // 4 runs in tasks of 3: a full task and a short last one.
    CommandResult r = runFluxgraph(clusterDir, {"batch", (clusterDir / "plan.toml").string(), "--slurm", "--submit",
                                                "--runs-per-task", "3", "--time", "00:05:00"});
    ASSERT_EQ(r.exitCode, 0) << r.out << r.err << cluster.logTails();
    EXPECT_TRUE(fs::exists(clusterDir / "out/batch.sbatch"));
    const std::string marker = "submitted job ";
    const std::size_t at = r.out.find(marker);
    ASSERT_NE(at, std::string::npos) << r.out;
    const std::string jobId = std::to_string(std::stol(r.out.substr(at + marker.size())));

    // squeue lists pending, running and completing tasks; finished ones drop out.
    const auto deadline = std::chrono::steady_clock::now() + kJobTimeout;
    std::string queue;
    for (;;) {
        const auto [status, output] = shell("squeue --noheader --jobs " + jobId);
        queue = output;
        if ((status == 0 && output.empty()) || output.find("Invalid job id") != std::string::npos) break;
        ASSERT_LT(std::chrono::steady_clock::now(), deadline)
            << "job " << jobId << " did not finish in " << kJobTimeout.count() << " s; squeue:\n" << queue << cluster.logTails();
        std::this_thread::sleep_for(std::chrono::milliseconds(250));
    }

    std::string taskLogs;
    for (const char* log : {"task-0.log", "task-1.log"})
        taskLogs += std::string("--- ") + log + ":\n" + readText(clusterDir / "out/tasks" / log);
    r = runFluxgraph(clusterDir, {"batch", "plan.toml", "--collect"});
    ASSERT_EQ(r.exitCode, 0) << r.out << r.err << taskLogs << cluster.logTails();
    EXPECT_NE(r.out.find("collected 4 of 4 runs"), std::string::npos) << r.out;
    EXPECT_NE(r.out.find("; 0 missing"), std::string::npos) << r.out;
    const std::string jsonl = readText(clusterDir / "out/results.jsonl");
    EXPECT_EQ(std::count(jsonl.begin(), jsonl.end(), '\n'), 4);

    // The tasks got the plan's absolute path; so does the local batch.
    r = runFluxgraph(localDir, {"batch", (localDir / "plan.toml").string()});
    ASSERT_EQ(r.exitCode, 0) << r.err;

    const std::vector<std::string> localRows = comparableRows(localDir);
    const std::vector<std::string> clusterRows = comparableRows(clusterDir);
    ASSERT_EQ(localRows.size(), 4u);
    EXPECT_EQ(clusterRows, localRows);

    std::size_t images = 0;
    for (const auto& entry : fs::directory_iterator(localDir / "out")) {
        if (entry.path().extension() != ".exr") continue;
        ++images;
        const fs::path name = entry.path().filename();
        const ImageChannels local = readExr(entry.path().string());
        const ImageChannels clustered = readExr((clusterDir / "out" / name).string());
        ASSERT_EQ(local.rgb.size(), clustered.rgb.size()) << name;
        EXPECT_EQ(std::memcmp(local.rgb.data(), clustered.rgb.data(), local.rgb.size() * sizeof local.rgb[0]), 0) << name;
    }
    EXPECT_EQ(images, 4u);
    EXPECT_LT(std::chrono::steady_clock::now() - testStart, std::chrono::minutes(3));
}

}  // namespace
}  // namespace fg
