// Batch plans and the in-process batch runner: plan expansion (globs, the
// cartesian product of a sweep, output names), the errors a malformed plan
// gives (one line naming the plan's line), resuming, failed runs and the
// results table. Every render is tiny: 16x16 pixels, 1 sample per pixel.
#include "engine/run/batch.h"

#include "engine/core/codec.h"
#include "engine/core/error.h"
#include "engine/image/film.h"
#include "engine/image/image_io.h"
#include "passes/passes.h"
#include "tests/support/batch_fixtures.h"
#include "tests/support/pass_helpers.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

namespace fg {
namespace {

namespace fs = std::filesystem;

using test::writeText;
const auto lines = test::fileLines;
const auto writeJobs = test::writeBatchJobs;
const char* const kTinySet = test::kTinyBatchSet;

fs::path scratchDirectory() { return test::scratchDirectory("batch"); }
std::string cornellScene() { return test::sourcePath("data/cornell-box/cornell-box.toml"); }

// Globbed jobs plus a 2x2 sweep: 6 runs.
fs::path writePlan(const fs::path& dir, const std::string& extra = "") {
    const fs::path plan = dir / "plan.toml";
    writeText(plan, "output = \"" + (dir / "out").string() + "\"\njobs = [\"jobs/*/pt.toml\"]\n" + kTinySet +
                        "[[sweep]]\njob = \"jobs/a/pt.toml\"\n" + extra +
                        "set = { \"passes.pt.max_depth\" = [1, 2], \"seed\" = [1, 2] }\n");
    return plan;
}

std::size_t countStatus(const std::vector<std::string>& rows, const std::string& status) {
    return static_cast<std::size_t>(std::count_if(rows.begin(), rows.end(), [&](const std::string& row) {
        return row.find("," + status + ",") != std::string::npos;
    }));
}

class BatchTest : public ::testing::Test {
protected:
    void SetUp() override { installRegistry(&builtinRegistry()); }
};

TEST_F(BatchTest, PlanExpandsGlobsAndTheCartesianProduct) {
    const fs::path dir = scratchDirectory();
    writeJobs(dir);
    const BatchPlan plan = loadBatchPlan(writePlan(dir).string());
    ASSERT_EQ(plan.runs.size(), 6u);
    std::vector<std::string> names;
    for (const BatchRun& run : plan.runs) names.push_back(run.name);
    EXPECT_EQ(names, (std::vector<std::string>{"jobs-a-pt", "jobs-b-pt", "jobs-a-pt--pt.max_depth=1--seed=1",
                                               "jobs-a-pt--pt.max_depth=1--seed=2", "jobs-a-pt--pt.max_depth=2--seed=1",
                                               "jobs-a-pt--pt.max_depth=2--seed=2"}));
    // Plan-wide values first, then the sweep's (each in key order); the sweep's value wins.
    EXPECT_EQ(plan.runs[3].sets.back(), "seed=2");
    EXPECT_EQ(plan.runs[3].sets.front(), "film.height=16");
    EXPECT_EQ(plan.runs[0].origin, (dir / "plan.toml").string() + ":2");
    EXPECT_EQ(validateBatchPlan(plan).size(), 6u);
}

TEST_F(BatchTest, StringValuesAreQuotedForTheJobAndPlainInNames) {
    const fs::path dir = scratchDirectory();
    writeJobs(dir);
    writeText(dir / "plan.toml", "output = \"out\"\n[[sweep]]\njob = \"jobs/a/pt.toml\"\nset = { \"film.filter\" = [\"box\", \"gaussian\"] }\n");
    const BatchPlan plan = loadBatchPlan((dir / "plan.toml").string());
    ASSERT_EQ(plan.runs.size(), 2u);
    EXPECT_EQ(plan.runs[0].sets, std::vector<std::string>{"film.filter='box'"});
    EXPECT_EQ(plan.runs[0].name, "jobs-a-pt--film.filter=box");
    EXPECT_EQ(validateBatchPlan(plan).size(), 2u);
}

// The message must start with "plan.toml:LINE: ".
void expectPlanError(const fs::path& dir, const std::string& text, int line, const std::string& fragment) {
    const fs::path plan = dir / "plan.toml";
    writeText(plan, text);
    try {
        validateBatchPlan(loadBatchPlan(plan.string()));
        ADD_FAILURE() << "no error for:\n" << text;
    } catch (const InputError& e) {
        const std::string message = e.what();
        EXPECT_EQ(message.rfind(plan.string() + ":" + std::to_string(line) + ": ", 0), 0u) << message;
        EXPECT_NE(message.find(fragment), std::string::npos) << message;
        EXPECT_EQ(message.find('\n'), std::string::npos) << message;
    }
}

TEST_F(BatchTest, MalformedPlansNameThePlanLine) {
    const fs::path dir = scratchDirectory();
    writeJobs(dir);
    expectPlanError(dir, "output = \"out\"\njobs = [\"jobs/a/pt.toml\"]\ncolour = 3\n", 3, "unknown key 'colour'");
    expectPlanError(dir, "output = \"out\"\n[[sweep]]\njob = \"jobs/a/pt.toml\"\nlabel = \"x\"\n", 4,
                    "unknown key 'sweep.label'");
    expectPlanError(dir, "output = \"out\"\njobs = [\"nothing/*/pt.toml\"]\n", 2, "matches no file");
    expectPlanError(dir, "output = \"out\"\n[[sweep]]\njob = \"jobs/a/pt.toml\"\nset = { seed = [] }\n", 4,
                    "empty list");
    expectPlanError(dir, "output = \"out\"\n[[sweep]]\njob = \"jobs/a/pt.toml\"\n\nset = { \"passes.pt.sppp\" = [1, 2] }\n",
                    5, "sppp");
    expectPlanError(dir, "output = \"out\"\n[[sweep]]\njob = \"jobs/a/pt.toml\"\nset = { \"passes.pt.spp\" = [0] }\n", 4,
                    "spp");
    expectPlanError(dir, "output = \"out\"\njobs = [\"jobs/a/pt.toml\",\n  \"jobs/a/pt.toml\"]\n", 3, "already in the plan");
    expectPlanError(dir, "output = \"out\"\njobs = [\"jobs/a/nope.toml\"]\n", 2, "cannot open job file");
    expectPlanError(dir, "output = \"out\"\n[[sweep]]\njob = \"jobs/a/pt.toml\"\nreference = \"ref.exr\"\n", 4,
                    "does not exist");
}

// Nothing in a batch saves buffers, so a job's imported files are checked
// with the plan, as validate checks them: a missing file or one cut short is
// a plan error naming the run's line and the file, before anything renders.
TEST_F(BatchTest, ImportedFilesAreCheckedWithThePlan) {
    const fs::path dir = scratchDirectory();
    FilmSettings settings;
    settings.width = settings.height = 16;
    auto film = std::make_shared<Film>(settings);
    fs::create_directories(dir / "jobs");
    saveBuffer(test::makeBuffer(film), (dir / "jobs" / "image.fgbuf").string(), "");
    const std::string bytes = test::readText(dir / "jobs" / "image.fgbuf");
    writeText(dir / "jobs" / "short.fgbuf", bytes.substr(0, bytes.size() - 1));
    const auto job = [&](const std::string& file) {
        writeText(dir / "jobs" / "imports.toml", "scene = \"" + cornellScene() +
                                                     "\"\npipeline = \"pt\"\n[import]\nimage = \"" + file + "\"\n");
    };
    const std::string plan = "output = \"out\"\n" + std::string(kTinySet) + "jobs = [\"jobs/imports.toml\"]\n";
    job("image.fgbuf");
    writeText(dir / "plan.toml", plan);
    EXPECT_EQ(validateBatchPlan(loadBatchPlan((dir / "plan.toml").string())).size(), 1u);
    job("short.fgbuf");
    expectPlanError(dir, plan, 3, (dir / "jobs" / "short.fgbuf").string() + ": truncated buffer file");
    job("missing.fgbuf");
    expectPlanError(dir, plan, 3, (dir / "jobs" / "missing.fgbuf").string() + ": cannot open buffer file");
    EXPECT_FALSE(fs::exists(dir / "out"));
}

TEST_F(BatchTest, RerunSkipsFinishedRunsAndRendersOnlyMissingOnes) {
    const fs::path dir = scratchDirectory();
    writeJobs(dir);
    const BatchPlan plan = loadBatchPlan(writePlan(dir).string());
    const fs::path out = dir / "out";

    BatchSummary first = runBatch(plan, {});
    EXPECT_EQ(first.ok, 6);
    EXPECT_EQ(first.failed, 0);
    for (const BatchRun& run : plan.runs) {
        EXPECT_TRUE(fs::exists(out / (run.name + ".exr"))) << run.name;
        EXPECT_TRUE(fs::exists(out / (run.name + ".png"))) << run.name;
    }
    std::vector<std::string> csv = lines(out / kBatchCsvName);
    ASSERT_EQ(csv.size(), 7u);
    EXPECT_EQ(csv[0].rfind("batch_started,run,job,overrides,seed,threads,status,error,", 0), 0u) << csv[0];
    EXPECT_EQ(countStatus(csv, "ok"), 6u);
    EXPECT_EQ(lines(out / kBatchJsonlName).size(), 6u);

    const BatchSummary second = runBatch(plan, {});
    EXPECT_EQ(second.skipped, 6);
    EXPECT_EQ(second.ok, 0);
    csv = lines(out / kBatchCsvName);
    ASSERT_EQ(csv.size(), 13u);  // one header, one row per run per invocation
    EXPECT_EQ(countStatus(csv, "skipped"), 6u);

    fs::remove(out / (plan.runs[4].name + ".exr"));
    const BatchSummary third = runBatch(plan, {});
    EXPECT_EQ(third.ok, 1);
    EXPECT_EQ(third.skipped, 5);
    csv = lines(out / kBatchCsvName);
    ASSERT_EQ(csv.size(), 19u);
    EXPECT_NE(csv[17].find("," + plan.runs[4].name + ","), std::string::npos) << csv[17];  // rows 13..18, in plan order
    EXPECT_NE(csv[17].find(",ok,"), std::string::npos) << csv[17];

    BatchOptions force;
    force.force = true;
    EXPECT_EQ(runBatch(plan, force).ok, 6);
}

TEST_F(BatchTest, ChangedOverridesOrJobTextAreRenderedAgain) {
    const fs::path dir = scratchDirectory();
    writeJobs(dir);
    EXPECT_EQ(runBatch(loadBatchPlan(writePlan(dir).string()), {}).ok, 6);
    writeText(dir / "jobs/b/pt.toml", "scene = \"" + cornellScene() + "\"\npipeline = \"pt\"\nseed = 7\n");
    const BatchSummary summary = runBatch(loadBatchPlan((dir / "plan.toml").string()), {});
    EXPECT_EQ(summary.ok, 1);  // only jobs/b/pt.toml changed
    EXPECT_EQ(summary.skipped, 5);
}

TEST_F(BatchTest, FailedRunIsRecordedAndTheOthersFinish) {
    const fs::path dir = scratchDirectory();
    writeJobs(dir);
    writeText(dir / "plan.toml", "output = \"" + (dir / "out").string() +
                                     "\"\njobs = [\"jobs/a/pt.toml\", \"broken/pt.toml\", \"jobs/b/pt.toml\"]\n" + kTinySet);
    const BatchPlan plan = loadBatchPlan((dir / "plan.toml").string());
    const BatchSummary summary = runBatch(plan, {});
    EXPECT_EQ(summary.ok, 2);
    EXPECT_EQ(summary.failed, 1);
    EXPECT_FALSE(summary.interrupted);
    const std::vector<std::string> csv = lines(dir / "out" / kBatchCsvName);
    ASSERT_EQ(csv.size(), 4u);
    EXPECT_NE(csv[2].find(",failed,"), std::string::npos) << csv[2];
    EXPECT_NE(csv[2].find("no-such-scene.toml"), std::string::npos) << csv[2];
    const std::vector<std::string> json = lines(dir / "out" / kBatchJsonlName);
    ASSERT_EQ(json.size(), 3u);
    EXPECT_NE(json[1].find("\"status\": \"failed\""), std::string::npos) << json[1];

    BatchOptions failFast;
    failFast.failFast = true;
    failFast.force = true;
    const BatchSummary stopped = runBatch(plan, failFast);
    EXPECT_EQ(stopped.ok, 1);
    EXPECT_EQ(stopped.failed, 1);
    EXPECT_TRUE(stopped.interrupted);
}

TEST_F(BatchTest, RowsCarryPassStatisticsAndReferenceMetrics) {
    const fs::path dir = scratchDirectory();
    writeJobs(dir);
    ImageChannels grey;
    grey.width = grey.height = 16;
    grey.rgb.assign(256, Rgb(0.25f));
    writeExr((dir / "ref.exr").string(), grey, {});
    const BatchPlan plan = loadBatchPlan(writePlan(dir, "reference = \"ref.exr\"\n").string());
    EXPECT_EQ(runBatch(plan, {}).ok, 6);
    const std::vector<std::string> json = lines(dir / "out" / kBatchJsonlName);
    ASSERT_EQ(json.size(), 6u);
    EXPECT_EQ(json[0].find("\"rmse\""), std::string::npos) << json[0];  // globbed jobs have no reference
    for (std::size_t i = 2; i < 6; ++i) {
        for (const char* key : {"\"rmse\": ", "\"relmse\": ", "\"mae\": ", "\"ssim\": ", "\"psnr\": ", "\"passes\": [{\"instance\": \"pt\"",
                                "\"counters\": {", "\"peak_rss_kib\": ", "\"seed\": "})
            EXPECT_NE(json[i].find(key), std::string::npos) << key << " in " << json[i];
    }
    // The CSV's metric columns are filled for the sweep's rows.
    const std::vector<std::string> csv = lines(dir / "out" / kBatchCsvName);
    ASSERT_EQ(csv.size(), 7u);
    const auto columns = [](const std::string& row) { return std::count(row.begin(), row.end(), ',') + 1; };
    EXPECT_EQ(static_cast<std::size_t>(columns(csv[0])), batchCsvColumns().size());
    EXPECT_FALSE(csv[3].ends_with(",,,,")) << csv[3];
}

TEST_F(BatchTest, WorkersSplitTheRunsBetweenThem) {
    const fs::path dir = scratchDirectory();
    writeJobs(dir);
    const BatchPlan plan = loadBatchPlan(writePlan(dir).string());
    BatchOptions first, second;
    first.workerCount = second.workerCount = 2;
    second.workerIndex = 1;
    second.writeHeader = false;
    EXPECT_EQ(runBatch(plan, first).ok, 3);
    EXPECT_EQ(runBatch(plan, second).ok, 3);
    EXPECT_EQ(lines(dir / "out" / kBatchCsvName).size(), 7u);
}

}  // namespace
}  // namespace fg
