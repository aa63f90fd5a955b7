// The engine for iterative algorithms: repeat blocks (unrolled, carried
// buffers, early exit), in-out slots, optional inputs, demand-driven streams,
// random-stream keys per instance and iteration, and scene hints that reach
// only the passes that declare them.
#include "engine/accel/ray_query.h"
#include "engine/buffers/photon_buffers.h"
#include "engine/core/codec.h"
#include "engine/core/error.h"
#include "engine/core/job.h"
#include "engine/core/render.h"
#include "engine/core/scheduler.h"
#include "engine/scene/scene_loader.h"
#include "jobs/parallel.h"
#include "passes/passes.h"
#include "tests/support/pass_helpers.h"

#include <gtest/gtest.h>

#include <atomic>
#include <cstring>
#include <filesystem>
#include <functional>
#include <memory>
#include <string>
#include <vector>

namespace fg {
namespace {

struct Counter {
    std::int64_t value = 0;
    std::size_t bytes() const { return sizeof(value); }
};

}  // namespace

template <>
struct BufferTypeName<Counter> {
    static constexpr const char* value = "Counter";
};

namespace {

std::string sourcePath(const std::string& relative) { return std::string(FLUXGRAPH_SOURCE_DIR) + "/" + relative; }

// FNV-1a over the resolved image's bytes: equal hashes, equal images.
std::uint64_t imageHash(const Film& film) {
    const std::vector<Rgb> pixels = film.resolve();
    std::uint64_t h = 0xCBF29CE484222325ull;
    const auto* bytes = reinterpret_cast<const unsigned char*>(pixels.data());
    for (std::size_t i = 0; i < pixels.size() * sizeof(Rgb); ++i) {
        h ^= bytes[i];
        h *= 0x100000001B3ull;
    }
    return h;
}

struct Rendered {
    ExecutionPlan plan;
    RunResult run;
    const Film& image() const { return *static_cast<const Film*>(run.results.at("image").data.get()); }
};

// Renders a job text (scene paths relative to data/jobs) without writing files.
Rendered renderText(const std::string& text, int threads = 0) {
    const Job job = parseJob(text, sourcePath("data/jobs/test.toml"));
    const Scene scene = loadScene(job.scenePath, job.sceneDefines);
    const jobs::ThreadLimit limit(threads);
    const RayQuery rays(scene);
    RunOptions options;
    options.seed = job.seed;
    options.film = job.film;
    Rendered out{ExecutionPlan::build(job.pipeline, job.params, job.path), {}};
    out.run = execute(out.plan, scene, rays, options);
    return out;
}

const std::string kCornell = R"(scene = "../cornell-box/cornell-box.toml"
seed = 3
[film]
width = 24
height = 24
filter = "box"
)";

std::string progressiveJob(int count, const std::string& extraBlockKeys = "", const std::string& params = "") {
    return kCornell + R"(
[pipeline]
name = "progressive"
[[pipeline.repeat]]
name = "progressive"
count = )" + std::to_string(count) +
           "\ncarry = { image = \"image\", noise = \"noise\" }\n" + extraBlockKeys + R"(
[[pipeline.repeat.pass]]
pass = "pt"
inputs = { accumulate = "image" }
[[pipeline.repeat.pass]]
pass = "film_noise"
name = "noise"
inputs = { image = "image", previous = "noise" }
[passes.pt]
spp = 2
)" + params;
}

TEST(RepeatBlock, GivesTheSameImageBytesAsThePipelineUnrolledByHand) {
    const Rendered block = renderText(progressiveJob(3));
    std::string byHand = kCornell + "\n[pipeline]\nname = \"by-hand\"\n";
    for (int i = 0; i < 3; ++i) {
        const std::string prefix = "progressive[" + std::to_string(i) + "].";
        byHand += "[[pipeline.pass]]\npass = \"pt\"\nname = \"" + prefix + "pt\"\n";
        byHand += i == 0 ? "outputs = { image = \"image0\" }\n"
                         : "inputs = { accumulate = \"image" + std::to_string(i - 1) + "\" }\noutputs = { image = \"" +
                               (i == 2 ? std::string("image") : "image" + std::to_string(i)) + "\" }\n";
    }
    for (int i = 0; i < 3; ++i) byHand += "[passes.\"progressive[" + std::to_string(i) + "].pt\"]\nspp = 2\n";
    const Rendered hand = renderText(byHand);
    EXPECT_EQ(imageHash(block.image()), imageHash(hand.image()));
    EXPECT_EQ(block.run.iterations.at("progressive"), 3);
}

