// Final gathering (Jensen 2001, "Realistic Image Synthesis Using Photon
// Mapping"; Herzog et al. 2007, §8.4), shared by the photon-map
// baseline (`final_gather`) and photon ray splatting (`fg_splat`): from every
// primary eye vertex, N rays sample its BSDF; the surfaces they reach become
// secondary vertices whose reflected radiance the density estimate gives,
//   L(x, w_o) ~ 1/N sum_j f_s(w_j, x, w_o) |cos theta_j| / p(w_j) L_r(x_j, -w_j),
// so a hit carries the primary's throughput times the sample's weight / N, as
// a primary vertex carries its sample weight.
//
// The image is rendered in tiles x tiles rectangles (§8.4 after Havran et al.
// 2005: with hundreds of gather rays per pixel the hits of the whole image
// would not fit in memory), one tile's hits at a time.
//
// A hit counts only on a surface with a diffuse or glossy lobe. Emission at
// the hit is direct light, which the eye pass estimates. A hit on a purely
// specular surface is dropped: the light it would bring comes from the
// caustic estimate at the primary vertices where it left the light through
// specular surfaces only (L S+ D), and is lost where it did not (L .. D S+ D
// at the primary, a lit wall seen through a mirror); Jensen follows such
// rays through the specular chain, which is not done here. A gather ray
// stops at the first surface: null boundaries and the clear parts of masks
// are not crossed.
//
// Random streams are keyed by (seed, pass instance, primary vertex index) and
// hits are stored in (primary, ray) order, so the hits do not depend on the
// thread count.
#pragma once

#include "engine/accel/ray_query.h"
#include "engine/buffers/photon_buffers.h"
#include "engine/core/math.h"
#include "engine/scene/scene.h"
#include "jobs/parallel.h"
#include "jobs/random.h"

#include <algorithm>
#include <cstdint>
#include <optional>
#include <span>
#include <stdexcept>
#include <vector>

