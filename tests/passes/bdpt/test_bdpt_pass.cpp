// Bidirectional path tracing against scenes with known answers and against pt.
#include "engine/shading/bsdf.h"
#include "engine/shading/light.h"
#include "engine/scene/scene.h"
#include "tests/support/airlight.h"
#include "tests/support/render_helpers.h"

#include "engine/accel/ray_query.h"
#include "engine/core/job.h"
#include "engine/core/scheduler.h"
#include "jobs/parallel.h"
#include "passes/passes.h"

#include <glm/gtc/matrix_transform.hpp>
#include <gtest/gtest.h>

#include <cmath>

namespace fg {
namespace {

using test::renderPipeline;

// Renders the bdpt pipeline and returns its film, AOVs included.
Film renderBdptFilm(const Scene& scene, const std::map<std::string, ParamValue>& params, const FilmSettings& film,
                    std::uint64_t seed = 1, int threads = 2) {
    const Pipeline* pipeline = findPipeline("bdpt");
    JobParams jobParams;
    for (const auto& [key, value] : params) jobParams.values["bdpt"][key] = {value, "test"};
    const ExecutionPlan plan = ExecutionPlan::build(*pipeline, jobParams, "test");
    const jobs::ThreadLimit limit(threads);
    const RayQuery rays(scene);
    RunOptions options;
    options.seed = seed;
    options.film = film;
    const RunResult result = execute(plan, scene, rays, options);
    return *static_cast<const Film*>(result.results.at("image").data.get());
}

// Mean of AOV channel `name` over the image.
double aovMean(Film& film, const std::string& name) {
    const std::vector<float>& values = film.aov(name);
    double sum = 0.0;
    for (float v : values) sum += v;
    return sum / static_cast<double>(values.size());
}

int addDiffuse(Scene& scene, const Rgb& albedo) {
    scene.bsdfs.push_back(makeDiffuse(makeConstantTexture(albedo)));
    return static_cast<int>(scene.bsdfs.size()) - 1;
}

FilmSettings smallFilm(int w, int h) {
    FilmSettings f;
    f.width = w;
    f.height = h;
    return f;
}

// pt's furnace: a camera inside a diffuse sphere of albedo 0.5 around a point
// light of intensity pi sees radiance 1 (sum of 0.5^k over k bounces; the
// depth limit of 64 segments leaves out 0.5^64).
TEST(BdptPass, FurnaceSphereHasUnitRadiance) {
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

    const auto image = renderPipeline(scene, "bdpt", {{"bdpt.spp", std::int64_t{16}}, {"bdpt.max_depth", std::int64_t{64}}},
                                      smallFilm(24, 24), 1, 2);
    const Rgb mean = image.mean();
    for (int c = 0; c < 3; ++c) EXPECT_NEAR(mean[c], 1.0f, 0.01f) << "channel " << c;
}

}  // namespace
}  // namespace fg
