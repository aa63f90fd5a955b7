#include "engine/accel/ray_query.h"

#include "jobs/random.h"

#include <gtest/gtest.h>

#include <glm/gtc/matrix_transform.hpp>

#include <array>
#include <cmath>
#include <map>
#include <thread>
#include <vector>

namespace fg {
namespace {

Shape meshShape(TriangleMesh mesh) {
    Shape s;
    s.geometry = std::move(mesh);
    return s;
}

Shape sphereShape(const Vec3& center, float radius, bool flip = false) {
    Shape s;
    s.geometry = Sphere{center, radius};
    s.flipNormals = flip;
    return s;
}

Ray makeRay(const Vec3& o, const Vec3& d, float tMax = kInfinity) {
    Ray r;
    r.origin = o;
    r.direction = d;
    r.tMax = tMax;
    return r;
}

void expectVecNear(const Vec3& a, const Vec3& b, float tol) {
    EXPECT_NEAR(a.x, b.x, tol);
    EXPECT_NEAR(a.y, b.y, tol);
    EXPECT_NEAR(a.z, b.z, tol);
}

TEST(RayQuery, RectangleHitAtKnownDistanceAndNormal) {
    Scene scene;
    scene.shapes.push_back(meshShape(makeRectangleMesh()));
    RayQuery query(scene);

    const Ray ray = makeRay({0.3f, 0.2f, 5.0f}, {0, 0, -1});
    const Hit hit = query.intersect(ray);
    ASSERT_TRUE(hit.valid());
    EXPECT_EQ(hit.shape, 0u);
    EXPECT_NEAR(hit.t, 5.0f, 1e-5f);
    // Embree's normal follows the winding, as ours does: +z for this rectangle.
    EXPECT_GT(glm::dot(glm::normalize(hit.geometricNormal), Vec3(0, 0, 1)), 0.999f);

    const SurfacePoint sp = query.surface(ray, hit);
    expectVecNear(sp.p, {0.3f, 0.2f, 0.0f}, 1e-5f);
    expectVecNear(sp.ng, {0, 0, 1}, 1e-6f);
    expectVecNear(sp.ns, {0, 0, 1}, 1e-6f);
    // The rectangle's uv maps [-1, 1]^2 onto [0, 1]^2.
    EXPECT_NEAR(sp.uv.x, 0.65f, 1e-5f);
    EXPECT_NEAR(sp.uv.y, 0.60f, 1e-5f);

    // Missing the rectangle, and a tMax short of it.
    EXPECT_FALSE(query.intersect(makeRay({1.5f, 0.0f, 5.0f}, {0, 0, -1})).valid());
    EXPECT_FALSE(query.intersect(makeRay({0.3f, 0.2f, 5.0f}, {0, 0, -1}, 4.9f)).valid());
    EXPECT_TRUE(query.intersect(makeRay({0.3f, 0.2f, 5.0f}, {0, 0, -1}, 5.1f)).valid());
}

TEST(RayQuery, CubeFacesFromOutsideAndInside) {
    Scene scene;
    TriangleMesh cube = makeCubeMesh();
    cube.transform(glm::translate(Mat4(1.0f), Vec3(10, 0, 0)));
    scene.shapes.push_back(meshShape(makeRectangleMesh()));  // shape 0, unrelated
    scene.shapes.push_back(meshShape(cube));
    RayQuery query(scene);

    const Ray outside = makeRay({15, 0.1f, 0.2f}, {-1, 0, 0});
    const Hit h1 = query.intersect(outside);
    ASSERT_TRUE(h1.valid());
    EXPECT_EQ(h1.shape, 1u);
    EXPECT_NEAR(h1.t, 4.0f, 1e-5f);
    const SurfacePoint s1 = query.surface(outside, h1);
    expectVecNear(s1.ng, {1, 0, 0}, 1e-6f);
    expectVecNear(s1.p, {11, 0.1f, 0.2f}, 1e-5f);

    // From the centre, the exit face's outward normal points along the ray.
    const Ray inside = makeRay({10, 0, 0}, {0, 1, 0});
    const Hit h2 = query.intersect(inside);
    ASSERT_TRUE(h2.valid());
    EXPECT_EQ(h2.shape, 1u);
    EXPECT_NEAR(h2.t, 1.0f, 1e-5f);
    expectVecNear(query.surface(inside, h2).ng, {0, 1, 0}, 1e-6f);
}

TEST(RayQuery, SphereHitFromOutsideAndInside) {
    Scene scene;
    const Vec3 c(1, 2, 3);
    scene.shapes.push_back(sphereShape(c, 0.5f));
    RayQuery query(scene);

    const Ray outside = makeRay(c + Vec3(0, 0, 7), {0, 0, -1});
    const Hit h = query.intersect(outside);
    ASSERT_TRUE(h.valid());
    EXPECT_EQ(h.shape, 0u);
    EXPECT_NEAR(h.t, 6.5f, 1e-5f);
    const SurfacePoint sp = query.surface(outside, h);
    expectVecNear(sp.p, c + Vec3(0, 0, 0.5f), 1e-5f);
    expectVecNear(sp.ng, {0, 0, 1}, 1e-5f);
    expectVecNear(sp.ns, sp.ng, 1e-6f);
    EXPECT_NEAR(sp.uv.y, 0.0f, 1e-3f);  // the +z pole is v = 0

    // An unnormalised direction scales t.
    const Hit scaled = query.intersect(makeRay(c + Vec3(0, 0, 7), {0, 0, -2}));
    ASSERT_TRUE(scaled.valid());
    EXPECT_NEAR(scaled.t, 3.25f, 1e-5f);

    // From the centre: exit point at t = r, outward normal along the ray.
    const Vec3 dir = glm::normalize(Vec3(1, -2, 0.5f));
    const Ray inside = makeRay(c, dir);
    const Hit hi = query.intersect(inside);
    ASSERT_TRUE(hi.valid());
    EXPECT_NEAR(hi.t, 0.5f, 1e-5f);
    expectVecNear(query.surface(inside, hi).ng, dir, 1e-5f);

    // From just inside the surface, the far side is found, not the near one.
    const Ray nearSurface = makeRay(c + Vec3(0, 0, 0.49f), {0, 0, 1});
    const Hit hn = query.intersect(nearSurface);
    ASSERT_TRUE(hn.valid());
    EXPECT_NEAR(hn.t, 0.01f, 1e-5f);
    const Ray nearSurfaceBack = makeRay(c + Vec3(0, 0, 0.49f), {0, 0, -1});
    const Hit hb = query.intersect(nearSurfaceBack);
    ASSERT_TRUE(hb.valid());
    EXPECT_NEAR(hb.t, 0.99f, 1e-5f);

    // tMin skips the crossing at the ray's own origin.
    const Ray leaving = makeRay(c + Vec3(0.5f, 0, 0), {1, 0, 0});
    EXPECT_FALSE(query.intersect(leaving, 1e-4f).valid());
    const Ray entering = makeRay(c + Vec3(0.5f, 0, 0), {-1, 0, 0});
    const Hit he = query.intersect(entering, 1e-4f);
    ASSERT_TRUE(he.valid());
    EXPECT_NEAR(he.t, 1.0f, 1e-5f);

    // Just past the silhouette misses, just inside it hits.
    EXPECT_FALSE(query.intersect(makeRay(c + Vec3(0.5005f, 0, 7), {0, 0, -1})).valid());
    EXPECT_TRUE(query.intersect(makeRay(c + Vec3(0.4995f, 0, 7), {0, 0, -1})).valid());
}

TEST(RayQuery, FlippedSpherePointsInwards) {
    Scene scene;
    scene.shapes.push_back(sphereShape({0, 0, 0}, 2.0f, true));
    RayQuery query(scene);
    const Ray ray = makeRay({0, 5, 0}, {0, -1, 0});
    const Hit h = query.intersect(ray);
    ASSERT_TRUE(h.valid());
    EXPECT_NEAR(h.t, 3.0f, 1e-5f);
    expectVecNear(query.surface(ray, h).ng, {0, -1, 0}, 1e-5f);
    EXPECT_LT(h.geometricNormal.y, 0.0f);
}

TEST(RayQuery, SmallDistantSphereSilhouetteIsExact) {
    // b^2 - 4ac in single precision cannot resolve this sphere: |o - c|^2 ~ 1e8
    // while r^2 ~ 1e-4.
    Scene scene;
    const float r = 0.01f;
    scene.shapes.push_back(sphereShape({0, 0, 0}, r));
    RayQuery query(scene);
    for (float f : {0.2f, 0.9f, 0.99f}) {
        const Ray ray = makeRay({f * r, 0, 1.0e4f}, {0, 0, -1});
        const Hit h = query.intersect(ray);
        ASSERT_TRUE(h.valid()) << f;
        const SurfacePoint sp = query.surface(ray, h);
        EXPECT_NEAR(glm::length(sp.p), r, 1e-6f);
        EXPECT_NEAR(sp.p.x, f * r, 1e-6f);
        EXPECT_GT(sp.p.z, 0.0f);
    }
    for (float f : {1.01f, 1.1f}) {
        EXPECT_FALSE(query.intersect(makeRay({f * r, 0, 1.0e4f}, {0, 0, -1})).valid()) << f;
    }
}

// Rays that pass the silhouette closely: the quick float rejection of misses
// must leave every hit to the exact solve. Each ray aims at a point at
// (1 + delta) r from the centre, perpendicular to the ray, with |delta| up to
// 1e-3; it hits iff delta < 0 (exactly, in long double), which the query must
// report except within 1e-6 of the silhouette.
TEST(RayQuery, RaysGrazingASphereAreHitIffTheyPassInside) {
    Scene scene;
    const Vec3 center(0.3f, -1.2f, 2.0f);
    const float r = 0.7f;
    scene.shapes.push_back(sphereShape(center, r));
    RayQuery query(scene);
    jobs::Rng rng(7, 0, 0);
    int hits = 0, misses = 0;
    for (int i = 0; i < 20000; ++i) {
        const Vec3 d = glm::normalize(Vec3(rng.uniform() - 0.5f, rng.uniform() - 0.5f, rng.uniform() - 0.5f));
        const Frame frame(d);
        const float phi = 2.0f * kPi * rng.uniform();
        const float delta = 2e-3f * (rng.uniform() - 0.5f);
        const Vec3 aim = center + (1.0f + delta) * r * (std::cos(phi) * frame.s + std::sin(phi) * frame.t);
        const float distance = 3.0f + 30.0f * rng.uniform();
        const Vec3 o = aim - distance * d;
        // The exact distance of the line (as rounded to float) from the centre.
        using L = long double;
        const L fx = L(o.x) - L(center.x), fy = L(o.y) - L(center.y), fz = L(o.z) - L(center.z);
        const L dd = L(d.x) * d.x + L(d.y) * d.y + L(d.z) * d.z;
        const L fd = (fx * d.x + fy * d.y + fz * d.z) / dd;
        const L px = fx - fd * d.x, py = fy - fd * d.y, pz = fz - fd * d.z;
        const L offset = std::sqrt(px * px + py * py + pz * pz) / L(r) - 1;
        if (std::abs(static_cast<double>(offset)) < 1e-6) continue;
        const bool inside = offset < 0;
        const Hit hit = query.intersect(makeRay(o, d));
        ASSERT_EQ(hit.valid(), inside) << "ray " << i << ", offset " << static_cast<double>(offset);
        EXPECT_EQ(query.occluded(makeRay(o, d)), inside) << "ray " << i;
        (inside ? hits : misses) += 1;
    }
    EXPECT_GT(hits, 5000);
    EXPECT_GT(misses, 5000);
}

TEST(RayQuery, TransformedAndFlippedMeshNormals) {
    Scene scene;
    // 0: rectangle rotated to face +x, moved to x = 2.
    TriangleMesh rotated = makeRectangleMesh();
    rotated.transform(glm::translate(Mat4(1.0f), Vec3(2, 0, 0)) * glm::rotate(Mat4(1.0f), kPi / 2, Vec3(0, 1, 0)));
    scene.shapes.push_back(meshShape(rotated));
    // 1: rectangle at z = -3, flipped: faces -z.
    TriangleMesh flipped = makeRectangleMesh();
    flipped.transform(glm::translate(Mat4(1.0f), Vec3(0, 0, -3)));
    flipped.flipNormals();
    scene.shapes.push_back(meshShape(flipped));
    // 2: rectangle at y = -4 mirrored in x: the winding is restored, still faces +z.
    TriangleMesh mirrored = makeRectangleMesh();
    mirrored.transform(glm::translate(Mat4(1.0f), Vec3(0, -4, 0)) * glm::scale(Mat4(1.0f), Vec3(-1, 1, 1)));
    scene.shapes.push_back(meshShape(mirrored));
    RayQuery query(scene);

    const Ray r0 = makeRay({-1, 0.2f, 0.1f}, {1, 0, 0});
    const Hit h0 = query.intersect(r0);
    ASSERT_TRUE(h0.valid());
    EXPECT_EQ(h0.shape, 0u);
    EXPECT_NEAR(h0.t, 3.0f, 1e-5f);
    const SurfacePoint s0 = query.surface(r0, h0);
    expectVecNear(s0.ng, {1, 0, 0}, 1e-5f);
    expectVecNear(s0.ns, {1, 0, 0}, 1e-5f);
    EXPECT_GT(glm::dot(h0.geometricNormal, s0.ng), 0.0f);

    const Ray r1 = makeRay({0.1f, 0.1f, 0}, {0, 0, -1});
    const Hit h1 = query.intersect(r1);
    ASSERT_TRUE(h1.valid());
    EXPECT_EQ(h1.shape, 1u);
    const SurfacePoint s1 = query.surface(r1, h1);
    expectVecNear(s1.ng, {0, 0, -1}, 1e-6f);
    expectVecNear(s1.ns, {0, 0, -1}, 1e-6f);
    EXPECT_LT(h1.geometricNormal.z, 0.0f);

    const Ray r2 = makeRay({0.5f, -4.2f, 2}, {0, 0, -1});
    const Hit h2 = query.intersect(r2);
    ASSERT_TRUE(h2.valid());
    EXPECT_EQ(h2.shape, 2u);
    expectVecNear(query.surface(r2, h2).ng, {0, 0, 1}, 1e-6f);
}

TEST(RayQuery, ShadingNormalIsInterpolatedAndKeptOnTheGeometricSide) {
    Scene scene;
    TriangleMesh tri;
    tri.positions = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}};  // faces +z
    // Normals deliberately disagree with the winding (all tilted towards -z).
    tri.normals = {glm::normalize(Vec3(0, 0, -1)), glm::normalize(Vec3(1, 0, -1)), glm::normalize(Vec3(0, 1, -1))};
    tri.uvs = {{0, 0}, {1, 0}, {0, 1}};
    tri.indices = {0, 1, 2};
    scene.shapes.push_back(meshShape(tri));
    RayQuery query(scene);