TEST(RepeatBlock, CarriedBuffersHaveTheExpectedVersions) {
    const Job job = parseJob(progressiveJob(4), sourcePath("data/jobs/test.toml"));
    const ExecutionPlan plan = ExecutionPlan::build(job.pipeline, job.params, job.path);
    ASSERT_EQ(plan.passes().size(), 8u);
    const auto pass = [&](const std::string& instance) -> const PlannedPass& {
        for (const PlannedPass& p : plan.passes())
            if (p.node.instance == instance) return p;
        throw std::runtime_error("no instance " + instance);
    };
    EXPECT_EQ(pass("progressive[0].pt").node.inputBindings.at("accumulate"), "");  // absent in iteration 0
    EXPECT_EQ(pass("progressive[0].pt").node.outputBindings.at("image"), "progressive[0].image");
    EXPECT_EQ(pass("progressive[2].pt").node.inputBindings.at("accumulate"), "progressive[1].image");
    EXPECT_EQ(pass("progressive[2].noise").node.inputBindings.at("image"), "progressive[2].image");
    EXPECT_EQ(pass("progressive[2].noise").node.inputBindings.at("previous"), "progressive[1].noise");
    // Were iteration 3 skipped, its outputs would take iteration 2's versions.
    EXPECT_EQ(pass("progressive[3].pt").skipAliases.at("image"), "progressive[2].image");
    EXPECT_EQ(pass("progressive[0].pt").skipAliases.count("image"), 0u);
    EXPECT_EQ(plan.finalVersion("image"), "progressive[3].image");
    EXPECT_EQ(pass("progressive[1].pt").paramsKey, "pt");
    EXPECT_EQ(pass("progressive[1].pt").params.getInt("spp"), 2);
}

TEST(RepeatBlock, ReadingABufferBeforeTheBlockMakesItWithoutCarryIsAnError) {
    std::string text = progressiveJob(2);
    text.replace(text.find("carry = { image = \"image\", noise = \"noise\" }"), 44, "carry = { noise = \"noise\" }");
    const Job job = parseJob(text, sourcePath("data/jobs/test.toml"));
    // pt's accumulate is optional: without carry it is absent in every iteration.
    const ExecutionPlan plan = ExecutionPlan::build(job.pipeline, job.params, job.path);
    EXPECT_EQ(plan.passes()[2].node.inputBindings.at("accumulate"), "");
    // film_noise's image is required and made earlier in the iteration: fine.
    EXPECT_EQ(plan.passes()[3].node.inputBindings.at("image"), "progressive[1].image");
}

TEST(RepeatBlock, UntilMustNameASignalOfAPassInTheBlock) {
    for (const char* until : {"nosuch.converged", "noise.nosuch", "noise"}) {
        const Job job = parseJob(progressiveJob(3, std::string("until = \"") + until + "\"\n"), sourcePath("data/jobs/test.toml"));
        try {
            ExecutionPlan::build(job.pipeline, job.params, job.path);
            ADD_FAILURE() << until;
        } catch (const InputError& e) {
            EXPECT_NE(std::string(e.what()).find("test.toml:"), std::string::npos) << e.what();
            EXPECT_NE(std::string(e.what()).find("until"), std::string::npos) << e.what();
        }
    }
}

TEST(RepeatBlock, EarlyExitByConditionRunsTheSameIterationsAtOneAndTwoThreads) {
    const std::string text =
        progressiveJob(40, "until = \"noise.converged\"\n", "[passes.noise]\nthreshold = 0.6\nmin_batches = 3\n");
    const Rendered one = renderText(text, 1);
    const Rendered two = renderText(text, 2);
    const int iterations = one.run.iterations.at("progressive");
    EXPECT_GE(iterations, 3);
    EXPECT_LT(iterations, 40);
    EXPECT_EQ(two.run.iterations.at("progressive"), iterations);
    EXPECT_EQ(imageHash(one.image()), imageHash(two.image()));
    // Skipped iterations leave no rows; the image is that of the last iteration run.
    EXPECT_EQ(one.run.stats.size(), static_cast<std::size_t>(2 * iterations));
    const Rendered fixed = renderText(progressiveJob(iterations), 2);
    EXPECT_EQ(imageHash(fixed.image()), imageHash(one.image()));
}

