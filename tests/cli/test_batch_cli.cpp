// End-to-end tests of `fluxgraph batch`: the real binary on small plans. Exit
// codes (0, 1 for a failed run, 2 with one line naming plan:line for a
// malformed plan, 130 after Ctrl-C), the results table, resuming, and that
// --jobs N (worker processes) renders the same pixels as one process.
#include "engine/image/image_io.h"

#include "tests/support/batch_fixtures.h"

#include <gtest/gtest.h>

#include <fcntl.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdlib>
#include <filesystem>
#include <fstream>
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

fs::path scratchDirectory() { return test::scratchDirectory("cli-batch"); }

const auto lines = test::fileLines;
const auto writeJobs = test::writeBatchJobs;
const char* const kTinySet = test::kTinyBatchSet;

std::size_t countStatus(const std::vector<std::string>& rows, const std::string& status) {
    return static_cast<std::size_t>(std::count_if(rows.begin(), rows.end(), [&](const std::string& row) {
        return row.find("," + status + ",") != std::string::npos;
    }));
}

void expectPlanError(const CommandResult& r, const std::string& prefix) {
    EXPECT_EQ(r.exitCode, 2) << r.err;
    EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1) << r.err;
    EXPECT_EQ(r.err.rfind(prefix, 0), 0u) << r.err;
}

TEST(BatchCli, RendersPlanResumesAndRerunsOnlyDeletedRuns) {
    const fs::path dir = scratchDirectory();
    writeJobs(dir);
    writeText(dir / "plan.toml", std::string("output = \"out\"\njobs = [\"jobs/*/pt.toml\"]\n") + kTinySet +
                                     "[[sweep]]\njob = \"jobs/a/pt.toml\"\nset = { \"passes.pt.max_depth\" = [1, 2], \"seed\" = [1, 2] }\n");
    CommandResult r = runFluxgraph(dir, {"batch", "plan.toml"});
    ASSERT_EQ(r.exitCode, 0) << r.err;
    EXPECT_NE(r.out.find("6 ok, 0 skipped, 0 failed"), std::string::npos) << r.out;
    std::vector<std::string> csv = lines(dir / "out/results.csv");
    ASSERT_EQ(csv.size(), 7u);
    EXPECT_EQ(countStatus(csv, "ok"), 6u);
    EXPECT_TRUE(fs::exists(dir / "out/jobs-a-pt--pt.max_depth=2--seed=1.exr"));
    EXPECT_TRUE(fs::exists(dir / "out/jobs-b-pt.png"));

    r = runFluxgraph(dir, {"batch", "plan.toml"});
    ASSERT_EQ(r.exitCode, 0) << r.err;
    EXPECT_NE(r.out.find("0 ok, 6 skipped, 0 failed"), std::string::npos) << r.out;

    fs::remove(dir / "out/jobs-a-pt--pt.max_depth=2--seed=1.exr");
    r = runFluxgraph(dir, {"batch", "plan.toml"});
    ASSERT_EQ(r.exitCode, 0) << r.err;
    EXPECT_NE(r.out.find("1 ok, 5 skipped, 0 failed"), std::string::npos) << r.out;
    csv = lines(dir / "out/results.csv");
    ASSERT_EQ(csv.size(), 19u);
    EXPECT_EQ(countStatus(csv, "ok"), 7u);

    r = runFluxgraph(dir, {"batch", "plan.toml", "--force", "--jobs", "2"});
    ASSERT_EQ(r.exitCode, 0) << r.err;
    EXPECT_EQ(lines(dir / "out/results.csv").size(), 25u);
}