    const Vec3 target(0.25f, 0.5f, 0.0f);
    const Ray ray = makeRay(target + Vec3(0, 0, 1), {0, 0, -1});
    const Hit h = query.intersect(ray);
    ASSERT_TRUE(h.valid());
    EXPECT_NEAR(h.barycentric.x, 0.25f, 1e-5f);
    EXPECT_NEAR(h.barycentric.y, 0.5f, 1e-5f);
    const SurfacePoint sp = query.surface(ray, h);
    expectVecNear(sp.ng, {0, 0, 1}, 1e-6f);
    const Vec3 expected = -glm::normalize(0.25f * tri.normals[0] + 0.25f * tri.normals[1] + 0.5f * tri.normals[2]);
    expectVecNear(sp.ns, expected, 1e-5f);
    EXPECT_GT(glm::dot(sp.ns, sp.ng), 0.0f);
    EXPECT_NEAR(sp.uv.x, 0.25f, 1e-5f);
    EXPECT_NEAR(sp.uv.y, 0.5f, 1e-5f);
}

// A cluttered scene for randomised comparisons.
Scene clutteredScene() {
    Scene scene;
    TriangleMesh floor = makeRectangleMesh();
    floor.transform(glm::translate(Mat4(1.0f), Vec3(0, -1, 0)) * glm::rotate(Mat4(1.0f), -kPi / 2, Vec3(1, 0, 0)) *
                    glm::scale(Mat4(1.0f), Vec3(4.0f)));
    scene.shapes.push_back(meshShape(floor));
    TriangleMesh cube = makeCubeMesh();
    cube.transform(glm::translate(Mat4(1.0f), Vec3(-1.5f, 0, 0)) * glm::rotate(Mat4(1.0f), 0.4f, Vec3(0, 1, 0)) *
                   glm::scale(Mat4(1.0f), Vec3(0.6f)));
    scene.shapes.push_back(meshShape(cube));
    scene.shapes.push_back(sphereShape({1.2f, 0.0f, 0.3f}, 0.8f));
    scene.shapes.push_back(sphereShape({0.0f, 1.5f, -1.0f}, 0.4f, true));
    TriangleMesh disk = makeDiskMesh(32);
    disk.transform(glm::translate(Mat4(1.0f), Vec3(0, 0, -2.5f)) * glm::scale(Mat4(1.0f), Vec3(2.0f)));
    scene.shapes.push_back(meshShape(disk));
    return scene;
}

