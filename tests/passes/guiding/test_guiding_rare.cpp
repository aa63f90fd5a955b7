// Where guiding is rare (cache_update's min_guiding_share, signal
// guiding_rare): the built-in guided-pt and guided-bdpt pipelines end their
// training after the first pass in a box whose broad light leaves nothing
// worth guiding, and guided-pt goes on in the occluded room, whose light
// reaches the camera's side through a gap; at the threshold the signal
// follows the share of query points that find a guiding record, and a rare
// cache guides nowhere.
#include "engine/accel/ray_query.h"
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
// left to BSDF sampling; below, the records guide as with no threshold.
TEST(GuidingRare, SignalAtItsThreshold) {
    const Scene scene = test::loadAjarRoom("guiding-rare");
    const RunResult free = trainBuiltin(scene, 1, {{"radiance_update.min_guiding_share", 0.0}}, 3);
    const auto counters = radianceCounters(free, 0);
    const double guided = static_cast<double>(counters.at("guided_queries"));
    const double queries = static_cast<double>(counters.at("queries"));
    ASSERT_GT(guided, 0.0);
    ASSERT_LT(guided, queries);
    const std::size_t guiding = guidingRecords(radianceCache(free));
    ASSERT_GT(guiding, 0u);

    const RunResult above = trainBuiltin(scene, 2, {{"radiance_update.min_guiding_share", (guided + 0.5) / queries}}, 3);
    EXPECT_EQ(radianceCounters(above, 0).at("guided_queries"), counters.at("guided_queries"));
    EXPECT_EQ(above.iterations.at("train"), 1);
    EXPECT_EQ(radianceCache(above).records.size(), radianceCache(free).records.size());
    EXPECT_EQ(guidingRecords(radianceCache(above)), 0u);

    const RunResult below = trainBuiltin(scene, 2, {{"radiance_update.min_guiding_share", (guided - 0.5) / queries}}, 3);
    EXPECT_EQ(radianceCounters(below, 0).at("guided_queries"), counters.at("guided_queries"));
    EXPECT_EQ(below.iterations.at("train"), 2);

    // One pass below the threshold: the cache of the run with none.
    const RunResult belowOnce = trainBuiltin(scene, 1, {{"radiance_update.min_guiding_share", (guided - 0.5) / queries}}, 3);
    EXPECT_EQ(guidingRecords(radianceCache(belowOnce)), guiding);
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