TEST(BatchCli, WorkerProcessesRenderTheSamePixels) {
    const fs::path dir = scratchDirectory();
    writeJobs(dir);
    const std::string sweep = std::string(kTinySet) + "[[sweep]]\njob = \"jobs/a/pt.toml\"\nset = { \"seed\" = [1, 2, 3] }\n";
    writeText(dir / "one.toml", "output = \"one\"\n" + sweep);
    writeText(dir / "three.toml", "output = \"three\"\n" + sweep);
    ASSERT_EQ(runFluxgraph(dir, {"batch", "one.toml", "--threads", "2"}).exitCode, 0);
    const CommandResult r = runFluxgraph(dir, {"batch", "three.toml", "--jobs", "3"});
    ASSERT_EQ(r.exitCode, 0) << r.err;
    EXPECT_EQ(lines(dir / "three/results.csv").size(), 4u);
    for (const char* name : {"jobs-a-pt--seed=1.exr", "jobs-a-pt--seed=2.exr", "jobs-a-pt--seed=3.exr"}) {
        const ImageChannels a = readExr((dir / "one" / name).string());
        const ImageChannels b = readExr((dir / "three" / name).string());
        ASSERT_EQ(a.rgb.size(), b.rgb.size()) << name;
        EXPECT_TRUE(std::equal(a.rgb.begin(), a.rgb.end(), b.rgb.begin())) << name;
    }
}

TEST(BatchCli, FailedRunIsRecordedAndTheOthersFinish) {
    const fs::path dir = scratchDirectory();
    writeJobs(dir);
    writeText(dir / "plan.toml",
              std::string("output = \"out\"\njobs = [\"broken/pt.toml\", \"jobs/*/pt.toml\"]\n") + kTinySet);
    CommandResult r = runFluxgraph(dir, {"batch", "plan.toml"});
    EXPECT_EQ(r.exitCode, 1) << r.err;
    std::vector<std::string> csv = lines(dir / "out/results.csv");
    ASSERT_EQ(csv.size(), 4u);
    EXPECT_NE(csv[1].find(",failed,"), std::string::npos) << csv[1];
    EXPECT_EQ(countStatus(csv, "ok"), 2u);

    r = runFluxgraph(dir, {"batch", "plan.toml", "--fail-fast", "--force"});
    EXPECT_EQ(r.exitCode, 1) << r.err;
    EXPECT_EQ(lines(dir / "out/results.csv").size(), 5u);  // stopped after the failed first run
}

TEST(BatchCli, MalformedPlansExitTwoNamingThePlanLine) {
    const fs::path dir = scratchDirectory();
    writeJobs(dir);
    const auto check = [&](const std::string& text, int line) {
        writeText(dir / "plan.toml", text);
        expectPlanError(runFluxgraph(dir, {"batch", "plan.toml"}), "plan.toml:" + std::to_string(line) + ": ");
        EXPECT_FALSE(fs::exists(dir / "out")) << text;
    };
    check("output = \"out\"\njobs = [\"jobs/a/pt.toml\"]\nthreads = 3\n", 3);
    check("output = \"out\"\njobs = [\"nothing/*.toml\"]\n", 2);
    check("output = \"out\"\n[[sweep]]\njob = \"jobs/a/pt.toml\"\nset = { \"passes.pt.spp\" = [] }\n", 4);
    check("output = \"out\"\n[[sweep]]\njob = \"jobs/a/pt.toml\"\nset = { \"passes.pt.no_such\" = [1, 2] }\n", 4);
    check("output = \"out\"\n[[sweep]]\njob = \"jobs/*/pt.toml\"\nset = { \"passes.nope.spp\" = [1] }\n", 4);
    expectPlanError(runFluxgraph(dir, {"batch", "missing.toml"}), "missing.toml: ");
}

