// Standard photon mapping (spm) and photon differential splatting (pds)
// converge towards the path-traced reference as the photon count grows, on the
// refractive (water-wave) and reflective (gold-ring) caustic scenes.
#include "engine/image/image_compare.h"
#include "engine/image/image_io.h"
#include "engine/scene/scene_loader.h"
#include "tests/support/render_helpers.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <filesystem>
#include <string>
#include <vector>

namespace fg {
namespace {

namespace fs = std::filesystem;

struct ConvergenceCase {
    std::string scene;
    std::string pipeline;
    std::string bandwidthParam;  // "gather.k_caustic" or "photon.smoothing"
    ParamValue bandwidth;
};

class CausticConvergence : public ::testing::TestWithParam<ConvergenceCase> {};

TEST_P(CausticConvergence, ErrorFallsAsPhotonsGrow) {
    const ConvergenceCase& c = GetParam();
    const fs::path dir = fs::path(FLUXGRAPH_SOURCE_DIR) / "data" / c.scene;
    const fs::path referencePath = dir / "reference" / "reference.exr";
    ASSERT_TRUE(fs::exists(referencePath)) << referencePath << " is missing: run tools/render_references.sh";
    const ImageChannels reference = readExr(referencePath.string());
    const Scene scene = loadScene((dir / (c.scene + ".xml")).string());

    FilmSettings film;
    film.width = reference.width;
    film.height = reference.height;
    std::vector<double> errors;
    for (std::int64_t photons : {25'000, 100'000, 400'000}) {
        const std::map<std::string, ParamValue> params = {
            {"eye.spp", std::int64_t{2}},
            {"photon.photons", photons},
            {"photon.store", std::string("caustic")},
            {c.bandwidthParam, c.bandwidth},
        };
        const test::RenderedImage image = test::renderPipeline(scene, c.pipeline, params, film);
        ImageChannels rendered;
        rendered.width = image.width;
        rendered.height = image.height;
        rendered.rgb = image.pixels;
        errors.push_back(compareImages(rendered, reference).rmse);
    }
    EXPECT_LT(errors[1], errors[0]) << c.pipeline << " on " << c.scene;
    EXPECT_LT(errors[2], errors[1]) << c.pipeline << " on " << c.scene;
}

INSTANTIATE_TEST_SUITE_P(
    Scenes, CausticConvergence,
    ::testing::Values(ConvergenceCase{"water-wave", "spm", "gather.k_caustic", std::int64_t{50}},
                      ConvergenceCase{"water-wave", "pds", "photon.smoothing", 10.0},
                      ConvergenceCase{"gold-ring", "spm", "gather.k_caustic", std::int64_t{50}},
                      ConvergenceCase{"gold-ring", "pds", "photon.smoothing", 10.0}),
    [](const ::testing::TestParamInfo<ConvergenceCase>& param) {
        std::string name = param.param.scene + "_" + param.param.pipeline;
        std::replace(name.begin(), name.end(), '-', '_');
        return name;
    });

}  // namespace
}  // namespace fg