std::vector<Ray> randomRays(std::size_t count, std::uint64_t seed) {
    jobs::Rng rng(seed, 0, 0);
    std::vector<Ray> rays(count);
    for (Ray& r : rays) {
        r.origin = Vec3(rng.uniform(), rng.uniform(), rng.uniform()) * 6.0f - Vec3(3.0f);
        r.direction = sampleUniformSphere(rng.uniform2());
        r.tMax = rng.uniform() < 0.3f ? 0.5f + 4.0f * rng.uniform() : kInfinity;
    }
    return rays;
}

TEST(RayQuery, StreamsMatchSingleRays) {
    const Scene scene = clutteredScene();
    RayQuery query(scene);
    const std::vector<Ray> rays = randomRays(3000, 7);
    std::vector<Hit> hits(rays.size());
    std::vector<std::uint8_t> blocked(rays.size());
    query.intersect(rays, hits);
    query.occluded(rays, blocked);
    std::size_t hitCount = 0;
    for (std::size_t i = 0; i < rays.size(); ++i) {
        const Hit single = query.intersect(rays[i]);
        ASSERT_EQ(single.shape, hits[i].shape) << i;
        if (single.valid()) {
            ++hitCount;
            EXPECT_EQ(single.primitive, hits[i].primitive);
            EXPECT_NEAR(single.t, hits[i].t, 1e-5f * (1.0f + single.t));
        }
        EXPECT_EQ(query.occluded(rays[i]), blocked[i] != 0) << i;
    }
    // The comparison means something only if both outcomes occur often.
    EXPECT_GT(hitCount, rays.size() / 4);
    EXPECT_LT(hitCount, rays.size() * 9 / 10);
}