// The cluster side without a cluster: the tasks of a job array run here one
// after another, each into its own table, and --collect merges them.
TEST(BatchCli, TasksWriteTheirOwnTablesAndCollectMergesThemInRunOrder) {
    const fs::path dir = scratchDirectory();
    writeJobs(dir);
    writeText(dir / "plan.toml", std::string("output = \"out\"\n") + kTinySet +
                                     "[[sweep]]\njob = \"jobs/a/pt.toml\"\nset = { \"seed\" = [1, 2, 3, 4, 5] }\n");
    CommandResult r = runFluxgraph(dir, {"batch", "plan.toml", "--slurm", "--runs-per-task", "2", "--partition", "debug"});
    ASSERT_EQ(r.exitCode, 0) << r.err;
    const std::string script = readText(dir / "out/batch.sbatch");
    EXPECT_NE(script.find("#SBATCH --array=0-2\n"), std::string::npos) << script;
    EXPECT_NE(script.find("#SBATCH --partition=debug\n"), std::string::npos) << script;
    EXPECT_NE(script.find("plan.toml' --task \"$SLURM_ARRAY_TASK_ID\" --runs-per-task 2\n"), std::string::npos) << script;
    EXPECT_NE(r.out.find("sbatch " + fs::absolute(dir / "out/batch.sbatch").lexically_normal().string()), std::string::npos)
        << r.out;
    EXPECT_TRUE(fs::is_directory(dir / "out/tasks"));

    ASSERT_EQ(runFluxgraph(dir, {"batch", "plan.toml", "--task", "2", "--runs-per-task", "2"}).exitCode, 0);
    EXPECT_EQ(lines(dir / "out/tasks/task-2.csv").size(), 2u);  // header and run 4
    r = runFluxgraph(dir, {"batch", "plan.toml", "--collect"});
    EXPECT_EQ(r.exitCode, 1) << r.err;
    EXPECT_NE(r.out.find("collected 1 of 5 runs"), std::string::npos) << r.out;
    EXPECT_NE(r.out.find("; 4 missing"), std::string::npos) << r.out;

    ASSERT_EQ(runFluxgraph(dir, {"batch", "plan.toml", "--task", "1", "--runs-per-task", "2"}).exitCode, 0);
    ASSERT_EQ(runFluxgraph(dir, {"batch", "plan.toml", "--task", "0", "--runs-per-task", "2"}).exitCode, 0);
    // A rerun task appends its rows again; the merged table keeps one per run.
    ASSERT_EQ(runFluxgraph(dir, {"batch", "plan.toml", "--task", "0", "--runs-per-task", "2", "--force"}).exitCode, 0);
    EXPECT_EQ(lines(dir / "out/tasks/task-0.csv").size(), 5u);
    r = runFluxgraph(dir, {"batch", "plan.toml", "--collect"});
    EXPECT_EQ(r.exitCode, 0) << r.out << r.err;
    EXPECT_NE(r.out.find("collected 5 of 5 runs"), std::string::npos) << r.out;
    const std::vector<std::string> csv = lines(dir / "out/results.csv");
    ASSERT_EQ(csv.size(), 6u);
    EXPECT_EQ(csv[0].rfind("batch_started,run,", 0), 0u);
    for (int seed = 1; seed <= 5; ++seed)
        EXPECT_NE(csv[seed].find(",jobs-a-pt--seed=" + std::to_string(seed) + ","), std::string::npos) << csv[seed];
    EXPECT_EQ(countStatus(csv, "ok"), 5u);
    EXPECT_EQ(lines(dir / "out/results.jsonl").size(), 5u);
    EXPECT_FALSE(fs::exists(dir / "out/results.csv.collecting"));
}

TEST(BatchCli, MalformedClusterOptionsExitTwoWithOneLine) {
    const fs::path dir = scratchDirectory();
    writeJobs(dir);
    writeText(dir / "plan.toml", std::string("output = \"out\"\njobs = [\"jobs/*/pt.toml\"]\n") + kTinySet);
    expectPlanError(runFluxgraph(dir, {"batch", "plan.toml", "--task", "2"}), "batch: --task 2 is out of range");
    expectPlanError(runFluxgraph(dir, {"batch", "plan.toml", "--task", "1", "--runs-per-task", "2"}),
                    "batch: --task 1 is out of range");
    expectPlanError(runFluxgraph(dir, {"batch", "plan.toml", "--task", "0", "--runs-per-task", "0"}),
                    "batch: --runs-per-task must be at least 1");
    expectPlanError(runFluxgraph(dir, {"batch", "plan.toml", "--slurm", "--runs-per-task", "-1"}),
                    "batch: --runs-per-task must be at least 1");
    expectPlanError(runFluxgraph(dir, {"batch", "plan.toml", "--slurm", "--task", "0"}), "batch: --task ");
    expectPlanError(runFluxgraph(dir, {"batch", "plan.toml", "--collect", "--task", "0"}), "batch: --collect ");
    expectPlanError(runFluxgraph(dir, {"batch", "plan.toml", "--submit"}), "batch: --submit");
    expectPlanError(runFluxgraph(dir, {"batch", "plan.toml", "--slurm", "--time", "1h; rm"}), "batch: --time ");
    EXPECT_FALSE(fs::exists(dir / "out"));
}

