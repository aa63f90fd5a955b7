// Photon tracing (`photon`): photon paths leave the lights, each light chosen
// in proportion to its power, and are traced through the scene's surfaces and
// homogeneous media by BSDF and phase-function sampling in importance
// transport (Jensen 1996, "Global Illumination using Photon Maps"; Jensen &
// Christensen 1998, "Efficient Simulation of Light Transport in Scenes with
// Participating Media using Photon Maps"), with Russian roulette on the path
// throughput. Every hit on a surface with a smooth (diffuse or glossy) lobe is
// a photon event, classified by the path so far:
//   direct   L D       first event, stored only when asked (store_direct), in global_photons;
//   caustic  L S+ D    only specular events before: caustic_photons;
//   global   L ... D ... D   at least one non-specular event before: global_photons.
// Each photon carries its share of the source's flux: flux / (pmf(light) N).
//
// Media. The medium a path is in is tracked as the path tracer does (camera /
// shape interior and exterior, index-matched `null` boundaries crossed). A
// path starts in its light's medium: the side of the emitting shape it leaves
// by, when that shape declares media; otherwise the medium found by walking a
// probe ray from the light to the first boundary that declares one (the
// camera's medium when the light, like the camera, lies outside every such
// boundary). In a medium the free-flight distance is sampled with
// HomogeneousMedium::sampleDistance; a real scattering event before the next
// surface stores a volume photon (class Volume, combined with the Direct,
// Caustic or Global bit of its history: Volume|Direct is single scattering,
// L V) in volume_photons, counts as a non-specular event of depth max_depth
// shares with surfaces, and continues in a direction sampled from the phase
// function (weight 1). The power of a volume photon is the emitted share times
// the path throughput *including* the scattering weight
// sigma_s Tr(t) / p(t) of its own event (the albedo, for grey media). So the
// photons' power density estimates sigma_s L: the in-scattered radiance along
// a camera ray is Eq. 3 of Jakob et al. 2011, sum_i K_i Tr f Phi_i, with no
// further sigma_s (the convention of Jensen & Christensen 1998 and Jakob et
// al., not the one of Jarosz et al. 2008).
//
// Photon counts. `photons` paths are emitted; with volume_photons > 0 paths
// are emitted, in order, until exactly that many volume photons are stored
// (the photons of later paths are dropped, and at most `photons` paths are
// emitted), and every map's `emitted` is the number of paths up to and
// including the one that stored the last volume photon. Powers are computed
// for `photons` paths and rescaled to the count actually emitted at the end
// (footprints by the square root: differentials are linear in the initial
// lengths of Eqs. 5-6, which go as 1 / sqrt(N)).
//
// Photon differentials (Frisvad et al. 2014, §3; engine/shading/differentials.h) are
// emitted with every path and followed across its leading chain of specular
// events (Igehy 1999); they end at the first non-specular event, so caustic
// and direct photons carry footprints (PhotonDu / PhotonDv) and global
// photons do not (zero vectors; global_photons.hasDifferentials stays false);
// volume photons are stored without them (VolumePhotonMap). N_e of Eqs. 5-6
// is the expected number of paths from the chosen
// source, pmf(light) N. Photons whose footprint has collapsed are discarded
// and counted.
//
// Batches. Paths are traced batch_size at a time. An output whose readers all
// consume batches (the splat) is streamed: each batch's photons are handed
// over as a PhotonMap of their own and dropped, so no map of all photons is
// ever held (Frisvad et al. 2014, §2: splatting needs no photon map). With a
// volume-photon target the powers are final only at the end, so streamed
// maps are then handed over once, whole.
//
// Later volume photons on demand (volume_batch > 0, volume_photons streamed,
// as progressive EM reads them: Jakob et al. 2011 Alg. 2, line 9). After the
// target's map, paths go on with the next path indices and every further
// volume_batch volume photons are handed over as a map of their own, while a
// reader wants more. The photons handed over are thus always the first N of
// the same sequence, whatever the thread count or batch sizes. Each later
// map's `emitted` is the number of paths up to and including the one that
// stored its last photon, and its powers are normalised to that count; a
// reader that pools maps rescales each by its emitted / the last one's.
// Surface photons of the later paths are dropped: the stored surface maps are
// those of the target, exactly as without later batches.
//
// Surfaces without a BSDF or with a `null` one are crossed without an event.
//
// Guided photons (Vorba et al. 2014, §4.1 "Sampling from the distribution
// model", applied to photons as in the paper's Fig. 1 loop, step 3). With an
// `importance_cache` input (a GuidingCache trained on importons, which learns
// where importance W_in comes from), a surface event whose BSDF has smooth,
// non-transmissive lobes only looks the cache up on the side the photon
// arrived from and, if a record holds the point, draws the next direction from
// the one-sample mixture α p_bsdf + (1 - α) p_gmm (GuidedBsdfSampler, the
// routine guided pt uses); the photon's power is multiplied by f |cos| / p_mix
// (times the shading-normal correction below), so the expected photon density
// is that of unguided tracing: only its spread over the scene changes. The
// GMM's mass outside its square ends the path, as in guided pt (§4.1).
// Specular, transmissive and null lobes are never guided, and without the
// input every path draws exactly the numbers and values it drew before.
//
// Guided environment emission (Vorba et al. 2014, §4.4, Fig. 6b). With an
// `environment` input (an EnvironmentGuide trained on the importons that left
// the scene, environment_update) that has importance somewhere, a path whose
// chosen light is an environment emitter (a non-delta infinite light) draws
// its direction towards the light from the one-sample mixture
// β p_L p_W + (1 − β) p_L (balance heuristic, Veach 1997 §9.2.4; the paper's
// "MIS of the product and p_L"), p_L the light's own direction sampling and
// p_W constant per bitmap cell, the product sampled exactly in p_L
// (EnvironmentSampler: a sun smaller than a cell is found by both halves), and
// its start on the emission disk perpendicular to the direction from
// γ p(x|ω) + (1 − γ) / (π R²), p(x|ω) the cell's disk GMM where one is
// fitted (§4.4 "Position distributions"; the uniform part, which the paper
// does not mention, keeps every line through the scene reachable). The flux
// is L_e(ω) / (p(x) p(ω)) with both mixture densities, as unguided emission's
// is L_e / (p_A p_ω), so the photon map's expected density does not change. A
// GMM sample outside its square ends the path, as in §4.1. β and γ are
// environment_direction_probability and environment_position_probability
// (0.5 each: not in the paper). Such a path draws five numbers more than an
// unguided one, after the light's; delta lights (directional) are never
// guided, and without the input (or with an empty model) every path draws
// exactly the numbers it drew before.
//
// Determinism: path i draws from the stream (seed, instance, i); a batch is
// split into fixed chunks, each chunk collects its photons in path order, and
// chunks are appended in order, so the maps do not depend on the thread count
// (nor on batch_size). Chunks are traced a wave at a time and their records
// copied into the maps after each wave, so that the next wave reuses their
// memory; the waves only bound that memory and do not change the order.
// Scenes without media draw exactly the random numbers they drew before media
// were simulated.
#include "passes/passes.h"
#include "passes/common/light_media.h"
#include "passes/common/path_vertex.h"
#include "passes/common/roulette.h"

#include "engine/shading/differentials.h"
#include "engine/core/error.h"
#include "engine/guiding/environment_guide.h"
#include "engine/guiding/guided_sampling.h"
#include "engine/guiding/guiding_cache.h"
#include "engine/buffers/photon_buffers.h"
#include "engine/buffers/photon_ray_buffers.h"
#include "engine/accel/ray_query.h"
#include "engine/scene/scene.h"
#include "jobs/parallel.h"
#include "jobs/random.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdint>
#include <memory>
#include <optional>
#include <span>
#include <type_traits>
#include <utility>
#include <vector>

