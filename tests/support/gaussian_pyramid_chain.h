// The chain of Jakob et al. 2011's passes from volume photons to a rendered
// pyramid (em_stats -> em_fit -> gmm_pyramid -> gmm_bbh), run on hand-made
// photons, for the tests of the passes that read the pyramid.
#pragma once

#include "engine/buffers/photon_buffers.h"
#include "engine/core/math.h"
#include "engine/image/film.h"
#include "engine/scene/scene.h"
#include "passes/passes.h"
#include "tests/support/pass_helpers.h"

#include <cmath>
#include <map>
#include <memory>
#include <random>
#include <string>
#include <vector>

namespace fg::test {

// Volume photons from a few anisotropic clusters in [-1, 1]^3.
inline std::shared_ptr<VolumePhotonMap> clusteredPhotons(std::size_t n, std::uint64_t seed) {
    std::mt19937_64 rng(seed);
    std::normal_distribution<float> normal;
    std::uniform_real_distribution<float> uniform(-0.6f, 0.6f);
    std::vector<Vec3> centres;
    for (int c = 0; c < 12; ++c) centres.emplace_back(uniform(rng), uniform(rng), uniform(rng));
    auto map = std::make_shared<VolumePhotonMap>();
    map->emitted = n;
    map->photons.resize(n);
    for (std::size_t i = 0; i < n; ++i) {
        const Vec3& c = centres[i % centres.size()];
        map->photons.column<PhotonPosition>()[i] =
            c + Vec3(0.15f * normal(rng), 0.05f * normal(rng), 0.08f * normal(rng) + 0.03f * normal(rng));
        map->photons.column<PhotonPower>()[i] = Rgb(1.0f, 0.5f + 0.5f * static_cast<float>(i % 3), 0.25f) / float(n);
        map->photons.column<PhotonClassColumn>()[i] = PhotonClass::Volume;
    }
    return map;
}

// Each pass's outputs, by slot name.
struct GmmChain {
    std::map<std::string, BufferHandle> stats, fit, pyramid, bbh;
};

inline GmmChain fitGmmChain(const Scene& scene, std::shared_ptr<VolumePhotonMap> photons, std::int64_t k,
                            std::int64_t maxIterations) {
    FilmSettings film;
    film.width = film.height = 4;
    GmmChain c;
    c.stats = runPass(*findPass("em_stats"), scene, nullptr, film, {{"photons", makeBuffer(std::move(photons))}});
    c.fit = runPass(*findPass("em_fit"), scene, nullptr, film, {{"tree", c.stats.at("tree")}},
                    {{"k", k}, {"max_iterations", maxIterations}});
    c.pyramid = runPass(*findPass("gmm_pyramid"), scene, nullptr, film, {{"gmm", c.fit.at("gmm")}});
    c.bbh = runPass(*findPass("gmm_bbh"), scene, nullptr, film, {{"pyramid", c.pyramid.at("pyramid")}});
    return c;
}

// ||a - reference|| / ||reference|| over all pixels and channels.
inline double relativeRms(const std::vector<Rgb>& a, const std::vector<Rgb>& reference) {
    double err = 0.0, ref = 0.0;
    for (std::size_t i = 0; i < a.size(); ++i) {
        const Rgb d = a[i] - reference[i];
        err += glm::dot(glm::dvec3(d), glm::dvec3(d));
        ref += glm::dot(glm::dvec3(reference[i]), glm::dvec3(reference[i]));
    }
    return std::sqrt(err / ref);
}

}  // namespace fg::test
