// Beam query pass (`beam_query`): the beam radiance estimate (Jarosz, Zwicker
// & Jensen 2008) of the media radiance along every camera-ray segment, in the
// form of Jakob et al. 2011, Eq. 3:
//
//   L_m(x, w, s) ~= sum_i K_i(x_i) Tr(x <-> x_i) f(theta_i) Phi_i,
//
// summed over the photons whose kernel spheres the segment passes through
// (found by traversing the photon BVH). For photon i with radius r_i, x_i is
// the point of the ray closest to the photon, at parameter t_i and distance
// d_i; K_i is a normalised 2D kernel of radius r_i evaluated at d_i (the
// photon's 3D kernel integrated across the ray), by default Silverman's
// second-order kernel 3/pi (1 - d^2/r^2)^2 / r^2 (Silverman 1986; smooth, so
// that photons entering and leaving the beam do not flicker), or the uniform
// disk 1/(pi r^2); Tr is the segment medium's transmittance from the start of
// the segment to t_i, times the segment's throughput (the transmittance and
// specular weights of the camera path before it, and 1/spp); f is the
// medium's Henyey-Greenstein phase function for light arriving along the
// photon's direction and leaving towards the camera (1/(4 pi) when isotropic);
// Phi_i is the photon's power, which already holds sigma_s (see the photon
// pass), so no sigma_s appears here. A photon counts for a segment when its
// closest point t_i lies inside [tNear, tFar]: a photon near the boundary
// between two consecutive segments of one ray is counted exactly once.
//
// Output: the `volume` radiance layer, a film from black holding per pixel the
// sum of its segments' estimates (the composite pass adds it to the surface
// layers, so the query need not wait for the surface gather), and AOVs of the
// query's cost per pixel —
// query_cost (BVH nodes + photons tested), query_nodes, query_photons and
// query_time_ns (wall time of the pixel's queries) — the time-per-pixel image of
// Jakob et al. 2011, Fig. 1. Segments are estimated in parallel and summed into
// pixels in segment order, so the image is identical for any thread count.
#include "passes/passes.h"
#include "passes/caustics/photon_estimate.h"

#include "engine/buffers/beam_buffers.h"
#include "engine/image/film.h"
#include "engine/buffers/photon_buffers.h"
#include "engine/accel/photon_bvh.h"
#include "engine/scene/scene.h"
#include "jobs/parallel.h"
#include "jobs/work_context.h"

#include <atomic>
#include <cmath>
#include <stdexcept>