namespace fg {

namespace {

constexpr std::size_t kGrain = 256;
// Chunks traced between two copies into the maps. A wave's chunks reuse the
// record vectors of the wave before, so records are written to memory that is
// already mapped (and mostly cached) instead of fresh pages per chunk; 32k
// paths keep the barrier at each wave's end to about 1 % of it at 2 threads.
constexpr std::size_t kWaveChunks = 128;
constexpr std::size_t kWavePaths = kWaveChunks * kGrain;
// Paths of the first batch when emission stops at a volume-photon target.
constexpr double kPilotPaths = 16384.0;
// Null boundaries crossed by one segment; the bound only guards against degenerate geometry.
constexpr int kMaxNullCrossings = 1024;

struct Settings {
    std::uint64_t photons = 0;
    std::uint64_t volumeTarget = 0;  // 0: emit `photons` paths
    int maxDepth = 16;
    int rrDepth = 5;
    float rrThreshold = 1.0f;
    bool storeCaustic = true;
    bool storeGlobal = true;
    bool storeVolume = true;
    bool storeDirect = false;
    bool storeSingleScattering = true;
    bool causticOnlyPaths = false;
    bool differentials = true;
    float smoothing = 10.0f;
    std::size_t batchSize = 1 << 18;
    // Photon rays (Herzog et al. 2007, Eq. 7): every segment with its bounded density p~.
    bool recordRays = false;
    float clampDistance2 = 0.0f;  // D~^2 of Eq. 7
    float specularPdf = 100.0f;   // stands in for p_s^perp at specular events, which have no density
    std::uint64_t volumeBatch = 0;  // later volume photons per streamed map; 0: none
    // Guided photons: the importance cache (null: BSDF sampling only) and how it is read.
    const GuidingCache* importanceCache = nullptr;
    float guidingBsdfProbability = 0.5f;  // α
    std::uint32_t guidingCandidates = 2;  // M of Eq. 11 without a cover grid
    bool guidingCovering = true;
    // Guided environment emission: the model (null: unguided emission) and,
    // per light, its sampler of p_L p_W (unusable for other lights).
    const EnvironmentGuide* environment = nullptr;
    std::vector<EnvironmentSampler> environmentSamplers;
    float environmentDirectionProbability = 0.5f;  // β
    float environmentPositionProbability = 0.5f;   // γ
};

// A photon and the path that stored it, for stopping at a photon-count target.
template <class Buffer>
struct PathRecord : Buffer::Record {
    std::uint64_t path = 0;
};
using PhotonRecord = PathRecord<PhotonBuffer>;
using VolumePhotonRecord = PathRecord<VolumePhotonBuffer>;

// What one chunk of paths produced, in path order.
struct ChunkResult {
    std::vector<PhotonRecord> caustic;
    std::vector<PhotonRecord> global;
    std::vector<VolumePhotonRecord> volume;
    std::vector<PhotonRayBuffer::Record> rays;
    std::int64_t collapsedCaustic = 0;
    std::int64_t collapsedGlobal = 0;
    std::int64_t segments = 0;
    std::int64_t guidedEvents = 0;
    std::int64_t guidedEmissions = 0;

    // Empties the chunk for its next paths; the vectors keep their capacity.
    void clear() {
        caustic.clear();
        global.clear();
        volume.clear();
        rays.clear();
        collapsedCaustic = collapsedGlobal = segments = guidedEvents = guidedEmissions = 0;
    }
};

// Capacity hints for a chunk's record vectors, from the records per path of
// the chunks traced so far: vectors grown from empty copy every record about
// once more and reallocate a dozen times per chunk. Only capacities depend on
// the hints (and on the order chunks finish in), never the records.
class RecordRates {
public:
    void reserve(ChunkResult& out, std::size_t paths) const {
        // A quarter more than the mean, so that most chunks never grow.
        const Expected records = expected(paths, 4);
        out.caustic.reserve(records.caustic);
        out.global.reserve(records.global);
        out.volume.reserve(records.volume);
        out.rays.reserve(records.rays);
    }
    // Records expected from `paths` paths at the mean rate so far, plus a
    // 1/marginDivisor margin; zero before any chunk is done.
    struct Expected {
        std::size_t caustic = 0, global = 0, volume = 0, rays = 0;
    };
    Expected expected(std::size_t paths, std::uint64_t marginDivisor) const {
        const std::uint64_t seen = paths_.load(std::memory_order_relaxed);
        if (seen == 0) return {};
        const auto hint = [&](const std::atomic<std::uint64_t>& records) {
            return static_cast<std::size_t>(records.load(std::memory_order_relaxed) * paths * (marginDivisor + 1) /
                                            (marginDivisor * seen));
        };
        return {hint(caustic_), hint(global_), hint(volume_), hint(rays_)};
    }
    void add(const ChunkResult& out, std::size_t paths) {
        paths_.fetch_add(paths, std::memory_order_relaxed);
        caustic_.fetch_add(out.caustic.size(), std::memory_order_relaxed);
        global_.fetch_add(out.global.size(), std::memory_order_relaxed);
        volume_.fetch_add(out.volume.size(), std::memory_order_relaxed);
        rays_.fetch_add(out.rays.size(), std::memory_order_relaxed);
    }

private:
    std::atomic<std::uint64_t> paths_{0}, caustic_{0}, global_{0}, volume_{0}, rays_{0};
};

// The photon ray being traced (Herzog et al. 2007, Eq. 7): where it left, and
// p~ of its origin vertex times the density of the direction it left in, to
// be divided by D once its length is known.
struct RayInFlight {
    Vec3 origin{0.0f};
    Vec3 originNormal{0.0f};
    double densityBeforeD = 0.0;
    double originDensity = 0.0;  // p~(x_i | x_{i-1}); 0 at the light
    bool divideByD = true;  // infinite lights emit from a disk far away: no distance term
    std::uint8_t rayClass = PhotonRayClass::Direct;
    std::uint16_t vertex = 0;
};

// Where a ray from `origin` (inside the box) leaves it.
float boxExitDistance(const Vec3& origin, const Vec3& direction, const Vec3& lo, const Vec3& hi) {
    float exit = kInfinity;
    for (int a = 0; a < 3; ++a) {
        if (direction[a] > 0.0f) exit = std::min(exit, (hi[a] - origin[a]) / direction[a]);
        else if (direction[a] < 0.0f) exit = std::min(exit, (lo[a] - origin[a]) / direction[a]);
    }
    return std::max(0.0f, exit);
}

class PhotonTracer {
public:
    PhotonTracer(const Scene& scene, const RayQuery& rays, const Settings& settings, std::uint64_t seed,
                 std::uint64_t stream)
        : scene_(scene), rays_(rays), settings_(settings), seed_(seed), stream_(stream),
          lightMedium_(lightStartMedia(scene, rays)) {}

