// Per-vertex path tracing logic shared by the path tracer's schedules (and by
// later passes that need path-traced remainders): one call advances a path by
// one segment — medium event or surface event — adding emission with MIS,
// queueing a next-event shadow ray, and choosing the next direction.
#pragma once

#include "engine/core/math.h"
#include "engine/accel/ray_query.h"
#include "engine/core/pass.h"
#include "engine/scene/scene.h"
#include "jobs/random.h"

#include <cmath>
#include <cstdint>
#include <limits>
#include <span>
#include <vector>

namespace fg {

class GuidingCache;
struct DirectionalGmm;

struct PathTracerScene {
    PathTracerScene(const Scene& scene, const RayQuery& rays);
    const Scene& scene;
    const RayQuery& rays;
    std::vector<int> infiniteLights;
    // Shadow rays must walk through null boundaries and media instead of a plain occlusion test.
    bool shadowsNeedTransmittance = false;
    // Path guiding (Vorba et al. 2014): a radiance cache of directional GMMs;
    // null = BSDF sampling only. At a guided vertex the BSDF is sampled with
    // probability guidingBsdfProbability (α), the cache's GMM otherwise.
    const GuidingCache* guiding = nullptr;
    float guidingBsdfProbability = 0.5f;
    // M of Eq. 11 for the nearest query (guidingCovering false, or a cache
    // without a cover grid); the paper does not give M. pt's parameter
    // guiding_candidates sets it.
    std::uint32_t guidingCandidates = 2;
    // Query of the radiance cache: true = the records covering the vertex
    // (GuidingCache::lookupCovering), false = the M nearest (Eq. 11 with
    // GuidingCache::lookup). pt's parameter guiding_query sets it.
    bool guidingCovering = true;
};

// The guided-sampling parameters of the passes whose camera paths may read a
// radiance cache (pt, importon), declared once so that their defaults and
// documentation agree.
std::vector<ParamSpec> guidedSamplingParams();
// `rr_threshold` of every pass whose paths end by roulette.h's rule (pt,
// importon, photon, bdpt), declared once; `pathName` names what the
// throughput is relative to the start of ("path", "subpath", ...).
ParamSpec rouletteThresholdParam(const std::string& pathName);
// Guides pts's paths by `cache` with the parameters above.
void guideByRadianceCache(PathTracerScene& pts, const GuidingCache& cache, const PassParams& params);

struct PathLimits {
    int maxDepth = 16;
    int rrDepth = 5;
    float rrThreshold = 1.0f;  // roulette.h
};

// What MIS and medium tracking need to remember about the previous vertex.
struct PathHistory {
    Vec3 previousPosition{0.0f};
    float previousPdf = 0.0f;  // solid-angle pdf of the direction sampled there
    float etaScale = 1.0f;     // product of eta^2 over refractions, undone for Russian roulette
    int medium = -1;
    int depth = 0;             // scattering events so far
    bool specular = true;      // previous vertex was the camera or a specular event: no MIS for emission
    // The caller has already drawn the mask decision (Bsdf::opacity) for the
    // surface this path reaches next and found it opaque; cleared when used.
    bool maskResolved = false;

