// One path segment of the reference path tracer. Emission found by BSDF or
// phase sampling and light found by next-event estimation are combined with
// the power heuristic (Veach 1997, Eq. 9.13); delta lights and specular
// vertices take their single strategy with weight 1. Throughput in media uses
// the spectral-MIS free-flight weights of HomogeneousMedium::sampleDistance.
//
// Guided vertices (Vorba et al. 2014, §4.1 "Sampling from the distribution
// model"): with a radiance cache, a surface vertex whose BSDF has only smooth
// reflection lobes picks the BSDF with probability α and the cached GMM
// otherwise; the one-sample mixture density α p_bsdf + (1 - α) p_gmm divides
// the sample and is the strategy's pdf in the power heuristic against
// next-event estimation; a light sample's weight, which needs the GMM's
// density of the light's direction, waits until its shadow ray is found
// unblocked (DeferredGuidedWeight). The GMM's mass outside its square ends the path. Other
// vertices, and every vertex without a cache, draw exactly the numbers and
// values of the unguided tracer.
#include "passes/common/path_vertex.h"
#include "passes/common/roulette.h"

#include "engine/guiding/guided_sampling.h"
#include "engine/guiding/guiding_cache.h"

#include <algorithm>
#include <array>
#include <optional>

namespace fg {

namespace {

// Relative length by which shadow rays stop short of the point they test.
constexpr float kShadowEpsilon = 1e-3f;

float lightSelectionPmf(const Scene& scene, int light) {
    return scene.lightChoice.discretePmf(static_cast<std::size_t>(light));
}

// The GMM (and its frame) guiding directions at a surface vertex, if any.
struct VertexGuide {
    const DirectionalGmm* gmm = nullptr;
    Frame frame;
    float bsdfProbability = 1.0f;
};

// Samples one light for next-event estimation from p. `scatter(wi)` returns the
// scattering value (BSDF * |cos| or phase) and its sampling pdf for direction wi.
// At a guided vertex (`guide` with a GMM) the scatter pdf is the BSDF's alone,
// and a sample of a non-delta light leaves its MIS weight to
// shadowContribution (DeferredGuidedWeight), which needs the GMM's density too.
template <class Scatter>
void queueLightSample(const PathTracerScene& pts, const Vec3& p, const Vec3& ng, const Shape* shape, int medium,
                      const Rgb& beta, jobs::Rng& rng, Scatter&& scatter, ShadowRequest& shadow,
                      const VertexGuide* guide = nullptr) {
    const Scene& scene = pts.scene;
    if (scene.lights.empty()) return;
    const float uLight = rng.uniform();
    const Vec2 uPoint = rng.uniform2();
    float pmf = 0.0f;
    const std::size_t index = scene.lightChoice.sampleDiscrete(uLight, &pmf);
    const Light& light = *scene.lights[index];
    const std::optional<LightSample> ls = light.sampleLi(p, uPoint);
    if (!ls || ls->pdf <= 0.0f || isBlack(ls->value)) return;
    const auto [f, scatterPdf] = scatter(ls->wi);
    if (isBlack(f)) return;
    const float lightPdf = ls->pdf * pmf;
    if (guide && guide->gmm && !light.isDelta()) {
        shadow.contribution = beta * f * ls->value;
        shadow.deferred = {guide->gmm, guide->frame.toLocal(ls->wi), scatterPdf, lightPdf, guide->bsdfProbability};
    } else {
        const float weight = light.isDelta() ? 1.0f : powerHeuristic(lightPdf, scatterPdf);
        shadow.contribution = beta * f * ls->value * (weight / lightPdf);
        shadow.deferred.gmm = nullptr;
    }
    const bool onSurface = shape != nullptr;
    shadow.ray.origin = onSurface ? offsetRayOrigin(p, ng, ls->wi) : p;
    if (std::isinf(ls->distance) || ls->distance >= kInfinity) {
        shadow.ray.direction = ls->wi;
        shadow.ray.tMax = kInfinity;
    } else {
        // Aim from the offset origin at the sampled point and stop just short of
        // it: the light's own surface must not count as a blocker, even for
        // grazing directions where the normal offset changes the distance most.
        const Vec3 toLight = ls->p - shadow.ray.origin;
        const float distance = glm::length(toLight);
        shadow.ray.direction = toLight / distance;
        shadow.ray.tMax = distance * (1.0f - kShadowEpsilon);
    }
    shadow.medium = onSurface ? mediumAfterCrossing(*shape, ng, ls->wi, medium) : medium;
    shadow.pending = true;
}

// The contribution of an unblocked shadow ray with its deferred weight, if
// any: the product and the order of an immediate weight.
Rgb unblockedContribution(const ShadowRequest& shadow) {
    const DeferredGuidedWeight& d = shadow.deferred;
    if (!d.gmm) return shadow.contribution;
    const float scatterPdf = d.bsdfProbability * d.bsdfPdf + (1.0f - d.bsdfProbability) * d.gmm->pdfLocal(d.gmmLocal);
    return shadow.contribution * (powerHeuristic(d.lightPdf, scatterPdf) / d.lightPdf);
}

// Specular and transmissive lobes and null events are never guided.
bool guidableBsdf(const Bsdf& bsdf) {
    constexpr std::uint32_t kUnguided = BsdfLobe::Specular | BsdfLobe::Transmission | BsdfLobe::Null;
    return (bsdf.lobes() & kUnguided) == 0 && bsdf.hasSmoothLobe();
}

Vec3 facingNormal(const SurfacePoint& sp, const Vec3& toViewer) {
    return glm::dot(sp.ns, toViewer) >= 0.0f ? sp.ns : -sp.ns;
}

VertexGuide findGuide(const PathTracerScene& pts, const Bsdf& bsdf, const SurfacePoint& sp, const Vec3& toViewer) {
    VertexGuide guide;
    if (!pts.guiding || !guidableBsdf(bsdf)) return guide;
    const Vec3 facing = facingNormal(sp, toViewer);
    const std::optional<std::uint32_t> record = pts.guidingCovering && pts.guiding->hasCoverGrid()
                                                     ? pts.guiding->lookupGuiding(sp.p, facing)
                                                     : pts.guiding->lookup(sp.p, facing, GuidingCacheQuery{pts.guidingCandidates});
    if (!record || !pts.guiding->guides(*record)) return guide;
    const DirectionalGmm& gmm = pts.guiding->records.column<GuideMixture>()[*record];
    // The record is rarely in cache; light sampling runs before the mixture is read.
    gmm.prefetch();
    guide.gmm = &gmm;
    guide.frame = Frame(pts.guiding->records.column<GuideNormal>()[*record]);
    guide.bsdfProbability = pts.guidingBsdfProbability;
    return guide;
}

bool russianRoulette(const PathLimits& limits, PathVertexState& s) {
    if (s.history.depth < limits.rrDepth) return true;
    return rouletteSurvives(maxComponent(s.throughput * s.history.etaScale), limits.rrThreshold, s.rng, s.throughput);
}

}  // namespace

PathTracerScene::PathTracerScene(const Scene& s, const RayQuery& r) : scene(s), rays(r), infiniteLights(s.infiniteLights()) {
    shadowsNeedTransmittance = !s.media.empty();
    for (const Shape& shape : s.shapes) {
        if (shape.bsdf < 0) {
            shadowsNeedTransmittance = true;
            continue;
        }
        const Bsdf& bsdf = *s.bsdfs[static_cast<std::size_t>(shape.bsdf)];
        if (bsdf.hasNullLobe() || bsdf.hasOpacity()) shadowsNeedTransmittance = true;
    }
}

bool advancePath(const PathTracerScene& pts, const PathLimits& limits, const Hit& hit, PathVertexState& s,
                 ShadowRequest& shadow) {
    const Scene& scene = pts.scene;
    PathHistory& h = s.history;
    Rgb& beta = s.throughput;

    // Medium: a real scattering event before the surface, or transmittance up to it.
    if (h.medium >= 0) {
        const HomogeneousMedium& medium = scene.media[static_cast<std::size_t>(h.medium)];
        const float tSurface = hit.valid() ? hit.t : kInfinity;
        const float uChannel = s.rng.uniform();
        const float uDistance = s.rng.uniform();
        const DistanceSample ds = medium.sampleDistance(tSurface, uChannel, uDistance, beta);
        beta *= ds.weight;
        if (isBlack(beta)) return false;
        if (ds.scattered) {
            if (++h.depth > limits.maxDepth) return false;
            const Vec3 p = s.ray.origin + ds.t * s.ray.direction;
            const Vec3 wo = -s.ray.direction;
            const HenyeyGreenstein& phase = medium.phase();
            queueLightSample(pts, p, Vec3(0.0f), nullptr, h.medium, beta, s.rng,
                             [&](const Vec3& wi) {
                                 const float value = phase.eval(wo, wi);
                                 return std::pair<Rgb, float>(Rgb(value), value);
                             },
                             shadow);
            const PhaseSample ps = phase.sample(wo, s.rng.uniform2());
            if (ps.pdf <= 0.0f) return false;
            h.previousPosition = p;
            h.previousPdf = ps.pdf;
            h.specular = false;
            s.ray = Ray{p, ps.wi, kInfinity};
            return russianRoulette(limits, s);
        }
    }

    return advancePathAtSurface(pts, limits, hit, s, shadow);
}

bool advancePathAtSurface(const PathTracerScene& pts, const PathLimits& limits, const Hit& hit, PathVertexState& s,
                          ShadowRequest& shadow) {
    const Scene& scene = pts.scene;
    PathHistory& h = s.history;
    Rgb& beta = s.throughput;

    if (!hit.valid()) {
        for (int index : pts.infiniteLights) {
            const Light& light = *scene.lights[static_cast<std::size_t>(index)];
            const Rgb Le = light.environment(s.ray.direction);
            if (isBlack(Le)) continue;
            float weight = 1.0f;
            if (!h.specular) {
                const float lightPdf = lightSelectionPmf(scene, index) *
                                       light.pdfLi(h.previousPosition, Vec3(0.0f), Vec3(0.0f), s.ray.direction);
                weight = powerHeuristic(h.previousPdf, lightPdf);
            }
            s.radiance += beta * Le * weight;
        }
        return false;
    }

    const SurfacePoint sp = pts.rays.surface(s.ray, hit);
    const Shape& shape = scene.shapes[sp.shape];

    if (shape.areaLight >= 0) {
        const Light& light = *scene.lights[static_cast<std::size_t>(shape.areaLight)];
        const Rgb Le = light.emittedAt(sp.ng, -s.ray.direction, sp.uv);
        if (!isBlack(Le)) {
            float weight = 1.0f;
            if (!h.specular) {
                const float lightPdf = lightSelectionPmf(scene, shape.areaLight) *
                                       light.pdfLi(h.previousPosition, sp.p, sp.ng, s.ray.direction);
                weight = powerHeuristic(h.previousPdf, lightPdf);
            }
            s.radiance += beta * Le * weight;
        }
    }

    const Bsdf* bsdf = shape.bsdf >= 0 ? scene.bsdfs[static_cast<std::size_t>(shape.bsdf)].get() : nullptr;
    const bool maskDecided = h.maskResolved;
    h.maskResolved = false;
    if (!bsdf || bsdf->isNull() || (!maskDecided && passesThroughMask(bsdf, sp.texturePoint(), s.rng))) {
        // Index-matched boundary or the transparent part of a mask: the ray goes
        // straight on into the next medium; the previous vertex stays the
        // reference for MIS. Passing a mask with probability 1 - opacity and
        // weight 1 estimates the transmitted 1 - opacity without bias.
        crossSurface(shape, sp, s);
        return true;
    }

    // Built from the components, not from sp.ns itself: GCC otherwise copies
    // the normal into the frame in two stores and reloads it across both,
    // a failed store forward at every vertex.
    const Frame frame(Vec3(sp.ns.x, sp.ns.y, sp.ns.z));
    const Vec3 wo = frame.toLocal(-s.ray.direction);

    // A material that lets part of the light straight through (thindielectric)
    // chooses first: a null event is no scattering vertex (Mitsuba 3 counts
    // neither its depth nor its MIS vertex), so the path crosses it as it
    // crosses a null boundary, and only a real event counts and scatters.
    std::optional<BsdfSample> chosen;
    if (bsdf->hasNullLobe()) {
        const float uLobe = s.rng.uniform();  // drawn in a fixed order, not as call arguments
        const Vec2 uDir = s.rng.uniform2();
        chosen = bsdf->sample(wo, sp.texturePoint(), uLobe, uDir, TransportMode::Radiance);
        if (!chosen || chosen->pdf <= 0.0f || isBlack(chosen->weight)) return false;
        if (chosen->lobe & BsdfLobe::Null) {
            beta *= chosen->weight;
            h.medium = mediumAfterCrossing(shape, sp.ng, s.ray.direction, h.medium);
            s.ray = Ray{offsetRayOrigin(sp.p, sp.ng, s.ray.direction), s.ray.direction, kInfinity};
            return true;
        }
    }

    if (++h.depth > limits.maxDepth) return false;

    if (s.guidable && !chosen && guidableBsdf(*bsdf)) {
        const Rgb& b = beta;
        s.guidable->push_back({sp.p, facingNormal(sp, -s.ray.direction), -s.ray.direction, (b.x + b.y + b.z) / 3.0f,
                               h.depth - 1});
    }

    // Only a guided vertex pays for the sampler's copies of the frames and the texture point.
    const VertexGuide guide = chosen ? VertexGuide{} : findGuide(pts, *bsdf, sp, -s.ray.direction);
    std::optional<GuidedBsdfSampler> guided;
    if (guide.gmm) guided.emplace(GuidedBsdfSampler{bsdf, frame, wo, sp.texturePoint(), guide.gmm, guide.frame, guide.bsdfProbability});

    if (bsdf->hasSmoothLobe()) {
        queueLightSample(
            pts, sp.p, sp.ng, &shape, h.medium, beta, s.rng,
            [&](const Vec3& wi) {
                const Vec3 wiLocal = frame.toLocal(wi);
                // Shading normals must not let light through the geometric surface.
                if (glm::dot(wi, sp.ng) * wiLocal.z <= 0.0f) return std::pair<Rgb, float>(Rgb(0.0f), 0.0f);
                const float pdf = bsdf->pdf(wo, wiLocal, sp.texturePoint());
                return std::pair<Rgb, float>(bsdf->eval(wo, wiLocal, sp.texturePoint(), TransportMode::Radiance), pdf);
            },
            shadow, &guide);
    }

    if (guided) {
        const float uStrategy = s.rng.uniform();
        const float uLobe = s.rng.uniform();
        const Vec2 uDir = s.rng.uniform2();
        const std::optional<GuidedDraw> drawn = guided->draw(uStrategy, uLobe, uDir);
        if (!drawn) return false;
        const Vec3 wiLocal = drawn->wi;
        const Vec3& wi = drawn->wiWorld;
        // Directions that end the path whatever their density are turned away
        // before the mixture's density is evaluated (GMM directions below the
        // surface of a BSDF that only reflects, mostly).
        if (glm::dot(wi, sp.ng) * wiLocal.z <= 0.0f) return false;
        const Rgb f = bsdf->eval(wo, wiLocal, sp.texturePoint(), TransportMode::Radiance);
        if (isBlack(f)) return false;
        const float pdf = guided->drawnPdf(*drawn);
        if (!(pdf > 0.0f)) return false;
        beta *= f / pdf;
        h.specular = false;
        h.previousPdf = pdf;
        h.previousPosition = sp.p;
        s.ray = Ray{offsetRayOrigin(sp.p, sp.ng, wi), wi, kInfinity};
        return russianRoulette(limits, s);
    }

    // Initialised by the call, not assigned from it: copying the fresh result
    // into `chosen` reloads it in wider pieces than the BSDF stored it, which
    // stalls store forwarding at every vertex.
    const std::optional<BsdfSample> drawn = chosen ? std::optional<BsdfSample>() : [&] {
        const float uLobe = s.rng.uniform();
        const Vec2 uDir = s.rng.uniform2();
        return bsdf->sample(wo, sp.texturePoint(), uLobe, uDir, TransportMode::Radiance);
    }();
    const std::optional<BsdfSample>& bs = chosen ? chosen : drawn;
    if (!bs || bs->pdf <= 0.0f || isBlack(bs->weight)) return false;
    const Vec3 wi = frame.toWorld(bs->wi);
    if (glm::dot(wi, sp.ng) * bs->wi.z <= 0.0f) return false;
    beta *= bs->weight;
    h.specular = bs->isSpecular();
    h.previousPdf = bs->pdf;
    h.previousPosition = sp.p;
    if (bs->lobe & BsdfLobe::Transmission) {
        h.etaScale *= sqr(bs->eta);
        h.medium = mediumAfterCrossing(shape, sp.ng, wi, h.medium);
    }
    s.ray = Ray{offsetRayOrigin(sp.p, sp.ng, wi), wi, kInfinity};
    return russianRoulette(limits, s);
}

void endPathAtEyeVertex(const PathTracerScene& pts, const Hit& hit, PathVertexState& state, bool segmentDone) {
    PathLimits last;
    last.maxDepth = state.history.depth + 1;
    last.rrDepth = kNoRoulette;
    ShadowRequest shadow;
    bool alive = segmentDone ? advancePathAtSurface(pts, last, hit, state, shadow)
                             : advancePath(pts, last, hit, state, shadow);
    if (shadow.pending) state.radiance += shadowContribution(pts, shadow);
    while (alive) {
        ShadowRequest unused;  // no light is sampled past the depth limit
        alive = advancePath(pts, last, pts.rays.intersect(state.ray), state, unused);
    }
}

Rgb shadowTransmittance(const PathTracerScene& pts, const ShadowRequest& shadow, FreeFlightSegment* freeFlight) {
    if (!pts.shadowsNeedTransmittance) return pts.rays.occluded(shadow.ray) ? Rgb(0.0f) : Rgb(1.0f);
    const Scene& scene = pts.scene;
    Rgb transmittance(1.0f);
    Ray ray = shadow.ray;
    int medium = shadow.medium;
    // Null boundaries are crossed one at a time; the bound only guards against degenerate geometry.
    for (int crossing = 0; crossing < 1024; ++crossing) {
        const Hit hit = pts.rays.intersect(ray);
        const float segment = hit.valid() ? hit.t : ray.tMax;
        if (medium >= 0) {
            const HomogeneousMedium& m = scene.media[static_cast<std::size_t>(medium)];
            transmittance *= segmentTransmittance(m, segment);
            if (freeFlight && segment < kInfinity) freeFlight->add(m, segment);
        }
        if (!hit.valid() || isBlack(transmittance)) return transmittance;
        const Shape& shape = scene.shapes[hit.shape];
        const Bsdf* bsdf = shape.bsdf >= 0 ? scene.bsdfs[static_cast<std::size_t>(shape.bsdf)].get() : nullptr;
        if (bsdf && !bsdf->hasNullLobe() && !bsdf->hasOpacity()) return Rgb(0.0f);
        const SurfacePoint sp = pts.rays.surface(ray, hit);
        // A mask lets 1 - opacity through; a surface with null events (null,
        // thindielectric) the light its null event lets through.
        if (bsdf) {
            transmittance *= bsdf->hasOpacity() ? Rgb(1.0f - bsdf->opacity(sp.texturePoint()))
                                                : bsdf->nullTransmission(Frame(sp.ns).toLocal(ray.direction), sp.texturePoint());
            if (isBlack(transmittance)) return transmittance;
        }
        medium = mediumAfterCrossing(shape, sp.ng, ray.direction, medium);
        const Vec3 origin = offsetRayOrigin(sp.p, sp.ng, ray.direction);
        ray.tMax -= glm::length(origin - ray.origin);
        ray.origin = origin;
        if (ray.tMax <= 0.0f) return transmittance;
    }
    return Rgb(0.0f);
}

Rgb shadowContribution(const PathTracerScene& pts, const ShadowRequest& shadow) {
    const Rgb transmittance = shadowTransmittance(pts, shadow);
    if (isBlack(transmittance)) return Rgb(0.0f);
    return unblockedContribution(shadow) * transmittance;
}

void resolveShadowRays(const PathTracerScene& pts, std::span<const std::uint32_t> paths,
                       std::span<const ShadowRequest> shadows, std::span<Rgb> radiance) {
    if (pts.shadowsNeedTransmittance) {
        for (std::uint32_t p : paths)
            if (shadows[p].pending) radiance[p] += shadowContribution(pts, shadows[p]);
        return;
    }
    // Plain visibility: one occlusion stream for the whole chunk.
    constexpr std::size_t kBatch = 256;
    std::array<Ray, kBatch> rays;
    std::array<std::uint32_t, kBatch> owner;
    std::array<std::uint8_t, kBatch> blocked;
    std::size_t n = 0;
    const auto flush = [&] {
        pts.rays.occluded(std::span<const Ray>(rays.data(), n), std::span<std::uint8_t>(blocked.data(), n));
        for (std::size_t k = 0; k < n; ++k)
            if (!blocked[k]) radiance[owner[k]] += unblockedContribution(shadows[owner[k]]);
        n = 0;
    };
    for (std::uint32_t p : paths) {
        if (!shadows[p].pending) continue;
        rays[n] = shadows[p].ray;
        owner[n++] = p;
        if (n == kBatch) flush();
    }
    if (n > 0) flush();
}

ParamSpec rouletteThresholdParam(const std::string& pathName) {
    return {"rr_threshold", ParamType::Float, 1.0, 1e-30, 1.0, {},
            "throughput, relative to the " + pathName + "'s start, below which Russian roulette may end it: it "
            "survives with probability min(throughput / rr_threshold, 0.95); 1 = classic roulette, 1e-5 = Vorba "
            "et al. 2014 §4.5 (for guided paths)"};
}

std::vector<ParamSpec> guidedSamplingParams() {
    return {
        {"guiding_bsdf_probability", ParamType::Float, 0.5, 0.01, 1.0, {},
         "alpha: probability of BSDF sampling at a guided vertex (the GMM otherwise)"},
        {"guiding_candidates", ParamType::Int, std::int64_t{2}, 1, 64, {},
         "M of Eq. 11 for guiding_query = nearest (and for a cache whose cover grid would be too large): "
         "nearest records compared per guided vertex"},
        {"guiding_query", ParamType::String, std::string("covering"), 0, 0, {"covering", "nearest"},
         "covering: the best by Eq. 11 of the records whose validity radius holds the vertex (a grid lookup); "
         "nearest: the best of the guiding_candidates nearest records, if its radius holds the vertex (a kd-tree search)"},
    };
}

void guideByRadianceCache(PathTracerScene& pts, const GuidingCache& cache, const PassParams& params) {
    // A cache whose records all leave their points to BSDF sampling guides
    // nothing: the paths need not look it up.
    pts.guiding = cache.anyGuides() ? &cache : nullptr;
    pts.guidingBsdfProbability = static_cast<float>(params.getFloat("guiding_bsdf_probability"));
    pts.guidingCandidates = static_cast<std::uint32_t>(params.getInt("guiding_candidates"));
    pts.guidingCovering = params.getString("guiding_query") == "covering";
}

}  // namespace fg
