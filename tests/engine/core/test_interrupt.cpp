// Interrupts and memory at the engine level: a stop request ends a pass at
// its unit boundary and a repeat block after its running iteration, with what
// was kept reported; a failed allocation names its pass; the memory check
// names the pass that needs the most; /proc figures are read correctly.
#include "engine/core/error.h"
#include "engine/core/interrupt.h"
#include "engine/core/memory.h"
#include "engine/core/render.h"
#include "engine/core/scheduler.h"
#include "jobs/parallel.h"
#include "tests/support/pass_helpers.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <new>
#include <optional>
#include <string>
#include <vector>

namespace fg {
namespace {

struct Tally {
    std::int64_t value = 0;
    std::size_t bytes() const { return sizeof(value); }
};

}  // namespace

template <>
struct BufferTypeName<Tally> {
    static constexpr const char* value = "Tally";
};

namespace {

using test::lambdaPass;

PipelineNode node(const std::string& instance, const std::string& pass, std::map<std::string, std::string> in = {},
                  std::map<std::string, std::string> out = {}) {
    return {instance, pass, std::move(in), std::move(out), 0};
}

RunResult runOnBareScene(const Pipeline& pipeline, const std::vector<PassRegistration>& registry, int threads = 0) {
    const Scene scene;
    const jobs::ThreadLimit limit(threads);
    const ExecutionPlan plan = ExecutionPlan::build(pipeline, {}, "test", registry);
    return execute(plan, scene, nullptr, RunOptions{});
}

// Every test starts and ends without a stop request: the state is process-wide.
class Interrupt : public ::testing::Test {
protected:
    void SetUp() override { resetStopState(); }
    void TearDown() override { resetStopState(); }
};

// A pass of 10 units that asks for a stop itself after its third (as the
// CLI's SIGINT handler would), then a reader of what it made.
std::vector<PassRegistration> unitRegistry() {
    return {
        lambdaPass({"units", "", {}, {{"sum", "Tally", ""}}, {}, {}, {}},
                   [](PassContext& ctx) {
                       Tally& sum = ctx.createOutput<Tally>("sum");
                       for (int unit = 1; unit <= 10; ++unit) {
                           sum.value += 1;
                           ctx.completedUnit();
                           if (unit == 3) requestStop();
                           if (unit < 10 && ctx.stopRequested()) {
                               ctx.keptPartial(ctx.instanceName() + ": " + std::to_string(unit) + " of 10 units");
                               break;
                           }
                       }
                   }),
        lambdaPass({"double", "", {{"sum", "Tally", ""}}, {{"twice", "Tally", ""}}, {}, {}, {}},
                   [](PassContext& ctx) { ctx.createOutput<Tally>("twice").value = 2 * ctx.input<Tally>("sum").value; }),
    };
}

TEST_F(Interrupt, APassStopsAtItsUnitBoundaryAndTheRestOfThePipelineRuns) {
    Pipeline pipeline;
    pipeline.name = "units";
    pipeline.nodes = {node("units", "units"), node("double", "double")};
    pipeline.results = {"twice"};
    for (int threads : {1, 2}) {
        resetStopState();
        const RunResult run = runOnBareScene(pipeline, unitRegistry(), threads);
        EXPECT_EQ(static_cast<const Tally*>(run.results.at("twice").data.get())->value, 6);
        EXPECT_EQ(run.partial, (std::vector<std::string>{"units: 3 of 10 units"}));
        EXPECT_EQ(completedUnits(), 3u);
        ASSERT_EQ(run.stats.size(), 2u) << "the statistics cover every pass that ran";
    }
}

TEST_F(Interrupt, WithoutAStopRequestNothingIsPartial) {
    Pipeline pipeline;
    pipeline.name = "plain";
    std::vector<PassRegistration> registry = {
        lambdaPass({"count", "", {}, {{"sum", "Tally", ""}}, {}, {}, {}},
                   [](PassContext& ctx) {
                       Tally& sum = ctx.createOutput<Tally>("sum");
                       for (int unit = 1; unit <= 10; ++unit) {
                           ++sum.value;
                           ctx.completedUnit();
                           if (ctx.stopRequested()) break;
                       }
                   }),
    };
    pipeline.nodes = {node("count", "count")};
    pipeline.results = {"sum"};
    const RunResult run = runOnBareScene(pipeline, registry);
    EXPECT_EQ(static_cast<const Tally*>(run.results.at("sum").data.get())->value, 10);
    EXPECT_TRUE(run.partial.empty());
    EXPECT_EQ(completedUnits(), 10u);
}

// Inside a block a pass never sees the request; the block ends after the
// iteration that was running, and its outputs are that iteration's.
TEST_F(Interrupt, ARepeatBlockStopsAfterTheRunningIteration) {
    SlotSpec previous{"previous", "Tally", ""};
    previous.optional = true;
    std::vector<PassRegistration> registry = {
        lambdaPass({"step", "", {previous}, {{"tally", "Tally", ""}}, {}, {}, {}},
                   [](PassContext& ctx) {
                       EXPECT_FALSE(ctx.stopRequested()) << "passes in blocks finish their iteration";
                       const std::int64_t value = (ctx.hasInput("previous") ? ctx.input<Tally>("previous").value : 0) + 1;
                       ctx.createOutput<Tally>("tally").value = value;
                       if (ctx.iteration() == 1) requestStop();
                   }),
    };
    Pipeline pipeline;
    pipeline.name = "loop";
    RepeatBlock block;
    block.name = "refine";
    block.count = 10;
    block.carry = {{"tally", "tally"}};
    block.nodes = {node("step", "step", {{"previous", "tally"}})};
    pipeline.blocks = {block};
    pipeline.results = {"tally"};
    for (int threads : {1, 2}) {
        resetStopState();
        const RunResult run = runOnBareScene(pipeline, registry, threads);
        EXPECT_EQ(run.iterations.at("refine"), 2);
        EXPECT_EQ(static_cast<const Tally*>(run.results.at("tally").data.get())->value, 2);
        EXPECT_EQ(run.partial, (std::vector<std::string>{"refine: 2 of 10 iterations"}));
        EXPECT_EQ(completedUnits(), 2u) << "each finished iteration is a unit";
    }
}

TEST_F(Interrupt, AFailedAllocationInAPassNamesThePass) {
    std::vector<PassRegistration> registry = {
        lambdaPass({"hog", "", {}, {{"sum", "Tally", ""}}, {}, {}, {}},
                   [](PassContext&) { throw std::bad_alloc(); }),
    };
    Pipeline pipeline;
    pipeline.name = "hog";
    pipeline.nodes = {node("greedy", "hog")};
    pipeline.results = {"sum"};
    try {
        runOnBareScene(pipeline, registry);
        FAIL() << "expected an InputError";
    } catch (const InputError& e) {
        const std::string message = e.what();
        EXPECT_EQ(message.rfind("pass 'greedy' ran out of memory", 0), 0u) << message;
        EXPECT_EQ(message.find('\n'), std::string::npos) << message;
    }
}

TEST(MemoryCheck, NamesThePassThatNeedsTheMostAndBothFigures) {
    const std::vector<PassMemory> estimates = {
        {"eye", "job.toml:4", {3u << 20, "film", {}}},
        {"photon", "job.toml:9", {7ull << 30, "1000000 photon paths", "lower `photons`"}},
    };
    EXPECT_NO_THROW(checkMemory(estimates, 8ull << 30, "MemAvailable"));
    try {
        checkMemory(estimates, 2ull << 30, "RLIMIT_AS");
        FAIL() << "expected an InputError";
    } catch (const InputError& e) {
        EXPECT_EQ(std::string(e.what()),
                  "job.toml:9: pass 'photon' needs about 7.0 GiB (1000000 photon paths), the job about 7.0 GiB in all, "
                  "but only 2.0 GiB is available (RLIMIT_AS); lower `photons`");
    }
}

// Estimates come from the pass's declared function with the job's film; a
// block pass counts for two iterations however many the block has.
TEST(MemoryCheck, EstimatesUseTheFilmAndCountTwoIterationsOfABlock) {
    PassRegistration pass = lambdaPass({"film", "", {}, {{"sum", "Tally", ""}}, {}, {}, {}},
                                       [](PassContext& ctx) { ctx.createOutput<Tally>("sum"); });
    pass.memory = [](const PreflightContext& pf) { return MemoryEstimate{filmBytes(pf.film), "film", {}}; };
    Pipeline pipeline;
    pipeline.name = "estimates";
    RepeatBlock block;
    block.name = "again";
    block.count = 10;
    block.nodes = {node("inner", "film")};
    pipeline.blocks = {block};
    pipeline.nodes = {node("outer", "film", {}, {{"sum", "outer_sum"}})};
    pipeline.results = {"sum", "outer_sum"};
    const ExecutionPlan plan = ExecutionPlan::build(pipeline, {}, "test", {pass});
    FilmSettings film;
    film.width = 100;
    film.height = 10;
    const std::vector<PassMemory> estimates = estimateMemory(plan, Scene{}, film);
    std::vector<std::string> instances;
    for (const PassMemory& e : estimates) {
        instances.push_back(e.instance);
        EXPECT_EQ(e.estimate.bytes, 1000u * 16u) << e.instance;
    }
    std::sort(instances.begin(), instances.end());
    EXPECT_EQ(instances, (std::vector<std::string>{"again[0].inner", "again[1].inner", "outer"}));
}

TEST(MemoryCheck, SaturatesInsteadOfWrappingAround) {
    EXPECT_EQ(multiplyBytes(1ull << 40, 1ull << 40), ~std::uint64_t(0));
    EXPECT_EQ(addBytes(~std::uint64_t(0) - 1, 5), ~std::uint64_t(0));
    FilmSettings film;
    film.width = 16384;
    film.height = 16384;
    EXPECT_EQ(filmBytes(film, 2), 16384ull * 16384ull * 24ull);
    EXPECT_EQ(describeBytes(6ull << 30), "6.0 GiB");
    EXPECT_EQ(describeBytes(512), "512 B");
}

TEST(MemoryCheck, ReadsKilobyteLinesOfProcFiles) {
    const std::string meminfo = "MemTotal:       131072000 kB\nMemFree:         1000 kB\nMemAvailable:    2048 kB\n";
    EXPECT_EQ(procKilobytes(meminfo, "MemAvailable"), std::optional<std::uint64_t>(2048u * 1024u));
    EXPECT_EQ(procKilobytes(meminfo, "MemFree"), std::optional<std::uint64_t>(1000u * 1024u));
    EXPECT_EQ(procKilobytes(meminfo, "Mem"), std::nullopt) << "a prefix of a key is not the key";
    EXPECT_EQ(procKilobytes(meminfo, "SwapTotal"), std::nullopt);
    const auto available = availableMemory();
    ASSERT_TRUE(available.has_value()) << "Linux has /proc/meminfo";
    EXPECT_GT(available->bytes, 0u);
}

TEST(CleanupTable, RemovesRegisteredFilesAndNewDirectoriesButNotOthers) {
    const std::string base = std::string(FLUXGRAPH_TEST_TMP) + "/cleanup-table";
    std::filesystem::remove_all(base);
    std::filesystem::create_directories(base + "/made/deeper");
    registerCreatedDirectory(base + "/made");
    registerCreatedDirectory(base + "/made/deeper");
    const std::string temporary = base + "/made/deeper/.image.tmp-1-0.exr";
    const std::string kept = base + "/kept.txt";
    for (const std::string& path : {temporary, kept}) std::ofstream(path) << "x";
    registerTemporaryFile(temporary);
    registerTemporaryFile(kept);
    unregisterCleanupPath(kept);
    removeRegisteredPaths();
    EXPECT_FALSE(std::filesystem::exists(base + "/made")) << "deepest directory first, each empty by then";
    EXPECT_TRUE(std::filesystem::exists(kept));
    removeRegisteredPaths();  // nothing left registered: a second call changes nothing
    EXPECT_TRUE(std::filesystem::exists(kept));
    std::filesystem::remove_all(base);
}

}  // namespace
}  // namespace fg