    void trace(std::uint64_t pathIndex, ChunkResult& out) const {
        jobs::Rng rng(seed_, stream_, pathIndex);
        const float uLight = rng.uniform();
        const Vec2 uPosition = rng.uniform2();
        const Vec2 uDirection = rng.uniform2();
        float pmf = 0.0f;
        const std::size_t lightIndex = scene_.lightPower.sampleDiscrete(uLight, &pmf);
        if (!(pmf > 0.0f)) return;
        const bool guidedEmission =
            settings_.environment && settings_.environmentSamplers[lightIndex].usable();
        const std::optional<EmissionSample> emission =
            guidedEmission ? guidedEnvironmentEmission(*scene_.lights[lightIndex], settings_.environmentSamplers[lightIndex],
                                                       uPosition, uDirection, rng)
                           : scene_.lights[lightIndex]->sampleEmission(uPosition, uDirection);
        if (guidedEmission) ++out.guidedEmissions;
        if (!emission) return;
        const double photonsFromSource = static_cast<double>(pmf) * static_cast<double>(settings_.photons);
        const Rgb power = emission->flux / static_cast<float>(photonsFromSource);
        if (isBlack(power) || !isFinite(power)) return;

        Vec3 direction = glm::normalize(emission->direction);
        bool tracking = settings_.differentials;
        PhotonDifferential differential;
        if (tracking) {
            differential = emitPhotonDifferential(direction, emission->normal, emission->emitterArea,
                                                  emission->emitterSolidAngle, photonsFromSource, settings_.smoothing);
        }
        int medium = lightMedium_[lightIndex];
        if (medium == kMediumBySide) {
            const Shape& shape = scene_.shapes[static_cast<std::size_t>(scene_.lightShape[lightIndex])];
            medium = mediumAfterCrossing(shape, emission->normal, direction, -1);
        }
        Vec3 previous = emission->origin;
        Ray ray{offsetRayOrigin(emission->origin, emission->normal, direction), direction, kInfinity};
        Rgb throughput(1.0f);
        int depth = 0;
        bool specularChain = true;  // every event so far was specular
        std::optional<RayInFlight> photonRay;
        if (settings_.recordRays) photonRay = emittedRay(*emission, pmf, scene_.lights[lightIndex]->isInfinite());
        int nullCrossings = 0;

        const auto survivesRoulette = [&] {
            if (depth < settings_.rrDepth) return true;
            return rouletteSurvives(maxComponent(throughput), settings_.rrThreshold, rng, throughput);
        };

        while (true) {
            const Hit hit = rays_.intersect(ray);
            ++out.segments;

            if (medium >= 0) {
                const HomogeneousMedium& m = scene_.media[static_cast<std::size_t>(medium)];
                const float uChannel = rng.uniform();
                const float uDistance = rng.uniform();
                const DistanceSample ds = m.sampleDistance(hit.valid() ? hit.t : kInfinity, uChannel, uDistance,
                                                           throughput);
                throughput *= ds.weight;
                if (isBlack(throughput) || !isFinite(throughput)) return;
                if (ds.scattered) {
                    ++depth;
                    nullCrossings = 0;
                    const Vec3 p = ray.origin + ds.t * ray.direction;
                    const std::uint8_t history = depth == 1       ? PhotonClass::Direct
                                                 : specularChain ? PhotonClass::Caustic
                                                                 : PhotonClass::Global;
                    storeVolume(static_cast<std::uint8_t>(PhotonClass::Volume | history), p, direction,
                                power * throughput, pathIndex, out);
                    photonRay.reset();  // photon rays are traced between surfaces only
                    if (settings_.causticOnlyPaths || depth >= settings_.maxDepth) return;
                    const PhaseSample ps = m.phase().sample(-direction, rng.uniform2());
                    if (!(ps.pdf > 0.0f)) return;
                    specularChain = false;
                    tracking = false;
                    direction = ps.wi;
                    previous = p;
                    ray = Ray{p, direction, kInfinity};
                    if (!survivesRoulette()) return;
                    continue;
                }
            }
            if (!hit.valid()) {
                if (photonRay) {
                    const float length = boxExitDistance(photonRay->origin, direction, scene_.boundsMin, scene_.boundsMax);
                    recordRay(*photonRay, direction, length, Vec3(0.0f), power * throughput, pathIndex, out);
                }
                return;
            }

            const SurfacePoint sp = rays_.surface(ray, hit);
            if (tracking) transferDifferential(differential, direction, glm::dot(sp.p - previous, direction), sp.ng);
            previous = sp.p;
            const Shape& shape = scene_.shapes[sp.shape];
            const Bsdf* bsdf = shape.bsdf >= 0 ? scene_.bsdfs[static_cast<std::size_t>(shape.bsdf)].get() : nullptr;
            // The transparent part of a mask is crossed as a null boundary (probability 1 - opacity).
            if (!bsdf || bsdf->isNull() || passesThroughMask(bsdf, sp.texturePoint(), rng)) {
                if (++nullCrossings > kMaxNullCrossings) return;
                medium = mediumAfterCrossing(shape, sp.ng, direction, medium);
                ray = Ray{offsetRayOrigin(sp.p, sp.ng, direction), direction, kInfinity};
                continue;
            }
            const Frame frame(sp.ns);
            const Vec3 wo = frame.toLocal(-direction);
            // Straight-through transmission (thindielectric) is a null event as in
            // the path tracer: the photon crosses as it crosses a null boundary,
            // keeping its depth and class, so that light the eye passes gather
            // by next-event estimation through the slab is not also a caustic.
            std::optional<BsdfSample> chosen;
            if (bsdf->hasNullLobe()) {
                const float uLobe = rng.uniform();
                const Vec2 uBsdf = rng.uniform2();
                chosen = bsdf->sample(wo, sp.texturePoint(), uLobe, uBsdf, TransportMode::Importance);
                if (!chosen || chosen->pdf <= 0.0f || isBlack(chosen->weight)) return;
                if (chosen->lobe & BsdfLobe::Null) {
                    if (++nullCrossings > kMaxNullCrossings) return;
                    throughput *= chosen->weight;
                    medium = mediumAfterCrossing(shape, sp.ng, direction, medium);
                    ray = Ray{offsetRayOrigin(sp.p, sp.ng, direction), direction, kInfinity};
                    continue;
                }
            }
            nullCrossings = 0;
            ++depth;
            if (photonRay) {
                const Vec3 facingRay = glm::dot(direction, sp.ng) < 0.0f ? sp.ng : -sp.ng;
                recordRay(*photonRay, direction, glm::length(sp.p - photonRay->origin), facingRay, power * throughput,
                          pathIndex, out);
            }

            if (bsdf->hasSmoothLobe()) {
                const std::uint8_t photonClass =
                    depth == 1 ? PhotonClass::Direct : (specularChain ? PhotonClass::Caustic : PhotonClass::Global);
                store(photonClass, sp, direction, power * throughput, tracking ? &differential : nullptr, pathIndex,
                      out);
                if (settings_.causticOnlyPaths) return;
            }
            if (depth >= settings_.maxDepth) return;

            if (!chosen) {
                if (const std::optional<GuidedBsdfSampler> guided = importanceGuide(*bsdf, frame, wo, sp, -direction)) {
                    const float uStrategy = rng.uniform();
                    const float uLobe = rng.uniform();
                    const Vec2 uGuided = rng.uniform2();
                    chosen = guided->sampleAsBsdf(uStrategy, uLobe, uGuided, TransportMode::Importance);
                    if (!chosen) return;
                    ++out.guidedEvents;
                } else {
                    const float uLobe = rng.uniform();
                    const Vec2 uBsdf = rng.uniform2();
                    chosen = bsdf->sample(wo, sp.texturePoint(), uLobe, uBsdf, TransportMode::Importance);
                }
            }
            const std::optional<BsdfSample>& bs = chosen;
            if (!bs || bs->pdf <= 0.0f || isBlack(bs->weight)) return;
            const Vec3 wi = frame.toWorld(bs->wi);
            const float cosGeometricIn = glm::dot(wi, sp.ng);
            if (cosGeometricIn * bs->wi.z <= 0.0f) return;
            // Shading normals make importance transport non-symmetric (Veach 1997, §5.3.2):
            // the adjoint BSDF carries |wo.ns| |wi.ng| / (|wo.ng| |wi.ns|).
            const float adjointDenominator = std::abs(glm::dot(direction, sp.ng)) * std::abs(bs->wi.z);
            if (!(adjointDenominator > 0.0f)) return;
            throughput *= bs->weight * (std::abs(wo.z) * std::abs(cosGeometricIn) / adjointDenominator);

            if (bs->isSpecular()) {
                if (tracking) {
                    const Vec3 dnU = rays_.shadingNormalDifferential(ray, hit, differential.dxU);
                    const Vec3 dnV = rays_.shadingNormalDifferential(ray, hit, differential.dxV);
                    scatterDifferential(differential, direction, wi, sp.ns, dnU, dnV, *bs);
                }
            } else {
                specularChain = false;
                tracking = false;  // a differential means nothing after a non-specular event
            }
            if (bs->lobe & BsdfLobe::Transmission) medium = mediumAfterCrossing(shape, sp.ng, wi, medium);
            if (photonRay) {
                // p_s^perp = p_s / cos theta' (Eq. 1); a specular event has no density.
                const double projectedPdf = bs->isSpecular() ? static_cast<double>(settings_.specularPdf)
                                                             : static_cast<double>(bs->pdf) / std::abs(bs->wi.z);
                photonRay->densityBeforeD *= projectedPdf;
                photonRay->divideByD = true;
                photonRay->origin = sp.p;
                photonRay->originNormal = glm::dot(wi, sp.ng) > 0.0f ? sp.ng : -sp.ng;
                photonRay->rayClass = specularChain ? PhotonRayClass::Caustic : PhotonRayClass::Global;
            }
            direction = wi;
            ray = Ray{offsetRayOrigin(sp.p, sp.ng, wi), wi, kInfinity};
            if (!survivesRoulette()) return;
        }
    }

private:
    // §4.4: the emission of an environment light from the guided mixtures (see
    // the opening comment), with the densities it was drawn with.
    std::optional<EmissionSample> guidedEnvironmentEmission(const Light& light, const EnvironmentSampler& sampler,
                                                            const Vec2& uPosition, const Vec2& uDirection,
                                                            jobs::Rng& rng) const {
        const float uDirectionStrategy = rng.uniform();
        const float uPositionStrategy = rng.uniform();
        const float uComponent = rng.uniform();
        const Vec2 uGauss = rng.uniform2();
        const EnvironmentGuide& guide = *settings_.environment;
        const float beta = settings_.environmentDirectionProbability;
        const float gamma = settings_.environmentPositionProbability;
        Vec3 towardsLight;
        if (uDirectionStrategy < beta) {
            const std::optional<Vec3> w = sampler.sample(uDirection);
            if (!w) return std::nullopt;
            towardsLight = *w;
        } else {
            const std::optional<LightSample> ls = light.sampleLi(guide.center, uDirection);
            if (!ls) return std::nullopt;
            towardsLight = ls->wi;
        }
        const float lightPdf = light.pdfLi(guide.center, Vec3(0.0f), Vec3(0.0f), towardsLight);
        const float directionPdf = environmentDirectionPdf(beta, sampler.pdf(towardsLight, lightPdf), lightPdf);
        const Rgb radiance = light.environment(towardsLight);
        if (!(directionPdf > 0.0f) || isBlack(radiance)) return std::nullopt;
        const std::uint32_t cell = guide.cellOf(towardsLight);
        const DirectionalGmm* gmm = guide.diskMixture(cell);
        Vec2 disk;
        if (gmm && uPositionStrategy < gamma) {
            const Vec2 s = gmm->samplePlane(uComponent, uGauss);
            if (!(s.x >= 0.0f && s.x <= 1.0f && s.y >= 0.0f && s.y <= 1.0f)) return std::nullopt;
            disk = squareToUnitDisk(s);
        } else {
            disk = sampleConcentricDisk(uPosition);
        }
        const float positionPdf = environmentPositionPdf(gmm, gamma, disk, guide.radius);
        if (!(positionPdf > 0.0f)) return std::nullopt;
        EmissionSample e;
        e.direction = -towardsLight;
        e.origin = guide.diskOrigin(cell, towardsLight, disk);
        e.normal = e.direction;
        e.pdfPosition = positionPdf;
        e.pdfDirection = directionPdf;
        e.flux = radiance / (positionPdf * directionPdf);
        e.emitterArea = kPi * guide.radius * guide.radius;
        e.emitterSolidAngle = 4.0f * kPi;
        return e;
    }

