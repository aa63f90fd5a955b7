// Densities and MIS weights of bidirectional path tracing (Veach 1997 §10.2-10.3).
// See bdpt_path.h for the conventions.
#include "passes/bdpt/bdpt_path.h"

#include "passes/common/light_media.h"
#include "passes/common/path_vertex.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <optional>

namespace fg {

namespace {

float remapZero(float pdf) { return pdf != 0.0f ? pdf : 1.0f; }

// Largest subpath the weights handle; the pass bounds max_depth below it.
constexpr std::size_t kMaxSubpath = 80;

}  // namespace

BdptScene::BdptScene(const Scene& s, const RayQuery& r, const Camera& c)
    : scene(s), rays(r), camera(c), infiniteLights(s.infiniteLights()), tracer(s, r) {
    const float tanHalfFovY = std::tan(0.5f * camera.fovYDegrees * kPi / 180.0f);
    const float aspect = static_cast<float>(camera.width) / static_cast<float>(camera.height);
    view.eye = camera.eye;
    view.forward = glm::normalize(camera.target - camera.eye);
    view.imagePlaneArea = 4.0f * tanHalfFovY * tanHalfFovY * aspect;
    view.rasterPerImagePlane = sqr(static_cast<float>(camera.height) / (2.0f * tanHalfFovY));
    view.nearClip = camera.nearClip;
    view.farClip = camera.farClip;
    view.width = camera.width;
    view.height = camera.height;
    view.medium = camera.medium;

    connectionsNeedTransmittance = tracer.shadowsNeedTransmittance;

    // Light subpaths start in the medium around their light, as photons do.
    const std::vector<int> startMedia = lightStartMedia(s, r);
    lights.resize(s.lights.size());
    for (std::size_t l = 0; l < s.lights.size(); ++l) {
        const Light& light = *s.lights[l];
        BdptLightInfo& info = lights[l];
        info.medium = startMedia[l];
        const int shapeIndex = l < s.lightShape.size() ? s.lightShape[l] : -1;
        const std::optional<EmissionSample> sample = light.sampleEmission(Vec2(0.5f), Vec2(0.5f));
        if (shapeIndex >= 0) {
            info.kind = BdptLightInfo::Kind::Area;
            if (sample) {
                info.positionPdf = sample->pdfPosition;
                // Directions are cosine-weighted over one hemisphere or, halved, over both.
                const float cosine = std::abs(glm::dot(sample->direction, sample->normal));
                info.directionScale = sample->pdfDirection < 0.75f * cosineHemispherePdf(cosine) ? 0.5f : 1.0f;
            }
        } else if (light.isInfinite()) {
            info.kind = light.isDelta() ? BdptLightInfo::Kind::Directional : BdptLightInfo::Kind::Environment;
            if (sample) info.positionPdf = sample->pdfPosition;
        } else {
            info.kind = BdptLightInfo::Kind::Point;
        }
    }
}

float BdptScene::lightPmf(int light) const { return scene.lightPower.discretePmf(static_cast<std::size_t>(light)); }

const Bsdf* BdptScene::bsdf(const BdptVertex& v) const {
    if (v.shape == Hit::kNoShape) return nullptr;
    const int index = scene.shapes[v.shape].bsdf;
    return index >= 0 ? scene.bsdfs[static_cast<std::size_t>(index)].get() : nullptr;
}

float BdptScene::cameraDirectionPdf(const Vec3& direction, Vec2* raster) const {
    const float cosTheta = glm::dot(direction, view.forward);
    if (!(cosTheta > 0.0f)) return 0.0f;
    Vec2 r;
    if (!camera.project(view.eye + direction, &r)) return 0.0f;
    if (!(r.x >= 0.0f && r.x < static_cast<float>(view.width) && r.y >= 0.0f && r.y < static_cast<float>(view.height)))
        return 0.0f;
    if (raster) *raster = r;
    return 1.0f / (view.imagePlaneArea * cosTheta * cosTheta * cosTheta);
}

Vec3 bdptDirection(const BdptVertex& from, const BdptVertex& to) {
    if (to.infinite) return to.p;
    if (from.infinite) return -from.p;
    const Vec3 d = to.p - from.p;
    const float length = glm::length(d);
    return length > 0.0f ? d / length : Vec3(0.0f);
}

float bdptConvertDensity(float pdfSolidAngle, const BdptVertex& from, const BdptVertex& to) {
    if (to.infinite) return pdfSolidAngle;
    const Vec3 d = to.p - from.p;
    const float distance2 = glm::dot(d, d);
    if (!(distance2 > 0.0f)) return 0.0f;
    float pdf = pdfSolidAngle / distance2;
    if (to.onSurface()) pdf *= std::abs(glm::dot(to.ng, d)) / std::sqrt(distance2);
    return pdf;
}

float bdptPdfLight(const BdptScene& bs, const BdptVertex& v, const BdptVertex& next) {
    if (v.light < 0) return 0.0f;
    const BdptLightInfo& info = bs.lights[static_cast<std::size_t>(v.light)];
    switch (info.kind) {
    case BdptLightInfo::Kind::Directional:
    case BdptLightInfo::Kind::Environment: {
        // Origins are uniform on the scene's bounding disk facing the light: a
        // planar density, projected onto the receiving surface.
        float pdf = info.positionPdf;
        if (next.onSurface()) pdf *= std::abs(glm::dot(next.ng, v.p));
        return pdf;
    }
    case BdptLightInfo::Kind::Point: {
        const Vec3 w = bdptDirection(v, next);
        return bdptConvertDensity(bs.scene.lights[static_cast<std::size_t>(v.light)]->emissionDirectionPdf(w), v, next);
    }
    case BdptLightInfo::Kind::Area: {
        const Vec3 w = bdptDirection(v, next);
        const float pdfDirection = std::abs(glm::dot(v.ng, w)) * kInvPi * info.directionScale;
        return bdptConvertDensity(pdfDirection, v, next);
    }
    }
    return 0.0f;
}

float bdptPdfLightOrigin(const BdptScene& bs, const BdptVertex& v) {
    if (v.light < 0) return 0.0f;
    const BdptLightInfo& info = bs.lights[static_cast<std::size_t>(v.light)];
    const float pmf = bs.lightPmf(v.light);
    switch (info.kind) {
    case BdptLightInfo::Kind::Environment:
        return pmf * bs.scene.lights[static_cast<std::size_t>(v.light)]->pdfLi(Vec3(0.0f), Vec3(0.0f), Vec3(0.0f), v.p);
    case BdptLightInfo::Kind::Area:
        return pmf * info.positionPdf;
    case BdptLightInfo::Kind::Point:
    case BdptLightInfo::Kind::Directional:
        return pmf;
    }
    return 0.0f;
}

std::optional<GuidedBsdfSampler> BdptScene::guide(const BdptVertex& v, const Bsdf& bsdf, const Vec3& toPrevious,
                                                  TransportMode walk) const {
    const GuidingCache* cache = walk == TransportMode::Radiance ? radianceCache : importanceCache;
    constexpr std::uint32_t kUnguided = BsdfLobe::Specular | BsdfLobe::Transmission | BsdfLobe::Null;
    if (!cache || v.kind != BdptVertexKind::Surface || (bsdf.lobes() & kUnguided) != 0 || !bsdf.hasSmoothLobe())
        return std::nullopt;
    const Vec3 facing = glm::dot(v.ns, toPrevious) >= 0.0f ? v.ns : -v.ns;
    const std::optional<std::uint32_t> record =
        guidingCovering && cache->hasCoverGrid() ? cache->lookupCovering(v.p, facing)
                                                 : cache->lookup(v.p, facing, GuidingCacheQuery{guidingCandidates});
    if (!record) return std::nullopt;
    const DirectionalGmm& gmm = cache->records.column<GuideMixture>()[*record];
    if (!(cache->hasCoverGrid() ? cache->usable(*record) : gmm.usable())) return std::nullopt;
    const Frame shading(v.ns);
    return GuidedBsdfSampler{&bsdf, shading, shading.toLocal(toPrevious), v.at, &gmm,
                             Frame(cache->records.column<GuideNormal>()[*record]), guidingBsdfProbability};
}

float bdptPdf(const BdptScene& bs, const BdptVertex* prev, const BdptVertex& cur, const BdptVertex& next,
              TransportMode walk) {
    switch (cur.kind) {
    case BdptVertexKind::Camera:
        return bdptConvertDensity(bs.cameraDirectionPdf(bdptDirection(cur, next)), cur, next);
    case BdptVertexKind::Light:
        return bdptPdfLight(bs, cur, next);
    case BdptVertexKind::Medium: {
        if (!prev || cur.medium < 0) return 0.0f;
        const HenyeyGreenstein& phase = bs.scene.media[static_cast<std::size_t>(cur.medium)].phase();
        return bdptConvertDensity(phase.eval(bdptDirection(cur, *prev), bdptDirection(cur, next)), cur, next);
    }
    case BdptVertexKind::Surface: {
        if (!prev) return bdptPdfLight(bs, cur, next);  // an emitter seen by the camera, leaving towards next
        const Bsdf* bsdf = bs.bsdf(cur);
        if (!bsdf) return 0.0f;
        const Vec3 toPrevious = bdptDirection(cur, *prev);
        const Vec3 toNext = bdptDirection(cur, next);
        if (const std::optional<GuidedBsdfSampler> guided = bs.guide(cur, *bsdf, toPrevious, walk))
            return bdptConvertDensity(guided->pdf(guided->shading.toLocal(toNext), toNext), cur, next);
        const Frame frame(cur.ns);
        return bdptConvertDensity(bsdf->pdf(frame.toLocal(toPrevious), frame.toLocal(toNext), cur.at), cur, next);
    }
    }
    return 0.0f;
}

BdptSpecularPdfs bdptSpecularPdfs(const Vec3& woLocal, const Vec3& wiLocal, float eta) {
    // A specular lobe maps wo to wi one to one and keeps eta^2 |cos theta| dw
    // (the invariant behind the eta^2 scaling of radiance, Veach 1997 §5.2),
    // so its Dirac density is one delta in that measure whichever direction is
    // sampled. In solid angle it is eta_side^2 |cos theta| times that delta on
    // the side of the direction; divided by eta_wi eta_wo, symmetric in the
    // two sides, it needs only the relative IOR. Setting both to 1 (pbrt-v3 §16.3's
    // convention) drops this Jacobian and, with the conversions to area, the
    // distances and cosines on either side of the vertex: through a refraction
    // between a floor at distance 1 and a lamp at distance 3 the light strategy
    // was undervalued about 16 times. The delta itself cancels: a ratio term of
    // the weights holds both or neither density of a specular vertex
    // (bdptMisTerms skips the terms between them).
    return {eta * std::abs(wiLocal.z), std::abs(woLocal.z) / eta};
}

float bdptDistancePdf(const FreeFlightSegment& segment, const BdptVertex& start, const BdptVertex& end, bool towardsEnd) {
    if (start.infinite || end.infinite) return 1.0f;
    return towardsEnd ? segment.towardEnd(end.kind == BdptVertexKind::Medium)
                      : segment.towardStart(start.kind == BdptVertexKind::Medium);
}

BdptWeightTerms bdptMisTerms(const BdptScene& bs, std::span<const BdptVertex> light, std::span<const BdptVertex> camera,
                             const BdptVertex* sampledLight, int s, int t, MisHeuristic heuristic) {
    BdptWeightTerms terms;
    terms.heuristic = heuristic;
    const auto S = static_cast<std::size_t>(s), T = static_cast<std::size_t>(t);
    if (S > kMaxSubpath || T > kMaxSubpath) {
        terms.cameraSum = kInfinity;  // weight 0
        return terms;
    }
    // Copies of the densities the connection changes: the ratios need the reverse
    // densities at the four vertices beside it as this strategy sees them.
    std::array<float, kMaxSubpath> camFwd, camRev, lightFwd, lightRev;
    std::array<bool, kMaxSubpath> camDelta, lightDelta;
    for (std::size_t i = 0; i < T; ++i) {
        camFwd[i] = camera[i].pdfFwd;
        camRev[i] = camera[i].pdfRev;
        camDelta[i] = camera[i].delta;
    }
    const auto lightVertex = [&](std::size_t i) -> const BdptVertex& {
        return (i == 0 && s == 1 && sampledLight) ? *sampledLight : light[i];
    };
    for (std::size_t i = 0; i < S; ++i) {
        lightFwd[i] = lightVertex(i).pdfFwd;
        lightRev[i] = lightVertex(i).pdfRev;
        lightDelta[i] = lightVertex(i).delta;
    }
    const BdptVertex& pt = (s == 0 && sampledLight) ? *sampledLight : camera[T - 1];
    const BdptVertex* ptMinus = t > 1 ? &camera[T - 2] : nullptr;
    const BdptVertex* qs = s > 0 ? &lightVertex(S - 1) : nullptr;
    const BdptVertex* qsMinus = s > 1 ? &lightVertex(S - 2) : nullptr;

    // The segments beside the connection were sampled towards pt and qs; the
    // reverse densities along them take the distance densities stored there.
    if (s > 0) {
        // Densities towards the camera side are those of a light subpath, towards the light side a camera subpath's.
        camRev[T - 1] = bdptPdf(bs, qsMinus, *qs, pt, TransportMode::Importance);
        if (ptMinus) camRev[T - 2] = bdptPdf(bs, qs, pt, *ptMinus, TransportMode::Importance) * pt.distancePdfRev;
        lightRev[S - 1] = bdptPdf(bs, ptMinus, pt, *qs, TransportMode::Radiance);
        if (qsMinus) lightRev[S - 2] = bdptPdf(bs, &pt, *qs, *qsMinus, TransportMode::Radiance) * qs->distancePdfRev;
        lightDelta[S - 1] = false;
        terms.connected = true;
        terms.cameraConnectionPdf = camRev[T - 1];
        terms.lightConnectionPdf = lightRev[S - 1];
        terms.cameraEndInMedium = pt.kind == BdptVertexKind::Medium;
        terms.lightEndInMedium = qs->kind == BdptVertexKind::Medium;
        terms.atInfinity = pt.infinite || qs->infinite;
    } else {
        camRev[T - 1] = bdptPdfLightOrigin(bs, pt);
        if (ptMinus) camRev[T - 2] = bdptPdfLight(bs, pt, *ptMinus) * pt.distancePdfRev;
    }
    camDelta[T - 1] = false;

    const auto term = [heuristic](float ratio) { return heuristic == MisHeuristic::Power ? ratio * ratio : ratio; };
    float ratio = 1.0f;
    for (std::size_t i = T - 1; i > 0; --i) {
        ratio *= remapZero(camRev[i]) / remapZero(camFwd[i]);
        if (!camDelta[i] && !camDelta[i - 1]) terms.cameraSum += term(ratio);
    }
    ratio = 1.0f;
    for (std::size_t k = S; k > 0; --k) {
        const std::size_t i = k - 1;
        ratio *= remapZero(lightRev[i]) / remapZero(lightFwd[i]);
        const BdptVertex& origin = lightVertex(0);
        const bool deltaBefore =
            i > 0 ? lightDelta[i - 1] : (origin.light >= 0 && bs.scene.lights[static_cast<std::size_t>(origin.light)]->isDelta());
        if (!lightDelta[i] && !deltaBefore) terms.lightSum += term(ratio);
    }
    return terms;
}

float bdptFinishWeight(const BdptWeightTerms& terms, const FreeFlightSegment& connection) {
    float cameraSum = terms.cameraSum, lightSum = terms.lightSum;
    if (terms.connected && !terms.atInfinity && !connection.empty()) {
        // Every camera-side term holds the connection's camera-end density once,
        // every light-side term its light-end density: scale them by what the
        // distance densities change there (as remapZero would have seen the products).
        const float cameraDistance = connection.towardStart(terms.cameraEndInMedium);
        const float lightDistance = connection.towardEnd(terms.lightEndInMedium);
        const float cameraScale = remapZero(terms.cameraConnectionPdf * cameraDistance) / remapZero(terms.cameraConnectionPdf);
        const float lightScale = remapZero(terms.lightConnectionPdf * lightDistance) / remapZero(terms.lightConnectionPdf);
        const bool power = terms.heuristic == MisHeuristic::Power;
        cameraSum *= power ? cameraScale * cameraScale : cameraScale;
        lightSum *= power ? lightScale * lightScale : lightScale;
    }
    const float weight = 1.0f / (1.0f + cameraSum + lightSum);
    return std::isfinite(weight) ? weight : 0.0f;
}

float bdptMisWeight(const BdptScene& bs, std::span<const BdptVertex> light, std::span<const BdptVertex> camera,
                    const BdptVertex* sampledLight, int s, int t, MisHeuristic heuristic,
                    const FreeFlightSegment& connection) {
    return bdptFinishWeight(bdptMisTerms(bs, light, camera, sampledLight, s, t, heuristic), connection);
}

bool bdptConnectible(const BdptScene& bs, const BdptVertex& v) {
    switch (v.kind) {
    case BdptVertexKind::Camera:
    case BdptVertexKind::Light:
    case BdptVertexKind::Medium:
        return true;
    case BdptVertexKind::Surface: {
        const Bsdf* bsdf = bs.bsdf(v);
        return bsdf && bsdf->hasSmoothLobe();
    }
    }
    return false;
}

Rgb bdptScatter(const BdptScene& bs, const BdptVertex& v, const Vec3& to, bool lightSubpath) {
    if (v.kind == BdptVertexKind::Medium) {
        if (v.medium < 0) return Rgb(0.0f);
        return Rgb(bs.scene.media[static_cast<std::size_t>(v.medium)].phase().eval(v.wo, to));
    }
    if (v.kind != BdptVertexKind::Surface) return Rgb(0.0f);
    const Bsdf* bsdf = bs.bsdf(v);
    if (!bsdf) return Rgb(0.0f);
    const Frame frame(v.ns);
    const Vec3 wo = frame.toLocal(v.wo), wi = frame.toLocal(to);
    // Shading normals must not let light through the geometric surface, on either side.
    if (glm::dot(to, v.ng) * wi.z <= 0.0f || glm::dot(v.wo, v.ng) * wo.z <= 0.0f) return Rgb(0.0f);
    return bsdf->eval(wo, wi, v.at, lightSubpath ? TransportMode::Importance : TransportMode::Radiance);
}

}  // namespace fg
