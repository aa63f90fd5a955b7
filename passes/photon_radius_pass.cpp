// Photon radius pass (`photon_radius`): the pilot density estimate of the beam
// radiance estimate (Jarosz, Zwicker & Jensen 2008 §4; Jakob et al. 2011 §3.2),
// which gives every volume photon i its own kernel radius
//
//   r_i = c * d_k(i),   d_k(i) = distance from photon i to its k-th nearest other photon,
//
// found with the balanced kd-tree (engine/kdtree.h). The constant c = 1 makes
// the sphere of radius r_i hold k photons besides photon i on average: for a
// locally uniform (Poisson) photon density rho, the volume V = 4/3 pi d_k^3 of
// the ball out to the k-th neighbour is Gamma(k, 1/rho) distributed, with mean
// k / rho, so the expected number of photons in the ball, rho E[V], is k. The
// BRE sums, at each point of a ray, the photons whose spheres cover it; with
// these radii about k of them do, so its noise is that of a k-nearest-neighbour
// estimate while the radii adapt to the density (small in bright, dense
// regions such as volume caustics, large in dim ones). `radius_scale` changes c
// (the expected count becomes c^3 k) and `max_radius` bounds r_i where photons
// are sparse. Photons with fewer than k others in reach get max_radius (or the
// distance to the farthest one found, when max_radius is unlimited).
//
// Deterministic: the tree is a function of the photons, each radius of its
// own query.
#include "passes/passes.h"

#include "engine/beam_buffers.h"
#include "engine/kdtree.h"
#include "engine/photon_buffers.h"
#include "jobs/parallel.h"

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <limits>

namespace fg {

namespace {

class PhotonRadiusPass final : public Pass {
public:
    void run(PassContext& ctx) override {
        const PhotonMap& map = ctx.input<PhotonMap>("photons");
        const auto k = static_cast<std::size_t>(ctx.params().getInt("k"));
        const auto scale = static_cast<float>(ctx.params().getFloat("radius_scale"));
        const double maxRadiusParam = ctx.params().getFloat("max_radius");
        const float maxRadius =
            maxRadiusParam > 0.0 ? static_cast<float>(maxRadiusParam) : std::numeric_limits<float>::infinity();

        PhotonRadii& radii = ctx.createOutput<PhotonRadii>("radii");
        radii.neighbours = static_cast<std::uint32_t>(k);
        radii.scale = scale;
        const auto positions = map.photons.column<PhotonPosition>();
        const std::size_t n = positions.size();
        radii.radii.resize(n);
        ctx.addItems(static_cast<std::int64_t>(n));
        if (n == 0) return;

        const KdTree tree(positions);
        const auto out = radii.radii.column<PhotonRadius>();
        // The photon itself is its own nearest neighbour (distance 0): ask for k + 1.
        const std::size_t wanted = k + 1;
        // The search may stop at the largest radius that survives the scale and the clamp.
        const float searchRadius = std::isfinite(maxRadius) ? maxRadius / scale : maxRadius;
        constexpr std::size_t kChunk = 1024;
        const std::size_t chunks = (n + kChunk - 1) / kChunk;
        std::vector<double> chunkSums(chunks, 0.0);
        std::vector<std::int64_t> chunkClamped(chunks, 0);
        // Queries run in the tree's order, so consecutive photons are neighbours:
        // each first tries a range query out to 1.15 times the previous photon's
        // k-th distance and takes the (k+1)-th smallest distance found there,
        // which is exact whenever the range holds at least k + 1 photons (all
        // photons outside it are farther); otherwise it asks for the k + 1
        // nearest. Either way the radius is the same number, bit for bit. On 1M
        // photons (k = 20) this took 1.9 s of CPU against 2.45 s for k-nearest
        // queries alone (factors 1.0, 1.08, 1.3: 2.5, 2.0, 2.3 s).
        const auto order = tree.permutation();
        jobs::parallelForChunks(n, kChunk, [&](jobs::IndexRange range) {
            std::vector<std::uint32_t> ids(wanted);
            std::vector<float> dist2(wanted);
            std::vector<float> candidates;
            double sum = 0.0;
            std::int64_t clamped = 0;
            float guess = 0.0f;  // search radius suggested by the previous photon; 0 = none
            for (std::size_t j = range.begin; j != range.end; ++j) {
                const std::uint32_t i = order[j];
                float kth2 = -1.0f;  // squared distance to the k-th other photon, if found
                if (guess > 0.0f) {
                    candidates.clear();
                    tree.forEachInRadius(positions[i], std::min(guess, searchRadius),
                                         [&](std::uint32_t, float d2) { candidates.push_back(d2); });
                    if (candidates.size() >= wanted) {
                        std::nth_element(candidates.begin(), candidates.begin() + static_cast<std::ptrdiff_t>(wanted - 1),
                                         candidates.end());
                        kth2 = candidates[wanted - 1];
                    }
                }
                std::size_t found = wanted;
                if (kth2 < 0.0f) {
                    found = tree.nearest(positions[i], wanted, searchRadius, ids, dist2);
                    if (found > 0) kth2 = dist2[found - 1];
                }
                float r;
                if (found == wanted) {
                    r = std::min(scale * std::sqrt(kth2), maxRadius);
                    guess = 1.15f * std::sqrt(kth2);
                } else {
                    r = std::isfinite(maxRadius) ? maxRadius : (found > 1 ? scale * std::sqrt(kth2) : 0.0f);
                    guess = 0.0f;
                }
                if (r >= maxRadius) ++clamped;
                out[i] = r;
                sum += r;
            }
            chunkSums[range.begin / kChunk] = sum;
            chunkClamped[range.begin / kChunk] = clamped;
        });
        double sum = 0.0;
        std::int64_t clamped = 0;
        for (std::size_t c = 0; c < chunks; ++c) {
            sum += chunkSums[c];
            clamped += chunkClamped[c];
        }
        ctx.addCounter("photons", static_cast<std::int64_t>(n));
        ctx.addCounter("clamped_radii", clamped);
        // Counters are integers: the mean radius in millionths of a scene unit.
        ctx.addCounter("mean_radius_1e-6", static_cast<std::int64_t>(std::llround(1e6 * sum / static_cast<double>(n))));
    }
};

}  // namespace

PassRegistration photonRadiusPass() {
    PassSpec spec;
    spec.name = "photon_radius";
    spec.doc = "Pilot density estimate for the beam radiance estimate: each photon's kernel radius from its k "
               "nearest photons (r_i = radius_scale * distance to the k-th nearest other photon)";
    spec.inputs = {{"photons", "PhotonMap", "the photons (usually volume_photons)"}};
    spec.outputs = {{"radii", "PhotonRadii", "one kernel radius per photon, in photon order"}};
    spec.params = {
        {"k", ParamType::Int, std::int64_t{20}, 1, 4096, {},
         "neighbours of the pilot estimate: a photon's sphere holds about k other photons"},
        {"radius_scale", ParamType::Float, 1.0, 1e-3, 1e3, {},
         "c in r_i = c * d_k; 1 makes the sphere hold k photons on average (c^3 k in general)"},
        {"max_radius", ParamType::Float, 0.0, 0.0, 1e30, {},
         "largest radius in scene units, for sparse photons (0 = unlimited)"},
    };
    return {spec, [] { return std::make_unique<PhotonRadiusPass>(); }};
}

}  // namespace fg