    // The importance cache's record that guides the photon leaving a surface
    // point, as a mixture sampler: only at BSDFs with smooth, non-transmissive
    // lobes only, and only where a record with a usable mixture covers the
    // point on the side the photon arrived from (`toSource`).
    std::optional<GuidedBsdfSampler> importanceGuide(const Bsdf& bsdf, const Frame& frame, const Vec3& wo,
                                                     const SurfacePoint& sp, const Vec3& toSource) const {
        const GuidingCache* cache = settings_.importanceCache;
        constexpr std::uint32_t kUnguided = BsdfLobe::Specular | BsdfLobe::Transmission | BsdfLobe::Null;
        if (!cache || (bsdf.lobes() & kUnguided) != 0 || !bsdf.hasSmoothLobe()) return std::nullopt;
        const Vec3 facing = glm::dot(sp.ns, toSource) >= 0.0f ? sp.ns : -sp.ns;
        const bool covering = settings_.guidingCovering && cache->hasCoverGrid();
        const std::optional<std::uint32_t> record =
            covering ? cache->lookupGuiding(sp.p, facing)
                     : cache->lookup(sp.p, facing, GuidingCacheQuery{settings_.guidingCandidates});
        if (!record || !cache->guides(*record)) return std::nullopt;
        const DirectionalGmm& gmm = cache->records.column<GuideMixture>()[*record];
        return GuidedBsdfSampler{&bsdf, frame, wo, sp.texturePoint(), &gmm,
                                 Frame(cache->records.column<GuideNormal>()[*record]),
                                 settings_.guidingBsdfProbability};
    }

    // Eq. 7, i = 0: p_e = area pdf x projected-solid-angle pdf (times the
    // light's selection probability); point and spot lights have only the
    // solid-angle pdf, collimated and other infinite lights only the density
    // on their emission disk, and no distance term.
    RayInFlight emittedRay(const EmissionSample& emission, float lightPmf, bool infinite) const {
        RayInFlight r;
        r.origin = emission.origin;
        const bool hasSurface = glm::dot(emission.normal, emission.normal) > 0.0f;
        r.originNormal = hasSurface ? glm::normalize(emission.normal) : Vec3(0.0f);
        double pe = static_cast<double>(lightPmf) * static_cast<double>(emission.pdfPosition) *
                    static_cast<double>(emission.pdfDirection);
        if (hasSurface) {
            const float cosine = std::abs(glm::dot(r.originNormal, glm::normalize(emission.direction)));
            pe = cosine > 0.0f ? pe / static_cast<double>(cosine) : 0.0;
        }
        r.divideByD = !infinite;
        r.densityBeforeD = pe;
        return r;
    }

    void recordRay(RayInFlight& r, const Vec3& direction, float length, const Vec3& endNormal, const Rgb& power,
                   std::uint64_t path, ChunkResult& out) const {
        const double d = std::max(static_cast<double>(settings_.clampDistance2), static_cast<double>(length) * length);
        const double density = r.divideByD ? r.densityBeforeD / d : r.densityBeforeD;
        if (length > 0.0f && !isBlack(power) && isFinite(power) && std::isfinite(density)) {
            out.rays.push_back(PhotonRayBuffer::Record{r.origin, direction, length, power, 0.0f, 0.0f,
                                                       static_cast<float>(density), static_cast<float>(r.originDensity),
                                                       r.rayClass, r.originNormal,
                                                       endNormal, path, r.vertex});
        }
        r.densityBeforeD = density;
        r.originDensity = density;
        r.vertex = static_cast<std::uint16_t>(std::min<int>(r.vertex + 1, 65535));
    }

    void store(std::uint8_t photonClass, const SurfacePoint& sp, const Vec3& direction, const Rgb& power,
               const PhotonDifferential* differential, std::uint64_t path, ChunkResult& out) const {
        const bool wanted = photonClass == PhotonClass::Direct    ? settings_.storeDirect
                            : photonClass == PhotonClass::Caustic ? settings_.storeCaustic
                                                                  : settings_.storeGlobal;
        if (!wanted || isBlack(power) || !isFinite(power)) return;
        const bool caustic = photonClass == PhotonClass::Caustic;
        PhotonRecord record{{sp.p, -direction, power, sp.ns, photonClass, Vec3(0.0f), Vec3(0.0f)}, path};
        if (differential) {
            if (footprintCollapsed(differential->dxU, differential->dxV, sp.ns)) {
                ++(caustic ? out.collapsedCaustic : out.collapsedGlobal);
                return;
            }
            record.get<PhotonDu>() = differential->dxU;
            record.get<PhotonDv>() = differential->dxV;
        }
        (caustic ? out.caustic : out.global).push_back(record);
    }