TEST(RepeatBlock, ATimeBudgetStopsAfterTheIterationThatEndsPastIt) {
    const Rendered run = renderText(progressiveJob(500, "seconds = 0.000001\n"));
    EXPECT_EQ(run.run.iterations.at("progressive"), 1);
}

// --- Test passes on a bare scene -------------------------------------------------

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

TEST(InoutSlot, AReaderOfTheOldVersionSeesTheOldDataAndRunsBeforeTheWrite) {
    std::vector<PassRegistration> registry = {
        lambdaPass({"make", "", {}, {{"counter", "Counter", ""}}, {}, {}, {}},
                   [](PassContext& ctx) { ctx.createOutput<Counter>("counter").value = 41; }),
        lambdaPass({"read", "", {{"counter", "Counter", ""}}, {{"seen", "Counter", ""}}, {}, {}, {}},
                   [](PassContext& ctx) {
                       ctx.createOutput<Counter>("seen").value = ctx.input<Counter>("counter").value;
                   }),
        lambdaPass({"bump", "", {}, {}, {{"counter", "Counter", ""}}, {}, {}},
                   [](PassContext& ctx) { ++ctx.inout<Counter>("counter").value; }),
    };
    Pipeline pipeline;
    pipeline.name = "inout";
    pipeline.nodes = {node("make", "make"), node("before", "read", {}, {{"seen", "before"}}), node("bump", "bump"),
                      node("after", "read", {}, {{"seen", "after"}})};
    pipeline.results = {"before", "after", "counter"};
    const ExecutionPlan plan = ExecutionPlan::build(pipeline, {}, "test", registry);
    EXPECT_EQ(plan.passes()[1].node.inputBindings.at("counter"), "counter");
    EXPECT_EQ(plan.passes()[2].node.outputBindings.at("counter"), "counter@2");
    EXPECT_EQ(plan.passes()[3].node.inputBindings.at("counter"), "counter@2");
    const auto& bumpDeps = plan.passes()[2].dependencies;
    EXPECT_NE(std::find(bumpDeps.begin(), bumpDeps.end(), 1), bumpDeps.end()) << "the write waits for the old reader";
    for (int threads : {1, 2}) {
        for (int repeat = 0; repeat < 20; ++repeat) {
            const RunResult run = runOnBareScene(pipeline, registry, threads);
            EXPECT_EQ(static_cast<const Counter*>(run.results.at("before").data.get())->value, 41);
            EXPECT_EQ(static_cast<const Counter*>(run.results.at("after").data.get())->value, 42);
        }
    }
}

TEST(OptionalInput, PresentAndAbsent) {
    SlotSpec base{"base", "Counter", ""};
    base.optional = true;
    std::vector<PassRegistration> registry = {
        lambdaPass({"make", "", {}, {{"counter", "Counter", ""}}, {}, {}, {}},
                   [](PassContext& ctx) { ctx.createOutput<Counter>("counter").value = 10; }),
        lambdaPass({"add", "", {base}, {{"sum", "Counter", ""}}, {}, {}, {}},
                   [](PassContext& ctx) {
                       ctx.createOutput<Counter>("sum").value =
                           1 + (ctx.hasInput("base") ? ctx.input<Counter>("base").value : 0);
                   }),
    };
    Pipeline withBase;
    withBase.name = "with";
    withBase.nodes = {node("make", "make"), node("add", "add", {{"base", "counter"}})};
    withBase.results = {"sum"};
    EXPECT_EQ(static_cast<const Counter*>(runOnBareScene(withBase, registry).results.at("sum").data.get())->value, 11);
    Pipeline without;
    without.name = "without";
    without.nodes = {node("add", "add")};
    without.results = {"sum"};
    EXPECT_EQ(static_cast<const Counter*>(runOnBareScene(without, registry).results.at("sum").data.get())->value, 1);
}

