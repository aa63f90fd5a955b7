// Where guiding is rare (cache_update's min_guiding_share, signal
// guiding_rare): the built-in guided-pt and guided-bdpt pipelines end their
// training after the first pass in a box whose broad light leaves nothing
// worth guiding, and guided-pt goes on in the occluded room, whose light
// reaches the camera's side through a gap; at the threshold the signal
// follows the share of query points that find a guiding record, and a rare
// cache guides nowhere. The share is judged first on fits stopped after
// decision_sweeps sweeps: where that is rare the fits are not finished, and
// elsewhere the finished cache is the one a single stage makes.
#include "engine/accel/ray_query.h"
#include "engine/core/codec.h"
#include "engine/core/job.h"
#include "engine/core/scheduler.h"
#include "engine/guiding/guiding_cache.h"
#include "engine/scene/scene_loader.h"
#include "passes/passes.h"
#include "tests/passes/guiding/ajar_room.h"
#include "tests/support/cli_helpers.h"
#include "tests/support/guiding_pipeline.h"
#include "tests/support/pass_helpers.h"
#include "tests/support/render_helpers.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cstdio>
#include <string>

namespace fg {
namespace {

// A closed diffuse box lit by a ceiling nearly as wide as the box: every point
// sees the light over a broad solid angle, where a mixture cuts little of BSDF
// sampling's variance.
constexpr const char* kLitBox = R"(
[camera]
eye = [0.0, 0.0, 0.9]
target = [0.0, 0.0, 0.0]
fov = 70
[[material]]
name = "wall"
type = "diffuse"
reflectance = 0.7
[[shape]]
type = "cube"
flip_normals = true
material = "wall"
[[shape]]
type = "rectangle"
transform = [{ scale = 0.95 }, { rotate = { axis = [1, 0, 0], angle = 90 } }, { translate = [0.0, 0.99, 0.0] }]
material = "wall"
emission = 2
)";

Scene loadLitBox() {
    const std::filesystem::path dir = test::scratchDirectory("guiding-rare");
    test::writeText(dir / "lit-box.toml", kLitBox);
    return loadScene((dir / "lit-box.toml").string());
}

// A built-in guided pipeline, at most `passes` training passes, run for its
// radiance cache.
RunResult trainBuiltin(const Scene& scene, int passes, std::map<std::string, ParamValue> params, std::uint64_t seed,
                       const std::string& name = "guided-pt") {
    Pipeline pipeline = *builtinRegistry().findPipeline(name);
    EXPECT_EQ(pipeline.blocks.size(), 1u);
    EXPECT_EQ(pipeline.blocks[0].until, "radiance_update.guiding_rare");
    pipeline.blocks[0].count = passes;
    pipeline.results = {"radiance_cache"};
    JobParams jobParams;
    for (const auto& [key, value] : test::bothCachesTrainingParams(4000)) params.emplace(key, value);
    for (const auto& [key, value] : params) {
        const auto dot = key.find('.');
        jobParams.values[key.substr(0, dot)][key.substr(dot + 1)] = {value, "test"};
    }
    const ExecutionPlan plan = ExecutionPlan::build(pipeline, jobParams, "test", builtinRegistry().passes);
    const RayQuery rays(scene);
    RunOptions options;
    options.seed = seed;
    options.film = test::smallFilm(24, 24);
    return execute(plan, scene, rays, options);
}

const GuidingCache& radianceCache(const RunResult& run) { return test::bufferAs<GuidingCache>(run.results.at("radiance_cache")); }

std::size_t guidingRecords(const GuidingCache& cache) {
    std::size_t n = 0;
    for (std::uint32_t i = 0; i < cache.records.size(); ++i) n += cache.guides(i) ? 1 : 0;
    return n;
}

// The cache's file bytes: every column, the index and the counters, as --save writes them.
std::string cacheBytes(const RunResult& run, const std::string& name) {
    const std::filesystem::path path = test::scratchDirectory("guiding-rare") / (name + ".fgbuf");
    saveBuffer(run.results.at("radiance_cache"), path.string(), "");
    return test::readText(path);
}

// The counters of the radiance update of training pass `pass`.
std::map<std::string, std::int64_t> radianceCounters(const RunResult& run, int pass) {
    const std::string instance = "train[" + std::to_string(pass) + "].radiance_update";
    for (const PassStats& s : run.stats)
        if (s.instance == instance) return s.counters;
    ADD_FAILURE() << "no pass " << instance;
    return {};
}

TEST(GuidingRare, TrainingStopsAfterFirstPassWhereNothingGuides) {
    const Scene scene = loadLitBox();
    const RunResult run = trainBuiltin(scene, 4, {}, 1);
    const auto counters = radianceCounters(run, 0);
    std::printf("lit box: %lld of %lld query points guided, %lld records\n",
                static_cast<long long>(counters.at("guided_queries")), static_cast<long long>(counters.at("queries")),
                static_cast<long long>(counters.at("records")));
    EXPECT_EQ(run.iterations.at("train"), 1);
    const GuidingCache& cache = radianceCache(run);
    EXPECT_EQ(cache.trainingPasses, 1u);
    EXPECT_GT(cache.records.size(), 10u);
    EXPECT_EQ(guidingRecords(cache), 0u);
    EXPECT_FALSE(cache.anyGuides());
}

TEST(GuidingRare, GuidedBdptTrainingStopsToo) {
    const Scene scene = loadLitBox();
    const RunResult run = trainBuiltin(scene, 3, {}, 1, "guided-bdpt");
    EXPECT_EQ(run.iterations.at("train"), 1);
    EXPECT_FALSE(radianceCache(run).anyGuides());
}

TEST(GuidingRare, TrainingGoesOnWhereRecordsGuide) {
    const Scene scene = test::loadAjarRoom("guiding-rare");
    const RunResult run = trainBuiltin(scene, 2, {}, 1);
    for (int pass = 0; pass < 2; ++pass) {
        const auto counters = radianceCounters(run, pass);
        std::printf("occluded room, pass %d: %lld of %lld query points guided\n", pass,
                    static_cast<long long>(counters.at("guided_queries")), static_cast<long long>(counters.at("queries")));
    }
    EXPECT_EQ(run.iterations.at("train"), 2);
    const GuidingCache& cache = radianceCache(run);
    EXPECT_EQ(cache.trainingPasses, 2u);
    EXPECT_GT(guidingRecords(cache), 0u);
}

// The same first pass with the threshold half a query point above and below
// the share it measured: only above is the block stopped and every record
// left to BSDF sampling; below, the records guide as with no threshold. The
// share judged here is the finished fits' (decision_sweeps = 0).
TEST(GuidingRare, SignalAtItsThreshold) {
    const Scene scene = test::loadAjarRoom("guiding-rare");
    const auto train = [](const Scene& s, int passes, std::map<std::string, ParamValue> params, std::uint64_t seed) {
        params["radiance_update.decision_sweeps"] = std::int64_t{0};
        return trainBuiltin(s, passes, std::move(params), seed);
    };
    const RunResult free = train(scene, 1, {{"radiance_update.min_guiding_share", 0.0}}, 3);
    const auto counters = radianceCounters(free, 0);
    const double guided = static_cast<double>(counters.at("guided_queries"));
    const double queries = static_cast<double>(counters.at("queries"));
    ASSERT_GT(guided, 0.0);
    ASSERT_LT(guided, queries);
    const std::size_t guiding = guidingRecords(radianceCache(free));
    ASSERT_GT(guiding, 0u);

    const RunResult above = train(scene, 2, {{"radiance_update.min_guiding_share", (guided + 0.5) / queries}}, 3);
    EXPECT_EQ(radianceCounters(above, 0).at("guided_queries"), counters.at("guided_queries"));
    EXPECT_EQ(above.iterations.at("train"), 1);
    EXPECT_EQ(radianceCache(above).records.size(), radianceCache(free).records.size());
    EXPECT_EQ(guidingRecords(radianceCache(above)), 0u);

    const RunResult below = train(scene, 2, {{"radiance_update.min_guiding_share", (guided - 0.5) / queries}}, 3);
    EXPECT_EQ(radianceCounters(below, 0).at("guided_queries"), counters.at("guided_queries"));
    EXPECT_EQ(below.iterations.at("train"), 2);

    // One pass below the threshold: the cache of the run with none.
    const RunResult belowOnce = train(scene, 1, {{"radiance_update.min_guiding_share", (guided - 0.5) / queries}}, 3);
    EXPECT_EQ(guidingRecords(radianceCache(belowOnce)), guiding);
}

// Where guiding is rare the new records' off-line EM stops after the
// decision's sweeps: the lit box's first pass runs at most decision_sweeps
// (2) sweeps per record, against the up to max_sweeps (12) of a pass that
// finishes the fits before it judges, and ends the same way.
TEST(GuidingRare, RareCacheLeavesFitsUnfinished) {
    const Scene scene = loadLitBox();
    const RunResult early = trainBuiltin(scene, 3, {}, 1);
    const RunResult late = trainBuiltin(scene, 3, {{"radiance_update.decision_sweeps", std::int64_t{0}}}, 1);
    const auto e = radianceCounters(early, 0), l = radianceCounters(late, 0);
    std::printf("lit box: %lld off-line sweeps for %lld new records (%lld query points guided), %lld with the fits "
                "finished (%lld guided)\n",
                static_cast<long long>(e.at("offline_em_sweeps")), static_cast<long long>(e.at("records_created")),
                static_cast<long long>(e.at("guided_queries")), static_cast<long long>(l.at("offline_em_sweeps")),
                static_cast<long long>(l.at("guided_queries")));
    EXPECT_EQ(early.iterations.at("train"), 1);
    EXPECT_EQ(late.iterations.at("train"), 1);
    EXPECT_EQ(e.at("records_created"), l.at("records_created"));
    EXPECT_EQ(e.at("guided_queries"), e.at("decision_guided_queries"));
    EXPECT_EQ(l.count("decision_guided_queries"), 0u);
    EXPECT_LE(e.at("offline_em_sweeps"), 2 * e.at("records_created"));
    EXPECT_GT(l.at("offline_em_sweeps"), 4 * l.at("records_created"));
    EXPECT_FALSE(radianceCache(early).anyGuides());
}

// Where the stopped fits' share reaches the threshold, the fits are finished
// and the cache, after one pass and after two, is the one judged on finished
// fits alone makes, byte for byte (the early stage's neighbour clamping of
// the records already there is undone).
TEST(GuidingRare, FinishedFitsEqualSingleStage) {
    const Scene scene = test::loadAjarRoom("guiding-rare");
    for (int passes : {1, 2}) {
        const RunResult staged = trainBuiltin(scene, passes, {}, 1);
        const RunResult single = trainBuiltin(scene, passes, {{"radiance_update.decision_sweeps", std::int64_t{0}}}, 1);
        EXPECT_EQ(staged.iterations.at("train"), passes);
        EXPECT_EQ(single.iterations.at("train"), passes);
        for (int pass = 0; pass < passes; ++pass) {
            const auto counters = radianceCounters(staged, pass);
            EXPECT_EQ(counters.at("guided_queries"), radianceCounters(single, pass).at("guided_queries"));
            EXPECT_GT(counters.at("records_created"), 0);
            std::printf("occluded room, pass %d: %lld query points guided by the stopped fits, %lld by the finished\n",
                        pass, static_cast<long long>(counters.at("decision_guided_queries")),
                        static_cast<long long>(counters.at("guided_queries")));
        }
        EXPECT_TRUE(cacheBytes(staged, "staged") == cacheBytes(single, "single")) << passes << " passes";
    }
}

// The early judgement at its own threshold (early_guiding_share, with
// min_guiding_share half a query point above the stopped fits' share so that
// it does not cap it): half a query point above the stopped fits' share ends
// the block with the fits unfinished; half a point below it (and below the
// finished fits' share) they are finished, into the cache of the default run.
TEST(GuidingRare, EarlySignalAtItsThreshold) {
    const Scene scene = test::loadAjarRoom("guiding-rare");
    const RunResult plain = trainBuiltin(scene, 1, {}, 3);
    const auto counters = radianceCounters(plain, 0);
    const double early = static_cast<double>(counters.at("decision_guided_queries"));
    const double queries = static_cast<double>(counters.at("queries"));
    ASSERT_GT(early, 0.0);
    ASSERT_LT(early + 0.5, static_cast<double>(counters.at("guided_queries")));
    const auto thresholds = [&](double earlyShare) -> std::map<std::string, ParamValue> {
        return {{"radiance_update.min_guiding_share", (early + 0.5) / queries},
                {"radiance_update.early_guiding_share", earlyShare}};
    };

    const RunResult above = trainBuiltin(scene, 2, thresholds((early + 0.5) / queries), 3);
    const auto a = radianceCounters(above, 0);
    EXPECT_EQ(above.iterations.at("train"), 1);
    EXPECT_EQ(a.at("guided_queries"), counters.at("decision_guided_queries"));
    EXPECT_LE(a.at("offline_em_sweeps"), 2 * a.at("records_created"));
    EXPECT_LT(a.at("offline_em_sweeps"), counters.at("offline_em_sweeps"));
    EXPECT_FALSE(radianceCache(above).anyGuides());

    const RunResult below = trainBuiltin(scene, 2, thresholds((early - 0.5) / queries), 3);
    EXPECT_EQ(below.iterations.at("train"), 2);
    const RunResult belowOnce = trainBuiltin(scene, 1, thresholds((early - 0.5) / queries), 3);
    EXPECT_TRUE(cacheBytes(belowOnce, "below") == cacheBytes(plain, "plain"));
}

// guide_decision = always samples every usable mixture: nothing is rare.
TEST(GuidingRare, AlwaysDecisionNeverStops) {
    const Scene scene = loadLitBox();
    const RunResult run = trainBuiltin(
        scene, 2,
        {{"radiance_update.guide_decision", std::string("always")}, {"radiance_update.min_guiding_share", 1.0}}, 1);
    EXPECT_EQ(run.iterations.at("train"), 2);
    EXPECT_GT(guidingRecords(radianceCache(run)), 0u);
}

}  // namespace
}  // namespace fg
