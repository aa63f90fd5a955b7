// The Gaussian-mixture passes of Jakob et al. 2011 on hand-made inputs: the
// pyramid's levels against the moments they must keep (Eqs. 12-14), the
// hierarchical render (Alg. 4) against the flat one and against its own
// thresholds, the whole chain photons -> statistics -> EM -> pyramid -> image
// at one and two threads, and the refusal of anisotropic media.
#include "engine/buffers/beam_buffers.h"
#include "engine/buffers/photon_buffers.h"
#include "engine/core/codec.h"
#include "engine/core/error.h"
#include "engine/gmm/em_tree.h"
#include "engine/gmm/gmm_buffers.h"
#include "engine/scene/scene.h"
#include "jobs/parallel.h"
#include "passes/passes.h"
#include "tests/support/cli_helpers.h"
#include "tests/support/gaussian_pyramid_chain.h"
#include "tests/support/pass_helpers.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <random>

namespace fg {
namespace {

using gmm::Sym3;
using Vec3d = glm::dvec3;

FilmSettings boxFilm(int w, int h) {
    FilmSettings f;
    f.width = w;
    f.height = h;
    return f;
}

Scene mediumScene(float g = 0.0f) {
    Scene scene;
    scene.media.emplace_back(Rgb(0.05f), Rgb(0.2f, 0.3f, 0.4f), g);
    scene.camera.fovYDegrees = 40.0f;
    return scene;
}

// One segment per pixel from a pinhole at (0, 0, -4) looking along +z, through the medium.
std::shared_ptr<EyeSegments> pinholeSegments(const Scene& scene, int size) {
    auto eye = std::make_shared<EyeSegments>();
    const float tanHalf = std::tan(0.5f * scene.camera.fovYDegrees * kPi / 180.0f);
    for (int y = 0; y < size; ++y) {
        for (int x = 0; x < size; ++x) {
            const Vec3 d = glm::normalize(Vec3((2.0f * (x + 0.5f) / size - 1.0f) * tanHalf,
                                               (1.0f - 2.0f * (y + 0.5f) / size) * tanHalf, 1.0f));
            SegmentBuffer::Record r{Vec3(0.0f, 0.0f, -4.0f), d, 2.5f, 6.0f, 0, static_cast<std::uint32_t>(y * size + x),
                                    Rgb(1.0f)};
            eye->segments.append(r);
        }
    }
    return eye;
}

using Chain = test::GmmChain;
using test::clusteredPhotons;
using test::relativeRms;

Chain fitChain(const Scene& scene, std::shared_ptr<VolumePhotonMap> photons, std::int64_t k) {
    return test::fitGmmChain(scene, std::move(photons), k, 30);
}

std::vector<Rgb> render(const Scene& scene, const Chain& c, std::shared_ptr<EyeSegments> segments, int size,
                        const std::map<std::string, ParamValue>& params, double* cost = nullptr) {
    const auto out = test::runPass(*findPass("gmm_render"), scene, nullptr, boxFilm(size, size),
                                   {{"eye_segments", test::makeBuffer(segments)}, {"pyramid", c.pyramid.at("pyramid")},
                                    {"bbh", c.bbh.at("bbh")}},
                                   params);
    const Film& film = test::bufferAs<Film>(out.at("volume"));
    if (cost) {
        *cost = 0.0;
        for (const auto& [name, values] : film.aovs())
            if (name == "query_cost")
                for (const float v : values) *cost += v;
    }
    return film.resolve();
}

TEST(PemPyramid, EveryLevelConservesWeightPowerAndMoments) {
    const Scene scene = mediumScene();
    const Chain c = fitChain(scene, clusteredPhotons(40000, 1), 64);
    const GmmPyramid& pyramid = test::bufferAs<GmmPyramid>(c.pyramid.at("pyramid"));
    const auto& nodes = pyramid.nodes;
    const std::size_t leaves = test::bufferAs<GaussianMixture>(c.fit.at("gmm")).components.size();
    ASSERT_EQ(nodes.size(), 2 * leaves - 1);
    EXPECT_EQ(pyramid.levels, static_cast<std::uint32_t>(std::ceil(std::log2(static_cast<double>(leaves)))));
    // Parent level of every node, from the depth-first layout.
    std::vector<std::uint32_t> parentLevel(nodes.size(), 1u << 30);
    const auto right = nodes.column<GmmRight>();
    const auto level = nodes.column<GmmLevel>();
    for (std::size_t j = 0; j < nodes.size(); ++j) {
        if (right[j] == kNoGmmNode) continue;
        parentLevel[j + 1] = level[j];
        parentLevel[right[j]] = level[j];
    }
    struct Moments {
        double weight = 0.0;
        Vec3d power{0.0}, first{0.0};
        Sym3 second;
    };
    std::vector<Moments> perLevel(pyramid.levels + 1);
    for (std::uint32_t l = 0; l <= pyramid.levels; ++l) {
        std::size_t count = 0;
        for (std::size_t j = 0; j < nodes.size(); ++j) {
            if (level[j] > l || parentLevel[j] <= l) continue;
            ++count;
            const double w = nodes.column<GmmWeight>()[j];
            const Vec3d mu = nodes.column<GmmMean>()[j];
            perLevel[l].weight += w;
            perLevel[l].power += nodes.column<GmmPower>()[j];
            perLevel[l].first += w * mu;
            perLevel[l].second += (nodes.column<GmmCovariance>()[j] + Sym3::outer(mu)) * w;
        }
        EXPECT_EQ(count, l == 0 ? leaves : (leaves + (1u << l) - 1) >> l) << "level " << l;
    }
    const Moments& leavesSum = perLevel[0];
    for (std::uint32_t l = 1; l <= pyramid.levels; ++l) {
        EXPECT_NEAR(perLevel[l].weight, leavesSum.weight, 1e-9);
        for (int i = 0; i < 3; ++i) {
            EXPECT_NEAR(perLevel[l].power[i], leavesSum.power[i], 1e-9 * leavesSum.power[i]);
            EXPECT_NEAR(perLevel[l].first[i], leavesSum.first[i], 1e-9);
        }
        for (std::size_t i = 0; i < 6; ++i) EXPECT_NEAR(perLevel[l].second.v[i], leavesSum.second.v[i], 1e-9);
    }
    // The fit keeps the photons' power, to the single-precision rounding of
    // each component's power (2^-24 of it) it is handed on with.
    const auto photons = clusteredPhotons(40000, 1);
    Vec3d photonPower(0.0);
    for (const Rgb& p : photons->photons.column<PhotonPower>()) photonPower += Vec3d(p);
    for (int i = 0; i < 3; ++i) EXPECT_NEAR(leavesSum.power[i], photonPower[i], 6e-8 * photonPower[i]);
}

TEST(PemRender, ZeroThresholdsEqualFlatAndLargerThresholdsTradeErrorForCost) {
    const Scene scene = mediumScene();
    const Chain c = fitChain(scene, clusteredPhotons(40000, 2), 128);
    const int size = 24;
    const auto segments = pinholeSegments(scene, size);
    double flatCost = 0.0;
    const std::vector<Rgb> flat = render(scene, c, segments, size, {{"mode", std::string("flat")}}, &flatCost);
    const std::vector<Rgb> exact = render(scene, c, segments, size, {{"eps_omega", 0.0}, {"eps_tr", 0.0}});
    EXPECT_LT(relativeRms(exact, flat), 1e-5);
    // The wide descent (zero thresholds) and the binary one (level 0) meet the
    // same leaves as the flat loop and sum them in the same order.
    EXPECT_EQ(std::memcmp(exact.data(), flat.data(), flat.size() * sizeof(Rgb)), 0);
    const std::vector<Rgb> leaves =
        render(scene, c, segments, size, {{"mode", std::string("level")}, {"level", std::int64_t{0}}});
    EXPECT_EQ(std::memcmp(leaves.data(), flat.data(), flat.size() * sizeof(Rgb)), 0);
    double previousError = -1.0, previousCost = 1e300;
    for (const double eps : {1.0, 30.0, 1000.0}) {
        double cost = 0.0;
        const std::vector<Rgb> image = render(scene, c, segments, size, {{"eps_omega", eps}, {"eps_tr", 0.0}}, &cost);
        const double error = relativeRms(image, flat);
        std::printf("eps_omega %g: relative RMS vs flat %.3g, cost %.0f (flat %.0f)\n", eps, error, cost, flatCost);
        EXPECT_GE(error, previousError);
        EXPECT_LE(cost, previousCost);
        previousError = error;
        previousCost = cost;
    }
    EXPECT_GT(previousError, 0.0);
}

// Skipping the Gaussians whose truncated ellipsoid a segment misses drops
// at most the energy the truncation already gives up (delta = 1e-3 of it),
// and does skip some.
TEST(PemRender, EllipsoidCullingChangesTheFlatImageByAtMostDelta) {
    const Scene scene = mediumScene();
    const Chain c = fitChain(scene, clusteredPhotons(40000, 4), 128);
    const int size = 24;
    const auto segments = pinholeSegments(scene, size);
    const std::vector<Rgb> all =
        render(scene, c, segments, size, {{"mode", std::string("flat")}, {"cull_ellipsoids", false}});
    const std::vector<Rgb> culled = render(scene, c, segments, size, {{"mode", std::string("flat")}});
    const double delta = test::bufferAs<GmmBbh>(c.bbh.at("bbh")).truncation;
    const double error = relativeRms(culled, all);
    std::printf("ellipsoid culling: relative RMS vs unculled %.3g (delta %g)\n", error, delta);
    EXPECT_GT(error, 0.0);
    EXPECT_LE(error, delta);
}

TEST(PemRender, OneAndTwoThreadsGiveIdenticalMixturesAndImages) {
    const Scene scene = mediumScene();
    const auto photons = clusteredPhotons(30000, 3);
    const int size = 16;
    const auto segments = pinholeSegments(scene, size);
    std::vector<std::vector<Rgb>> images;
    std::vector<std::vector<double>> parameters;
    for (const int threads : {1, 2}) {
        jobs::ThreadLimit limit(threads);
        const Chain c = fitChain(scene, photons, 64);
        const GmmBuffer& gmm = test::bufferAs<GaussianMixture>(c.fit.at("gmm")).components;
        std::vector<double> values;
        for (std::size_t s = 0; s < gmm.size(); ++s) {
            values.push_back(gmm.column<GmmWeight>()[s]);
            for (int i = 0; i < 3; ++i) values.push_back(gmm.column<GmmMean>()[s][i]);
            for (const double v : gmm.column<GmmCovariance>()[s].v) values.push_back(v);
        }
        parameters.push_back(values);
        images.push_back(render(scene, c, segments, size, {}));
    }
    ASSERT_EQ(parameters[0].size(), parameters[1].size());
    EXPECT_EQ(std::memcmp(parameters[0].data(), parameters[1].data(), parameters[0].size() * sizeof(double)), 0);
    EXPECT_EQ(std::memcmp(images[0].data(), images[1].data(), images[0].size() * sizeof(Rgb)), 0);
}

// The fit hands its mixture on in the single precision it is saved in
// (GmmStoredBuffer), so a mixture saved with `--save gmm=FILE` and imported
// again gives the same pyramid, boxes and image, bit for bit.
TEST(PemRender, ASavedAndLoadedMixtureRendersTheSameImage) {
    const Scene scene = mediumScene();
    const int size = 16;
    const auto segments = pinholeSegments(scene, size);
    const Chain c = fitChain(scene, clusteredPhotons(30000, 3), 64);
    const std::string path = (test::scratchDirectory("pem-render") / "gmm.fgbuf").string();
    registerBuiltinCodecs();
    saveBuffer(c.fit.at("gmm"), path, "# test\n");
    Chain loaded;
    loaded.fit["gmm"] = loadBuffer(path, "GaussianMixture", "gmm");
    const FilmSettings film = boxFilm(4, 4);
    loaded.pyramid = test::runPass(*findPass("gmm_pyramid"), scene, nullptr, film, {{"gmm", loaded.fit.at("gmm")}});
    loaded.bbh = test::runPass(*findPass("gmm_bbh"), scene, nullptr, film, {{"pyramid", loaded.pyramid.at("pyramid")}});
    const GmmPyramidBuffer& a = test::bufferAs<GmmPyramid>(c.pyramid.at("pyramid")).nodes;
    const GmmPyramidBuffer& b = test::bufferAs<GmmPyramid>(loaded.pyramid.at("pyramid")).nodes;
    ASSERT_EQ(a.size(), b.size());
    ASSERT_GT(a.size(), 64u);
    EXPECT_EQ(std::memcmp(a.column<GmmPrecision>().data(), b.column<GmmPrecision>().data(), a.size() * sizeof(Sym3)), 0);
    EXPECT_EQ(std::memcmp(a.column<GmmPower>().data(), b.column<GmmPower>().data(), a.size() * sizeof(Vec3d)), 0);
    const std::vector<Rgb> inMemory = render(scene, c, segments, size, {});
    const std::vector<Rgb> fromFile = render(scene, loaded, segments, size, {});
    ASSERT_EQ(inMemory.size(), fromFile.size());
    double total = 0.0;
    for (const Rgb& v : inMemory) total += static_cast<double>(v.x + v.y + v.z);
    EXPECT_GT(total, 0.0);
    EXPECT_EQ(std::memcmp(inMemory.data(), fromFile.data(), inMemory.size() * sizeof(Rgb)), 0);
}

TEST(PemPyramid, KdTreePairingEqualsBruteForce) {
    const Scene scene = mediumScene();
    const Chain c = fitChain(scene, clusteredPhotons(60000, 5), 256);
    std::map<std::string, BufferHandle> pyramids[2];
    const char* pairings[2] = {"kdtree", "brute"};
    for (int p = 0; p < 2; ++p)
        pyramids[p] = test::runPass(*findPass("gmm_pyramid"), scene, nullptr, boxFilm(4, 4), {{"gmm", c.fit.at("gmm")}},
                                    {{"pairing", std::string(pairings[p])}});
    const GmmPyramidBuffer& a = test::bufferAs<GmmPyramid>(pyramids[0].at("pyramid")).nodes;
    const GmmPyramidBuffer& b = test::bufferAs<GmmPyramid>(pyramids[1].at("pyramid")).nodes;
    ASSERT_EQ(a.size(), b.size());
    ASSERT_GT(a.size(), 256u);
    EXPECT_EQ(std::memcmp(a.column<GmmMean>().data(), b.column<GmmMean>().data(), a.size() * sizeof(Vec3d)), 0);
    EXPECT_EQ(std::memcmp(a.column<GmmCovariance>().data(), b.column<GmmCovariance>().data(), a.size() * sizeof(Sym3)), 0);
    EXPECT_EQ(std::memcmp(a.column<GmmWeight>().data(), b.column<GmmWeight>().data(), a.size() * sizeof(double)), 0);
    EXPECT_EQ(std::memcmp(a.column<GmmRight>().data(), b.column<GmmRight>().data(), a.size() * sizeof(std::uint32_t)), 0);
}

TEST(PemPreflight, AnisotropicMediaAreRefused) {
    const Scene scene = mediumScene(0.5f);
    PassParams params;
    PreflightContext pf{scene, params, "em_fit", "job.toml:3", {}, {}, {}, {}};
    EXPECT_THROW(findPass("em_fit")->preflight(pf), InputError);
    const Scene isotropic = mediumScene(0.0f);
    PreflightContext ok{isotropic, params, "em_fit", "job.toml:3", {}, {}, {}, {}};
    EXPECT_NO_THROW(findPass("em_fit")->preflight(ok));
}

}  // namespace
}  // namespace fg