    static PathHistory atCamera(int cameraMedium) {
        PathHistory h;
        h.medium = cameraMedium;
        return h;
    }
};

// The power-heuristic weight of a light sample taken at a guided vertex,
// left for after the shadow ray: its scattering pdf is the mixture density
// α p_bsdf + (1 - α) p_gmm (Vorba et al. 2014 §4.1), and the GMM's density is
// most of a guided vertex's next-event cost, while most shadow rays are
// blocked (81 % of the pt pass's on veach-ajar). Only an unblocked ray's
// weight is evaluated, with the same arithmetic as an immediate one.
struct DeferredGuidedWeight {
    const DirectionalGmm* gmm = nullptr;  // null: the contribution is already weighted
    Vec3 gmmLocal{0.0f};                  // the light's direction in the record's frame
    float bsdfPdf = 0.0f;                 // p_bsdf of that direction
    float lightPdf = 0.0f;                // light pdf times the light's selection pmf
    float bsdfProbability = 0.0f;         // α
};

struct ShadowRequest {
    Ray ray;
    Rgb contribution{0.0f};  // added to the path's radiance times the transmittance found (and the deferred weight)
    int medium = -1;
    bool pending = false;
    DeferredGuidedWeight deferred;
};

// A vertex at which a camera path could be guided (a surface event of a BSDF
// with smooth, non-transmissive lobes only): where the radiance cache is
// looked up when there is one. The importon pass stores these (Vorba et al.
// 2014 §4.1: records are created where guided paths query the cache).
struct GuidableVertex {
    Vec3 position;
    Vec3 normal;    // shading normal on the side the path arrived from
    Vec3 incident;  // unit direction back along the arriving ray
    float weight;   // mean of the path throughput on arrival
    int bounces;    // scattering events before this one
};

struct PathVertexState {
    Ray& ray;
    Rgb& throughput;
    Rgb& radiance;
    PathHistory& history;
    jobs::Rng& rng;
    // Receives the guidable vertices the path passes, if set. Recording them
    // draws no random number, so the path is the same with or without it.
    std::vector<GuidableVertex>* guidable = nullptr;
};

// Consumes the hit of state.ray; returns false when the path ends. May fill `shadow`.
bool advancePath(const PathTracerScene& pts, const PathLimits& limits, const Hit& hit, PathVertexState& state,
                 ShadowRequest& shadow);
// advancePath without its first step, the free-flight sampling in the current
// medium: the path reaches the hit (or escapes) with no medium event. For
// callers that account for the medium along the segment themselves, e.g. by
// its transmittance.
bool advancePathAtSurface(const PathTracerScene& pts, const PathLimits& limits, const Hit& hit,
                          PathVertexState& state, ShadowRequest& shadow);

// Masked materials (Bsdf::hasOpacity): whether a ray passes through the surface
// at `at`, with probability 1 - opacity. Draws a random number only for masked materials.
inline bool passesThroughMask(const Bsdf* bsdf, const TexturePoint& at, jobs::Rng& rng) {
    return bsdf && bsdf->hasOpacity() && rng.uniform() >= bsdf->opacity(at);
}

// Transmittance along a shadow ray: 0 if blocked by a non-null surface, 1 - opacity through a masked one.
// `freeFlight`, if given, receives the media the ray crosses (up to where it stops; a piece of infinite length is left out).
Rgb shadowTransmittance(const PathTracerScene& pts, const ShadowRequest& shadow, FreeFlightSegment* freeFlight = nullptr);

// Camera paths of the eye passes: their specular chains end by the depth limit,
// never by Russian roulette, which would only add noise to the vertex weights.
constexpr int kNoRoulette = std::numeric_limits<int>::max();

// Ends a camera path at its eye vertex, the surface hit `hit`: adds to
// state.radiance the vertex's emission, its next-event estimate and the
// emission the BSDF-sampled ray reaches, and follows the path no further.
// `segmentDone`: the medium along the segment to `hit` is already accounted
// for (advancePathAtSurface); otherwise advancePath samples it first.
void endPathAtEyeVertex(const PathTracerScene& pts, const Hit& hit, PathVertexState& state, bool segmentDone);

// What a pending shadow request adds to its path's radiance: its contribution
// times the transmittance along its ray, times the deferred MIS weight if any,
// which is evaluated only when the transmittance is not zero.
Rgb shadowContribution(const PathTracerScene& pts, const ShadowRequest& shadow);

// Resolves the pending shadow rays of `paths` and adds their contributions to radiance[path].
void resolveShadowRays(const PathTracerScene& pts, std::span<const std::uint32_t> paths,
                       std::span<const ShadowRequest> shadows, std::span<Rgb> radiance);

// Transmittance over a segment that may be infinitely long (kInfinity or inf):
// zero in channels that attenuate, one in the others.
inline Rgb segmentTransmittance(const HomogeneousMedium& medium, float distance) {
    if (std::isinf(distance) || distance >= kInfinity) {
        const Rgb st = medium.sigmaT();
        return {st.x > 0 ? 0.0f : 1.0f, st.y > 0 ? 0.0f : 1.0f, st.z > 0 ? 0.0f : 1.0f};
    }
    return medium.transmittance(distance);
}

// Medium on the side of a shape's surface that direction `dir` enters; shapes
// that declare no media keep the current one.
inline int mediumAfterCrossing(const Shape& shape, const Vec3& ng, const Vec3& dir, int current) {
    if (shape.interiorMedium < 0 && shape.exteriorMedium < 0) return current;
    return glm::dot(dir, ng) < 0.0f ? shape.interiorMedium : shape.exteriorMedium;
}

// Continues the path straight through the surface at sp (a null boundary or
// the transparent part of a mask) into the medium on the other side.
inline void crossSurface(const Shape& shape, const SurfacePoint& sp, PathVertexState& s) {
    s.history.medium = mediumAfterCrossing(shape, sp.ng, s.ray.direction, s.history.medium);
    s.ray = Ray{offsetRayOrigin(sp.p, sp.ng, s.ray.direction), s.ray.direction, kInfinity};
}

}  // namespace fg
