// Film noise pass (`film_noise`): how noisy a progressively rendered film
// still is, for repeat blocks that stop when the image is good enough. Each
// iteration adds an independent batch of samples to the film (pt's
// `accumulate` input); the batch's own estimate of a pixel is the difference
// of the film's sums before and after it, divided by the difference of the
// weights. Over n batches the per-pixel sample variance s² of those estimates
// (Welford's update) gives the variance of the accumulated pixel, s²/n — the
// usual batch-means estimate, unbiased whatever the pixel's distribution. The
// pass reports the image's relative standard error
//     sqrt(mean over pixels of s²/n) / mean pixel value   (luminance)
// and raises `converged` once it falls below `threshold` (after `min_batches`).
// Deterministic: pixels are visited in order and sums are in double.
#include "passes/passes.h"

#include "engine/buffers/film_noise.h"
#include "engine/core/error.h"
#include "engine/image/film.h"

#include <cmath>

namespace fg {

namespace {

float luminanceOf(const Rgb& c) { return 0.2126f * c.x + 0.7152f * c.y + 0.0722f * c.z; }

class FilmNoisePass final : public Pass {
public:
    void run(PassContext& ctx) override {
        const Film& film = ctx.input<Film>("image");
        const std::size_t pixels = film.pixelCount();
        FilmNoise& noise = ctx.hasInput("previous") ? ctx.createOutput<FilmNoise>("noise", ctx.input<FilmNoise>("previous"))
                                                    : ctx.createOutput<FilmNoise>("noise", pixels);
        if (noise.previousSums.size() != pixels)
            throw InputError("pass '" + ctx.instanceName() + "': the noise statistics are for " +
                             std::to_string(noise.previousSums.size()) + " pixels, the film has " + std::to_string(pixels));
        const auto& sums = film.weightedSums();
        const auto& weights = film.weightSums();
        double varianceOfMeans = 0.0, meanValue = 0.0;
        ++noise.batches;
        const auto n = static_cast<double>(noise.batches);
        for (std::size_t p = 0; p < pixels; ++p) {
            const float batchWeight = weights[p] - noise.previousWeights[p];
            if (batchWeight > 0.0f) {
                const double value = luminanceOf(sums[p] - noise.previousSums[p]) / batchWeight;
                const double delta = value - noise.mean[p];
                noise.mean[p] += delta / n;
                noise.m2[p] += delta * (value - noise.mean[p]);
            }
            noise.previousSums[p] = sums[p];
            noise.previousWeights[p] = weights[p];
            meanValue += noise.mean[p];
            if (noise.batches > 1) varianceOfMeans += noise.m2[p] / (n - 1.0) / n;
        }
        meanValue /= static_cast<double>(pixels);
        noise.relativeError = noise.batches > 1 && meanValue > 0.0
                                  ? std::sqrt(varianceOfMeans / static_cast<double>(pixels)) / meanValue
                                  : INFINITY;
        ctx.addItems(static_cast<std::int64_t>(pixels));
        ctx.addCounter("relative_error_ppm",
                       std::isfinite(noise.relativeError) ? static_cast<std::int64_t>(noise.relativeError * 1e6) : -1);
        if (noise.batches >= ctx.params().getInt("min_batches") && noise.relativeError <= ctx.params().getFloat("threshold"))
            ctx.signal("converged");
    }
};

}  // namespace

PassRegistration filmNoisePass() {
    PassSpec spec;
    spec.name = "film_noise";
    spec.doc = "Relative standard error of a progressively accumulated film (batch means); raises 'converged'";
    SlotSpec previous{"previous", "FilmNoise", "the statistics after the previous batch (carried)"};
    previous.optional = true;
    spec.inputs = {{"image", "Film", "the film after this batch of samples was added"}, previous};
    spec.outputs = {{"noise", "FilmNoise", "per-pixel batch statistics and the image's relative standard error"}};
    spec.params = {
        {"threshold", ParamType::Float, 0.01, 1e-9, 1e9, {},
         "relative standard error of the mean image (luminance) below which 'converged' is raised"},
        {"min_batches", ParamType::Int, std::int64_t{4}, 2, 1 << 30, {},
         "batches before the estimate is trusted (the variance of fewer is itself too noisy)"},
    };
    spec.signals = {"converged"};
    // Per pixel: the previous sums and weights and two running moments.
    const auto memory = [](const PreflightContext& pf) {
        const std::uint64_t pixels = static_cast<std::uint64_t>(pf.film.width) * static_cast<std::uint64_t>(pf.film.height);
        return MemoryEstimate{multiplyBytes(pixels, sizeof(Rgb) + sizeof(float) + 2 * sizeof(double)),
                              "noise statistics of " + std::to_string(pixels) + " pixels", {}};
    };
    return {spec, [] { return std::make_unique<FilmNoisePass>(); }, {}, memory};
}

}  // namespace fg