// Starts the binary in the background, sends SIGINT once the first row is in
// the table, and checks that what is left is whole and consistent.
TEST(BatchCli, SigintStopsAfterWholeRowsAndExits130) {
    const fs::path dir = scratchDirectory();
    writeJobs(dir);
    std::string seeds;
    for (int s = 1; s <= 200; ++s) seeds += (s > 1 ? ", " : "") + std::to_string(s);
    writeText(dir / "plan.toml", "output = \"out\"\nset = { \"film.width\" = 32, \"film.height\" = 32, \"passes.pt.spp\" = 8 }\n"
                                 "[[sweep]]\njob = \"jobs/a/pt.toml\"\nset = { seed = [" + seeds + "] }\n");
    const std::string binary = FLUXGRAPH_BINARY;
    const std::string logPath = (dir / "stderr").string();
    const pid_t pid = ::fork();
    ASSERT_GE(pid, 0);
    if (pid == 0) {
        if (::chdir(dir.c_str()) != 0) ::_exit(126);
        const int log = ::open(logPath.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
        ::dup2(log, STDOUT_FILENO);
        ::dup2(log, STDERR_FILENO);
        ::execl(binary.c_str(), binary.c_str(), "batch", "plan.toml", "--threads", "1", static_cast<char*>(nullptr));
        ::_exit(127);
    }
    const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(60);
    while (lines(dir / "out/results.csv").size() < 2 && std::chrono::steady_clock::now() < deadline)
        std::this_thread::sleep_for(std::chrono::milliseconds(2));
    ::kill(pid, SIGINT);
    int status = 0;
    ASSERT_EQ(::waitpid(pid, &status, 0), pid);
    ASSERT_TRUE(WIFEXITED(status)) << readText(logPath);
    EXPECT_EQ(WEXITSTATUS(status), 130) << readText(logPath);

    const std::string csvText = readText(dir / "out/results.csv");
    const std::string jsonText = readText(dir / "out/results.jsonl");
    ASSERT_FALSE(csvText.empty());
    EXPECT_EQ(csvText.back(), '\n');
    EXPECT_TRUE(jsonText.empty() || jsonText.back() == '\n');
    const std::vector<std::string> csv = lines(dir / "out/results.csv");
    ASSERT_GE(csv.size(), 2u);
    EXPECT_LT(csv.size(), 201u) << "the batch was not interrupted";
    EXPECT_EQ(lines(dir / "out/results.jsonl").size(), csv.size() - 1);
    for (std::size_t i = 1; i < csv.size(); ++i) {
        EXPECT_NE(csv[i].find(",ok,"), std::string::npos) << csv[i];
        const std::string run = "jobs-a-pt--seed=" + std::to_string(i);
        EXPECT_NE(csv[i].find("," + run + ","), std::string::npos) << csv[i];
        EXPECT_TRUE(fs::exists(dir / "out" / (run + ".exr"))) << run;
    }
    // No temporaries and no image without a row.
    std::size_t images = 0;
    for (const auto& entry : fs::directory_iterator(dir / "out")) {
        const std::string name = entry.path().filename().string();
        EXPECT_NE(name.front(), '.') << name;
        images += entry.path().extension() == ".exr" ? 1 : 0;
    }
    EXPECT_EQ(images, csv.size() - 1);

    // Resuming renders only what is missing.
    const CommandResult r = runFluxgraph(dir, {"batch", "plan.toml", "--threads", "1"});
    EXPECT_EQ(r.exitCode, 0) << r.err;
    EXPECT_NE(r.out.find(std::to_string(csv.size() - 1) + " skipped"), std::string::npos) << r.out;
}

}  // namespace
}  // namespace fg
