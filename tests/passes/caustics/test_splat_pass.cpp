// Photon differential splatting (PDS): single photons with known footprints
// against the closed form of Eqs. 4, 10-12, and the pds pipeline's wiring with
// a stand-in photon pass.
#include "engine/shading/bsdf.h"
#include "engine/core/error.h"
#include "engine/shading/light.h"
#include "engine/buffers/photon_buffers.h"
#include "engine/accel/point_index.h"
#include "engine/accel/ray_query.h"
#include "engine/scene/scene.h"
#include "engine/scene/scene_loader.h"
#include "engine/core/scheduler.h"
#include "jobs/parallel.h"
#include "passes/passes.h"
#include "tests/support/pass_helpers.h"
#include "tests/support/photon_fixtures.h"

#include <glm/gtc/matrix_transform.hpp>
#include <gtest/gtest.h>

#include <filesystem>

namespace fg {
namespace {

using test::bufferAs;
using test::makeBuffer;

using test::diffuseScene;
using test::film;
using test::kAlbedo;

std::vector<Rgb> splat(const Scene& scene, const std::shared_ptr<EyeVertices>& eye,
                       const std::shared_ptr<PhotonMap>& caustics, const FilmSettings& settings,
                       const std::map<std::string, ParamValue>& params = {}) {
    const BufferHandle eyeBuffer = makeBuffer(eye);
    auto index = test::runPass(eyeIndexPass(), scene, nullptr, settings, {{"eye_vertices", eyeBuffer}});
    auto out = test::runPass(splatPass(), scene, nullptr, settings,
                             {{"eye_vertices", eyeBuffer},
                              {"eye_index", index.at("eye_index")},
                              {"caustic_photons", makeBuffer(caustics)}},
                             params);
    return bufferAs<Film>(out.at("caustics")).resolve();
}

// A rigid placement of the footprint's plane, so that nothing relies on z = 0.
struct PlaneFrame {
    Mat3 rotation = Mat3(glm::rotate(Mat4(1.0f), 0.7f, glm::normalize(Vec3(1.0f, 2.0f, 3.0f))));
    Vec3 origin{0.3f, -0.2f, 1.1f};
    Vec3 point(float x, float y, float z = 0.0f) const { return origin + rotation * Vec3(x, y, z); }
    Vec3 vector(float x, float y, float z = 0.0f) const { return rotation * Vec3(x, y, z); }
};

struct GridOfVertices {
    std::shared_ptr<EyeVertices> eye = std::make_shared<EyeVertices>();
    std::vector<Vec2> local;  // plane coordinates of each vertex (= its pixel)
    int side = 0;
    float spacing = 0.0f;
};

// side x side vertices with the given spacing centred on the plane's origin, throughput 1.
GridOfVertices vertexGrid(const PlaneFrame& plane, int side, float spacing, float height = 0.0f) {
    GridOfVertices g;
    g.side = side;
    g.spacing = spacing;
    const float half = 0.5f * spacing * static_cast<float>(side - 1);
    const Vec3 outgoing = glm::normalize(plane.vector(0.2f, -0.1f, 1.0f));
    for (int y = 0; y < side; ++y) {
        for (int x = 0; x < side; ++x) {
            const Vec2 p(-half + spacing * static_cast<float>(x), -half + spacing * static_cast<float>(y));
            g.local.push_back(p);
            test::addEyeVertex(*g.eye, plane.point(p.x, p.y, height), static_cast<std::uint32_t>(y * side + x),
                               Rgb(1.0f), 0, plane.vector(0.0f, 0.0f, 1.0f), outgoing);
        }
    }
    return g;
}

// Filter-space radius² of plane offset d for semi-axes a = Du/2, b = Dv/2 (2D), by Cramer's rule.
float filterRadius2(const Vec2& d, const Vec2& du, const Vec2& dv) {
    const Vec2 a = 0.5f * du, b = 0.5f * dv;
    const float det = a.x * b.y - a.y * b.x;
    const float alpha = (d.x * b.y - d.y * b.x) / det;
    const float beta = (a.x * d.y - a.y * d.x) / det;
    return alpha * alpha + beta * beta;
}

// One photon with footprint Du, Dv (plane coordinates) at the plane's origin:
// checks every vertex against pi K(|M_p d|) f_r Phi / A_p and the total
// against Phi f_r (the kernel is normalised; the vertex grid is a Riemann sum).
void checkSinglePhoton(const Vec2& du, const Vec2& dv, int side, float spacing) {
    const Scene scene = diffuseScene();
    const PlaneFrame plane;
    const GridOfVertices grid = vertexGrid(plane, side, spacing);
    auto caustics = std::make_shared<PhotonMap>();
    caustics->hasDifferentials = true;
    const Rgb power(2.0f, 1.0f, 0.5f);
    const Vec3 incident = glm::normalize(plane.vector(-0.4f, 0.3f, 1.0f));
    test::addPhoton(*caustics, plane.point(0.0f, 0.0f), incident, power, plane.vector(0.0f, 0.0f, 1.0f),
                    PhotonClass::Caustic, plane.vector(du.x, du.y), plane.vector(dv.x, dv.y));
    const std::vector<Rgb> image = splat(scene, grid.eye, caustics, film(side, side));

    const float area = 0.25f * kPi * std::abs(du.x * dv.y - du.y * dv.x);  // Eq. 4
    const Rgb f = kAlbedo * kInvPi;
    const float paperRadius = 0.5f * std::max(glm::length(du), glm::length(dv));
    glm::dvec3 total(0.0);
    int inside = 0, beyondPaperRadius = 0;
    for (std::size_t v = 0; v < grid.local.size(); ++v) {
        total += glm::dvec3(image[v]) * static_cast<double>(spacing * spacing);
        const float s2 = filterRadius2(grid.local[v], du, dv);
        if (std::abs(s2 - 1.0f) < 1e-3f) continue;  // too close to the rim to call
        const Rgb expected = s2 < 1.0f ? 3.0f * sqr(1.0f - s2) * f * power / area : Rgb(0.0f);
        for (int c = 0; c < 3; ++c)
            ASSERT_NEAR(image[v][c], expected[c], 2e-4f * (expected[c] + 1e-3f)) << "vertex " << v << " s2 " << s2;
        if (s2 < 1.0f) {
            ++inside;
            beyondPaperRadius += glm::length(grid.local[v]) > paperRadius ? 1 : 0;
        }
    }
    EXPECT_GT(inside, 100);
    for (int c = 0; c < 3; ++c) EXPECT_NEAR(total[c] / (f[c] * power[c]), 1.0, 0.01) << "channel " << c;
    if (std::abs(glm::dot(du, dv)) > 0.3f * glm::length(du) * glm::length(dv)) {
        EXPECT_GT(beyondPaperRadius, 0) << "a skewed footprint reaches past max(|Du|, |Dv|) / 2";
    }
}

TEST(PhotonSplat, CircularFootprintDepositsTheKernelAndItsFlux) {
    const float radius = 0.5f;
    checkSinglePhoton(Vec2(2.0f * radius, 0.0f), Vec2(0.0f, 2.0f * radius), 97, 0.0125f);
}

TEST(PhotonSplat, AnisotropicFootprintReachesOnlyVerticesInsideTheEllipse) {
    // Elongated and skewed: the ellipse's major axis is longer than either differential.
    checkSinglePhoton(Vec2(0.8f, 0.1f), Vec2(0.6f, 0.3f), 141, 0.0075f);
    checkSinglePhoton(Vec2(0.05f, -0.3f), Vec2(0.4f, 0.02f), 101, 0.006f);
}

TEST(PhotonSplat, CollapsedFootprintsAndMissingDifferentials) {
    const Scene scene = diffuseScene();
    const PlaneFrame plane;
    const GridOfVertices grid = vertexGrid(plane, 11, 0.05f);
    auto caustics = std::make_shared<PhotonMap>();
    caustics->hasDifferentials = true;
    const Vec3 n = plane.vector(0, 0, 1);
    // Parallel differentials, zero differentials, a normal in the footprint's plane.
    test::addPhoton(*caustics, plane.point(0, 0), n, Rgb(1.0f), n, PhotonClass::Caustic, plane.vector(0.2f, 0.1f),
                    plane.vector(0.4f, 0.2f));
    test::addPhoton(*caustics, plane.point(0, 0), n, Rgb(1.0f), n, PhotonClass::Caustic);
    test::addPhoton(*caustics, plane.point(0, 0), n, Rgb(1.0f), plane.vector(1, 0, 0), PhotonClass::Caustic,
                    plane.vector(0.2f, 0.0f), plane.vector(0.0f, 0.2f));
    for (const Rgb& p : splat(scene, grid.eye, caustics, film(11, 11))) EXPECT_EQ(p, Rgb(0.0f));

    caustics->hasDifferentials = false;
    EXPECT_THROW(splat(scene, grid.eye, caustics, film(11, 11)), InputError);
}

// Each eye vertex receives pi K f_r E_p times its throughput with its own BSDF:
// Lambertian vertices (whose pi f_r throughput the splat caches), plastic and
// rough metal (evaluated per deposit), seen from below their normal, or lit
// from behind their geometric surface, side by side at the photon's centre.
TEST(PhotonSplat, EachVertexUsesItsOwnBsdfAndSide) {
    Scene scene;
    scene.bsdfs.push_back(makeDiffuse(makeConstantTexture(kAlbedo)));
    scene.bsdfs.push_back(makePlastic(makeConstantTexture(Rgb(0.2f, 0.4f, 0.6f)), 1.5f));
    scene.bsdfs.push_back(makeRoughConductor(ConductorIor{Rgb(0.2f), Rgb(3.0f)}, 0.3f));
    const Vec3 n(0, 0, 1);
    const Vec3 wi = glm::normalize(Vec3(0.3f, -0.2f, 1.0f));
    const Vec3 up = glm::normalize(Vec3(-0.2f, 0.1f, 1.0f));
    struct VertexCase {
        std::uint32_t bsdf;
        Vec3 outgoing, normal, geometricNormal;
        Rgb throughput;
    };
    const std::vector<VertexCase> cases = {
        {0, up, n, n, Rgb(1.0f)},
        {0, up, n, n, Rgb(0.5f, 2.0f, 1.0f)},
        {1, up, n, n, Rgb(1.0f)},
        {2, up, n, n, Rgb(0.7f)},
        {0, glm::normalize(Vec3(0.2f, 0.0f, -1.0f)), n, n, Rgb(1.0f)},          // seen from below
        {0, up, n, glm::normalize(Vec3(0.0f, -0.99f, -0.2f)), Rgb(1.0f)},       // light behind the geometry
        {2, up, glm::normalize(Vec3(0.1f, 0.0f, 1.0f)), n, Rgb(1.0f)},          // shading normal tilted
    };
    auto eye = std::make_shared<EyeVertices>();
    for (std::uint32_t i = 0; i < cases.size(); ++i) {
        test::addEyeVertex(*eye, Vec3(0.0f), i, cases[i].throughput, cases[i].bsdf, cases[i].normal,
                           cases[i].outgoing);
        eye->vertices.column<EyeGeometricNormal>()[i] = cases[i].geometricNormal;
    }
    auto caustics = std::make_shared<PhotonMap>();
    caustics->hasDifferentials = true;
    const Rgb power(1.0f, 2.0f, 3.0f);
    test::addPhoton(*caustics, Vec3(0.0f), wi, power, n, PhotonClass::Caustic, Vec3(0.2f, 0, 0), Vec3(0, 0.2f, 0));
    const std::vector<Rgb> image = splat(scene, eye, caustics, film(static_cast<int>(cases.size()), 1));
    const float area = 0.25f * kPi * 0.04f;
    int lit = 0;
    for (std::size_t i = 0; i < cases.size(); ++i) {
        const VertexCase& c = cases[i];
        const Frame frame(c.normal);
        const Vec3 wiLocal = frame.toLocal(wi), woLocal = frame.toLocal(c.outgoing);
        Rgb f(0.0f);
        if (glm::dot(wi, c.geometricNormal) * wiLocal.z > 0.0f)
            f = scene.bsdfs[c.bsdf]->eval(woLocal, wiLocal, Vec2(0.0f), TransportMode::Radiance) / std::abs(wiLocal.z);
        // K(0) = 3 / pi.
        const Rgb expected = kPi * (3.0f * kInvPi) * f * power / area * c.throughput;
        for (int ch = 0; ch < 3; ++ch)
            EXPECT_NEAR(image[i][ch], expected[ch], 1e-4f * (expected[ch] + 1e-3f)) << "vertex " << i;
        lit += luminance(expected) > 0.0f ? 1 : 0;
    }
    EXPECT_EQ(lit, 5);  // the comparison covers lit and dark vertices
}

// Vertices off the photon's plane (as at a corner) are reached only while the
// topological-bias test is off or lenient enough.
TEST(PhotonSplat, TopologicalTestDropsVerticesOffThePhotonsPlane) {
    const Scene scene = diffuseScene();
    const PlaneFrame plane;
    auto caustics = std::make_shared<PhotonMap>();
    caustics->hasDifferentials = true;
    const Vec3 n = plane.vector(0, 0, 1);
    test::addPhoton(*caustics, plane.point(0, 0), n, Rgb(1.0f), n, PhotonClass::Caustic, plane.vector(0.6f, 0.0f),
                    plane.vector(0.0f, 0.6f));
    const auto litVertices = [&](float height, double threshold) {
        const GridOfVertices grid = vertexGrid(plane, 9, 0.05f, height);
        int lit = 0;
        for (const Rgb& p : splat(scene, grid.eye, caustics, film(9, 9), {{"max_normal_distance", threshold}}))
            lit += p.x > 0.0f ? 1 : 0;
        return lit;
    };
    EXPECT_GT(litVertices(0.05f, 0.0), 40);
    EXPECT_EQ(litVertices(0.05f, 0.01), 0);
    EXPECT_EQ(litVertices(0.005f, 0.01), litVertices(0.05f, 0.0));
}

TEST(PhotonSplat, ImageIsIdenticalForOneAndTwoThreads) {
    const Scene scene = diffuseScene();
    auto caustics = std::make_shared<PhotonMap>();
    caustics->hasDifferentials = true;
    jobs::Rng rng(12, jobs::streamKey("splat-threads"), 0);
    for (int i = 0; i < 20000; ++i) {
        const Vec2 u = rng.uniform2();
        const float angle = 2.0f * kPi * rng.uniform();
        const float a = 0.02f + 0.1f * rng.uniform(), b = 0.02f + 0.1f * rng.uniform();
        test::addPhoton(*caustics, Vec3(2.0f * u.x - 1.0f, 2.0f * u.y - 1.0f, 0.0f),
                        sampleCosineHemisphere(rng.uniform2()), Rgb(rng.uniform(), 0.5f, 1.0f), Vec3(0, 0, 1),
                        PhotonClass::Caustic, Vec3(a * std::cos(angle), a * std::sin(angle), 0.0f),
                        Vec3(-b * std::sin(angle + 0.3f), b * std::cos(angle + 0.3f), 0.0f));
    }
    auto eye = std::make_shared<EyeVertices>();
    for (std::uint32_t i = 0; i < 8000; ++i) {
        const Vec2 u = rng.uniform2();
        test::addEyeVertex(*eye, Vec3(2.0f * u.x - 1.0f, 2.0f * u.y - 1.0f, 0.0f), i / 8, Rgb(rng.uniform()));
    }
    const FilmSettings settings = film(50, 20);
    const auto render = [&](int threads) {
        const jobs::ThreadLimit limit(threads);
        return splat(scene, eye, caustics, settings);
    };
    const std::vector<Rgb> one = render(1);
    EXPECT_GT(luminance(one[123]), 0.0f);
    EXPECT_EQ(one, render(2));
}

// The pds pipeline as registered, with a stand-in photon pass: a lattice of
// caustic photons with round footprints wider than their spacing adds up to a
// uniform irradiance, random global photons to another; the image exceeds the
// direct film by rho (E_caustic + E_global) / pi.
TEST(PhotonSplat, PdsPipelineSplatsCausticsAndGathersGlobalLight) {
    Scene scene;
    Shape floor;
    TriangleMesh plane = makeRectangleMesh();
    plane.transform(glm::scale(Mat4(1.0f), Vec3(2.0f)));
    floor.geometry = plane;
    scene.bsdfs.push_back(makeDiffuse(makeConstantTexture(kAlbedo)));
    floor.bsdf = 0;
    scene.shapes.push_back(floor);
    scene.lights.push_back(makePointLight(Vec3(-0.3f, 0.2f, 1.5f), Rgb(4.0f)));
    scene.lightShape.push_back(-1);
    scene.camera.eye = Vec3(0.0f, 0.0f, 3.0f);
    scene.camera.target = Vec3(0.0f);
    scene.camera.fovYDegrees = 25.0f;
    scene.finalize();

    const Rgb causticE(1.0f, 0.5f, 0.2f), globalE(0.5f, 1.0f, 2.0f);
    const float spacing = 0.02f, footprintRadius = 0.08f;
    std::vector<PassRegistration> registry = passRegistry();
    // The stand-in replaces the real photon tracer.
    std::erase_if(registry, [](const PassRegistration& r) { return r.spec.name == "photon"; });
    registry.push_back(test::standInPhotonPass([&](PhotonMap& caustic, PhotonMap& global) {
        caustic.hasDifferentials = true;
        const int n = static_cast<int>(std::lround(4.0f / spacing));
        for (int y = 0; y < n; ++y) {
            for (int x = 0; x < n; ++x) {
                const Vec3 p(-2.0f + spacing * (x + 0.5f), -2.0f + spacing * (y + 0.5f), 0.0f);
                test::addPhoton(caustic, p, Vec3(0, 0, 1), causticE * (spacing * spacing), Vec3(0, 0, 1),
                                PhotonClass::Caustic, Vec3(2.0f * footprintRadius, 0, 0),
                                Vec3(0, 2.0f * footprintRadius, 0));
            }
        }
        test::addUniformPlanePhotons(global, 40000, 2.0f, globalE, PhotonClass::Global, 2);
    }));
    const FilmSettings settings = film(16, 16);
    const std::map<std::string, ParamValue> params = {{"eye.spp", std::int64_t{2}},
                                                      {"gather.k_global", std::int64_t{50}}};
    const Pipeline pds = *findPipeline("pds");
    const std::vector<Rgb> image =
        bufferAs<Film>(test::runPipeline(scene, pds, registry, params, settings, "image")).resolve();
    const std::vector<Rgb> caustics =
        bufferAs<Film>(test::runPipeline(scene, pds, registry, params, settings, "caustic")).resolve();
    const std::vector<Rgb> direct =
        bufferAs<Film>(test::runPipeline(scene, pds, registry, params, settings, "direct")).resolve();
    const Rgb causticL = kAlbedo * causticE * kInvPi, globalL = kAlbedo * globalE * kInvPi;
    glm::dvec3 globalSum(0.0);
    for (std::size_t i = 0; i < image.size(); ++i) {
        EXPECT_GT(luminance(direct[i]), 0.0f);
        // The lattice's splats are smooth: every pixel, not only the mean.
        for (int c = 0; c < 3; ++c) EXPECT_NEAR(caustics[i][c] / causticL[c], 1.0, 0.02) << "pixel " << i;
        globalSum += glm::dvec3(image[i] - direct[i] - caustics[i]);
    }
    const glm::dvec3 globalMean = globalSum / static_cast<double>(image.size());
    for (int c = 0; c < 3; ++c) EXPECT_NEAR(globalMean[c] / globalL[c], 1.0, 0.03) << "channel " << c;
}

// The real photon pass feeding the splat on water-wave, in small batches: the
// caustic map is streamed (never stored whole), the image is the one splatting
// the stored map gives, up to the order of floating-point sums, and it is the
// same for one and two threads.
TEST(PhotonSplat, PdsStreamsCausticPhotonsBatchByBatch) {
    const Scene scene = loadScene((std::filesystem::path(FLUXGRAPH_SOURCE_DIR) / "data" / "water-wave" /
                                   "water-wave.xml").string());
    const RayQuery rays(scene);
    JobParams params;
    params.values["eye"]["spp"] = {std::int64_t{1}, "test"};
    params.values["photon"]["photons"] = {std::int64_t{120000}, "test"};
    params.values["photon"]["batch_size"] = {std::int64_t{8192}, "test"};
    params.values["photon"]["store"] = {std::string("caustic"), "test"};
    RunOptions options;
    options.film = film(32, 32);
    const auto render = [&](bool stream, int threads, std::vector<PassStats>* stats = nullptr) {
        Pipeline pipeline = *findPipeline("pds");
        pipeline.streamBatches = stream;
        const ExecutionPlan plan = ExecutionPlan::build(pipeline, params, "test");
        EXPECT_EQ(plan.streamed("caustic_photons"), stream);
        EXPECT_FALSE(plan.streamed("global_photons"));  // the global map is gathered, so stored
        const jobs::ThreadLimit limit(threads);
        RunResult run = execute(plan, scene, rays, options);
        if (stats) *stats = run.stats;
        return bufferAs<Film>(run.results.at("image")).resolve();
    };
    std::vector<PassStats> streamedStats, storedStats;
    const std::vector<Rgb> streamed = render(true, 2, &streamedStats);
    const std::vector<Rgb> stored = render(false, 2, &storedStats);
    const auto statsOf = [](const std::vector<PassStats>& all, const std::string& instance) {
        return *std::find_if(all.begin(), all.end(), [&](const PassStats& s) { return s.instance == instance; });
    };
    const PassStats photon = statsOf(streamedStats, "photon");
    const std::int64_t causticPhotons = photon.counters.at("caustic_photons");
    ASSERT_GT(causticPhotons, 3000);
    EXPECT_EQ(photon.batchesEmitted, (120000 + 8191) / 8192);
    // What the photon pass held at once: one batch, a small part of the map the stored run kept.
    EXPECT_LT(photon.outputBytes * 5, statsOf(storedStats, "photon").outputBytes);
    EXPECT_EQ(statsOf(streamedStats, "splat").counters.at("splatted_photons"), causticPhotons);

    double sum = 0.0, difference = 0.0;
    for (std::size_t i = 0; i < streamed.size(); ++i) {
        sum += luminance(stored[i]);
        difference += std::abs(luminance(streamed[i]) - luminance(stored[i]));
    }
    ASSERT_GT(sum, 0.0);
    EXPECT_LT(difference / sum, 1e-5);
    EXPECT_EQ(streamed, render(true, 1));
}

}  // namespace
}  // namespace fg