// A stream of camera rays gets exactly the hits single rays get, even where
// two coplanar triangles overlap and tie in t (the floor repeated with the
// opposite winding, as the Cornell box's ceiling holds its light opening): the
// schedules of `pt` trace the same paths only if the kernels agree.
TEST(RayQuery, CameraStreamHitsWhatSingleRaysHit) {
    Scene scene = clutteredScene();
    TriangleMesh overlap = std::get<TriangleMesh>(scene.shapes[0].geometry);
    for (std::size_t corner = 0; corner + 2 < overlap.indices.size(); corner += 3) {
        std::swap(overlap.indices[corner + 1], overlap.indices[corner + 2]);
    }
    scene.shapes.push_back(meshShape(overlap));
    RayQuery query(scene);
    Camera camera;
    camera.eye = Vec3(0, 0.5f, 6);
    camera.target = Vec3(0, 0, 0);
    camera.width = 80;
    camera.height = 60;
    std::vector<Ray> rays;
    for (int y = 0; y < camera.height; ++y) {
        for (int x = 0; x < camera.width; ++x) rays.push_back(camera.generateRay({x + 0.5f, y + 0.5f}));
    }
    std::vector<Hit> hits(rays.size());
    query.intersect(rays, hits);
    std::vector<std::uint8_t> blocked(rays.size());
    query.occluded(rays, blocked);
    std::size_t hitCount = 0, overlapCount = 0;
    const auto overlapShape = static_cast<std::uint32_t>(scene.shapes.size() - 1);
    for (std::size_t i = 0; i < rays.size(); ++i) {
        const Hit single = query.intersect(rays[i]);
        ASSERT_EQ(single.shape, hits[i].shape) << i;
        if (single.valid()) {
            ++hitCount;
            overlapCount += single.shape == overlapShape || single.shape == 0 ? 1 : 0;
            EXPECT_EQ(single.primitive, hits[i].primitive) << i;
            EXPECT_EQ(single.t, hits[i].t) << i;
            EXPECT_EQ(single.barycentric, hits[i].barycentric) << i;
        }
        EXPECT_EQ(single.valid(), blocked[i] != 0) << i;
    }
    EXPECT_GT(hitCount, rays.size() / 4);
    EXPECT_GT(overlapCount, rays.size() / 20);
}

