// The splat pass of Jakob et al. 2011 §8.1 (`gmm_splat`) against the ray
// traversal of the same pyramid level (`gmm_render`, mode = level) along the
// same pixel-centre rays: in a medium-only scene (to infinity), with a wall
// (depth_clip, to the wall), and seen from outside the medium through an
// index-matched boundary; its independence of the thread count and the tile
// size, and the refusal of a level the pyramid cannot have.
#include "engine/accel/ray_query.h"
#include "engine/buffers/beam_buffers.h"
#include "engine/buffers/photon_buffers.h"
#include "engine/core/codec.h"
#include "engine/core/error.h"
#include "engine/gmm/gmm_buffers.h"
#include "engine/scene/scene.h"
#include "engine/shading/bsdf.h"
#include "jobs/parallel.h"
#include "passes/passes.h"
#include "tests/support/cli_helpers.h"
#include "tests/support/gaussian_pyramid_chain.h"
#include "tests/support/pass_helpers.h"
#include "tests/support/render_helpers.h"

#include <gtest/gtest.h>

#include <glm/gtc/matrix_transform.hpp>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <random>

namespace fg {
namespace {

FilmSettings boxFilm(int size) {
    FilmSettings f;
    f.width = size;
    f.height = size;
    return f;
}

// A grey-absorbing, colour-scattering isotropic medium; the camera at
// (0, 0, -4) looks along +z at the photons in [-1, 1]^3, from inside the
// medium unless `cameraInMedium` is false.
Scene mediumScene(bool cameraInMedium = true) {
    Scene scene;
    scene.media.emplace_back(Rgb(0.05f), Rgb(0.2f, 0.3f, 0.4f), 0.0f);
    scene.camera.eye = Vec3(0.0f, 0.0f, -4.0f);
    scene.camera.target = Vec3(0.0f);
    scene.camera.fovYDegrees = 40.0f;
    scene.camera.medium = cameraInMedium ? 0 : -1;
    return scene;
}

// A 20 x 20 rectangle in the plane z = depth facing the camera.
Shape wallAt(float depth, int bsdf) {
    Shape wall;
    TriangleMesh plane = makeRectangleMesh();
    plane.transform(glm::translate(Mat4(1.0f), Vec3(0.0f, 0.0f, depth)) *
                    glm::rotate(Mat4(1.0f), kPi, Vec3(0.0f, 1.0f, 0.0f)) * glm::scale(Mat4(1.0f), Vec3(10.0f)));
    wall.geometry = plane;
    wall.bsdf = bsdf;
    return wall;
}

using Chain = test::GmmChain;
using test::relativeRms;

Chain fitChain(const Scene& scene, std::int64_t k) {
    return test::fitGmmChain(scene, test::clusteredPhotons(40000, 7), k, 20);
}

// One segment per pixel along its centre ray: from where it enters the medium
// (`tNear`: the distance to the boundary, 0 with the camera inside) to the
// first surface behind, or to infinity without `rays`.
std::shared_ptr<EyeSegments> centreSegments(const Scene& scene, int size, const RayQuery* rays, float tNear = 0.0f) {
    Camera camera = scene.camera;
    camera.width = camera.height = size;
    auto eye = std::make_shared<EyeSegments>();
    eye->samplesPerPixel = 1;
    for (int y = 0; y < size; ++y) {
        for (int x = 0; x < size; ++x) {
            Ray ray = camera.generateRay(Vec2(static_cast<float>(x) + 0.5f, static_cast<float>(y) + 0.5f));
            ray.direction = glm::normalize(ray.direction);
            float tFar = kInfinity;
            if (rays) {
                const Hit hit = rays->intersect(ray);
                if (hit.valid()) tFar = hit.t;
            }
            const float boundary = tNear > 0.0f ? tNear / ray.direction.z : 0.0f;
            eye->segments.append(SegmentBuffer::Record{ray.origin, ray.direction, boundary, tFar, 0,
                                                       static_cast<std::uint32_t>(y * size + x), Rgb(1.0f)});
        }
    }
    return eye;
}

std::vector<Rgb> render(const Scene& scene, const Chain& c, std::shared_ptr<EyeSegments> segments, int size,
                        std::int64_t level) {
    const auto out = test::runPass(*findPass("gmm_render"), scene, nullptr, boxFilm(size),
                                   {{"eye_segments", test::makeBuffer(segments)}, {"pyramid", c.pyramid.at("pyramid")},
                                    {"bbh", c.bbh.at("bbh")}},
                                   {{"mode", std::string("level")}, {"level", level}});
    return test::bufferAs<Film>(out.at("volume")).resolve();
}

std::vector<Rgb> splat(const Scene& scene, const RayQuery* rays, const Chain& c, int size,
                       std::map<std::string, ParamValue> params, double* gaussians = nullptr) {
    const auto out = test::runPass(*findPass("gmm_splat"), scene, rays, boxFilm(size),
                                   {{"pyramid", c.pyramid.at("pyramid")}}, params);
    const Film& film = test::bufferAs<Film>(out.at("volume"));
    if (gaussians) {
        *gaussians = 0.0;
        for (const auto& [name, values] : film.aovs())
            if (name == "query_gaussians")
                for (const float v : values) *gaussians += v;
    }
    return film.resolve();
}

TEST(GmmSplat, EveryLevelEqualsGmmRenderOfThatLevelInAMediumOnlyScene) {
    const Scene scene = mediumScene();
    const Chain c = fitChain(scene, 64);
    const GmmPyramid& pyramid = test::bufferAs<GmmPyramid>(c.pyramid.at("pyramid"));
    ASSERT_EQ(pyramid.levels, 6u);
    const int size = 32;
    const auto segments = centreSegments(scene, size, nullptr);
    std::vector<std::vector<Rgb>> splats;
    for (std::uint32_t level = 0; level <= pyramid.levels; ++level) {
        double gaussians = 0.0;
        const std::vector<Rgb> image = splat(scene, nullptr, c, size, {{"level", std::int64_t{level}}}, &gaussians);
        const std::vector<Rgb> traced = render(scene, c, segments, size, level);
        const double error = relativeRms(image, traced);
        std::printf("level %u: relative RMS vs gmm_render %.3g, %.0f Gaussians evaluated\n", level, error, gaussians);
        EXPECT_LT(error, 0.01) << "level " << level;
        EXPECT_GT(gaussians, 0.0);
        splats.push_back(image);
    }
    // The levels differ by more than the tolerance, so the comparison tells them apart.
    for (std::size_t level = 1; level < splats.size(); ++level)
        EXPECT_GT(relativeRms(splats[level], splats[0]), 0.02) << "level " << level;
}

// Pixel-splat pairs whose centre ray (from the camera, in the medium, to
// infinity) meets the splat's truncated ellipsoid, over every pixel and every
// node of the level: what the screen rectangles must not lose.
double pairsMeetingEllipsoids(const Scene& scene, const GmmPyramid& pyramid, std::uint32_t level, int size) {
    const GmmPyramidBuffer& nodes = pyramid.nodes;
    const double allowed = 1e-3 * energy(nodes.column<GmmPower>()[0]) / static_cast<double>((nodes.size() + 1) / 2);
    const auto chi3Tail = [](double r) {
        return std::erfc(r / std::sqrt(2.0)) + std::sqrt(2.0 / M_PI) * r * std::exp(-0.5 * r * r);
    };
    Camera camera = scene.camera;
    camera.width = camera.height = size;
    double pairs = 0.0;
    for (std::size_t j = 0; j < nodes.size(); ++j) {
        // A node of the level: at or below it, its parent above it (the root has none).
        if (nodes.column<GmmLevel>()[j] > level) continue;
        bool parentAbove = j == 0;
        for (std::size_t parent = 0; parent < j && !parentAbove; ++parent) {
            const std::uint32_t right = nodes.column<GmmRight>()[parent];
            if (right != kNoGmmNode && (parent + 1 == j || right == j))
                parentAbove = nodes.column<GmmLevel>()[parent] > level;
        }
        if (!parentAbove) continue;
        // The truncation radius r: chi3Tail(r) = the node's allowed share of its energy, by bisection.
        const double tail = allowed / energy(nodes.column<GmmPower>()[j]);
        double lo = 0.0, hi = 64.0;
        for (int i = 0; i < 100; ++i) {
            const double mid = 0.5 * (lo + hi);
            (chi3Tail(mid) > tail ? lo : hi) = mid;
        }
        const gmm::Gaussian g = gaussianAt(nodes, j);
        for (int y = 0; y < size; ++y) {
            for (int x = 0; x < size; ++x) {
                const Ray ray = camera.generateRay(Vec2(static_cast<float>(x) + 0.5f, static_cast<float>(y) + 0.5f));
                const glm::dvec3 w(glm::normalize(ray.direction));
                const glm::dvec3 q = glm::dvec3(ray.origin) - g.mean;
                const double a = g.factors.precision.quadratic(w);
                const double b = glm::dot(q, g.factors.precision * w);
                const double discriminant = b * b - a * (g.factors.precision.quadratic(q) - hi * hi);
                if (discriminant >= 0.0 && (-b + std::sqrt(discriminant)) / a >= 0.0) pairs += 1.0;
            }
        }
    }
    return pairs;
}

TEST(GmmSplat, ScreenRectanglesHoldEveryPixelWhoseRayMeetsTheEllipsoid) {
    Scene scene = mediumScene();
    const Chain c = fitChain(scene, 64);
    const GmmPyramid& pyramid = test::bufferAs<GmmPyramid>(c.pyramid.at("pyramid"));
    const int size = 32;
    // From outside the Gaussians, and from among them, where ellipsoids reach
    // behind the eye and off the film's edges.
    for (const Vec3 eye : {Vec3(0.0f, 0.0f, -4.0f), Vec3(0.3f, -0.2f, -0.3f)}) {
        scene.camera.eye = eye;
        scene.camera.target = eye + Vec3(0.0f, 0.0f, 1.0f);
        for (const std::uint32_t level : {0u, 3u}) {
            double gaussians = 0.0;
            splat(scene, nullptr, c, size, {{"level", std::int64_t{level}}}, &gaussians);
            const double expected = pairsMeetingEllipsoids(scene, pyramid, level, size);
            EXPECT_GT(expected, 0.0);
            EXPECT_EQ(gaussians, expected) << "eye z " << eye.z << ", level " << level;
        }
    }
}

TEST(GmmSplat, DepthClipEqualsGmmRenderToTheFirstSurface) {
    Scene scene = mediumScene();
    scene.shapes.push_back(wallAt(0.1f, test::addDiffuse(scene, Rgb(0.5f))));
    scene.finalize();
    const RayQuery rays(scene);
    const Chain c = fitChain(scene, 64);
    const int size = 32;
    const auto clipped = centreSegments(scene, size, &rays);
    for (const std::int64_t level : {0, 3}) {
        const std::vector<Rgb> image = splat(scene, &rays, c, size, {{"level", level}, {"depth_clip", true}});
        const std::vector<Rgb> traced = render(scene, c, clipped, size, level);
        // The wall cuts through the clusters: the unclipped splat sees what lies behind it.
        const std::vector<Rgb> unclipped = splat(scene, &rays, c, size, {{"level", level}});
        std::printf("level %d: relative RMS vs gmm_render %.3g clipped, %.3g unclipped\n", static_cast<int>(level),
                    relativeRms(image, traced), relativeRms(unclipped, traced));
        EXPECT_LT(relativeRms(image, traced), 0.01) << "level " << level;
        EXPECT_GT(relativeRms(unclipped, traced), 0.1) << "level " << level;
    }
}

TEST(GmmSplat, EntersTheMediumThroughAnIndexMatchedBoundary) {
    Scene outside = mediumScene(false);
    outside.bsdfs.push_back(makeNull());
    Shape boundary = wallAt(-3.0f, static_cast<int>(outside.bsdfs.size()) - 1);
    boundary.interiorMedium = 0;  // the medium lies behind the boundary, on the side away from the camera
    outside.shapes.push_back(boundary);
    outside.finalize();
    const RayQuery rays(outside);
    const Chain c = fitChain(outside, 64);
    const int size = 24;
    // The camera at z = -4, the boundary at z = -3: segments start 1 / w_z along each ray.
    const auto segments = centreSegments(outside, size, nullptr, 1.0f);
    const std::vector<Rgb> image = splat(outside, &rays, c, size, {});
    const std::vector<Rgb> traced = render(outside, c, segments, size, 0);
    // From the camera, the extra unit of medium would dim the image by e^-0.25 to e^-0.45.
    const Scene inside = mediumScene(true);
    const std::vector<Rgb> fromCamera = splat(inside, nullptr, c, size, {});
    std::printf("relative RMS vs gmm_render %.3g from the boundary, %.3g from the camera\n", relativeRms(image, traced),
                relativeRms(fromCamera, traced));
    EXPECT_LT(relativeRms(image, traced), 0.01);
    EXPECT_GT(relativeRms(fromCamera, traced), 0.15);
}

TEST(GmmSplat, OneAndTwoThreadsAndAnyTileSizeGiveIdenticalImages) {
    Scene scene = mediumScene();
    scene.shapes.push_back(wallAt(0.1f, test::addDiffuse(scene, Rgb(0.5f))));
    scene.finalize();
    const RayQuery rays(scene);
    const Chain c = fitChain(scene, 64);
    const int size = 40;
    for (const bool depthClip : {false, true}) {
        std::vector<std::vector<Rgb>> images;
        for (const int threads : {1, 2}) {
            jobs::ThreadLimit limit(threads);
            for (const std::int64_t tile : {16, 7})
                images.push_back(splat(scene, &rays, c, size, {{"depth_clip", depthClip}, {"tile", tile}}));
        }
        for (std::size_t i = 1; i < images.size(); ++i)
            EXPECT_EQ(std::memcmp(images[0].data(), images[i].data(), images[0].size() * sizeof(Rgb)), 0)
                << "depth_clip " << depthClip << ", run " << i;
    }
}

TEST(GmmSplat, ALevelThePyramidCannotHaveIsRefused) {
    const Scene scene = mediumScene();
    PassParams fit;
    fit.set("k", std::int64_t{1000});  // ceil(log2 1000) = 10 levels above the leaves
    const auto preflight = [&](std::int64_t level) {
        PassParams params;
        params.set("level", level);
        const PreflightContext pf{scene,
                                  params,
                                  "gmm_splat",
                                  "job.toml:3",
                                  [&](const std::string& slot) { return slot == "gmm" ? &fit : nullptr; },
                                  [](const std::string& slot) { return slot == "gmm" ? std::string("pem_fit") : ""; },
                                  {},
                                  {}};
        findPass("gmm_splat")->preflight(pf);
    };
    EXPECT_NO_THROW(preflight(10));
    EXPECT_THROW(preflight(11), InputError);

    // A pyramid smaller than k allows (components dropped by the fit) is checked when the pass runs.
    const Chain c = fitChain(scene, 16);
    EXPECT_THROW(splat(scene, nullptr, c, 8, {{"level", std::int64_t{5}}}), InputError);
    EXPECT_NO_THROW(splat(scene, nullptr, c, 8, {{"level", std::int64_t{4}}}));
}

TEST(GmmSplat, TheCommandLineRefusesAMissingLevelBeforeAnyWork) {
    const std::filesystem::path dir = test::scratchDirectory("pem");
    const test::CommandResult r =
        test::runFluxgraph(dir, {"render", test::sourcePath("data/volumetric-caustic/pem-splat.toml"), "--set",
                                 "passes.gmm_splat.level=13", "--out", "out"});
    EXPECT_EQ(r.exitCode, 2) << r.err;
    EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1) << r.err;
    EXPECT_NE(r.err.find("level 13 does not exist"), std::string::npos) << r.err;
}


// The pyramid and its BBH go through their codecs byte for byte (so that
// `replay` can feed the splat and the renderer), and a file whose tree or
// boxes the renderers could not walk safely is refused with one line.
TEST(GmmSplat, PyramidAndBbhRoundTripAndBrokenOnesAreRefused) {
    registerBuiltinCodecs();
    const std::filesystem::path dir = test::scratchDirectory("gmm-splat-codec");
    const Chain c = fitChain(mediumScene(), 16);
    const auto roundTrip = [&](const BufferHandle& buffer, const std::string& type) {
        const std::string first = (dir / (type + "-1.fgbuf")).string(), second = (dir / (type + "-2.fgbuf")).string();
        saveBuffer(buffer, first, "");
        saveBuffer(loadBuffer(first, type), second, "");
        EXPECT_EQ(test::readText(first), test::readText(second)) << type;
    };
    roundTrip(c.pyramid.at("pyramid"), "GmmPyramid");
    roundTrip(c.bbh.at("bbh"), "GmmBbh");

    const auto refused = [&](const BufferHandle& buffer, const std::string& type, const std::string& expected) {
        const std::string path = (dir / "broken.fgbuf").string();
        saveBuffer(buffer, path, "");
        try {
            loadBuffer(path, type);
            ADD_FAILURE() << "accepted: " << expected;
        } catch (const InputError& error) {
            EXPECT_NE(std::string(error.what()).find(expected), std::string::npos) << error.what();
            EXPECT_EQ(std::string(error.what()).find('\n'), std::string::npos);
        }
    };
    // Fresh copies to break (the buffers are move-only): loaded from the saved files.
    const auto fresh = [&](const std::string& type) { return loadBuffer((dir / (type + "-1.fgbuf")).string(), type); };
    const auto mutablePyramid = [](const BufferHandle& h) -> GmmPyramid& {
        return const_cast<GmmPyramid&>(test::bufferAs<GmmPyramid>(h));
    };
    const BufferHandle cyclic = fresh("GmmPyramid");
    mutablePyramid(cyclic).nodes.column<GmmRight>()[0] = 0;
    refused(cyclic, "GmmPyramid", "pyramid node 0 has its children out of order");
    const BufferHandle flat = fresh("GmmPyramid");
    auto level = mutablePyramid(flat).nodes.column<GmmLevel>();
    level[1] = level[0];
    refused(flat, "GmmPyramid", "pyramid node 0 is not above its children");
    const BufferHandle inverted = fresh("GmmBbh");
    auto& bbh = const_cast<GmmBbh&>(test::bufferAs<GmmBbh>(inverted));
    std::swap(bbh.nodes.column<BbhLo>()[3], bbh.nodes.column<BbhHi>()[3]);
    refused(inverted, "GmmBbh", "BBH node 3");
}

}  // namespace
}  // namespace fg