TEST(DemandDrivenStream, StopsAtABatchBoundaryWithTheSameBatchesForAnyThreadCount) {
    struct Seen {
        std::vector<std::int64_t> values;
    };
    for (int threads : {1, 2}) {
        auto seen = std::make_shared<Seen>();
        auto emitted = std::make_shared<std::atomic<int>>(0);
        SlotSpec out{"values", "Counter", "", true};
        SlotSpec in{"values", "Counter", "", true};
        std::vector<PassRegistration> registry = {
            lambdaPass({"produce", "", {}, {out}, {}, {}, {}},
                       [emitted](PassContext& ctx) {
                           for (int b = 0; b < 1000; ++b) {
                               auto batch = std::make_shared<Counter>();
                               batch->value = b * 7 % 13;
                               ++*emitted;
                               if (!ctx.emitBatch<Counter>("values", batch)) return;
                           }
                       }),
            lambdaPass({"consume", "", {in}, {{"total", "Counter", ""}}, {}, {}, {}},
                       [seen](PassContext& ctx) {
                           std::int64_t total = 0;
                           for (auto v : seen->values) total += v;
                           ctx.createOutput<Counter>("total").value = total;
                       },
                       [seen](PassContext& ctx, const std::string& slot) {
                           seen->values.push_back(ctx.input<Counter>(slot).value);
                           std::int64_t total = 0;
                           for (auto v : seen->values) total += v;
                           if (total >= 100) ctx.wantNoMoreBatches(slot);
                       }),
        };
        Pipeline pipeline;
        pipeline.name = "demand";
        pipeline.nodes = {node("produce", "produce"), node("consume", "consume")};
        pipeline.results = {"total"};
        const RunResult run = runOnBareScene(pipeline, registry, threads);
        // 0 7 1 8 2 9 3 10 4 11 5 12 6 0 7 1 8 2 9: the sum first reaches 100 (105) at batch 19,
        // and the producer makes no batch after it.
        EXPECT_EQ(emitted->load(), 19) << threads;
        EXPECT_EQ(seen->values.size(), 19u);
        EXPECT_EQ(static_cast<const Counter*>(run.results.at("total").data.get())->value, 105);
    }
}

// A block output read only after the block (not carried) comes from the last
// iteration that ran, even though the later iterations' copies of its producer
// would otherwise be culled.
TEST(RepeatBlock, AnOutputReadAfterAnEarlyExitIsTheLastRunIterations) {
    SlotSpec previous{"previous", "Counter", ""};
    previous.optional = true;
    PassSpec step{"step", "", {previous}, {{"tally", "Counter", ""}}, {}, {}, {"done"}};
    PassSpec mark{"mark", "", {}, {{"side", "Counter", ""}}, {}, {}, {}};
    PassSpec read{"read", "", {{"side", "Counter", ""}}, {{"final", "Counter", ""}}, {}, {}, {}};
    std::vector<PassRegistration> registry = {
        lambdaPass(step,
                   [](PassContext& ctx) {
                       const std::int64_t value = (ctx.hasInput("previous") ? ctx.input<Counter>("previous").value : 0) + 1;
                       ctx.createOutput<Counter>("tally").value = value;
                       if (value >= 3) ctx.signal("done");
                   }),
        lambdaPass(mark, [](PassContext& ctx) { ctx.createOutput<Counter>("side").value = 100 + ctx.iteration(); }),
        lambdaPass(read, [](PassContext& ctx) { ctx.createOutput<Counter>("final").value = ctx.input<Counter>("side").value; }),
    };
    Pipeline pipeline;
    pipeline.name = "early";
    RepeatBlock block;
    block.name = "loop";
    block.count = 10;
    block.carry = {{"tally", "tally"}};
    block.until = "step.done";
    block.nodes = {node("step", "step", {{"previous", "tally"}}), node("mark", "mark")};
    pipeline.blocks = {block};
    pipeline.nodes = {node("read", "read")};
    pipeline.results = {"final", "tally"};
    for (int threads : {1, 2}) {
        const RunResult run = runOnBareScene(pipeline, registry, threads);
        EXPECT_EQ(run.iterations.at("loop"), 3);
        EXPECT_EQ(static_cast<const Counter*>(run.results.at("tally").data.get())->value, 3);
        EXPECT_EQ(static_cast<const Counter*>(run.results.at("final").data.get())->value, 102);
    }
}