namespace fg {

// Where a gather ray leaves from: an eye vertex or a final-gather hit.
struct GatherOrigin {
    Vec3 position{0.0f};
    Vec3 normal{0.0f};
    Vec3 geometricNormal{0.0f};
    Vec3 outgoing{0.0f};
    Vec2 uv{0.0f};
    std::uint32_t bsdf = 0;
};

inline GatherOrigin gatherOrigin(const EyeVertexBuffer::View& vertices, std::size_t v) {
    return {vertices.column<EyePosition>()[v], vertices.column<EyeNormal>()[v], vertices.column<EyeGeometricNormal>()[v],
            vertices.column<EyeOutgoing>()[v], vertices.column<EyeUv>()[v], vertices.column<EyeBsdf>()[v]};
}

struct GatherHit {
    SurfacePoint point;
    Vec3 direction{0.0f};  // from the origin to the hit
    Rgb weight{0.0f};      // f_s |cos| / pdf of the sampled direction
    float distance = 0.0f;
    const Bsdf* bsdf = nullptr;  // the hit surface's material; null if it has none
    int areaLight = -1;
};

// One BSDF-sampled ray from `origin` and what it hits; nullopt if the sample
// fails or the ray escapes.
inline std::optional<GatherHit> traceGatherRay(const Scene& scene, const RayQuery& rays, const GatherOrigin& origin,
                                               jobs::Rng& rng) {
    const Frame frame(origin.normal);
    const float uLobe = rng.uniform();
    const Vec2 u = rng.uniform2();
    const std::optional<BsdfSample> sample =
        scene.bsdfs[origin.bsdf]->sample(frame.toLocal(origin.outgoing), origin.uv, uLobe, u, TransportMode::Radiance);
    if (!sample || isBlack(sample->weight) || !isFinite(sample->weight)) return std::nullopt;
    const Vec3 direction = glm::normalize(frame.toWorld(sample->wi));
    const Ray ray{offsetRayOrigin(origin.position, origin.geometricNormal, direction), direction, kInfinity};
    const Hit hit = rays.intersect(ray);
    if (!hit.valid()) return std::nullopt;
    GatherHit out;
    out.point = rays.surface(ray, hit);
    out.direction = direction;
    out.weight = sample->weight;
    out.distance = hit.t;
    const Shape& shape = scene.shapes[out.point.shape];
    if (shape.bsdf >= 0) out.bsdf = scene.bsdfs[static_cast<std::size_t>(shape.bsdf)].get();
    out.areaLight = shape.areaLight;
    return out;
}

// The primary vertices of each tile, in vertex order; tile (tx, ty) is entry
// ty * tiles + tx and covers the pixels x with tx = x * tiles / width.
inline std::vector<std::vector<std::uint32_t>> primariesByTile(const EyeVertexBuffer::View& eye, int width, int height,
                                                               int tiles) {
    std::vector<std::vector<std::uint32_t>> byTile(static_cast<std::size_t>(tiles) * static_cast<std::size_t>(tiles));
    const auto pixel = eye.column<EyePixel>();
    const auto w = static_cast<std::size_t>(width), h = static_cast<std::size_t>(height);
    const auto t = static_cast<std::size_t>(tiles);
    for (std::size_t v = 0; v < eye.size(); ++v) {
        const std::size_t x = pixel[v] % w, y = pixel[v] / w;
        if (y >= h) throw std::logic_error("final gathering: eye vertex outside the film");
        byTile[(y * t / h) * t + x * t / w].push_back(static_cast<std::uint32_t>(v));
    }
    return byTile;
}

// The final-gather hits of one tile's primaries. hitParent[i] is the primary
// vertex (index into `eye`) hit i was gathered for, hitDistance[i] its
// distance from there.
struct FinalGatherHits {
    EyeVertexBuffer vertices;
    std::vector<std::uint32_t> parent;
    std::vector<float> distance;
};

inline void traceFinalGatherHits(const Scene& scene, const RayQuery& rays, const EyeVertexBuffer::View& eye,
                                 std::span<const std::uint32_t> primaries, int raysPerVertex, std::uint64_t seed,
                                 std::uint64_t stream, FinalGatherHits& out) {
    const auto n = static_cast<std::size_t>(raysPerVertex);
    const float inverseCount = 1.0f / static_cast<float>(raysPerVertex);
    struct Slot {
        EyeVertexBuffer::Record record;
        float distance = 0.0f;
        bool valid = false;
    };
    std::vector<Slot> slots(primaries.size() * n);
    jobs::parallelForChunks(primaries.size(), 64, [&](jobs::IndexRange range) {
        for (std::size_t i = range.begin; i != range.end; ++i) {
            const std::uint32_t v = primaries[i];
            const GatherOrigin origin = gatherOrigin(eye, v);
            const Rgb throughput = eye.column<EyeThroughput>()[v] * inverseCount;
            jobs::Rng rng(seed, stream, v);
            for (std::size_t j = 0; j < n; ++j) {
                const std::optional<GatherHit> hit = traceGatherRay(scene, rays, origin, rng);
                if (!hit || !hit->bsdf || !hit->bsdf->hasSmoothLobe()) continue;
                Slot& slot = slots[i * n + j];
                EyeVertexBuffer::Record& r = slot.record;
                r.get<EyePosition>() = hit->point.p;
                r.get<EyeNormal>() = hit->point.ns;
                r.get<EyeGeometricNormal>() = hit->point.ng;
                r.get<EyeOutgoing>() = -hit->direction;
                r.get<EyeUv>() = hit->point.uv;
                r.get<EyeThroughput>() = throughput * hit->weight;
                r.get<EyeBsdf>() = static_cast<std::uint32_t>(scene.shapes[hit->point.shape].bsdf);
                r.get<EyePixel>() = eye.column<EyePixel>()[v];
                slot.distance = hit->distance;
                slot.valid = true;
            }
        }
    });
    std::size_t count = 0;
    for (const Slot& s : slots) count += s.valid ? 1 : 0;
    out.vertices.resize(count);
    out.parent.resize(count);
    out.distance.resize(count);
    std::size_t next = 0;
    for (std::size_t k = 0; k < slots.size(); ++k) {
        if (!slots[k].valid) continue;
        out.vertices.set(next, slots[k].record);
        out.parent[next] = primaries[k / n];
        out.distance[next] = slots[k].distance;
        ++next;
    }
}

}  // namespace fg