TEST(RayQuery, OcclusionAgreesWithIntersection) {
    const Scene scene = clutteredScene();
    RayQuery query(scene);
    std::vector<Ray> rays = randomRays(3000, 11);
    std::size_t occludedCount = 0, compared = 0;
    for (Ray ray : rays) {
        const Hit full = query.intersect(makeRay(ray.origin, ray.direction));
        ray.tMax = 0.5f + 3.0f * std::abs(ray.direction.x);
        // Skip near-ties between the hit distance and the segment end.
        if (full.valid() && std::abs(full.t - ray.tMax) < 1e-3f) continue;
        const bool expected = full.valid() && full.t < ray.tMax;
        EXPECT_EQ(query.occluded(ray), expected);
        occludedCount += expected ? 1 : 0;
        ++compared;
        // tMin beyond the first hit must find the next surface or nothing.
        if (full.valid()) {
            const Hit after = query.intersect(makeRay(ray.origin, ray.direction), full.t + 1e-3f);
            if (after.valid()) {
                EXPECT_GT(after.t, full.t);
            }
        }
    }
    EXPECT_GT(occludedCount, compared / 10);
    EXPECT_LT(occludedCount, compared * 9 / 10);
}

TEST(RayQuery, ConcurrentQueriesAgree) {
    const Scene scene = clutteredScene();
    RayQuery query(scene);
    const std::vector<Ray> rays = randomRays(2000, 3);
    std::vector<Hit> reference(rays.size());
    for (std::size_t i = 0; i < rays.size(); ++i) reference[i] = query.intersect(rays[i]);
    std::vector<int> mismatches(4, 0);
    std::vector<std::thread> threads;
    for (int t = 0; t < 4; ++t) {
        threads.emplace_back([&, t] {
            for (int repeat = 0; repeat < 3; ++repeat) {
                for (std::size_t i = static_cast<std::size_t>(t); i < rays.size(); i += 2) {
                    const Hit h = query.intersect(rays[i]);
                    if (h.shape != reference[i].shape || h.t != reference[i].t) ++mismatches[t];
                }
                std::vector<Hit> streamed(rays.size());
                query.intersect(rays, streamed);
                for (std::size_t i = 0; i < rays.size(); ++i) {
                    if (streamed[i].shape != reference[i].shape) ++mismatches[t];
                }
            }
        });
    }
    for (std::thread& th : threads) th.join();
    for (int m : mismatches) EXPECT_EQ(m, 0);
}