TEST(DemandDrivenStream, ThePhotonPassStopsTracingWhenItsReadersHaveEnough) {
    const Scene scene = loadScene(sourcePath("data/water-wave/water-wave.xml"), {});
    const RayQuery rays(scene);
    struct Taken {
        std::vector<std::size_t> batchSizes;
    };
    std::vector<std::int64_t> pathsTraced;
    std::vector<std::vector<std::size_t>> batches;
    for (int threads : {1, 2}) {
        auto taken = std::make_shared<Taken>();
        std::vector<PassRegistration> registry = passRegistry();
        SlotSpec caustics{"caustic_photons", "PhotonMap", "", true};
        registry.push_back(lambdaPass(
            {"take_caustics", "", {caustics}, {{"count", "Counter", ""}}, {}, {}, {}},
            [taken](PassContext& ctx) {
                std::int64_t total = 0;
                for (std::size_t n : taken->batchSizes) total += static_cast<std::int64_t>(n);
                ctx.createOutput<Counter>("count").value = total;
            },
            [taken](PassContext& ctx, const std::string& slot) {
                taken->batchSizes.push_back(ctx.input<PhotonMap>(slot).photons.size());
                std::size_t total = 0;
                for (std::size_t n : taken->batchSizes) total += n;
                if (total >= 3000) ctx.wantNoMoreBatches(slot);
            }));
        Pipeline pipeline;
        pipeline.name = "demand";
        pipeline.nodes = {node("photon", "photon"), node("take", "take_caustics")};
        pipeline.results = {"count"};
        JobParams params;
        params.values["photon"]["photons"] = {std::int64_t{4000000}, "test"};
        params.values["photon"]["batch_size"] = {std::int64_t{4096}, "test"};
        const ExecutionPlan plan = ExecutionPlan::build(pipeline, params, "test", registry);
        ASSERT_TRUE(plan.streamed("caustic_photons"));
        const jobs::ThreadLimit limit(threads);
        const RunResult run = execute(plan, scene, &rays, RunOptions{});
        for (const PassStats& s : run.stats)
            if (s.pass == "photon") {
                pathsTraced.push_back(s.items);
                EXPECT_EQ(s.counters.at("stopped_by_readers"), 1);
            }
        batches.push_back(taken->batchSizes);
    }
    ASSERT_EQ(pathsTraced.size(), 2u);
    EXPECT_EQ(pathsTraced[0], pathsTraced[1]);
    EXPECT_EQ(batches[0], batches[1]);
    EXPECT_EQ(pathsTraced[0] % 4096, 0) << "stopped at a batch boundary";
    EXPECT_LT(pathsTraced[0], 4000000);
}

TEST(RandomStreams, KeysArePerInstanceAndKeepTheirOldValueForAPassNamedInstance) {
    // The quickstart image, bit for bit as before keys took the instance name:
    // its hash was recorded from the render of the previous engine, and again
    // when pt began to render in sample passes (the same samples; the film
    // sums them in other rounds: RMSE 1e-7 against the earlier image), and
    // again when Embree's robust mode was dropped and every query became
    // incoherent (hits differ from the robust traversal's in the last bits).
    const Job job = loadJob(sourcePath("data/jobs/quickstart.toml"));
    const Scene scene = loadScene(job.scenePath, job.sceneDefines);
    const RayQuery rays(scene);
    RunOptions options;
    options.seed = job.seed;
    options.film = job.film;
    const RunResult run = execute(ExecutionPlan::build(job.pipeline, job.params, job.path), scene, rays, options);
    EXPECT_EQ(imageHash(*static_cast<const Film*>(run.results.at("image").data.get())), 0x304d6180b3dbb200ull);

    // Another instance name draws other numbers.
    const Rendered a = renderText("pipeline = \"pt\"\n" + kCornell + "[passes.pt]\nspp = 1\n");
    const Rendered b = renderText(kCornell + "[pipeline]\n[[pipeline.pass]]\npass = \"pt\"\nname = \"other\"\n[passes.other]\nspp = 1\n");
    EXPECT_NE(imageHash(a.image()), imageHash(b.image()));
}

TEST(SceneHints, ReachOnlyPassesThatDeclareThem) {
    // spot-fog.xml has an integrator depth and a sample count; bre's photon pass
    // declares neither, its volume eye pass takes the sample count.
    const std::string text = R"(scene = "../spot-fog/spot-fog.xml"
pipeline = "bre"
scene_defines = { max_depth = 5, spp = 3 }
)";
    const Job job = parseJob(text, sourcePath("data/jobs/test.toml"));
    const ExecutionPlan plan = validateJob(job);
    for (const PlannedPass& p : plan.passes()) {
        if (p.node.pass == "photon") {
            EXPECT_EQ(p.params.getInt("max_depth"), 16);
        }
        if (p.node.pass == "volume_eye") {
            EXPECT_EQ(p.params.getInt("spp"), 3);
        }
    }
    const Job ptJob = parseJob(R"(scene = "../spot-fog/spot-fog.xml"
pipeline = "pt"
scene_defines = { max_depth = 5, spp = 3 }
)", sourcePath("data/jobs/test.toml"));
    const ExecutionPlan ptPlan = validateJob(ptJob);
    EXPECT_EQ(ptPlan.passes()[0].params.getInt("max_depth"), 4);  // Mitsuba's 5 path vertices
    EXPECT_EQ(ptPlan.passes()[0].params.getInt("spp"), 3);
}