    void storeVolume(std::uint8_t photonClass, const Vec3& position, const Vec3& direction, const Rgb& power,
                     std::uint64_t path, ChunkResult& out) const {
        if (!settings_.storeVolume || isBlack(power) || !isFinite(power)) return;
        if ((photonClass & PhotonClass::Direct) && !settings_.storeSingleScattering) return;
        out.volume.push_back(VolumePhotonRecord{{position, -direction, power, photonClass}, path});
    }

    const Scene& scene_;
    const RayQuery& rays_;
    const Settings& settings_;
    std::uint64_t seed_;
    std::uint64_t stream_;
    std::vector<int> lightMedium_;
};

// Records of paths up to and including `lastPath` (records are in path order).
std::size_t recordsUpTo(const std::vector<PhotonRecord>& records, std::uint64_t lastPath) {
    return static_cast<std::size_t>(
        std::partition_point(records.begin(), records.end(), [&](const PhotonRecord& r) { return r.path <= lastPath; }) -
        records.begin());
}

// Powers were computed for `planned` paths; `emitted` were traced.
template <class Map>
void renormalise(Map& map, std::uint64_t planned, std::uint64_t emitted) {
    if (planned == emitted || emitted == 0) return;
    const float powerScale = static_cast<float>(static_cast<double>(planned) / static_cast<double>(emitted));
    for (Rgb& p : map.photons.template column<PhotonPower>()) p *= powerScale;
    if constexpr (std::is_same_v<Map, PhotonMap>) {
        const float lengthScale = std::sqrt(powerScale);
        for (Vec3& d : map.photons.template column<PhotonDu>()) d *= lengthScale;
        for (Vec3& d : map.photons.template column<PhotonDv>()) d *= lengthScale;
    }
}

class PhotonPass final : public Pass {
private:
    // Hands over maps of settings.volumeBatch further volume photons while a
    // reader wants more; `pending` holds the records traced beyond the
    // target's last photon, from paths below `pathsTraced`.
    static void traceLaterVolumePhotons(PassContext& ctx, const PhotonTracer& tracer, const Settings& settings,
                                        std::int64_t targetPhotons, std::uint64_t targetPaths,
                                        std::uint64_t pathsTraced, std::vector<VolumePhotonRecord>& pending) {
        // Paths per volume photon so far, to size the path batches (the photons do not depend on the sizes).
        const double rate = static_cast<double>(targetPhotons) / static_cast<double>(std::max<std::uint64_t>(targetPaths, 1));
        std::int64_t maps = 0, photons = 0, segments = 0;
        RecordRates rates;
        std::uint64_t lastEmitted = targetPaths;
        const auto handOverFirst = [&](std::size_t count, std::uint64_t emitted) {
            auto map = std::make_shared<VolumePhotonMap>();
            map->photons.append(std::span<const VolumePhotonRecord>(pending).first(count));
            renormalise(*map, settings.photons, emitted);
            map->emitted = emitted;
            pending.erase(pending.begin(), pending.begin() + static_cast<std::ptrdiff_t>(count));
            ++maps;
            photons += static_cast<std::int64_t>(count);
            lastEmitted = emitted;
            return ctx.emitBatch<VolumePhotonMap>("volume_photons", std::move(map));
        };
        bool wanted = true;
        while (wanted) {
            while (wanted && pending.size() >= settings.volumeBatch)
                wanted = handOverFirst(static_cast<std::size_t>(settings.volumeBatch),
                                       pending[static_cast<std::size_t>(settings.volumeBatch) - 1].path + 1);
            if (!wanted) break;
            if (pathsTraced >= settings.photons) {
                // The path cap: what is left, over every path traced.
                if (!pending.empty()) handOverFirst(pending.size(), settings.photons);
                break;
            }
            if (ctx.stopRequested()) {
                ctx.keptPartial(ctx.instanceName() + ": " + std::to_string(photons) +
                                " later volume photons before the interrupt");
                break;
            }
            const double missing = static_cast<double>(settings.volumeBatch - pending.size());
            const double estimate = rate > 0.0 ? 1.1 * missing / rate + 1024.0 : static_cast<double>(settings.batchSize);
            const auto count = static_cast<std::size_t>(std::min<std::uint64_t>(
                std::min<std::uint64_t>(settings.batchSize, static_cast<std::uint64_t>(std::min(estimate, 1e15))),
                settings.photons - pathsTraced));
            std::vector<ChunkResult> chunks((count + kGrain - 1) / kGrain);
            jobs::parallelForChunks(count, kGrain, [&](jobs::IndexRange r) {
                ChunkResult& out = chunks[r.begin / kGrain];
                rates.reserve(out, r.end - r.begin);
                for (std::size_t i = r.begin; i != r.end; ++i) tracer.trace(pathsTraced + i, out);
                rates.add(out, r.end - r.begin);
            });
            for (const ChunkResult& chunk : chunks) {
                pending.insert(pending.end(), chunk.volume.begin(), chunk.volume.end());
                segments += chunk.segments;
            }
            ctx.addItems(static_cast<std::int64_t>(count));
            pathsTraced += count;
            ctx.completedUnit();
        }
        ctx.addCounter("later_volume_maps", maps);
        ctx.addCounter("later_volume_photons", photons);
        ctx.addCounter("later_paths", static_cast<std::int64_t>(lastEmitted - targetPaths));
        ctx.addCounter("later_photon_segments", segments);
    }

public:
    void run(PassContext& ctx) override {
        const Scene& scene = ctx.scene();
        const PassParams& params = ctx.params();
        Settings settings;
        settings.photons = static_cast<std::uint64_t>(params.getInt("photons"));
        settings.volumeTarget = static_cast<std::uint64_t>(params.getInt("volume_photons"));
        settings.maxDepth = static_cast<int>(params.getInt("max_depth"));
        settings.rrDepth = static_cast<int>(params.getInt("rr_depth"));
        settings.rrThreshold = static_cast<float>(params.getFloat("rr_threshold"));
        const std::string& store = params.getString("store");
        settings.storeCaustic = store == "caustic" || store == "surface" || store == "all";
        settings.storeGlobal = store == "global" || store == "surface" || store == "all";
        settings.storeVolume = store == "volume" || store == "all";
        settings.storeDirect = params.getBool("store_direct");
        settings.storeSingleScattering = params.getBool("store_single_scattering");
        settings.causticOnlyPaths = params.getBool("caustic_only_paths");
        settings.differentials = params.getBool("differentials");
        settings.smoothing = static_cast<float>(params.getFloat("smoothing"));
        settings.batchSize = static_cast<std::size_t>(params.getInt("batch_size"));
        settings.recordRays = params.getBool("photon_rays");
        const float clampDistance = params.getFloat("clamp_distance") > 0.0
                                        ? static_cast<float>(params.getFloat("clamp_distance"))
                                        : 0.01f * glm::length(scene.boundsMax - scene.boundsMin);
        settings.clampDistance2 = clampDistance * clampDistance;
        settings.specularPdf = static_cast<float>(params.getFloat("specular_pdf"));
        settings.volumeBatch = static_cast<std::uint64_t>(params.getInt("volume_batch"));
        const bool guided = ctx.hasInput("importance_cache");
        if (guided) {
            // A cache none of whose records guides leaves every photon to BSDF sampling.
            const GuidingCache& cache = ctx.input<GuidingCache>("importance_cache");
            settings.importanceCache = cache.anyGuides() ? &cache : nullptr;
            settings.guidingBsdfProbability = static_cast<float>(params.getFloat("guiding_bsdf_probability"));
            settings.guidingCandidates = static_cast<std::uint32_t>(params.getInt("guiding_candidates"));
            settings.guidingCovering = params.getString("guiding_query") == "covering";
        }
        const bool guidedEnvironment = ctx.hasInput("environment");
        if (guidedEnvironment) {
            // An empty model (no environment emitter, or no importon left the
            // scene yet) leaves every path to unguided emission.
            const EnvironmentGuide& guide = ctx.input<EnvironmentGuide>("environment");
            if (guide.guides()) {
                settings.environmentSamplers.resize(scene.lights.size());
                bool any = false;
                for (std::size_t l = 0; l < scene.lights.size(); ++l) {
                    const Light& light = *scene.lights[l];
                    if (!isEnvironmentEmitter(light)) continue;
                    settings.environmentSamplers[l] = EnvironmentSampler(guide, light);
                    any = any || settings.environmentSamplers[l].usable();
                }
                if (any) settings.environment = &guide;
            }
            settings.environmentDirectionProbability =
                static_cast<float>(params.getFloat("environment_direction_probability"));
            settings.environmentPositionProbability =
                static_cast<float>(params.getFloat("environment_position_probability"));
        }
        // An own seed gives an independent photon set at the same eye vertices (the job's
        // seed keys the camera paths): what variance measurements and comparisons against a
        // reference rendered with the job's seed need.
        const std::int64_t ownSeed = params.getInt("seed");
        const std::uint64_t seed = ownSeed == 0 ? ctx.seed() : static_cast<std::uint64_t>(ownSeed);
        const bool targetMode = settings.volumeTarget > 0;
        if (targetMode && !settings.storeVolume) {
            throw InputError(scene.sourcePath, 0,
                             "pass '" + ctx.instanceName() + "': volume_photons = " +
                                 std::to_string(settings.volumeTarget) + " needs store = \"volume\" or \"all\"");
        }

        // A streamed map is handed over after every batch and begun afresh; with a
        // volume-photon target the powers are only known at the end, so it is
        // handed over once, whole.
        const auto openMap = [&]<class Map>(std::shared_ptr<Map>& batch, const char* slot) {
            const bool streamed = ctx.streamed(slot);
            if (streamed) batch = std::make_shared<Map>();
            Map& target = streamed ? *batch : ctx.createOutput<Map>(slot);
            target.emitted = settings.photons;
            return &target;
        };
        std::shared_ptr<PhotonMap> causticBatch, globalBatch;
        std::shared_ptr<VolumePhotonMap> volumeBatch;
        PhotonMap* causticMap = openMap(causticBatch, "caustic_photons");
        PhotonMap* globalMap = openMap(globalBatch, "global_photons");
        VolumePhotonMap* volumeMap = openMap(volumeBatch, "volume_photons");
        causticMap->hasDifferentials = settings.differentials;
        PhotonRays& photonRays = ctx.createOutput<PhotonRays>("photon_rays");
        // Demand-driven streams: once every reader of every streamed map has said
        // it needs no more, tracing stops at this batch boundary. Stored maps then
        // hold the photons of the paths traced, renormalised to that count; the
        // batches already handed over keep the planned count as their divisor
        // (emitted), which a reader that stops early rescales.
        bool anyStreamed = false, allSatisfied = true, interrupted = false;
        const auto handOverMap = [&]<class Map>(const char* slot, std::shared_ptr<Map>& batch, Map*& map) {
            if (!batch) return;
            anyStreamed = true;
            if (!batch->photons.empty() || interrupted) {
                const auto next = std::make_shared<Map>();
                next->emitted = batch->emitted;
                if constexpr (std::is_same_v<Map, PhotonMap>) next->hasDifferentials = batch->hasDifferentials;
                if (ctx.emitBatch<Map>(slot, std::exchange(batch, next))) allSatisfied = false;
            } else {
                allSatisfied = false;  // nothing was offered, so nothing was declined
            }
            map = batch.get();
        };
        const auto handOver = [&] {
            anyStreamed = false;
            allSatisfied = true;
            handOverMap("caustic_photons", causticBatch, causticMap);
            handOverMap("global_photons", globalBatch, globalMap);
            handOverMap("volume_photons", volumeBatch, volumeMap);
        };
        if (scene.lights.empty() || !(scene.lightPower.total() > 0.0f)) {
            ctx.addItems(static_cast<std::int64_t>(settings.photons));
            return;
        }

        const PhotonTracer tracer(scene, ctx.rays(), settings, seed, ctx.streamKey());
        std::int64_t storedCaustic = 0, storedGlobal = 0, storedDirect = 0, storedVolume = 0, singleScattering = 0;
        std::int64_t segments = 0, guidedEvents = 0, guidedEmissions = 0;
        std::uint64_t collapsed = 0;
        std::uint64_t emitted = 0;
        bool targetReached = false;
        // Later volume photons: what the target's batch traced beyond its last photon.
        const bool laterVolume = targetMode && settings.volumeBatch > 0 && ctx.streamed("volume_photons");
        std::vector<VolumePhotonRecord> laterRecords;
        std::uint64_t pathsTraced = 0;
        RecordRates rates;
        // The batch is traced in waves (kWaveChunks); the records of a wave's
        // chunks are copied into the maps before the next wave reuses them.
        std::vector<ChunkResult> chunks(kWaveChunks);
        struct Take {
            std::size_t caustic = 0, global = 0, volume = 0, rays = 0;
            std::size_t causticAt = 0, globalAt = 0, volumeAt = 0, raysAt = 0;
            std::int64_t direct = 0, singleScattering = 0;
        };
        std::vector<Take> takes(kWaveChunks);
        // Room in the maps for the records expected from a batch of `paths` paths,
        // made once per batch after its first wave (whose records the rate already
        // counts) rather than by growing the maps wave by wave, which would copy
        // them again at every doubling. Only capacities depend on the estimate.
        const auto sizeMaps = [&](std::size_t paths) {
            // A batch's count varies far less than a chunk's: 1/32 more than the mean.
            const RecordRates::Expected records = rates.expected(paths, 32);
            const auto makeRoom = [](auto& buffer, std::size_t more) { buffer.reserve(buffer.size() + more); };
            makeRoom(causticMap->photons, records.caustic);
            makeRoom(globalMap->photons, records.global);
            makeRoom(volumeMap->photons, records.volume);
            makeRoom(photonRays.rays, records.rays);
        };
        for (std::uint64_t batchStart = 0; batchStart < settings.photons && !targetReached;) {
            std::uint64_t wanted = settings.batchSize;
            if (targetMode) {
                // A pilot batch, then enough paths for the photons still missing at the rate
                // seen so far (plus a margin), so that paths are not traced in vain. The sizes
                // depend only on earlier results, and the photons not on the sizes.
                const std::uint64_t missing = settings.volumeTarget - static_cast<std::uint64_t>(storedVolume);
                const double rate = storedVolume == 0 ? 0.0
                                                      : static_cast<double>(storedVolume) /
                                                            static_cast<double>(batchStart);
                const double estimate = rate > 0.0 ? 1.1 * static_cast<double>(missing) / rate + 1024.0
                                                   : static_cast<double>(batchStart == 0 ? kPilotPaths
                                                                                         : 8 * batchStart);
                wanted = std::min<std::uint64_t>(settings.batchSize,
                                                 static_cast<std::uint64_t>(std::min(estimate, 1e15)));
            }
            const auto count =
                static_cast<std::size_t>(std::min<std::uint64_t>(wanted, settings.photons - batchStart));
            for (std::size_t waveStart = 0; waveStart < count && !targetReached; waveStart += kWavePaths) {
                const std::size_t waveCount = std::min(kWavePaths, count - waveStart);
                const std::size_t waveChunks = (waveCount + kGrain - 1) / kGrain;
                const std::uint64_t firstPath = batchStart + waveStart;
                jobs::parallelForChunks(waveCount, kGrain, [&](jobs::IndexRange r) {
                    ChunkResult& out = chunks[r.begin / kGrain];
                    out.clear();
                    rates.reserve(out, r.end - r.begin);
                    for (std::size_t i = r.begin; i != r.end; ++i) tracer.trace(firstPath + i, out);
                    rates.add(out, r.end - r.begin);
                });
                emitted = firstPath + waveCount;
                if (waveStart == 0) sizeMaps(count);
                // How many records each chunk hands over is decided in chunk order
                // (a volume-photon target cuts the batch at one path); the copying
                // into the maps, at offsets fixed by those counts, runs in parallel.
                std::size_t causticEnd = causticMap->photons.size(), globalEnd = globalMap->photons.size(),
                            volumeEnd = volumeMap->photons.size(), raysEnd = photonRays.rays.size();
                std::size_t usedChunks = 0;
                for (const ChunkResult& chunk : std::span(chunks).first(waveChunks)) {
                    Take& take = takes[usedChunks++];
                    take = Take{};
                    take.volume = chunk.volume.size();
                    std::uint64_t lastPath = ~std::uint64_t(0);
                    if (targetMode && static_cast<std::uint64_t>(storedVolume) + take.volume >= settings.volumeTarget) {
                        take.volume = static_cast<std::size_t>(settings.volumeTarget - static_cast<std::uint64_t>(storedVolume));
                        lastPath = chunk.volume[take.volume - 1].path;
                        emitted = lastPath + 1;
                        targetReached = true;
                    }
                    take.caustic = recordsUpTo(chunk.caustic, lastPath);
                    take.global = recordsUpTo(chunk.global, lastPath);
                    take.causticAt = causticEnd;
                    take.globalAt = globalEnd;
                    take.volumeAt = volumeEnd;
                    causticEnd += take.caustic;
                    globalEnd += take.global;
                    volumeEnd += take.volume;
                    take.rays = static_cast<std::size_t>(
                        std::partition_point(chunk.rays.begin(), chunk.rays.end(),
                                             [&](const PhotonRayBuffer::Record& r) { return r.get<RayPath>() <= lastPath; }) -
                        chunk.rays.begin());
                    take.raysAt = raysEnd;
                    raysEnd += take.rays;
                    causticMap->collapsedFootprints += static_cast<std::uint64_t>(chunk.collapsedCaustic);
                    globalMap->collapsedFootprints += static_cast<std::uint64_t>(chunk.collapsedGlobal);
                    collapsed += static_cast<std::uint64_t>(chunk.collapsedCaustic + chunk.collapsedGlobal);
                    storedCaustic += static_cast<std::int64_t>(take.caustic);
                    storedVolume += static_cast<std::int64_t>(take.volume);
                    segments += chunk.segments;
                    guidedEvents += chunk.guidedEvents;
                    guidedEmissions += chunk.guidedEmissions;
                    if (targetReached) {
                        if (laterVolume) {
                            laterRecords.assign(chunk.volume.begin() + static_cast<std::ptrdiff_t>(take.volume),
                                                chunk.volume.end());
                            for (const ChunkResult* rest = &chunk + 1; rest != chunks.data() + waveChunks; ++rest)
                                laterRecords.insert(laterRecords.end(), rest->volume.begin(), rest->volume.end());
                        }
                        break;
                    }
                }
                causticMap->photons.resize(causticEnd);
                globalMap->photons.resize(globalEnd);
                volumeMap->photons.resize(volumeEnd);
                photonRays.rays.resize(raysEnd);
                jobs::parallelFor(usedChunks, 1, [&](std::size_t c) {
                    const ChunkResult& chunk = chunks[c];
                    Take& take = takes[c];
                    for (std::size_t k = 0; k < take.caustic; ++k) causticMap->photons.set(take.causticAt + k, chunk.caustic[k]);
                    for (std::size_t k = 0; k < take.global; ++k) {
                        globalMap->photons.set(take.globalAt + k, chunk.global[k]);
                        take.direct += chunk.global[k].get<PhotonClassColumn>() == PhotonClass::Direct;
                    }
                    for (std::size_t k = 0; k < take.volume; ++k) {
                        volumeMap->photons.set(take.volumeAt + k, chunk.volume[k]);
                        take.singleScattering += (chunk.volume[k].get<PhotonClassColumn>() & PhotonClass::Direct) != 0;
                    }
                    for (std::size_t k = 0; k < take.rays; ++k) photonRays.rays.set(take.raysAt + k, chunk.rays[k]);
                });
                for (std::size_t c = 0; c < usedChunks; ++c) {
                    storedDirect += takes[c].direct;
                    storedGlobal += static_cast<std::int64_t>(takes[c].global) - takes[c].direct;
                    singleScattering += takes[c].singleScattering;
                }
                ctx.addItems(static_cast<std::int64_t>(waveCount));
                pathsTraced = firstPath + waveCount;
            }
            batchStart += count;
            if (!targetMode) handOver();
            if (!targetMode && anyStreamed && allSatisfied) {
                ctx.addCounter("stopped_by_readers", 1);
                break;
            }
            ctx.completedUnit();
            // Interrupted: stored maps are renormalised below to the paths traced;
            // streamed ones end with a batch (empty) whose `emitted` is that count,
            // from which their readers rescale what they took. A volume-photon
            // target runs to its end (the count is the point of it).
            if (!targetMode && batchStart < settings.photons && ctx.stopRequested()) {
                ctx.keptPartial(ctx.instanceName() + ": " + std::to_string(batchStart) + " of " +
                                std::to_string(settings.photons) + " photon paths");
                interrupted = true;
                break;
            }
            ctx.reportProgress(targetMode ? static_cast<double>(storedVolume) /
                                                static_cast<double>(settings.volumeTarget)
                                          : static_cast<double>(batchStart) / static_cast<double>(settings.photons));
        }
        for (PhotonMap* map : {causticMap, globalMap}) {
            renormalise(*map, settings.photons, emitted);
            map->emitted = emitted;
        }
        renormalise(*volumeMap, settings.photons, emitted);
        volumeMap->emitted = emitted;
        if (emitted > 0 && emitted != settings.photons) {
            const float powerScale = static_cast<float>(static_cast<double>(settings.photons) / static_cast<double>(emitted));
            for (Rgb& p : photonRays.rays.column<RayPower>()) p *= powerScale;
        }
        photonRays.emitted = emitted;
        photonRays.clampDistance = clampDistance;
        ctx.addCounter("photon_rays", static_cast<std::int64_t>(photonRays.rays.size()));
        handOver();
        if (laterVolume && targetReached && anyStreamed && !allSatisfied)
            traceLaterVolumePhotons(ctx, tracer, settings, storedVolume, emitted, pathsTraced, laterRecords);

        ctx.addCounter("caustic_photons", storedCaustic);
        ctx.addCounter("global_photons", storedGlobal);
        ctx.addCounter("direct_photons", storedDirect);
        ctx.addCounter("volume_photons", storedVolume);
        ctx.addCounter("single_scattering_photons", singleScattering);
        ctx.addCounter("emitted_paths", static_cast<std::int64_t>(emitted));
        ctx.addCounter("collapsed_footprints", static_cast<std::int64_t>(collapsed));
        ctx.addCounter("photon_segments", segments);
        if (guided) ctx.addCounter("guided_events", guidedEvents);
        if (guidedEnvironment) ctx.addCounter("guided_emissions", guidedEmissions);
    }
};

}  // namespace

PassRegistration photonPass() {
    PassSpec spec;
    spec.name = "photon";
    spec.doc = "Photon tracing from all lights (by power) through surfaces and homogeneous media, with Russian "
               "roulette, optional photon differentials and optional guiding by an importance cache (Vorba et al. 2014)";
    SlotSpec importanceCache{"importance_cache", "GuidingCache",
                             "importance cache trained on importons (Vorba et al. 2014): guides the directions "
                             "photons leave non-specular reflecting surfaces in (absent: BSDF sampling)"};
    importanceCache.optional = true;
    SlotSpec environment{"environment", "EnvironmentGuide",
                         "environment sampler trained on importons that left the scene (Vorba et al. 2014, §4.4): "
                         "guides emission from environment lights (absent or empty: unguided emission)"};
    environment.optional = true;
    spec.inputs = {importanceCache, environment};
    spec.outputs = {
        {"caustic_photons", "PhotonMap", "photons at smooth surfaces after only specular events (L S+ D), with footprints",
         true},
        {"global_photons", "PhotonMap",
         "photons at smooth surfaces after a non-specular event (and direct photons with store_direct)", true},
        {"volume_photons", "VolumePhotonMap",
         "photons at scattering events in media (class Volume); power includes sigma_s: Eq. 3 needs no sigma_s", true},
        {"photon_rays", "PhotonRays",
         "with photon_rays = true: every path segment between surfaces with its bounded density (Herzog et al. 2007, "
         "Eq. 7); empty otherwise"},
    };
    spec.params = {
        {"photons", ParamType::Int, std::int64_t{1000000}, 1, 1e15, {},
         "photon paths emitted from all lights; with volume_photons > 0, the most that may be emitted"},
        {"volume_photons", ParamType::Int, std::int64_t{0}, 0, 2147483647, {},
         "if > 0: emit paths until exactly this many volume photons are stored (0 = emit `photons` paths)"},
        {"max_depth", ParamType::Int, std::int64_t{16}, 1, 4096, {},
         "maximum scattering events (surface or medium) per photon path; 1 = only the first event"},
        {"rr_depth", ParamType::Int, std::int64_t{5}, 1, 4096, {},
         "scattering events before Russian roulette may end a photon path"},
        rouletteThresholdParam("photon path"),
        {"store", ParamType::String, std::string("all"), 0, 0, {"caustic", "global", "surface", "volume", "all", "none"},
         "which photons to keep: caustic (L S+ D), global (after a non-specular event), surface (both), "
         "volume (medium events), all, or none (photon rays only)"},
        {"store_direct", ParamType::Bool, false, 0, 0, {},
         "also keep direct photons (L D) in global_photons; usually next-event estimation covers them"},
        {"store_single_scattering", ParamType::Bool, true, 0, 0, {},
         "keep volume photons at a path's first event (L V, directly lit); off = multiple scattering only"},
        {"caustic_only_paths", ParamType::Bool, false, 0, 0, {},
         "end every path at its first non-specular event (enough for caustic photons)"},
        {"differentials", ParamType::Bool, true, 0, 0, {},
         "trace photon differentials and store footprints for caustic and direct photons"},
        {"smoothing", ParamType::Float, 10.0, 1e-3, 1e4, {},
         "smoothing s of the initial differentials: footprints of one source add up to s^2 times its area"},
        {"batch_size", ParamType::Int, std::int64_t{1 << 18}, 1, 1 << 26, {},
         "photon paths per batch (memory vs. parallelism; a streamed map is handed over per batch); does not "
         "change the photons"},
        {"photon_rays", ParamType::Bool, false, 0, 0, {},
         "record every path segment as a photon ray with Eq. 7's bounded density (photon ray splatting)"},
        {"clamp_distance", ParamType::Float, 0.0, 0.0, 1e30, {},
         "D~ of Eq. 7: segment lengths below it count as this long in the density (0 = 0.01 x scene diagonal)"},
        {"specular_pdf", ParamType::Float, 100.0, 1e-6, 1e30, {},
         "p_s^perp (1/sr) used at specular events in Eq. 7, which have no density: large = small caustic bandwidths"},
        {"volume_batch", ParamType::Int, std::int64_t{0}, 0, 2147483647, {},
         "with volume_photons > 0 and a streamed volume map: further maps of this many volume photons while a "
         "reader wants more (progressive EM; 0 = none)"},
        {"seed", ParamType::Int, std::int64_t{0}, 0, 1e15, {},
         "seed of the photon paths' random streams (0 = the job's seed); another seed traces an independent "
         "photon set at the same eye vertices"},
    };
    const std::vector<ParamSpec> guidedParams = guidedSamplingParams();
    spec.params.insert(spec.params.end(), guidedParams.begin(), guidedParams.end());
    spec.params.push_back({"environment_direction_probability", ParamType::Float, 0.5, 0.0, 0.999, {},
                           "beta: with an environment input, the share of environment photons whose direction is "
                           "drawn from p_L p_W (the rest from p_L alone, which keeps every direction reachable)"});
    spec.params.push_back({"environment_position_probability", ParamType::Float, 0.5, 0.0, 0.999, {},
                           "gamma: with an environment input, the share of environment photons that start at a point "
                           "drawn from the cell's disk GMM p(x|w) (the rest uniformly on the disk)"});
    const auto preflight = [](const PreflightContext& pf) {
        const std::string& store = pf.params.getString("store");
        if (pf.params.getInt("volume_photons") > 0 && store != "volume" && store != "all") {
            throw InputError(pf.source + ": pass '" + pf.instance + "': volume_photons = " +
                             std::to_string(pf.params.getInt("volume_photons")) + " needs store = \"volume\" or \"all\"");
        }
    };
    // How many photons a path stores cannot be known before tracing: a caustic
    // map holds only paths that met a specular surface first, an open scene's
    // paths escape. So the estimate counts what is certain or typical: a
    // volume map with a volume_photons target holds exactly that many; a
    // global map one photon per path (the Cornell box stores 2.3; an open
    // scene fewer); a caustic map nothing. A streamed map holds one batch,
    // and tracing holds one wave of records (below one batch's estimate).
    const auto memory = [](const PreflightContext& pf) {
        constexpr std::uint64_t kSurfacePhoton = 5 * sizeof(Vec3) + sizeof(Rgb) + sizeof(std::uint8_t);
        constexpr std::uint64_t kVolumePhoton = 2 * sizeof(Vec3) + sizeof(Rgb) + sizeof(std::uint8_t);
        const auto photons = static_cast<std::uint64_t>(pf.params.getInt("photons"));
        const auto volumeTarget = static_cast<std::uint64_t>(pf.params.getInt("volume_photons"));
        const auto batch = std::min(photons, static_cast<std::uint64_t>(pf.params.getInt("batch_size")));
        const std::string& store = pf.params.getString("store");
        const auto streamed = [&](const char* slot) { return pf.outputStreamed && pf.outputStreamed(slot); };
        MemoryEstimate estimate;
        estimate.bytes = multiplyBytes(batch, kSurfacePhoton);
        estimate.what = "one batch of " + std::to_string(batch) + " paths";
        const bool global = (store == "global" || store == "surface" || store == "all") &&
                            !pf.params.getBool("caustic_only_paths") && volumeTarget == 0;
        if (global && !streamed("global_photons")) {
            estimate.bytes = addBytes(estimate.bytes, multiplyBytes(photons, kSurfacePhoton));
            estimate.what = std::to_string(photons) + " photon paths, one " + std::to_string(kSurfacePhoton) +
                            "-byte global photon per path assumed";
            estimate.hint = "lower `photons`, or use a pipeline whose readers take batches with stream_batches = true "
                            "(pds, lt: one batch of batch_size paths is held)";
        }
        if (volumeTarget > 0 && (store == "volume" || store == "all")) {
            estimate.bytes = addBytes(estimate.bytes, multiplyBytes(volumeTarget, kVolumePhoton));
            estimate.what += ", " + std::to_string(volumeTarget) + " volume photons";
        }
        return estimate;
    };
    return {spec, [] { return std::make_unique<PhotonPass>(); }, preflight, memory};
}

}  // namespace fg
