// Photon gathering (SPM) on synthetic photon maps of known irradiance, and
// the spm pipeline's wiring with a stand-in photon pass.
#include "engine/shading/bsdf.h"
#include "engine/shading/light.h"
#include "engine/buffers/photon_buffers.h"
#include "engine/accel/point_index.h"
#include "engine/scene/scene.h"
#include "jobs/parallel.h"
#include "passes/passes.h"
#include "tests/support/pass_helpers.h"
#include "tests/support/photon_fixtures.h"

#include <glm/gtc/matrix_transform.hpp>
#include <gtest/gtest.h>

namespace fg {
namespace {

using test::bufferAs;
using test::makeBuffer;

using test::diffuseScene;
using test::film;
using test::kAlbedo;

BufferHandle indexOf(const Scene& scene, const BufferHandle& photons, bool includeDirect = false) {
    auto out = test::runPass(photonIndexPass(), scene, nullptr, film(1, 1), {{"photons", photons}},
                             {{"include_direct", includeDirect}});
    return out.at("index");
}

// The caustic and global layers of a gather's outputs, summed per pixel.
std::vector<Rgb> causticPlusGlobal(const std::map<std::string, BufferHandle>& out) {
    std::vector<Rgb> sum = bufferAs<Film>(out.at("caustic")).resolve();
    const std::vector<Rgb> global = bufferAs<Film>(out.at("global")).resolve();
    for (std::size_t p = 0; p < sum.size(); ++p) sum[p] += global[p];
    return sum;
}

// m x m eye vertices on [-extent, extent]^2, one per pixel, with varying throughput.
std::shared_ptr<EyeVertices> vertexGrid(int m, float extent) {
    auto eye = std::make_shared<EyeVertices>();
    for (int y = 0; y < m; ++y) {
        for (int x = 0; x < m; ++x) {
            const Vec3 p((2.0f * x / (m - 1) - 1.0f) * extent, (2.0f * y / (m - 1) - 1.0f) * extent, 0.0f);
            const float t = 0.5f + static_cast<float>((x * 7 + y * 3) % 5) * 0.25f;
            test::addEyeVertex(*eye, p, static_cast<std::uint32_t>(y * m + x), Rgb(t, 0.8f * t, 1.2f * t));
        }
    }
    return eye;
}

// Uniform photons of irradiance E on a diffuse plane: the estimate is
// rho E / pi (the k-th-neighbour kernel estimate is unbiased for a uniform
// density); caustic and global estimates go to their own layers, which
// start from black; Direct-class photons are not counted.
TEST(PhotonGather, UniformPhotonsGiveLambertianRadiance) {
    const Scene scene = diffuseScene();
    const Rgb causticE(2.0f, 1.0f, 3.0f), globalE(3.0f, 4.0f, 1.0f);
    auto caustic = std::make_shared<PhotonMap>();
    auto global = std::make_shared<PhotonMap>();
    test::addUniformPlanePhotons(*caustic, 40000, 1.0f, causticE, PhotonClass::Caustic, 1);
    test::addUniformPlanePhotons(*global, 60000, 1.0f, globalE, PhotonClass::Global, 2);
    // Light the eye pass already counts: far too bright to go unnoticed.
    test::addUniformPlanePhotons(*global, 20000, 1.0f, Rgb(1000.0f), PhotonClass::Direct, 3);
    const BufferHandle causticMap = makeBuffer(caustic), globalMap = makeBuffer(global);

    const int m = 30;
    const FilmSettings settings = film(m, m);
    auto eye = vertexGrid(m, 0.6f);
    auto out = test::runPass(gatherPass(), scene, nullptr, settings,
                             {{"eye_vertices", makeBuffer(eye)},
                              {"caustic_photons", causticMap},
                              {"global_photons", globalMap},
                              {"caustic_index", indexOf(scene, causticMap)},
                              {"global_index", indexOf(scene, globalMap)}},
                             {{"k_caustic", std::int64_t{40}}, {"k_global", std::int64_t{80}}});
    const std::vector<Rgb> image = causticPlusGlobal(out);
    const Rgb expected = kAlbedo * (causticE + globalE) * kInvPi;
    const double n = static_cast<double>(eye->vertices.size());
    const auto layerMean = [&](const std::string& layer, const Rgb& irradiance) {
        const std::vector<Rgb> radiance = bufferAs<Film>(out.at(layer)).resolve();
        glm::dvec3 sum(0.0);
        for (std::size_t v = 0; v < eye->vertices.size(); ++v) {
            const Rgb t = eye->vertices.column<EyeThroughput>()[v];
            sum += glm::dvec3(radiance[eye->vertices.column<EyePixel>()[v]] / t / (kAlbedo * irradiance * kInvPi));
        }
        return sum / n;
    };
    for (int c = 0; c < 3; ++c) {
        EXPECT_NEAR(layerMean("caustic", causticE)[c], 1.0, 0.04) << "caustic layer, channel " << c;
        EXPECT_NEAR(layerMean("global", globalE)[c], 1.0, 0.04) << "global layer, channel " << c;
    }
    glm::dvec3 ratioSum(0.0), ratioSquares(0.0);
    for (std::size_t v = 0; v < eye->vertices.size(); ++v) {
        const Rgb t = eye->vertices.column<EyeThroughput>()[v];
        const glm::dvec3 ratio(image[eye->vertices.column<EyePixel>()[v]] / t / expected);
        ratioSum += ratio;
        ratioSquares += ratio * ratio;
    }
    const glm::dvec3 meanRatio = ratioSum / n;
    const glm::dvec3 spread = glm::sqrt(glm::max(ratioSquares / n - meanRatio * meanRatio, glm::dvec3(0.0)));
    for (int c = 0; c < 3; ++c) {
        EXPECT_NEAR(meanRatio[c], 1.0, 0.03) << "channel " << c;
        // A kernel estimate from 40 + 80 photons scatters by some 10-30 %: not
        // zero (the photons are random), not more (k would be ignored).
        EXPECT_GT(spread[c], 0.03) << "channel " << c;
        EXPECT_LT(spread[c], 0.4) << "channel " << c;
    }
}

// With fewer than k photons inside max_radius, the radius is the bandwidth:
// one photon straight at a vertex gives f_r Phi K(0) / r^2.
TEST(PhotonGather, MaxRadiusBoundsTheBandwidth) {
    const Scene scene = diffuseScene();
    auto global = std::make_shared<PhotonMap>();
    const Rgb power(1.0f, 2.0f, 0.5f);
    test::addPhoton(*global, Vec3(0.0f), glm::normalize(Vec3(1, 1, 1)), power);
    test::addPhoton(*global, Vec3(0.2f, 0.0f, 0.0f), Vec3(0, 0, 1), power);  // outside the radius
    auto caustic = std::make_shared<PhotonMap>();
    const BufferHandle causticMap = makeBuffer(caustic), globalMap = makeBuffer(global);
    auto eye = std::make_shared<EyeVertices>();
    test::addEyeVertex(*eye, Vec3(0.0f), 0, Rgb(1.0f));
    test::addEyeVertex(*eye, Vec3(0.0f, 0.05f, 0.0f), 1, Rgb(1.0f));  // half the radius away
    test::addEyeVertex(*eye, Vec3(5.0f, 5.0f, 0.0f), 2, Rgb(1.0f));   // no photon in reach
    const float radius = 0.1f;
    const FilmSettings settings = film(3, 1);
    auto out = test::runPass(gatherPass(), scene, nullptr, settings,
                             {{"eye_vertices", makeBuffer(eye)},
                              {"caustic_photons", causticMap},
                              {"global_photons", globalMap},
                              {"caustic_index", indexOf(scene, causticMap)},
                              {"global_index", indexOf(scene, globalMap)}},
                             {{"k_global", std::int64_t{10}}, {"max_radius", static_cast<double>(radius)}});
    const std::vector<Rgb> image = causticPlusGlobal(out);
    const Rgb f = kAlbedo * kInvPi;
    const Rgb atCentre = f * power * (3.0f * kInvPi) / (radius * radius);
    const Rgb halfWay = f * power * (3.0f * kInvPi * sqr(1.0f - 0.25f)) / (radius * radius);
    for (int c = 0; c < 3; ++c) {
        EXPECT_NEAR(image[0][c], atCentre[c], 1e-4f * atCentre[c]);
        EXPECT_NEAR(image[1][c], halfWay[c], 1e-4f * halfWay[c]);
    }
    EXPECT_EQ(image[2], Rgb(0.0f));
}

// Photons from below the surface do not light it.
TEST(PhotonGather, PhotonsFromTheOtherSideAreIgnored) {
    const Scene scene = diffuseScene();
    auto global = std::make_shared<PhotonMap>();
    for (int i = 0; i < 50; ++i)
        test::addPhoton(*global, Vec3(0.001f * i, 0.0f, 0.0f), glm::normalize(Vec3(0.2f, 0.0f, -1.0f)), Rgb(1.0f));
    const BufferHandle causticMap = makeBuffer(std::make_shared<PhotonMap>()), globalMap = makeBuffer(global);
    auto eye = std::make_shared<EyeVertices>();
    test::addEyeVertex(*eye, Vec3(0.01f, 0.0f, 0.0f), 0, Rgb(1.0f));
    const FilmSettings settings = film(1, 1);
    auto out = test::runPass(gatherPass(), scene, nullptr, settings,
                             {{"eye_vertices", makeBuffer(eye)},
                              {"caustic_photons", causticMap},
                              {"global_photons", globalMap},
                              {"caustic_index", indexOf(scene, causticMap)},
                              {"global_index", indexOf(scene, globalMap)}});
    EXPECT_EQ(causticPlusGlobal(out)[0], Rgb(0.0f));
}

TEST(PhotonGather, ImageIsIdenticalForOneAndTwoThreads) {
    const Scene scene = diffuseScene();
    auto caustic = std::make_shared<PhotonMap>();
    auto global = std::make_shared<PhotonMap>();
    test::addUniformPlanePhotons(*caustic, 20000, 1.0f, Rgb(1.0f), PhotonClass::Caustic, 5);
    test::addUniformPlanePhotons(*global, 20000, 1.0f, Rgb(2.0f), PhotonClass::Global, 6);
    const BufferHandle causticMap = makeBuffer(caustic), globalMap = makeBuffer(global);
    // Several vertices per pixel, so per-pixel sums exercise the summation order.
    auto eye = std::make_shared<EyeVertices>();
    jobs::Rng rng(9, jobs::streamKey("gather-threads"), 0);
    for (std::uint32_t i = 0; i < 6000; ++i) {
        const Vec2 u = rng.uniform2();
        test::addEyeVertex(*eye, Vec3(2.0f * u.x - 1.0f, 2.0f * u.y - 1.0f, 0.0f), i / 6, Rgb(rng.uniform()));
    }
    const FilmSettings settings = film(40, 25);
    const auto render = [&](int threads) {
        const jobs::ThreadLimit limit(threads);
        auto out = test::runPass(gatherPass(), scene, nullptr, settings,
                                 {{"eye_vertices", makeBuffer(eye)},
                                  {"caustic_photons", causticMap},
                                  {"global_photons", globalMap},
                                  {"caustic_index", indexOf(scene, causticMap)},
                                  {"global_index", indexOf(scene, globalMap)}});
        return causticPlusGlobal(out);
    };
    const std::vector<Rgb> one = render(1);
    EXPECT_GT(luminance(one[500]), 0.0f);
    EXPECT_EQ(one, render(2));
}

// The spm pipeline as registered, with a stand-in photon pass: a diffuse floor
// lit by a point light; the photon maps hold uniform irradiance on the floor,
// so the image exceeds the eye pass's direct film by rho E / pi per pixel.
TEST(PhotonGather, SpmPipelineAddsPhotonEstimatesToDirectLight) {
    Scene scene;
    Shape floor;
    TriangleMesh plane = makeRectangleMesh();
    plane.transform(glm::scale(Mat4(1.0f), Vec3(2.0f)));
    floor.geometry = plane;
    scene.bsdfs.push_back(makeDiffuse(makeConstantTexture(kAlbedo)));
    floor.bsdf = 0;
    scene.shapes.push_back(floor);
    scene.lights.push_back(makePointLight(Vec3(0.3f, 0.2f, 1.5f), Rgb(4.0f)));
    scene.lightShape.push_back(-1);
    scene.camera.eye = Vec3(0.0f, 0.0f, 3.0f);
    scene.camera.target = Vec3(0.0f);
    scene.camera.fovYDegrees = 25.0f;
    scene.finalize();

    const Rgb causticE(1.0f, 0.5f, 0.2f), globalE(0.5f, 1.0f, 2.0f);
    std::vector<PassRegistration> registry = passRegistry();
    // The stand-in replaces the real photon tracer.
    std::erase_if(registry, [](const PassRegistration& r) { return r.spec.name == "photon"; });
    registry.push_back(test::standInPhotonPass([&](PhotonMap& caustic, PhotonMap& global) {
        test::addUniformPlanePhotons(caustic, 30000, 2.0f, causticE, PhotonClass::Caustic, 1);
        test::addUniformPlanePhotons(global, 30000, 2.0f, globalE, PhotonClass::Global, 2);
    }));
    const FilmSettings settings = film(16, 16);
    const std::map<std::string, ParamValue> params = {{"eye.spp", std::int64_t{2}},
                                                      {"gather.k_caustic", std::int64_t{50}},
                                                      {"gather.k_global", std::int64_t{50}}};
    const Pipeline spm = *findPipeline("spm");
    const std::vector<Rgb> image =
        bufferAs<Film>(test::runPipeline(scene, spm, registry, params, settings, "image")).resolve();
    const std::vector<Rgb> direct =
        bufferAs<Film>(test::runPipeline(scene, spm, registry, params, settings, "direct")).resolve();
    const Rgb expected = kAlbedo * (causticE + globalE) * kInvPi;
    glm::dvec3 sum(0.0);
    for (std::size_t i = 0; i < image.size(); ++i) {
        EXPECT_GT(luminance(direct[i]), 0.0f);
        sum += glm::dvec3(image[i] - direct[i]);
    }
    const glm::dvec3 mean = sum / static_cast<double>(image.size());
    for (int c = 0; c < 3; ++c) EXPECT_NEAR(mean[c] / expected[c], 1.0, 0.03) << "channel " << c;
}

}  // namespace
}  // namespace fg
