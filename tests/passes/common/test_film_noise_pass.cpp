// film_noise: the batch-means estimate of a progressive film's relative
// standard error, checked against the formula on hand-made batches.
#include "engine/buffers/film_noise.h"
#include "engine/core/error.h"
#include "engine/image/film.h"
#include "engine/scene/scene.h"
#include "passes/passes.h"
#include "tests/support/pass_helpers.h"

#include <gtest/gtest.h>

#include <cmath>
#include <memory>
#include <vector>

namespace fg {
namespace {

using test::bufferAs;
using test::makeBuffer;

// Adds one sample per pixel (grey `values[p]`) at the pixel centres: with the
// box filter each is its pixel's only contribution, of weight 1.
void addBatch(Film& film, const std::vector<float>& values) {
    std::vector<Vec2> raster;
    std::vector<Rgb> radiance;
    for (int p = 0; p < film.width(); ++p) {
        raster.emplace_back(static_cast<float>(p) + 0.5f, 0.5f);
        radiance.emplace_back(values[static_cast<std::size_t>(p)]);
    }
    film.addRound({0, raster.size(), 1, raster, radiance});
}

TEST(FilmNoise, RelativeErrorIsTheBatchMeansEstimate) {
    FilmSettings settings;
    settings.width = 2;
    settings.height = 1;
    const std::vector<std::vector<float>> batches = {{1.0f, 4.0f}, {3.0f, 2.0f}, {2.0f, 6.0f}, {2.0f, 4.0f}};
    auto film = std::make_shared<Film>(settings);
    std::shared_ptr<const FilmNoise> previous;
    const Scene scene;
    for (std::size_t n = 1; n <= batches.size(); ++n) {
        addBatch(*film, batches[n - 1]);
        std::map<std::string, BufferHandle> inputs = {{"image", makeBuffer(std::make_shared<Film>(*film))}};
        if (previous) inputs["previous"] = makeBuffer(std::make_shared<FilmNoise>(*previous));
        const auto out = test::runPass(filmNoisePass(), scene, nullptr, settings, inputs, {{"min_batches", std::int64_t{2}}});
        const FilmNoise& noise = bufferAs<FilmNoise>(out.at("noise"));
        EXPECT_EQ(noise.batches, static_cast<std::int64_t>(n));
        // Per pixel: mean and sample variance of its n batch values (luminance of grey = the value).
        double varianceOfMeans = 0.0, meanValue = 0.0;
        for (std::size_t p = 0; p < 2; ++p) {
            double mean = 0.0;
            for (std::size_t b = 0; b < n; ++b) mean += batches[b][p];
            mean /= static_cast<double>(n);
            double squares = 0.0;
            for (std::size_t b = 0; b < n; ++b) squares += (batches[b][p] - mean) * (batches[b][p] - mean);
            meanValue += mean / 2.0;
            if (n > 1) varianceOfMeans += squares / static_cast<double>(n - 1) / static_cast<double>(n) / 2.0;
        }
        if (n == 1) {
            EXPECT_TRUE(std::isinf(noise.relativeError));
        } else {
            EXPECT_NEAR(noise.relativeError, std::sqrt(varianceOfMeans) / meanValue, 1e-6) << n << " batches";
        }
        previous = std::make_shared<FilmNoise>(noise);
    }
}

TEST(FilmNoise, StatisticsForAnotherFilmSizeAreAnInputError) {
    FilmSettings settings;
    settings.width = 2;
    settings.height = 1;
    auto film = std::make_shared<Film>(settings);
    addBatch(*film, {1.0f, 1.0f});
    const Scene scene;
    EXPECT_THROW(test::runPass(filmNoisePass(), scene, nullptr, settings,
                               {{"image", makeBuffer(film)}, {"previous", makeBuffer(std::make_shared<FilmNoise>(5))}}),
                 InputError);
}

}  // namespace
}  // namespace fg
