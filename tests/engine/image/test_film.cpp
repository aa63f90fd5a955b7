#include "engine/image/film.h"

#include "jobs/parallel.h"
#include "jobs/random.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <vector>

namespace fg {
namespace {

// Sample storage for a round over pixels [first, first + count), in pixel order.
struct RoundData {
    std::size_t firstPixel = 0;
    std::size_t pixelCount = 0;
    int samplesPerPixel = 1;
    std::vector<Vec2> raster;
    std::vector<Rgb> radiance;

    SampleRound view() const { return {firstPixel, pixelCount, samplesPerPixel, raster, radiance}; }
    RoundData slice(std::size_t first, std::size_t count) const {
        RoundData part;
        part.firstPixel = first;
        part.pixelCount = count;
        part.samplesPerPixel = samplesPerPixel;
        const std::size_t spp = static_cast<std::size_t>(samplesPerPixel);
        const std::size_t begin = (first - firstPixel) * spp;
        part.raster.assign(raster.begin() + static_cast<std::ptrdiff_t>(begin),
                           raster.begin() + static_cast<std::ptrdiff_t>(begin + count * spp));
        part.radiance.assign(radiance.begin() + static_cast<std::ptrdiff_t>(begin),
                             radiance.begin() + static_cast<std::ptrdiff_t>(begin + count * spp));
        return part;
    }
};

// Random positions inside each pixel's raster cell. Radiance values are
// multiples of 1/8 below 64, so sums of a few of them are exact in float.
RoundData randomRound(int width, int height, int spp, std::uint64_t seed, bool includeCellCorner = false) {
    RoundData round;
    round.pixelCount = static_cast<std::size_t>(width) * static_cast<std::size_t>(height);
    round.samplesPerPixel = spp;
    for (std::size_t p = 0; p < round.pixelCount; ++p) {
        jobs::Rng rng(seed, 0, p);
        const float px = static_cast<float>(p % static_cast<std::size_t>(width));
        const float py = static_cast<float>(p / static_cast<std::size_t>(width));
        for (int s = 0; s < spp; ++s) {
            Vec2 u = 0.999f * rng.uniform2();
            // The cell's top-left corner lies on the edge shared with three
            // neighbours; it must still belong to this pixel alone.
            if (includeCellCorner && s == 0) u = Vec2(0.0f);
            round.raster.emplace_back(px + u.x, py + u.y);
            auto eighths = [&] { return std::floor(rng.uniform() * 512.0f) / 8.0f; };
            round.radiance.emplace_back(eighths(), eighths(), eighths());
        }
    }
    return round;
}

bool bitIdentical(const std::vector<Rgb>& a, const std::vector<Rgb>& b) {
    return a.size() == b.size() && std::memcmp(a.data(), b.data(), a.size() * sizeof(Rgb)) == 0;
}

double gaussian1D(double d, double radius, double sigma) {
    if (std::abs(d) >= radius) return 0.0;
    return std::max(0.0, std::exp(-d * d / (2 * sigma * sigma)) - std::exp(-radius * radius / (2 * sigma * sigma)));
}

TEST(Film, BoxFilterIsThePerPixelMean) {
    FilmSettings settings;
    settings.width = 13;
    settings.height = 7;
    Film film(settings);
    const RoundData first = randomRound(13, 7, 3, 1, /*includeCellCorner=*/true);
    const RoundData second = randomRound(13, 7, 5, 2);
    film.addRound(first.view());
    film.addRound(second.view());

    const std::vector<Rgb> image = film.resolve();
    ASSERT_EQ(image.size(), film.pixelCount());
    for (std::size_t p = 0; p < film.pixelCount(); ++p) {
        Rgb sum(0.0f);
        for (int s = 0; s < 3; ++s) sum += first.radiance[p * 3 + static_cast<std::size_t>(s)];
        for (int s = 0; s < 5; ++s) sum += second.radiance[p * 5 + static_cast<std::size_t>(s)];
        const Rgb mean = sum / 8.0f;
        EXPECT_EQ(image[p].x, mean.x) << "pixel " << p;
        EXPECT_EQ(image[p].y, mean.y) << "pixel " << p;
        EXPECT_EQ(image[p].z, mean.z) << "pixel " << p;
    }
}

TEST(Film, GaussianFilterKeepsAConstantImageConstant) {
    FilmSettings settings;
    settings.width = 17;
    settings.height = 11;
    settings.filter = FilterKind::Gaussian;
    settings.filterRadius = 1.5f;
    settings.gaussianSigma = 0.5f;
    Film film(settings);
    RoundData round = randomRound(17, 11, 4, 3);
    const Rgb constant(0.3f, 1.7f, 42.0f);
    for (Rgb& l : round.radiance) l = constant;
    film.addRound(round.view());
    film.addRound(round.view());

    for (const Rgb& pixel : film.resolve()) {
        EXPECT_NEAR(pixel.x, constant.x, 1e-6f * constant.x);
        EXPECT_NEAR(pixel.y, constant.y, 1e-6f * constant.y);
        EXPECT_NEAR(pixel.z, constant.z, 1e-6f * constant.z);
    }
}

TEST(Film, TentFilterKeepsAConstantImageConstant) {
    FilmSettings settings;
    settings.width = 13;
    settings.height = 9;
    settings.filter = FilterKind::Tent;
    settings.filterRadius = 1.0f;
    Film film(settings);
    RoundData round = randomRound(13, 9, 5, 11);
    const Rgb constant(0.25f, 3.5f, 17.0f);
    for (Rgb& l : round.radiance) l = constant;
    film.addRound(round.view());

    for (const Rgb& pixel : film.resolve()) {
        EXPECT_NEAR(pixel.x, constant.x, 1e-6f * constant.x);
        EXPECT_NEAR(pixel.y, constant.y, 1e-6f * constant.y);
        EXPECT_NEAR(pixel.z, constant.z, 1e-6f * constant.z);
    }
}

TEST(Film, TentWeightFallsLinearlyToZeroAtTheRadius) {
    FilmSettings settings;
    settings.filter = FilterKind::Tent;
    settings.filterRadius = 1.5f;
    const PixelFilter tent(settings);
    for (float dx : {-1.4f, -0.5f, 0.0f, 0.75f, 1.2f}) {
        for (float dy : {-1.0f, 0.0f, 0.3f, 1.49f}) {
            const double expected = (1.0 - std::abs(dx) / 1.5) * (1.0 - std::abs(dy) / 1.5);
            EXPECT_NEAR(tent(dx, dy), expected, 1e-6) << dx << ", " << dy;
        }
    }
    EXPECT_EQ(tent(1.5f, 0.0f), 0.0f);
    EXPECT_EQ(tent(0.0f, -2.0f), 0.0f);
}

// A tent of radius 1 interpolates linearly: a bright column of samples at one
// pixel centre shares itself with its neighbours by distance.
TEST(Film, TentFilterSpreadsASampleLinearly) {
    FilmSettings settings;
    settings.width = 4;
    settings.height = 1;
    settings.filter = FilterKind::Tent;
    settings.filterRadius = 1.0f;
    Film film(settings);
    // Pixel 1 holds one sample 0.25 px right of its centre, the others one dark sample each at their centres.
    const std::vector<Vec2> raster = {{0.5f, 0.5f}, {1.75f, 0.5f}, {2.5f, 0.5f}, {3.5f, 0.5f}};
    const std::vector<Rgb> radiance = {Rgb(0.0f), Rgb(1.0f), Rgb(0.0f), Rgb(0.0f)};
    SampleRound round;
    round.firstPixel = 0;
    round.pixelCount = 4;
    round.samplesPerPixel = 1;
    round.raster = raster;
    round.radiance = radiance;
    film.addRound(round);
    const std::vector<Rgb> image = film.resolve();
    // Pixel 1: weight 0.75 on the bright sample, 0 on its neighbours (distance 1): 1.
    EXPECT_NEAR(image[1].x, 1.0f, 1e-6f);
    // Pixel 2: bright at distance 0.75 (weight 0.25), its own dark at 0 (weight 1): 0.25 / 1.25.
    EXPECT_NEAR(image[2].x, 0.2f, 1e-6f);
    // Pixel 0: the bright sample is 1.25 away, beyond the radius.
    EXPECT_EQ(image[0].x, 0.0f);
}

TEST(Film, GaussianWeightIsSeparableAndVanishesAtTheRadius) {
    FilmSettings settings;
    settings.filter = FilterKind::Gaussian;
    settings.filterRadius = 2.0f;
    settings.gaussianSigma = 0.7f;
    const PixelFilter gaussian(settings);
    for (float dx : {-1.9f, -0.6f, 0.0f, 0.25f, 1.3f}) {
        for (float dy : {-1.2f, 0.0f, 0.4f, 1.99f}) {
            const double expected = gaussian1D(dx, 2.0, 0.7) * gaussian1D(dy, 2.0, 0.7);
            EXPECT_NEAR(gaussian(dx, dy), expected, 1e-6) << dx << ", " << dy;
        }
    }
    EXPECT_EQ(gaussian(2.0f, 0.0f), 0.0f);
    EXPECT_EQ(gaussian(0.0f, -2.5f), 0.0f);
    EXPECT_GT(gaussian(0.0f, 0.0f), gaussian(0.1f, 0.0f));

    FilmSettings box;
    box.filterRadius = 0.5f;
    const PixelFilter boxFilter(box);
    EXPECT_EQ(boxFilter(0.0f, 0.0f), 1.0f);
    EXPECT_EQ(boxFilter(-0.5f, -0.5f), 1.0f);
    EXPECT_EQ(boxFilter(0.5f, 0.0f), 0.0f);
    EXPECT_EQ(boxFilter(0.0f, 0.5f), 0.0f);
}

TEST(Film, GaussianResultIsTheNormalisedWeightedMeanOverAllSamples) {
    FilmSettings settings;
    settings.width = 7;
    settings.height = 5;
    settings.filter = FilterKind::Gaussian;
    settings.filterRadius = 2.0f;
    settings.gaussianSigma = 0.8f;
    Film film(settings);
    const RoundData round = randomRound(7, 5, 2, 17);
    film.addRound(round.view());
    const std::vector<Rgb> image = film.resolve();

    // Brute force: every sample of the image, whatever pixel it belongs to.
    for (int py = 0; py < 5; ++py) {
        for (int px = 0; px < 7; ++px) {
            double sumW = 0.0;
            double sum[3] = {0.0, 0.0, 0.0};
            for (std::size_t s = 0; s < round.raster.size(); ++s) {
                const double w = gaussian1D(round.raster[s].x - (px + 0.5), 2.0, 0.8) *
                                 gaussian1D(round.raster[s].y - (py + 0.5), 2.0, 0.8);
                sumW += w;
                for (int c = 0; c < 3; ++c) sum[c] += w * round.radiance[s][c];
            }
            ASSERT_GT(sumW, 0.0);
            const Rgb& pixel = image[static_cast<std::size_t>(py * 7 + px)];
            for (int c = 0; c < 3; ++c)
                EXPECT_NEAR(pixel[c], sum[c] / sumW, 1e-5 * std::max(1.0, sum[c] / sumW))
                    << "pixel " << px << "," << py << " channel " << c;
        }
    }
}

TEST(Film, PixelsWithoutWeightResolveToZeroPlusDirectAdditions) {
    FilmSettings settings;
    settings.width = 4;
    settings.height = 2;
    Film film(settings);
    RoundData round = randomRound(4, 2, 2, 5).slice(0, 4);  // only the top row
    film.addRound(round.view());
    std::vector<Rgb> direct(8);
    for (std::size_t p = 0; p < 8; ++p) direct[p] = Rgb(static_cast<float>(p), 0.5f, 0.0f);
    film.addToPixels(direct, 2.0f);
    film.addToPixels(direct, 0.25f);

    const std::vector<Rgb> image = film.resolve();
    for (std::size_t p = 0; p < 8; ++p) {
        Rgb expected = direct[p] * 2.25f;
        if (p < 4) expected += (round.radiance[p * 2] + round.radiance[p * 2 + 1]) / 2.0f;
        EXPECT_FLOAT_EQ(image[p].x, expected.x) << p;
        EXPECT_FLOAT_EQ(image[p].y, expected.y) << p;
        EXPECT_FLOAT_EQ(image[p].z, expected.z) << p;
    }
}

TEST(Film, ResultDoesNotDependOnTheThreadCount) {
    FilmSettings settings;
    settings.width = 96;
    settings.height = 80;
    settings.filter = FilterKind::Gaussian;
    settings.filterRadius = 2.0f;
    settings.gaussianSigma = 0.6f;
    const RoundData round = randomRound(96, 80, 4, 7);
    auto render = [&](int threads) {
        jobs::ThreadLimit limit(threads);
        Film film(settings);
        film.addRound(round.view());
        // Uneven tiles whose boundaries fall inside rows.
        film.addRound(round.slice(0, 1234).view());
        film.addRound(round.slice(1234, round.pixelCount - 1234).view());
        return film.resolve();
    };
    const std::vector<Rgb> single = render(1);
    const std::vector<Rgb> two = render(2);
    EXPECT_TRUE(bitIdentical(single, two));
}

TEST(Film, SubRangeRoundsMatchOneFullRoundWithTheBoxFilter) {
    FilmSettings settings;
    settings.width = 31;
    settings.height = 9;
    const RoundData round = randomRound(31, 9, 3, 11);
    Film whole(settings), pieces(settings);
    whole.addRound(round.view());
    pieces.addRound(round.slice(100, round.pixelCount - 100).view());
    pieces.addRound(round.slice(0, 100).view());
    EXPECT_TRUE(bitIdentical(whole.resolve(), pieces.resolve()));
}

TEST(Film, SubRangeRoundsReachNeighbouringRowsWithTheGaussianFilter) {
    FilmSettings settings;
    settings.width = 20;
    settings.height = 10;
    settings.filter = FilterKind::Gaussian;
    settings.filterRadius = 1.5f;
    settings.gaussianSigma = 0.5f;
    const RoundData round = randomRound(20, 10, 4, 13);
    Film whole(settings), rows(settings);
    whole.addRound(round.view());
    for (std::size_t row = 0; row < 10; ++row) rows.addRound(round.slice(row * 20, 20).view());
    const std::vector<Rgb> a = whole.resolve(), b = rows.resolve();
    for (std::size_t p = 0; p < a.size(); ++p)
        for (int c = 0; c < 3; ++c) EXPECT_NEAR(a[p][c], b[p][c], 1e-5f * std::max(1.0f, a[p][c])) << p;
}

TEST(Film, NamedAovsAreCreatedOnceAndCountedInBytes) {
    FilmSettings settings;
    settings.width = 8;
    settings.height = 4;
    Film film(settings);
    const std::size_t before = film.bytes();
    EXPECT_GE(before, film.pixelCount() * (sizeof(Rgb) + sizeof(float)));
    film.aov("time_ns")[3] = 5.0f;
    film.aov("samples")[0] = 1.0f;
    EXPECT_EQ(film.aov("time_ns")[3], 5.0f);
    ASSERT_EQ(film.aovs().size(), 2u);
    EXPECT_EQ(film.aovs()[0].first, "time_ns");
    EXPECT_EQ(film.aovs()[1].first, "samples");
    EXPECT_EQ(film.aovs()[1].second.size(), film.pixelCount());
    EXPECT_GE(film.bytes(), before + 2 * film.pixelCount() * sizeof(float));
}

TEST(Film, RejectsMismatchedRounds) {
    Film film(FilmSettings{});
    RoundData round = randomRound(4, 1, 2, 1);
    round.raster.pop_back();
    EXPECT_THROW(film.addRound(round.view()), std::invalid_argument);
    RoundData outside = randomRound(4, 1, 1, 1);
    outside.firstPixel = film.pixelCount() - 2;
    EXPECT_THROW(film.addRound(outside.view()), std::invalid_argument);
}

}  // namespace
}  // namespace fg
