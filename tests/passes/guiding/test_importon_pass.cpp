// The importon pass (Vorba et al. 2014 §4.1): camera paths guided by the
// previous radiance cache, storing importons where a guided path would query it.
#include "engine/core/codec.h"
#include "engine/guiding/importons.h"
#include "engine/scene/scene_loader.h"
#include "passes/passes.h"
#include "tests/support/cli_helpers.h"
#include "tests/support/guiding_pipeline.h"
#include "tests/support/pass_helpers.h"
#include "tests/support/render_helpers.h"

#include <gtest/gtest.h>

#include <filesystem>

namespace fg {
namespace {

using test::guidedPipeline;
using test::RecordsAt;
using test::trainingParams;

// Importons guided by a trained cache, then the cache: the same bytes at 1
// and 2 threads (paths are gathered per fixed chunk and concatenated in path
// order). The importons lie where a guided camera path could be guided: their
// normals face the direction they came from, their weights are positive, and
// both first hits (0 bounces) and later ones are there.
TEST(ImportonPass, IdenticalAtOneAndTwoThreads) {
    const Scene scene = loadScene(test::sourcePath("data/cornell-box/cornell-box.toml"));
    const std::filesystem::path dir = test::scratchDirectory("guided-pt");
    auto params = trainingParams(4000, 4);
    params.erase("pt.spp");  // this pipeline ends with importons, not pt
    params.erase("pt.max_depth");
    const std::string tail = R"([[pipeline.pass]]
pass = "importon"
name = "final_importons"
inputs = { radiance_cache = "radiance_cache" }
outputs = { importons = "importons" }
)";
    const auto run = [&](int threads) {
        return test::runPipeline(scene, guidedPipeline(2, "importons", RecordsAt::Importons, tail),
                                 builtinRegistry().passes, params, test::smallFilm(16, 16), "importons", 7, threads);
    };
    const BufferHandle one = run(1), two = run(2);
    const ImportonMap& map = test::bufferAs<ImportonMap>(one);
    EXPECT_EQ(map.paths, 16u * 16u);
    ASSERT_GT(map.importons.size(), map.paths);  // most paths make more than one guidable vertex
    std::size_t first = 0;
    const auto normals = map.importons.column<ImportonNormal>();
    const auto incident = map.importons.column<ImportonIncident>();
    const auto weights = map.importons.column<ImportonWeight>();
    const auto bounces = map.importons.column<ImportonBounces>();
    for (std::size_t i = 0; i < map.importons.size(); ++i) {
        EXPECT_GE(glm::dot(normals[i], incident[i]), 0.0f) << i;
        EXPECT_GT(weights[i], 0.0f) << i;
        if (bounces[i] == 0) ++first;
    }
    EXPECT_GT(first, map.paths / 2);
    EXPECT_LT(first, map.importons.size());
    saveBuffer(one, (dir / "importons1.fgbuf").string(), "");
    saveBuffer(two, (dir / "importons2.fgbuf").string(), "");
    EXPECT_TRUE(test::readText(dir / "importons1.fgbuf") == test::readText(dir / "importons2.fgbuf"))
        << "the importons traced at 1 and 2 threads differ";
}

}  // namespace
}  // namespace fg
