// The one interface through which passes ask geometric questions. It owns the
// Embree device and scene built from Scene::shapes (triangle meshes as Embree
// triangle geometry, spheres as user geometry with an analytic intersector).
// Geometry id == shape index. Single rays and streams of rays (rtcIntersect1M /
// rtcOccluded1M) are both offered and give the same hits; the wavefront
// integrators use the streams.
#pragma once

#include "engine/core/math.h"
#include "engine/scene/scene.h"
#include "engine/shading/texture.h"

#include <cstdint>
#include <memory>
#include <span>

namespace fg {

struct Hit {
    float t = kInfinity;
    std::uint32_t shape = kNoShape;
    std::uint32_t primitive = 0;
    Vec2 barycentric{0.0f};  // Embree's (u, v); unused for spheres
    Vec3 geometricNormal{0.0f};  // unnormalised, as Embree reports it (meshes: winding order)
    static constexpr std::uint32_t kNoShape = 0xFFFFFFFFu;
    bool valid() const { return shape != kNoShape; }
};

// Everything about a surface point that shading needs.
struct SurfacePoint {
    Vec3 p{0.0f};
    Vec3 ng{0.0f};      // unit geometric normal, oriented by the shape (outward / winding, flips applied)
    Vec3 ns{0.0f};      // unit shading normal (the material's bump / normal map applied), same hemisphere as ng
    Vec2 uv{0.0f};
    std::uint32_t shape = Hit::kNoShape;
    // Meshes: the triangle hit and Embree's barycentrics, for textures that read mesh attributes.
    const TriangleMesh* mesh = nullptr;
    std::uint32_t triangle = 0;
    Vec2 barycentric{0.0f};

    TexturePoint texturePoint() const { return {uv, mesh, triangle, barycentric}; }
};

class RayQuery {
public:
    explicit RayQuery(const Scene& scene);
    ~RayQuery();
    RayQuery(const RayQuery&) = delete;
    RayQuery& operator=(const RayQuery&) = delete;

    Hit intersect(const Ray& ray, float tMin = 0.0f) const;
    bool occluded(const Ray& ray, float tMin = 0.0f) const;
    // Streams: out[i] / occluded[i] for rays[i]; tMin applies to all.
    void intersect(std::span<const Ray> rays, std::span<Hit> out, float tMin = 0.0f) const;
    void occluded(std::span<const Ray> rays, std::span<std::uint8_t> occludedOut, float tMin = 0.0f) const;

    SurfacePoint surface(const Ray& ray, const Hit& hit) const;
    // Derivative of the unit shading normal (as surface() reports it, except
    // that bump and normal maps are not differentiated) when the
    // hit point moves by the tangent offset dp: analytic for spheres, from the
    // per-vertex normal interpolation for meshes with normals, zero for flat
    // triangles. Ray differentials at curved specular surfaces need it (Igehy 1999).
    Vec3 shadingNormalDifferential(const Ray& ray, const Hit& hit, const Vec3& dp) const;
    const Scene& scene() const { return scene_; }

private:
    struct Impl;
    const Scene& scene_;
    std::unique_ptr<Impl> impl_;
};

// Origin offset along the geometric normal that keeps a spawned ray off its own surface.
inline Vec3 offsetRayOrigin(const Vec3& p, const Vec3& ng, const Vec3& dir) {
    const float scale = kRayEpsilon * (1.0f + std::max(std::abs(p.x), std::max(std::abs(p.y), std::abs(p.z))));
    return glm::dot(dir, ng) >= 0.0f ? p + scale * ng : p - scale * ng;
}

}  // namespace fg