// The cube [-1, 1]^3 with each face cut into n x n squares of two triangles,
// every vertex shared by all the triangles that meet there (a closed mesh).
TriangleMesh tessellatedCube(int n) {
    TriangleMesh mesh;
    std::map<std::array<int, 3>, std::uint32_t> vertexAt;
    const auto vertex = [&](std::array<int, 3> lattice) {
        const auto [it, added] = vertexAt.try_emplace(lattice, static_cast<std::uint32_t>(mesh.positions.size()));
        if (added) {
            mesh.positions.push_back(Vec3(static_cast<float>(lattice[0]), static_cast<float>(lattice[1]),
                                          static_cast<float>(lattice[2])) *
                                         (2.0f / static_cast<float>(n)) -
                                     Vec3(1.0f));
        }
        return it->second;
    };
    for (int axis = 0; axis < 3; ++axis) {
        for (int side : {0, n}) {
            const auto corner = [&](int a, int b) {
                std::array<int, 3> lattice{};
                lattice[static_cast<std::size_t>(axis)] = side;
                lattice[static_cast<std::size_t>((axis + 1) % 3)] = a;
                lattice[static_cast<std::size_t>((axis + 2) % 3)] = b;
                return vertex(lattice);
            };
            for (int a = 0; a < n; ++a) {
                for (int b = 0; b < n; ++b) {
                    const std::uint32_t v00 = corner(a, b), v10 = corner(a + 1, b), v11 = corner(a + 1, b + 1),
                                        v01 = corner(a, b + 1);
                    mesh.indices.insert(mesh.indices.end(), {v00, v10, v11, v00, v11, v01});
                }
            }
        }
    }
    return mesh;
}

