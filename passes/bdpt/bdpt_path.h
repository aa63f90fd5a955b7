// Vertices of bidirectional subpaths and the densities their multiple
// importance sampling weights are made of (Veach 1997, ch. 10; the vertex
// bookkeeping follows the design of pbrt-v3 §16.3, written anew here).
//
// Every vertex keeps two densities, per unit area at surface vertices and per
// unit volume at medium vertices (the path-space measure of Veach ch. 8):
//   pdfFwd: the density with which the subpath that made it sampled it;
//   pdfRev: the density with which a subpath growing from the other end would
//           sample it (filled in once the next vertex exists, and at the two
//           vertices beside a connection when the weight of that connection
//           is computed).
// The weight of strategy (s, t) (Veach §10.2-10.3: the balance heuristic for
// beta = 1, the power heuristic for beta = 2, §9.2) is
// w = 1 / (1 + sum_i (p_i / p_s)^beta): walking from the connection
// outwards the ratio of neighbouring strategies is pdfRev / pdfFwd of the
// vertex that changes sides.
//
// Both densities include the free-flight distance of the segment that reaches
// the vertex (Veach §8.2's volume path space; FreeFlightSegment of medium.h):
// a medium vertex carries sigma_t T of the media it was reached through, a
// surface reached through media the probability T of passing them, in either
// direction. The connecting segment is sampled by neither end, but its
// densities enter the ratios pdfRev / pdfFwd of the two vertices beside it;
// they are known only once the connection's shadow ray has walked the media,
// so the weight is computed in two steps (BdptWeightTerms). Segments to
// vertices at infinity carry no distance density in either direction: light
// subpaths of lights at infinity start on a disk outside the scene, not at
// infinity, and so no density of theirs matches a camera ray escaping.
#pragma once

#include "engine/accel/ray_query.h"
#include "engine/guiding/guided_sampling.h"
#include "engine/guiding/guiding_cache.h"
#include "passes/common/path_vertex.h"
#include "engine/core/math.h"
#include "engine/scene/scene.h"

#include <cstdint>
#include <optional>
#include <span>
#include <vector>

namespace fg {

enum class BdptVertexKind : std::uint8_t { Camera, Light, Surface, Medium };

struct BdptVertex {
    Vec3 p{0.0f};    // position; for a light at infinity the unit direction from the scene towards it
    Vec3 ng{0.0f};   // unit geometric normal (surfaces, area-light origins), zero elsewhere
    Vec3 ns{0.0f};   // unit shading normal (surfaces)
    Vec3 wo{0.0f};   // unit direction towards the vertex before it on its own subpath
    Rgb beta{0.0f};  // throughput of the subpath up to this vertex (not its own scattering)
    TexturePoint at{Vec2(0.0f)};  // where its material and an emitter's texture are looked up
    float pdfFwd = 0.0f;
    float pdfRev = 0.0f;
    // Free-flight density with which this vertex, sampling backwards along the
    // segment that reached it, would reach the vertex before it (a factor of that vertex's pdfRev).
    float distancePdfRev = 1.0f;
    int medium = -1;  // the medium the vertex was reached through (light origins: the one they emit into)
    int light = -1;   // the light it emits as (light origins, surfaces of area lights, escaped camera rays)
    std::uint32_t shape = Hit::kNoShape;
    BdptVertexKind kind = BdptVertexKind::Surface;
    bool delta = false;     // the subpath left it by a specular (Dirac) lobe
    bool infinite = false;  // a light at infinity (environment, directional) or an escaped camera ray

    bool onSurface() const { return kind == BdptVertexKind::Surface || (kind == BdptVertexKind::Light && ng != Vec3(0.0f)); }
};

// Per light, what the weights need beyond the Light interface.
struct BdptLightInfo {
    enum class Kind : std::uint8_t { Point, Area, Directional, Environment };
    Kind kind = Kind::Point;
    float positionPdf = 1.0f;       // area density of emission origins (area lights, bounding disks)
    float directionScale = 1.0f;    // area lights: 1 one-sided, 1/2 two-sided (cosine-weighted directions)
    int medium = -1;                // medium subpaths start in, or kMediumBySide (light_media.h)
};

// The camera as the weights see it: a pinhole whose rays have the solid-angle
// density 1 / (A cos^3 theta), A the image-plane area at unit distance (the
// raster is sampled uniformly, as many camera paths per unit raster area as
// light paths are connected to it).
struct BdptCamera {
    Vec3 eye{0.0f};
    Vec3 forward{0.0f, 0.0f, -1.0f};
    float imagePlaneArea = 1.0f;        // at unit distance
    float rasterPerImagePlane = 1.0f;   // raster area per unit image-plane area at unit distance
    float nearClip = 0.0f;
    float farClip = kInfinity;
    int width = 1, height = 1;
    int medium = -1;
};

struct BdptScene {
    BdptScene(const Scene& scene, const RayQuery& rays, const Camera& camera);
    const Scene& scene;
    const RayQuery& rays;
    Camera camera;
    BdptCamera view;
    std::vector<BdptLightInfo> lights;
    std::vector<int> infiniteLights;
    // Shadow rays through null boundaries and media, shared with the path tracer.
    PathTracerScene tracer;
    // Connections must walk through null boundaries and media instead of a plain occlusion test.
    bool connectionsNeedTransmittance = false;
    // Guided BDPT (Vorba et al. 2014, Fig. 1): camera subpaths draw their
    // directions from the radiance cache's mixtures, light subpaths from the
    // importance cache's (null: BSDF sampling on that side).
    const GuidingCache* radianceCache = nullptr;
    const GuidingCache* importanceCache = nullptr;
    float guidingBsdfProbability = 0.5f;  // α
    std::uint32_t guidingCandidates = 2;  // M of Eq. 11 without a cover grid
    bool guidingCovering = true;