namespace fg {

namespace {

constexpr std::size_t kSegmentGrain = 64;

struct SegmentResult {
    Rgb radiance{0.0f};
    BvhQueryStats stats;
    std::int64_t used = 0;
    float timeNs = 0.0f;
};

class BeamQueryPass final : public Pass {
public:
    void run(PassContext& ctx) override {
        const Scene& scene = ctx.scene();
        const EyeSegments& eyeSegments = ctx.input<EyeSegments>("eye_segments");
        const VolumePhotonMap& photons = ctx.input<VolumePhotonMap>("photons");
        const PhotonBvh& bvh = ctx.input<PhotonBvh>("bvh");
        const bool silverman = ctx.params().getString("kernel") == "silverman";
        if (bvh.size() != photons.photons.size()) {
            throw std::logic_error("beam_query: the BVH holds " + std::to_string(bvh.size()) + " spheres but the map " +
                                   std::to_string(photons.photons.size()) + " photons");
        }

        // Photon power and direction in BVH order, so that leaves read them contiguously.
        bool anisotropic = false;
        for (const HomogeneousMedium& m : scene.media) anisotropic = anisotropic || m.phase().g() != 0.0f;
        const std::size_t n = bvh.size();
        std::vector<Rgb> power(n);
        std::vector<Vec3> incident(anisotropic ? n : 0);
        {
            const auto ids = bvh.sphereIds();
            const auto sourcePower = photons.photons.column<PhotonPower>();
            const auto sourceIncident = photons.photons.column<PhotonIncident>();
            jobs::parallelFor(n, 1 << 14, [&](std::size_t s) {
                power[s] = sourcePower[ids[s]];
                if (anisotropic) incident[s] = sourceIncident[ids[s]];
            });
        }
        const auto radius = bvh.spheres().column<BvhSphereRadius>();

        const SegmentBuffer& segments = eyeSegments.segments;
        const auto origin = segments.column<SegmentOrigin>();
        const auto direction = segments.column<SegmentDirection>();
        const auto tNear = segments.column<SegmentTNear>();
        const auto tFar = segments.column<SegmentTFar>();
        const auto mediumOf = segments.column<SegmentMedium>();
        const auto pixelOf = segments.column<SegmentPixel>();
        const auto throughput = segments.column<SegmentThroughput>();
        const std::size_t segmentCount = segments.size();
        std::vector<SegmentResult> results(segmentCount);

        jobs::parallelForChunks(segmentCount, kSegmentGrain, [&](jobs::IndexRange range) {
            for (std::size_t i = range.begin; i != range.end; ++i) {
                const std::int64_t start = jobs::wallNanos();
                const HomogeneousMedium& medium = scene.media.at(static_cast<std::size_t>(mediumOf[i]));
                const Rgb sigmaT = medium.sigmaT();
                const bool grey = sigmaT.x == sigmaT.y && sigmaT.y == sigmaT.z;
                const HenyeyGreenstein& phase = medium.phase();
                const bool isotropic = phase.g() == 0.0f;
                const Vec3 d = direction[i];
                const float t0 = tNear[i], t1 = tFar[i];
                SegmentResult& result = results[i];
                Rgb sum(0.0f);
                std::int64_t used = 0;
                bvh.forEachSphereOnSegment(
                    origin[i], d, t0, t1,
                    [&](std::uint32_t s, float tClosest, float dist2) {
                        if (tClosest < t0 || tClosest > t1) return;
                        const float r2 = radius[s] * radius[s];
                        if (!(r2 > 0.0f)) return;
                        const float x2 = dist2 / r2;
                        const float kernel = (silverman ? silvermanKernel(x2) : kInvPi) / r2;
                        if (kernel == 0.0f) return;
                        const float distance = tClosest - t0;
                        const Rgb tr = grey ? Rgb(std::exp(-sigmaT.x * distance))
                                            : Rgb(std::exp(-sigmaT.x * distance), std::exp(-sigmaT.y * distance),
                                                  std::exp(-sigmaT.z * distance));
                        const float f = isotropic ? 1.0f : phase.eval(incident[s], -d);
                        sum += power[s] * tr * (kernel * f);
                        ++used;
                    },
                    &result.stats);
                const float f = isotropic ? kInv4Pi : 1.0f;
                const Rgb value = sum * throughput[i] * f;
                result.radiance = isFinite(value) ? value : Rgb(0.0f);
                result.used = used;
                result.timeNs = static_cast<float>(jobs::wallNanos() - start);
            }
        });

        Film& image = ctx.createOutput<Film>("volume", ctx.filmSettings());
        image.aov("query_cost");  // create all channels before holding references into them
        image.aov("query_nodes");
        image.aov("query_photons");
        image.aov("query_time_ns");
        std::vector<float>& cost = image.aov("query_cost");
        std::vector<float>& nodes = image.aov("query_nodes");
        std::vector<float>& tested = image.aov("query_photons");
        std::vector<float>& time = image.aov("query_time_ns");
        std::vector<Rgb> perPixel(image.pixelCount(), Rgb(0.0f));
        std::int64_t totalNodes = 0, totalTested = 0, totalUsed = 0;
        for (std::size_t i = 0; i < segmentCount; ++i) {
            const std::uint32_t p = pixelOf[i];
            if (p >= perPixel.size()) throw std::logic_error("beam_query: segment outside the film");
            const SegmentResult& r = results[i];
            perPixel[p] += r.radiance;
            nodes[p] += static_cast<float>(r.stats.nodes);
            tested[p] += static_cast<float>(r.stats.spheres);
            cost[p] += static_cast<float>(r.stats.nodes + r.stats.spheres);
            time[p] += r.timeNs;
            totalNodes += r.stats.nodes;
            totalTested += r.stats.spheres;
            totalUsed += r.used;
        }
        image.addToPixels(perPixel, 1.0f);
        ctx.addItems(static_cast<std::int64_t>(segmentCount));
        ctx.addCounter("segments", static_cast<std::int64_t>(segmentCount));
        ctx.addCounter("camera_samples",
                       static_cast<std::int64_t>(image.pixelCount()) * std::max(1, eyeSegments.samplesPerPixel));
        ctx.addCounter("nodes_visited", totalNodes);
        ctx.addCounter("photons_tested", totalTested);
        ctx.addCounter("photons_used", totalUsed);
    }
};

}  // namespace

PassRegistration beamQueryPass() {
    PassSpec spec;
    spec.name = "beam_query";
    spec.doc = "Beam radiance estimate (Jakob et al. 2011 Eq. 3): all photon spheres along each camera segment "
               "(BVH traversal), 2D kernel x transmittance x phase x power, as the volume radiance layer, with "
               "per-pixel query-cost AOVs";
    spec.inputs = {
        {"eye_segments", "EyeSegments", "camera-ray segments inside media (volume_eye)"},
        {"photons", "VolumePhotonMap", "the volume photons the BVH was built over"},
        {"bvh", "PhotonBvh", "hierarchy over the photons' kernel spheres (photon_bvh)"},
    };
    spec.outputs = {{"volume", "Film", "media radiance alone (a film from black); AOVs query_cost, query_nodes, "
                                       "query_photons, query_time_ns"}};
    spec.params = {
        {"kernel", ParamType::String, std::string("silverman"), 0, 0, {"silverman", "uniform"},
         "normalised 2D kernel K_i: silverman = 3/pi (1 - d^2/r^2)^2 / r^2, uniform = 1 / (pi r^2)"},
    };
    const auto memory = [](const PreflightContext& pf) {
        return MemoryEstimate{filmBytes(pf.film),
                              "film " + std::to_string(pf.film.width) + " x " + std::to_string(pf.film.height), {}};
    };
    return {spec, [] { return std::make_unique<BeamQueryPass>(); }, {}, memory};
}

}  // namespace fg