// Embree's fast (non-robust) triangle test is not watertight at shared edges;
// a ray that passes between two triangles ends a path early. Rays from inside
// a closed mesh towards uniformly random points of its surface, as sampled
// directions are, must practically never escape: measured 4 in 3e7 for this
// cube (none of the 10^6 here), while 60 of its triangles pulled 0.1 % off
// their neighbours let 81 of these 10^6 through. Cornell-box-sized
// coordinates, rotated so that no edge is axis-aligned.
TEST(RayQuery, ClosedMeshKeepsRandomRaysIn) {
    const Mat4 toWorld = glm::scale(glm::rotate(glm::translate(Mat4(1.0f), Vec3(278.0f, 273.0f, 279.0f)), 0.7f,
                                                glm::normalize(Vec3(1, 2, 3))),
                                    Vec3(270.0f));
    TriangleMesh cube = tessellatedCube(8);
    cube.transform(toWorld);
    Scene scene;
    scene.shapes.push_back(meshShape(cube));
    RayQuery query(scene);

    jobs::Rng rng(5, 0, 0);
    constexpr std::size_t kRays = 1000000, kBatch = 256;
    std::vector<Ray> rays(kBatch);
    std::vector<Hit> hits(kBatch);
    std::size_t escaped = 0;
    for (std::size_t done = 0; done < kRays; done += kBatch) {
        for (Ray& ray : rays) {
            const Vec3 inside = Vec3(rng.uniform(), rng.uniform(), rng.uniform()) * 1.6f - Vec3(0.8f);
            Vec3 onSurface = Vec3(rng.uniform(), rng.uniform(), rng.uniform()) * 2.0f - Vec3(1.0f);
            onSurface[static_cast<int>(rng.uniformIndex(3))] = rng.uniform() < 0.5f ? -1.0f : 1.0f;
            const Vec3 origin = Vec3(toWorld * Vec4(inside, 1.0f));
            ray = makeRay(origin, glm::normalize(Vec3(toWorld * Vec4(onSurface, 1.0f)) - origin));
        }
        query.intersect(rays, hits);
        for (const Hit& hit : hits) escaped += hit.valid() ? 0 : 1;
    }
    EXPECT_LE(escaped, 3u) << "of " << kRays;
}

