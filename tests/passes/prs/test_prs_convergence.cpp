// Photon ray splatting (prs, tangent-plane end cap) on the Cornell box
// converges towards the path-traced reference as the photon count grows.
//
// What is compared is the indirect light alone, in 8 x 8 blocks of a 64 x 64
// image (16 x 16 blocks of the 128 x 128 reference), leaving out the blocks
// that hold the emitter: prs renders with the eye pass's direct light off,
// and the target is the reference minus a one-bounce pt image (emission and
// direct light) at 64 samples per pixel. With the direct light in, its noise
// at one eye sample per pixel set a floor the photon count cannot move (the
// full image's block error stalled at 0.0027 from 32k photons on). Block
// means keep the smoothing bias of the splats, which spans many pixels.
#include "engine/image/image_io.h"
#include "engine/scene/scene_loader.h"
#include "tests/support/render_helpers.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <vector>

namespace fg {
namespace {

namespace fs = std::filesystem;

constexpr int kSize = 64;
constexpr int kBlock = 8;  // pixels of the 64 x 64 image per block side
constexpr int kBlocks = kSize / kBlock;

std::vector<double> blockMeans(const std::vector<Rgb>& pixels, int width, int height) {
    return test::blockMeans(pixels, width, height, kBlocks);
}

struct BlockError {
    double rms = 0.0;   // root mean square of block errors
    double bias = 0.0;  // mean signed block error
};

BlockError blockError(const std::vector<double>& test, const std::vector<double>& reference,
                      const std::vector<bool>& used) {
    double sum2 = 0.0, sum = 0.0;
    int n = 0;
    for (std::size_t b = 0; b < test.size(); ++b) {
        if (!used[b]) continue;
        const double e = test[b] - reference[b];
        sum2 += e * e;
        sum += e;
        ++n;
    }
    return {std::sqrt(sum2 / n), sum / n};
}

TEST(PrsCornellBox, IndirectBlockErrorFallsAsPhotonsGrow) {
    const fs::path dir = fs::path(FLUXGRAPH_SOURCE_DIR) / "data" / "cornell-box";
    const ImageChannels reference = readExr((dir / "reference" / "reference.exr").string());
    ASSERT_EQ(reference.width % kBlocks, 0);
    std::vector<double> target = blockMeans(reference.rgb, reference.width, reference.height);
    // Blocks with emitter pixels (radiance in the tens) are left out.
    std::vector<bool> used(target.size(), true);
    const int scale = reference.width / kBlocks;
    for (int y = 0; y < reference.height; ++y)
        for (int x = 0; x < reference.width; ++x)
            if (maxComponent(reference.rgb[static_cast<std::size_t>(y) * reference.width + x]) > 2.0f)
                used[static_cast<std::size_t>((y / scale) * kBlocks + x / scale)] = false;

    const Scene scene = loadScene((dir / "cornell-box.xml").string());
    FilmSettings film;
    film.width = kSize;
    film.height = kSize;
    // The indirect light of the reference: minus emission and direct light
    // (pt with one bounce, at 64 samples per pixel).
    const test::RenderedImage direct =
        test::renderPipeline(scene, "pt", {{"pt.spp", std::int64_t{64}}, {"pt.max_depth", std::int64_t{1}}}, film);
    const std::vector<double> directBlocks = blockMeans(direct.pixels, direct.width, direct.height);
    for (std::size_t b = 0; b < target.size(); ++b) target[b] -= directBlocks[b];

    double indirectMean = 0.0;
    int usedBlocks = 0;
    for (std::size_t b = 0; b < target.size(); ++b)
        if (used[b]) {
            indirectMean += target[b];
            ++usedBlocks;
        }
    indirectMean /= usedBlocks;

    std::vector<BlockError> errors;
    for (std::int64_t photons : {4'000, 32'000, 256'000}) {
        const std::map<std::string, ParamValue> params = {
            {"eye.spp", std::int64_t{1}},
            {"eye.direct_light", false},
            {"photon.photons", photons},
            {"photon.photon_rays", true},
            {"photon.store", std::string("none")},
            {"ray_splat.end_cap", std::string("tangent_plane")},
        };
        const test::RenderedImage image = test::renderPipeline(scene, "prs", params, film);
        errors.push_back(blockError(blockMeans(image.pixels, image.width, image.height), target, used));
        std::printf("photons %lld: block rms error %.5f, mean signed %.5f\n", static_cast<long long>(photons),
                    errors.back().rms, errors.back().bias);
    }
    // Over five photon seeds (0, 11-14) the block rms errors were
    // 0.00326 +- 0.00024, 0.00184 +- 0.00014 and 0.00126 +- 0.00008; each
    // eightfold step shrank them by 0.57 +- 0.06 and 0.68 +- 0.05. A factor
    // of 0.85 lies 4.6 and 3.4 standard deviations above those, and an
    // estimate off by a constant factor (the 1/pi or lost-footprint bugs this
    // test was written after) stops falling once its bias dominates.
    EXPECT_LT(errors[1].rms, 0.85 * errors[0].rms);
    EXPECT_LT(errors[2].rms, 0.85 * errors[1].rms);
    // The indirect light's mean over the blocks: the remaining smoothing bias
    // was -0.00085 +- 0.00003 against a mean of 0.0217 (3.7 %, the kernel
    // spilling out through the open front and round corners); a missing factor
    // shows as tens of percent.
    std::printf("indirect mean %.5f\n", indirectMean);
    EXPECT_LT(std::abs(errors[2].bias), 0.1 * indirectMean);
}

}  // namespace
}  // namespace fg
