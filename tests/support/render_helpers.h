// Helpers for tests that render small programmatic scenes through the real
// scheduler and passes.
#pragma once

#include "engine/image/film.h"
#include "engine/scene/scene.h"
#include "engine/core/scheduler.h"

#include <map>
#include <string>
#include <vector>

namespace fg::test {

struct RenderedImage {
    int width = 0;
    int height = 0;
    std::vector<Rgb> pixels;
    const Rgb& at(int x, int y) const { return pixels[static_cast<std::size_t>(y) * width + x]; }
    Rgb mean() const;
};

// A diffuse BSDF of constant albedo added to the scene; returns its index.
int addDiffuse(Scene& scene, const Rgb& albedo);
// Film settings of the given size, everything else default.
FilmSettings smallFilm(int width, int height);
// The furnace: a camera inside a diffuse sphere (radius 1, albedo 0.5, normals
// inward) around a point light of intensity pi at its centre. Direct radiance
// is 0.5 and every bounce adds half the previous, so every pixel sees radiance
// 1 (less 0.5^(d+1) at a depth limit of d scattering events).
Scene furnaceSphereScene();

// Runs a built-in pipeline on `scene` with the given pass parameters
// ("instance.param" -> value) and returns its "image" result.
RenderedImage renderPipeline(const Scene& scene, const std::string& pipeline,
                             const std::map<std::string, ParamValue>& params, const FilmSettings& film,
                             std::uint64_t seed = 1, int threads = 0);

// Renders the pipeline at 1 and at 2 threads and expects the same pixels bit
// for bit, and an image that is not black (which any thread count would
// give alike). `label` names the case in failure messages.
void expectSameImageAtOneAndTwoThreads(const Scene& scene, const std::string& pipeline,
                                       const std::map<std::string, ParamValue>& params, const FilmSettings& film,
                                       const std::string& label = "");

// Means (R, G, B averaged) of a width x height image over blocksPerSide x
// blocksPerSide blocks, row by row.
std::vector<double> blockMeans(const std::vector<Rgb>& pixels, int width, int height, int blocksPerSide);

}  // namespace fg::test