TEST(RayQuery, EmptySceneAndEmptyMesh) {
    Scene scene;
    scene.shapes.push_back(meshShape(TriangleMesh{}));
    scene.shapes.push_back(sphereShape({0, 0, -5}, 1.0f));
    RayQuery query(scene);
    const Hit h = query.intersect(makeRay({0, 0, 0}, {0, 0, -1}));
    ASSERT_TRUE(h.valid());
    EXPECT_EQ(h.shape, 1u);  // ids stay equal to shape indices past an empty mesh
    EXPECT_FALSE(query.intersect(makeRay({0, 0, 0}, {0, 0, 1})).valid());
}

// ---- camera ------------------------------------------------------------------

TEST(Camera, CentreRayLooksAtTarget) {
    Camera cam;
    cam.eye = Vec3(1, 2, 3);
    cam.target = Vec3(4, 2, -1);
    cam.width = 64;
    cam.height = 48;
    const Ray r = cam.generateRay({32, 24});
    expectVecNear(r.origin, cam.eye, 0.0f);
    expectVecNear(r.direction, glm::normalize(cam.target - cam.eye), 1e-6f);
    EXPECT_NEAR(glm::length(r.direction), 1.0f, 1e-6f);
}

TEST(Camera, VerticalFovAndAspect) {
    Camera cam;
    cam.eye = Vec3(0);
    cam.target = Vec3(0, 0, -1);
    cam.up = Vec3(0, 1, 0);
    cam.fovYDegrees = 60.0f;
    cam.width = 200;
    cam.height = 100;
    const float half = 30.0f * kPi / 180.0f;
    // Top edge (raster y = 0) is up, at half the vertical field of view.
    const Ray top = cam.generateRay({100, 0});
    EXPECT_NEAR(std::acos(-top.direction.z), half, 1e-5f);
    EXPECT_GT(top.direction.y, 0.0f);
    const Ray bottom = cam.generateRay({100, 100});
    EXPECT_LT(bottom.direction.y, 0.0f);
    // Right edge: horizontal half-angle atan(aspect * tan(half)), to the camera's right (+x here).
    const Ray right = cam.generateRay({200, 50});
    EXPECT_NEAR(std::atan2(right.direction.x, -right.direction.z), std::atan(2.0f * std::tan(half)), 1e-5f);
    EXPECT_NEAR(right.direction.y, 0.0f, 1e-6f);
}

TEST(Camera, HandednessMatchesMitsubaLookAt) {
    // Looking along +z with +y up (the Cornell box camera), screen right is world -x.
    Camera cam;
    cam.eye = Vec3(0);
    cam.target = Vec3(0, 0, 1);
    cam.up = Vec3(0, 1, 0);
    EXPECT_LT(cam.generateRay({static_cast<float>(cam.width), cam.height * 0.5f}).direction.x, 0.0f);
    EXPECT_GT(cam.generateRay({0.0f, cam.height * 0.5f}).direction.x, 0.0f);
}

TEST(Camera, ProjectInvertsGenerateRay) {
    Camera cam;
    cam.eye = Vec3(0.5f, 1, 5);
    cam.target = Vec3(0, 0.5f, 0);
    cam.up = Vec3(0.1f, 1, 0);
    cam.fovYDegrees = 35.0f;
    cam.width = 320;
    cam.height = 180;
    jobs::Rng rng(5, 0, 0);
    for (int i = 0; i < 500; ++i) {
        const Vec2 raster(rng.uniform() * cam.width, rng.uniform() * cam.height);
        const Ray r = cam.generateRay(raster);
        const float distance = 0.5f + 20.0f * rng.uniform();
        Vec2 back;
        ASSERT_TRUE(cam.project(r.origin + distance * r.direction, &back));
        EXPECT_NEAR(back.x, raster.x, 2e-3f);
        EXPECT_NEAR(back.y, raster.y, 2e-3f);
    }
    // Behind the camera.
    Vec2 unused;
    EXPECT_FALSE(cam.project(cam.eye - (cam.target - cam.eye), &unused));
}

}  // namespace
}  // namespace fg
