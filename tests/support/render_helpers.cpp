#include "tests/support/render_helpers.h"

#include "passes/passes.h"
#include "engine/accel/ray_query.h"
#include "engine/shading/bsdf.h"
#include "engine/shading/light.h"
#include "engine/shading/texture.h"
#include "jobs/parallel.h"

#include <gtest/gtest.h>

#include <stdexcept>

namespace fg::test {

Rgb RenderedImage::mean() const {
    glm::dvec3 sum(0.0);
    for (const Rgb& p : pixels) sum += glm::dvec3(p);
    return Rgb(sum / static_cast<double>(std::max<std::size_t>(1, pixels.size())));
}

int addDiffuse(Scene& scene, const Rgb& albedo) {
    scene.bsdfs.push_back(makeDiffuse(makeConstantTexture(albedo)));
    return static_cast<int>(scene.bsdfs.size()) - 1;
}

FilmSettings smallFilm(int width, int height) {
    FilmSettings film;
    film.width = width;
    film.height = height;
    return film;
}

Scene furnaceSphereScene() {
    Scene scene;
    Shape sphere;
    sphere.geometry = Sphere{Vec3(0.0f), 1.0f};
    sphere.flipNormals = true;
    sphere.bsdf = addDiffuse(scene, Rgb(0.5f));
    scene.shapes.push_back(sphere);
    scene.lights.push_back(makePointLight(Vec3(0.0f), Rgb(kPi)));
    scene.lightShape.push_back(-1);
    scene.camera.eye = Vec3(0.0f, 0.0f, 0.3f);
    scene.camera.target = Vec3(0.3f, 0.2f, -1.0f);
    scene.camera.fovYDegrees = 90.0f;
    scene.finalize();
    return scene;
}

RenderedImage renderPipeline(const Scene& scene, const std::string& pipeline,
                             const std::map<std::string, ParamValue>& params, const FilmSettings& film,
                             std::uint64_t seed, int threads) {
    const Pipeline* p = findPipeline(pipeline);
    if (!p) throw std::invalid_argument("no pipeline " + pipeline);
    JobParams jobParams;
    for (const auto& [key, value] : params) {
        const auto dot = key.find('.');
        jobParams.values[key.substr(0, dot)][key.substr(dot + 1)] = {value, "test"};
    }
    const ExecutionPlan plan = ExecutionPlan::build(*p, jobParams, "test");
    const jobs::ThreadLimit limit(threads);
    const RayQuery rays(scene);
    RunOptions options;
    options.seed = seed;
    options.film = film;
    const RunResult result = execute(plan, scene, rays, options);
    const Film& image = *static_cast<const Film*>(result.results.at("image").data.get());
    return {image.width(), image.height(), image.resolve()};
}

void expectSameImageAtOneAndTwoThreads(const Scene& scene, const std::string& pipeline,
                                       const std::map<std::string, ParamValue>& params, const FilmSettings& film,
                                       const std::string& label) {
    const RenderedImage one = renderPipeline(scene, pipeline, params, film, 1, 1);
    const RenderedImage two = renderPipeline(scene, pipeline, params, film, 1, 2);
    ASSERT_EQ(one.pixels.size(), two.pixels.size()) << label;
    double sum = 0.0;
    for (std::size_t i = 0; i < one.pixels.size(); ++i) {
        ASSERT_EQ(one.pixels[i], two.pixels[i]) << label << ": pixel " << i;
        sum += one.pixels[i].x + one.pixels[i].y + one.pixels[i].z;
    }
    EXPECT_GT(sum, 0.0) << label;
}

std::vector<double> blockMeans(const std::vector<Rgb>& pixels, int width, int height, int blocksPerSide) {
    std::vector<double> means(static_cast<std::size_t>(blocksPerSide * blocksPerSide), 0.0);
    const int bw = width / blocksPerSide, bh = height / blocksPerSide;
    for (int y = 0; y < height; ++y)
        for (int x = 0; x < width; ++x) {
            const Rgb& p = pixels[static_cast<std::size_t>(y) * static_cast<std::size_t>(width) + x];
            means[static_cast<std::size_t>((y / bh) * blocksPerSide + x / bw)] +=
                (static_cast<double>(p.x) + p.y + p.z) / (3.0 * bw * bh);
        }
    return means;
}

}  // namespace fg::test