TEST(Preflight, ValidateCatchesWhatRenderWouldOnlyFindAfterWork) {
    const auto message = [](const std::string& text) {
        try {
            validateJob(parseJob(text, sourcePath("data/jobs/test.toml")));
        } catch (const InputError& e) {
            return std::string(e.what());
        }
        return std::string("(no error)");
    };
    EXPECT_NE(message(R"(scene = "../cornell-box/cornell-box.toml"
pipeline = "pds"
[passes.photon]
differentials = false
)").find("photon differentials"),
              std::string::npos);
    EXPECT_NE(message("scene = \"../medium-box/medium-box.toml\"\npipeline = \"spm\"\n").find("participating media"),
              std::string::npos);
    EXPECT_NE(message("scene = \"../medium-box/medium-box.toml\"\npipeline = \"lt\"\n").find("participating media"),
              std::string::npos);
    EXPECT_NE(message(R"(scene = "../cornell-box/cornell-box.toml"
pipeline = "spm"
[passes.photon]
volume_photons = 10
store = "surface"
)").find("needs store"),
              std::string::npos);
}

TEST(SavedBuffers, AnImportedBufferReplacesAndCullsItsProducerAndGivesTheSameImage) {
    const std::string dir = std::string(FLUXGRAPH_TEST_TMP) + "/saved-buffers";
    std::filesystem::create_directories(dir);
    const std::string text = R"(scene = "../cornell-box/cornell-box.toml"
pipeline = "spm"
[film]
width = 24
height = 24
[passes.eye]
spp = 2
[passes.photon]
photons = 20000
)";
    const Job job = parseJob(text, sourcePath("data/jobs/test.toml"));
    const Scene scene = loadScene(job.scenePath, job.sceneDefines);
    const RayQuery rays(scene);
    RunOptions options;
    options.film = job.film;

    BufferFiles saves;
    saves.saves = {{"caustic_photons", dir + "/caustic.fgbuf"}, {"global_photons", dir + "/global.fgbuf"}};
    const ExecutionPlan saving = ExecutionPlan::build(job.pipeline, job.params, job.path, passRegistry(), saves);
    RunOptions saveOptions = options;
    int written = 0;
    saveOptions.save = [&](const std::string&, const std::string& path, const BufferHandle& buffer) {
        saveBuffer(buffer, path, text);
        ++written;
    };
    const RunResult first = execute(saving, scene, rays, saveOptions);
    EXPECT_EQ(written, 2);

    BufferFiles imports;
    imports.imports = {{"caustic_photons", dir + "/caustic.fgbuf"}, {"global_photons", dir + "/global.fgbuf"}};
    const ExecutionPlan importing = ExecutionPlan::build(job.pipeline, job.params, job.path, passRegistry(), imports);
    for (const PlannedPass& p : importing.passes())
        EXPECT_EQ(p.culled, p.node.pass == "photon") << p.node.instance;
    RunOptions importOptions = options;
    for (const auto& [version, typeAndPath] : importing.imports())
        importOptions.imported[version] = loadBuffer(typeAndPath.second, typeAndPath.first, version);
    const RunResult second = execute(importing, scene, rays, importOptions);
    EXPECT_EQ(imageHash(*static_cast<const Film*>(first.results.at("image").data.get())),
              imageHash(*static_cast<const Film*>(second.results.at("image").data.get())));
    for (const PassStats& s : second.stats) EXPECT_NE(s.pass, "photon");
}

TEST(BuiltinPipelines, AreDataFilesThatValidate) {
    for (const Pipeline& p : builtinPipelines()) {
        EXPECT_EQ(p.file, "passes/pipelines/" + p.name + ".toml");
        EXPECT_FALSE(p.doc.empty()) << p.name;
        EXPECT_NO_THROW(ExecutionPlan::build(p, {}, p.file)) << p.name;
    }
}

}  // namespace
}  // namespace fg