    float lightPmf(int light) const;
    const Bsdf* bsdf(const BdptVertex& v) const;
    // Solid-angle density of a camera ray along `direction`; zero outside the image.
    float cameraDirectionPdf(const Vec3& direction, Vec2* raster = nullptr) const;
    // The mixture sampler of surface vertex `v` for a subpath of transport
    // `walk` that reached it from direction `toPrevious` (world space): the
    // radiance cache's record for camera subpaths, the importance cache's for
    // light subpaths, on the side the subpath arrived from. Nothing where that
    // cache is absent or holds no usable record, or where the BSDF has
    // specular, transmissive or null lobes (never guided).
    std::optional<GuidedBsdfSampler> guide(const BdptVertex& v, const Bsdf& bsdf, const Vec3& toPrevious,
                                           TransportMode walk) const;
};

// Unit direction from a to b (either may be at infinity).
Vec3 bdptDirection(const BdptVertex& from, const BdptVertex& to);
// Converts a solid-angle density at `from` into the density of `to` (area at
// surfaces, volume in media; unchanged for a vertex at infinity).
float bdptConvertDensity(float pdfSolidAngle, const BdptVertex& from, const BdptVertex& to);
// Area density with which `cur`, reached from `prev` (null for subpath origins),
// samples `next`. Surfaces use the BSDF density, media the phase function,
// the camera its ray density, light origins their emission density. At a
// guided vertex the density is the mixture α p_bsdf + (1 - α) p_gmm of the
// cache of the subpath kind `walk` that would sample `next` (§4.1).
float bdptPdf(const BdptScene& bs, const BdptVertex* prev, const BdptVertex& cur, const BdptVertex& next,
              TransportMode walk = TransportMode::Radiance);
// Density of choosing `v` as the origin of a light subpath (light selection
// included): area density for area lights, solid angle for lights at infinity.
float bdptPdfLightOrigin(const BdptScene& bs, const BdptVertex& v);
// Density of `next` when a light subpath starts at light vertex `v` and leaves towards it.
float bdptPdfLight(const BdptScene& bs, const BdptVertex& v, const BdptVertex& next);

// Solid-angle densities a specular (Dirac) scattering is given in the
// weights: `forward` for the sampled direction wi, `reverse` for wo (both in
// the shading frame; eta = IOR on wi's side / IOR on wo's side, BsdfSample::eta),
// the coefficients of one common delta: the same value for a direction
// whichever subpath crossed the vertex, as densities must be for their ratios
// to be those of the strategies (Veach §10.2).
struct BdptSpecularPdfs {
    float forward = 0.0f;
    float reverse = 0.0f;
};
BdptSpecularPdfs bdptSpecularPdfs(const Vec3& woLocal, const Vec3& wiLocal, float eta);

// Free-flight density of reaching `end` from `start` (towardsEnd) or `start`
// from `end` along a segment whose media were walked from `start`.
float bdptDistancePdf(const FreeFlightSegment& segment, const BdptVertex& start, const BdptVertex& end, bool towardsEnd);

enum class MisHeuristic : std::uint8_t { Balance, Power };

// A weight before the media along its connecting segment are known: the sums
// of the ratio terms on the camera and on the light side, each of which holds
// the density of one end sampling the other once.
struct BdptWeightTerms {
    float cameraSum = 0.0f;
    float lightSum = 0.0f;
    float cameraConnectionPdf = 0.0f;  // the light end sampling the camera end, without distance
    float lightConnectionPdf = 0.0f;   // the camera end sampling the light end, without distance
    bool connected = false;            // s > 0: the strategy has a connecting segment
    bool cameraEndInMedium = false;
    bool lightEndInMedium = false;
    bool atInfinity = false;           // either end is at infinity
    MisHeuristic heuristic = MisHeuristic::Power;
};

// Terms of the weight of connecting the first s light vertices with the first
// t camera vertices. `sampledLight` replaces light[0] for s = 1 (next-event
// estimation resamples the light) and, for s = 0, the camera subpath's last
// vertex (an escaped ray as one of several lights at infinity sees it); null otherwise.
BdptWeightTerms bdptMisTerms(const BdptScene& bs, std::span<const BdptVertex> light, std::span<const BdptVertex> camera,
                             const BdptVertex* sampledLight, int s, int t, MisHeuristic heuristic);
// The weight, given the media along the connecting segment walked from the
// camera end to the light end (empty where it crosses none or s = 0).
float bdptFinishWeight(const BdptWeightTerms& terms, const FreeFlightSegment& connection);
// Both steps at once.
float bdptMisWeight(const BdptScene& bs, std::span<const BdptVertex> light, std::span<const BdptVertex> camera,
                    const BdptVertex* sampledLight, int s, int t, MisHeuristic heuristic,
                    const FreeFlightSegment& connection = FreeFlightSegment());

// f * |cos| at a connectible vertex towards `to` (BSDF at surfaces, phase in
// media); zero where the vertex cannot connect (specular lobes, the wrong side
// of the geometric surface).
Rgb bdptScatter(const BdptScene& bs, const BdptVertex& v, const Vec3& to, bool lightSubpath);
bool bdptConnectible(const BdptScene& bs, const BdptVertex& v);

}  // namespace fg
