// Photon differentials (Frisvad et al. 2014): emission directions and lengths
// (Eqs. 2-6, Appendix A), the filter matrix (Eq. 12), the shading-normal
// derivative, and the propagated differentials against finite differences of
// neighbouring rays traced through real scenes (refraction and reflection).
#include "engine/shading/bsdf.h"
#include "engine/shading/differentials.h"
#include "engine/shading/light.h"
#include "engine/accel/ray_query.h"
#include "engine/scene/scene.h"
#include "jobs/random.h"

#include <glm/gtc/matrix_transform.hpp>
#include <gtest/gtest.h>

#include <cmath>
#include <vector>

namespace fg {
namespace {

// |a x b| / (|a| |b|): the sine of the angle between two vectors.
float parallelism(const Vec3& a, const Vec3& b) {
    return glm::length(glm::cross(a, b)) / (glm::length(a) * glm::length(b));
}

Vec3 randomDirection(jobs::Rng& rng) { return sampleUniformSphere(rng.uniform2()); }

TEST(Differentials, FrisvadBasisIsRightHandedOrthonormal) {
    jobs::Rng rng(7, jobs::streamKey("basis"), 0);
    std::vector<Vec3> normals = {Vec3(0, 0, 1), Vec3(0, 0, -1), Vec3(1, 0, 0), Vec3(0, -1, 0),
                                 glm::normalize(Vec3(1e-3f, 0.0f, -1.0f)), glm::normalize(Vec3(0.0f, 1e-4f, 1.0f))};
    for (int i = 0; i < 5000; ++i) normals.push_back(randomDirection(rng));
    for (const Vec3& n : normals) {
        Vec3 b1, b2;
        frisvadBasis(n, &b1, &b2);
        EXPECT_NEAR(glm::length(b1), 1.0f, 1e-5f) << n.x << " " << n.y << " " << n.z;
        EXPECT_NEAR(glm::length(b2), 1.0f, 1e-5f);
        EXPECT_NEAR(glm::dot(b1, b2), 0.0f, 1e-5f);
        EXPECT_NEAR(glm::dot(b1, n), 0.0f, 1e-5f);
        EXPECT_NEAR(glm::dot(b2, n), 0.0f, 1e-5f);
        EXPECT_LT(glm::length(glm::cross(b1, b2) - n), 2e-5f);
    }
}

TEST(Differentials, InitialLengthsFollowEqs5And6) {
    const float s = 7.0f, area = 0.3f, solidAngle = 2.0f * kPi;
    const double photons = 12345.0;
    EXPECT_NEAR(initialPositionalLength(s, area, photons), 2.0 * s * std::sqrt(area / (M_PI * photons)), 1e-7);
    EXPECT_NEAR(initialDirectionalLength(s, solidAngle, photons), 2.0 * s * std::sqrt(solidAngle / (M_PI * photons)),
                1e-6);
    EXPECT_EQ(initialPositionalLength(s, 0.0f, photons), 0.0f);   // point sources
    EXPECT_EQ(initialDirectionalLength(s, 0.0f, photons), 0.0f);  // collimated sources
}

// Eqs. 2-3: D_u x and D_theta w along n x w, D_v x = D_u x x n, D_phi w =
// D_theta w x w; each pair orthogonal, lengths from Eqs. 5-6.
TEST(Differentials, EmissionDirectionsFollowEqs2And3) {
    jobs::Rng rng(11, jobs::streamKey("emission"), 0);
    const float s = 3.0f, area = 2.0f, solidAngle = 2.0f * kPi;
    const double photons = 1000.0;
    const float positional = initialPositionalLength(s, area, photons);
    const float directional = initialDirectionalLength(s, solidAngle, photons);
    for (int i = 0; i < 1000; ++i) {
        const Vec3 n = randomDirection(rng);
        Vec3 w = randomDirection(rng);
        if (glm::dot(w, n) < 0.0f) w = -w;
        if (glm::length(glm::cross(n, w)) < 1e-2f) continue;
        const PhotonDifferential d = emitPhotonDifferential(w, n, area, solidAngle, photons, s);
        const Vec3 u = glm::normalize(glm::cross(n, w));
        EXPECT_LT(glm::length(d.dxU / positional - u), 1e-5f);
        EXPECT_LT(glm::length(d.dwU / directional - u), 1e-5f);
        EXPECT_LT(glm::length(d.dxV / positional - glm::cross(u, n)), 1e-5f);
        EXPECT_LT(glm::length(d.dwV / directional - glm::cross(u, w)), 1e-5f);
        EXPECT_NEAR(glm::length(d.dxU), positional, 1e-5f * positional);
        EXPECT_NEAR(glm::length(d.dxV), positional, 1e-5f * positional);
        EXPECT_NEAR(glm::length(d.dwU), directional, 1e-5f * directional);
        EXPECT_NEAR(glm::length(d.dwV), directional, 1e-5f * directional);
        // The uv-basis spans the tangent plane, the theta-phi-basis the plane perpendicular to w.
        EXPECT_NEAR(glm::dot(d.dxU, n), 0.0f, 1e-5f * positional);
        EXPECT_NEAR(glm::dot(d.dxV, n), 0.0f, 1e-5f * positional);
        EXPECT_NEAR(glm::dot(d.dxU, d.dxV), 0.0f, 1e-5f * positional * positional);
        EXPECT_NEAR(glm::dot(d.dwU, w), 0.0f, 1e-5f * directional);
        EXPECT_NEAR(glm::dot(d.dwV, w), 0.0f, 1e-5f * directional);
        EXPECT_NEAR(glm::dot(d.dwU, d.dwV), 0.0f, 1e-5f * directional * directional);
    }
}

// Appendix A: after the first transfer (Eqs. 8-9) D_theta x' = t' |D_theta w| /
// |D_u x| D_u x', and D_v x' is parallel to D_phi x', on any receiving plane.
// A basis rotated away from Eqs. 2-3 does not have this property.
TEST(Differentials, PairsAreParallelAfterFirstTransfer) {
    jobs::Rng rng(12, jobs::streamKey("appendix-a"), 0);
    int rotatedNotParallel = 0, tried = 0;
    for (int i = 0; i < 1000; ++i) {
        const Vec3 n = randomDirection(rng);
        Vec3 w = randomDirection(rng);
        if (glm::dot(w, n) < 0.0f) w = -w;
        Vec3 receiver = randomDirection(rng);
        if (glm::length(glm::cross(n, w)) < 1e-2f || std::abs(glm::dot(receiver, w)) < 0.1f) continue;
        const float t = 0.1f + 5.0f * rng.uniform();
        const PhotonDifferential d = emitPhotonDifferential(w, n, 1.0f, 2.0f * kPi, 100.0, 1.0f);
        const Vec3 dux = transferPositional(d.dxU, w, receiver);
        const Vec3 dvx = transferPositional(d.dxV, w, receiver);
        const Vec3 dthetax = transferDirectional(d.dwU, t, w, receiver);
        const Vec3 dphix = transferDirectional(d.dwV, t, w, receiver);
        const Vec3 expectedTheta = t * glm::length(d.dwU) / glm::length(d.dxU) * dux;
        EXPECT_LT(glm::length(dthetax - expectedTheta), 1e-4f * glm::length(expectedTheta));
        EXPECT_LT(parallelism(dvx, dphix), 1e-4f);
        // Transferred vectors lie in the receiving plane.
        EXPECT_NEAR(glm::dot(dux, receiver), 0.0f, 1e-4f * glm::length(dux));
        EXPECT_NEAR(glm::dot(dthetax, receiver), 0.0f, 1e-4f * glm::length(dthetax));

        // Rotate the positional pair by 30 degrees within the tangent plane.
        const float c = std::cos(0.5236f), sn = std::sin(0.5236f);
        const Vec3 rotatedU = c * d.dxU + sn * d.dxV;
        ++tried;
        if (parallelism(transferPositional(rotatedU, w, receiver), dthetax) > 1e-2f) ++rotatedNotParallel;
    }
    EXPECT_GT(tried, 500);
    EXPECT_GT(rotatedNotParallel, tried * 9 / 10);
}

TEST(Differentials, EmissionFallbacksGiveValidBases) {
    const float s = 2.0f;
    const double photons = 500.0;
    const float positional = initialPositionalLength(s, 1.5f, photons);
    const float directional = initialDirectionalLength(s, 2.0f * kPi, photons);
    const Vec3 n = glm::normalize(Vec3(0.3f, -0.2f, 0.9f));
    // Emission along the normal, exactly and nearly.
    for (const Vec3& w : {n, glm::normalize(n + Vec3(1e-5f, 0.0f, 0.0f)), -n}) {
        const PhotonDifferential d = emitPhotonDifferential(w, n, 1.5f, 2.0f * kPi, photons, s);
        EXPECT_NEAR(glm::length(d.dxU), positional, 1e-4f * positional);
        EXPECT_NEAR(glm::length(d.dxV), positional, 1e-4f * positional);
        EXPECT_NEAR(glm::length(d.dwU), directional, 1e-4f * directional);
        EXPECT_NEAR(glm::length(d.dwV), directional, 1e-4f * directional);
        EXPECT_NEAR(glm::dot(d.dxU, n), 0.0f, 1e-4f * positional);
        EXPECT_NEAR(glm::dot(d.dxV, n), 0.0f, 1e-4f * positional);
        EXPECT_NEAR(glm::dot(d.dxU, d.dxV), 0.0f, 1e-4f * positional * positional);
        EXPECT_NEAR(glm::dot(d.dwU, w), 0.0f, 1e-4f * directional);
        EXPECT_NEAR(glm::dot(d.dwV, w), 0.0f, 1e-4f * directional);
        EXPECT_NEAR(glm::dot(d.dwU, d.dwV), 0.0f, 1e-4f * directional * directional);
        // The pairs still agree: D_u x parallel to D_theta w.
        EXPECT_LT(parallelism(d.dxU, d.dwU), 1e-3f);
    }
    // A point source: no normal, zero positional vectors.
    const Vec3 w = glm::normalize(Vec3(-0.4f, 0.1f, -0.7f));
    const PhotonDifferential point = emitPhotonDifferential(w, Vec3(0.0f), 0.0f, 4.0f * kPi, photons, s);
    EXPECT_EQ(point.dxU, Vec3(0.0f));
    EXPECT_EQ(point.dxV, Vec3(0.0f));
    const float pointDirectional = initialDirectionalLength(s, 4.0f * kPi, photons);
    EXPECT_NEAR(glm::length(point.dwU), pointDirectional, 1e-4f * pointDirectional);
    EXPECT_NEAR(glm::length(point.dwV), pointDirectional, 1e-4f * pointDirectional);
    EXPECT_NEAR(glm::dot(point.dwU, w), 0.0f, 1e-5f);
    EXPECT_NEAR(glm::dot(point.dwV, w), 0.0f, 1e-5f);
    EXPECT_NEAR(glm::dot(point.dwU, point.dwV), 0.0f, 1e-5f);
    // Collimated light: the source's "normal" is the direction, no directional vectors.
    const PhotonDifferential collimated = emitPhotonDifferential(w, w, 3.0f, 0.0f, photons, s);
    EXPECT_EQ(collimated.dwU, Vec3(0.0f));
    EXPECT_EQ(collimated.dwV, Vec3(0.0f));
    EXPECT_GT(footprintArea(collimated.dxU, collimated.dxV), 0.0f);
}

// §3.1: the initial footprints of the N_e photons of a source add up to s^2 A_e,
// and their solid angles to s^2 omega_e.
TEST(Differentials, InitialFootprintsSumToSmoothingSquaredTimesArea) {
    Shape disk;
    TriangleMesh diskMesh = makeDiskMesh(64);
    diskMesh.transform(glm::translate(Mat4(1.0f), Vec3(0.5f, 0.0f, 2.0f)) *
                       glm::rotate(Mat4(1.0f), 2.0f, Vec3(1, 1, 0)) * glm::scale(Mat4(1.0f), Vec3(0.7f)));
    disk.geometry = diskMesh;
    Shape ball;
    ball.geometry = Sphere{Vec3(1.0f, 2.0f, 3.0f), 0.4f};
    const float s = 6.0f;
    const int photons = 20000;
    for (const auto& light : {makeAreaLight(disk, Rgb(1.0f)), makeAreaLight(ball, Rgb(1.0f), true)}) {
        jobs::Rng rng(3, jobs::streamKey("footprints"), 0);
        double areaSum = 0.0, solidAngleSum = 0.0;
        float emitterArea = 0.0f, emitterSolidAngle = 0.0f;
        for (int i = 0; i < photons; ++i) {
            const Vec2 uPos = rng.uniform2();
            const Vec2 uDir = rng.uniform2();
            const auto e = light->sampleEmission(uPos, uDir);
            ASSERT_TRUE(e.has_value());
            emitterArea = e->emitterArea;
            emitterSolidAngle = e->emitterSolidAngle;
            const PhotonDifferential d =
                emitPhotonDifferential(e->direction, e->normal, e->emitterArea, e->emitterSolidAngle, photons, s);
            areaSum += footprintArea(d.dxU, d.dxV);
            solidAngleSum += photonSolidAngle(d.dwU, d.dwV);
        }
        EXPECT_GT(emitterArea, 0.0f);
        EXPECT_NEAR(areaSum, s * s * emitterArea, 1e-3 * s * s * emitterArea);
        EXPECT_NEAR(solidAngleSum, s * s * emitterSolidAngle, 1e-3 * s * s * emitterSolidAngle);
    }
}

// Eq. 12 against the inverse of the change of basis [1/2 D_u x, 1/2 D_v x, n].
TEST(Differentials, FilterMatrixIsTopOfInverseChangeOfBasis) {
    jobs::Rng rng(5, jobs::streamKey("filter"), 0);
    for (int i = 0; i < 1000; ++i) {
        const Vec3 n = randomDirection(rng);
        Vec3 b1, b2;
        frisvadBasis(n, &b1, &b2);
        // Skewed, anisotropic footprints in the tangent plane (i even) or anywhere (i odd).
        Vec3 dxU = (0.01f + rng.uniform()) * (b1 + (rng.uniform() - 0.5f) * b2);
        Vec3 dxV = (0.01f + rng.uniform()) * (b2 + (rng.uniform() - 0.5f) * b1);
        if (i % 2) {
            dxU += 0.3f * (rng.uniform() - 0.5f) * n;
            dxV += 0.3f * (rng.uniform() - 0.5f) * n;
        }
        const FootprintFilter m = footprintFilter(dxU, dxV, n);
        const Vec2 a = m.apply(0.5f * dxU);
        const Vec2 b = m.apply(0.5f * dxV);
        EXPECT_NEAR(a.x, 1.0f, 1e-4f);
        EXPECT_NEAR(a.y, 0.0f, 1e-4f);
        EXPECT_NEAR(b.x, 0.0f, 1e-4f);
        EXPECT_NEAR(b.y, 1.0f, 1e-4f);
        EXPECT_NEAR(glm::length(m.apply(n)), 0.0f, 1e-4f * glm::length(m.row0) + 1e-4f);
        const Mat3 inverse = glm::inverse(Mat3(0.5f * dxU, 0.5f * dxV, n));  // columns
        const Vec3 row0(inverse[0][0], inverse[1][0], inverse[2][0]);
        const Vec3 row1(inverse[0][1], inverse[1][1], inverse[2][1]);
        EXPECT_LT(glm::length(m.row0 - row0), 1e-3f * glm::length(row0));
        EXPECT_LT(glm::length(m.row1 - row1), 1e-3f * glm::length(row1));
        // Points on the footprint ellipse map onto the unit circle.
        const float angle = 2.0f * kPi * rng.uniform();
        const Vec3 boundary = 0.5f * std::cos(angle) * dxU + 0.5f * std::sin(angle) * dxV;
        EXPECT_NEAR(glm::length(m.apply(boundary)), 1.0f, 1e-4f);
    }
}

// Eqs. 4, 11 and 12 together: pi K(|M (x - x_p)|) / A_p integrates to 1 over the
// tangent plane, so every splat deposits exactly the photon's flux.
TEST(Differentials, NormalisedKernelOverFootprintIntegratesToOne) {
    const Vec3 n = glm::normalize(Vec3(0.2f, 0.3f, 1.0f));
    Vec3 b1, b2;
    frisvadBasis(n, &b1, &b2);
    const Vec3 dxU = 0.8f * b1 + 0.3f * b2;
    const Vec3 dxV = -0.2f * b1 + 0.4f * b2;
    const FootprintFilter m = footprintFilter(dxU, dxV, n);
    const float area = footprintArea(dxU, dxV);
    const int steps = 800;
    const float extent = 1.0f, h = 2.0f * extent / steps;
    double integral = 0.0;
    for (int i = 0; i < steps; ++i)
        for (int j = 0; j < steps; ++j) {
            const Vec3 y = (-extent + (i + 0.5f) * h) * b1 + (-extent + (j + 0.5f) * h) * b2;
            integral += kPi * silvermanKernel(glm::length(m.apply(y))) / area * h * h;
        }
    EXPECT_NEAR(integral, 1.0, 2e-3);
}

TEST(Differentials, CollapsedFootprintsAreDetected) {
    const Vec3 n(0, 0, 1);
    EXPECT_FALSE(footprintCollapsed(Vec3(1, 0, 0), Vec3(0, 1, 0), n));
    EXPECT_FALSE(footprintCollapsed(Vec3(1e-20f, 0, 0), Vec3(0, 1e-20f, 0), n));  // tiny but well shaped
    EXPECT_FALSE(footprintCollapsed(Vec3(1, 0, 0), Vec3(1, 1e-3f, 0), n));
    EXPECT_TRUE(footprintCollapsed(Vec3(1, 0, 0), Vec3(2, 0, 0), n));
    EXPECT_TRUE(footprintCollapsed(Vec3(1, 0, 0), Vec3(0.0f), n));
    EXPECT_TRUE(footprintCollapsed(Vec3(0, 0, 1), Vec3(0, 1, 0), Vec3(0, 1, 0)));
    EXPECT_TRUE(footprintCollapsed(Vec3(NAN, 0, 0), Vec3(0, 1, 0), n));
    EXPECT_TRUE(footprintCollapsed(Vec3(INFINITY, 0, 0), Vec3(0, 1, 0), n));
}

// ---------------------------------------------------------------------------
// Against neighbouring rays in real scenes.

int addBsdf(Scene& scene, std::shared_ptr<Bsdf> bsdf) {
    scene.bsdfs.push_back(std::move(bsdf));
    return static_cast<int>(scene.bsdfs.size()) - 1;
}

int addDiffuse(Scene& scene) { return addBsdf(scene, makeDiffuse(makeConstantTexture(Rgb(0.5f)))); }
int addMirror(Scene& scene) { return addBsdf(scene, makeConductor(*conductorPreset("none"))); }

void addShape(Scene& scene, decltype(Shape::geometry) geometry, int bsdf, bool flip = false) {
    Shape shape;
    shape.geometry = std::move(geometry);
    shape.bsdf = bsdf;
    shape.flipNormals = flip;
    scene.shapes.push_back(std::move(shape));
}

// A large rectangle through `center` facing `normal`.
TriangleMesh plane(const Vec3& center, const Vec3& normal, float halfSize) {
    TriangleMesh mesh = makeRectangleMesh();
    const Vec3 z(0, 0, 1);
    const Vec3 axis = glm::cross(z, normal);
    Mat4 rotation(1.0f);
    if (glm::length(axis) > 1e-6f) rotation = glm::rotate(Mat4(1.0f), std::acos(glm::dot(z, normal)), axis);
    else if (normal.z < 0.0f) rotation = glm::rotate(Mat4(1.0f), kPi, Vec3(1, 0, 0));
    mesh.transform(glm::translate(Mat4(1.0f), center) * rotation * glm::scale(Mat4(1.0f), Vec3(halfSize)));
    return mesh;
}

struct ChainEnd {
    bool reached = false;
    Vec3 position{0.0f};   // hit on the first smooth surface
    Vec3 direction{0.0f};  // the direction that arrived there
    std::vector<std::uint32_t> shapes;  // specular surfaces crossed, in order
};

// Follows a ray through specular surfaces (transmission preferred at dielectrics)
// until it hits a smooth one, carrying the differential along when given.
ChainEnd traceSpecularChain(const Scene& scene, const RayQuery& rays, Vec3 origin, Vec3 direction,
                            PhotonDifferential* differential) {
    ChainEnd end;
    Vec3 previous = origin;
    Ray ray{origin, direction, kInfinity};
    for (int event = 0; event < 8; ++event) {
        const Hit hit = rays.intersect(ray);
        if (!hit.valid()) return end;
        const SurfacePoint sp = rays.surface(ray, hit);
        if (differential) transferDifferential(*differential, direction, glm::dot(sp.p - previous, direction), sp.ng);
        previous = sp.p;
        const Bsdf& bsdf = *scene.bsdfs[static_cast<std::size_t>(scene.shapes[sp.shape].bsdf)];
        if (bsdf.hasSmoothLobe()) {
            end.reached = true;
            end.position = sp.p;
            end.direction = direction;
            return end;
        }
        const Frame frame(sp.ns);
        const auto bs = bsdf.sample(frame.toLocal(-direction), sp.uv, 0.999999f, Vec2(0.5f), TransportMode::Importance);
        if (!bs) return end;
        const Vec3 wi = frame.toWorld(bs->wi);
        if (differential) {
            const Vec3 dnU = rays.shadingNormalDifferential(ray, hit, differential->dxU);
            const Vec3 dnV = rays.shadingNormalDifferential(ray, hit, differential->dxV);
            EXPECT_TRUE(scatterDifferential(*differential, direction, wi, sp.ns, dnU, dnV, *bs));
        }
        end.shapes.push_back(sp.shape);
        direction = wi;
        ray = Ray{offsetRayOrigin(sp.p, sp.ng, wi), wi, kInfinity};
    }
    return end;
}

struct FiniteDifferenceError {
    float positional = 0.0f;
    float directional = 0.0f;
};

// Relative errors of (x(eps) - x(0)) / eps against the propagated differential,
// for the ray offset along (dxU, dwU) (useV = false) or (dxV, dwV).
FiniteDifferenceError compareWithNeighbour(const Scene& scene, const RayQuery& rays, const Vec3& origin,
                                           const Vec3& direction, const PhotonDifferential& emitted, bool useV,
                                           float eps, std::size_t expectedEvents) {
    PhotonDifferential d = emitted;
    const ChainEnd centre = traceSpecularChain(scene, rays, origin, direction, &d);
    const Vec3 dx0 = useV ? emitted.dxV : emitted.dxU;
    const Vec3 dw0 = useV ? emitted.dwV : emitted.dwU;
    const ChainEnd offset =
        traceSpecularChain(scene, rays, origin + eps * dx0, glm::normalize(direction + eps * dw0), nullptr);
    EXPECT_TRUE(centre.reached && offset.reached);
    EXPECT_EQ(centre.shapes.size(), expectedEvents);
    EXPECT_EQ(centre.shapes, offset.shapes);
    const Vec3 dx = useV ? d.dxV : d.dxU;
    const Vec3 dw = useV ? d.dwV : d.dwU;
    const Vec3 fdx = (offset.position - centre.position) / eps;
    const Vec3 fdw = (offset.direction - centre.direction) / eps;
    return {glm::length(fdx - dx) / glm::length(dx), glm::length(fdw - dw) / glm::length(dw)};
}

// Checks first-order agreement for both parameters: the relative error of the
// one-sided difference is small, and it falls in proportion to the step (to a
// quarter for a quarter of the step) until rounding takes over, which a wrong
// derivative would not do.
void expectFirstOrderAgreement(const Scene& scene, const Vec3& origin, const Vec3& direction,
                               const PhotonDifferential& emitted, std::size_t expectedEvents, float tolerance) {
    const RayQuery rays(scene);
    const float roundingFloor = 1e-3f;
    for (bool useV : {false, true}) {
        SCOPED_TRACE(useV ? "v" : "u");
        const float scale = glm::length(useV ? emitted.dxV : emitted.dxU) + glm::length(useV ? emitted.dwV : emitted.dwU);
        const float coarse = 4e-3f / scale, fine = 1e-3f / scale;
        const FiniteDifferenceError a =
            compareWithNeighbour(scene, rays, origin, direction, emitted, useV, coarse, expectedEvents);
        const FiniteDifferenceError b =
            compareWithNeighbour(scene, rays, origin, direction, emitted, useV, fine, expectedEvents);
        EXPECT_LT(b.positional, tolerance);
        EXPECT_LT(b.directional, tolerance);
        EXPECT_TRUE(b.positional < 0.4f * a.positional || b.positional < roundingFloor)
            << a.positional << " -> " << b.positional;
        EXPECT_TRUE(b.directional < 0.4f * a.directional || b.directional < roundingFloor)
            << a.directional << " -> " << b.directional;
    }
}

// Emission from a disk source facing down at `lightCenter`, aimed at `target`.
PhotonDifferential emitTowards(const Vec3& origin, const Vec3& target, Vec3* direction) {
    *direction = glm::normalize(target - origin);
    return emitPhotonDifferential(*direction, Vec3(0, 0, -1), kPi * 0.25f, 2.0f * kPi, 1.0, 1.0f);
}

TEST(DifferentialsAgainstNeighbours, GlassSphereTwoRefractions) {
    Scene scene;
    addShape(scene, Sphere{Vec3(0.0f), 1.0f}, addBsdf(scene, makeDielectric(1.5f)));
    addShape(scene, plane(Vec3(0, 0, -1.05f), Vec3(0, 0, 1), 10.0f), addDiffuse(scene));
    const Vec3 origin(0.2f, 0.1f, 3.0f);
    Vec3 direction;
    const PhotonDifferential emitted = emitTowards(origin, Vec3(0.45f, -0.3f, 0.8f), &direction);
    expectFirstOrderAgreement(scene, origin, direction, emitted, 2, 0.02f);
}

TEST(DifferentialsAgainstNeighbours, FlatMirror) {
    Scene scene;
    addShape(scene, plane(Vec3(0, 0, 0), glm::normalize(Vec3(0.3f, 0.1f, 1.0f)), 5.0f), addMirror(scene));
    addShape(scene, plane(Vec3(3.0f, 0, 0), Vec3(-1, 0, 0), 10.0f), addDiffuse(scene));
    const Vec3 origin(-0.5f, 0.2f, 2.0f);
    Vec3 direction;
    const PhotonDifferential emitted = emitTowards(origin, Vec3(0.2f, 0.1f, 0.0f), &direction);
    expectFirstOrderAgreement(scene, origin, direction, emitted, 1, 0.02f);
}

TEST(DifferentialsAgainstNeighbours, CurvedSphereMirror) {
    Scene scene;
    addShape(scene, Sphere{Vec3(0.0f), 1.0f}, addMirror(scene));
    addShape(scene, plane(Vec3(3.0f, 0, 0), Vec3(-1, 0, 0), 10.0f), addDiffuse(scene));
    const Vec3 origin(0.3f, 0.1f, 3.0f);
    Vec3 direction;
    const PhotonDifferential emitted = emitTowards(origin, Vec3(0.5f, 0.2f, 0.84f), &direction);
    expectFirstOrderAgreement(scene, origin, direction, emitted, 1, 0.02f);
}

// Inside a mirrored sphere of radius 2 (normals flipped inwards): a chord at
// distance 1 from the centre spans 120 degrees, so the ray from (1, 0, 0) along
// +y reflects at 60 and 180 degrees and then crosses a small receiver placed
// across the third chord's midpoint.
TEST(DifferentialsAgainstNeighbours, InsideSphereMirrorTwoReflections) {
    Scene scene;
    addShape(scene, Sphere{Vec3(0.0f), 2.0f}, addMirror(scene), true);
    const Vec3 thirdChord(0.5f * std::sqrt(3.0f), -0.5f, 0.0f);
    addShape(scene, plane(Vec3(-0.5f, -0.5f * std::sqrt(3.0f), 0.0f), -thirdChord, 0.3f), addDiffuse(scene));
    const Vec3 origin(1.0f, 0.0f, 0.0f);
    const Vec3 direction(0.0f, 1.0f, 0.0f);
    const PhotonDifferential emitted =
        emitPhotonDifferential(direction, glm::normalize(Vec3(0.3f, 1.0f, 0.2f)), 0.05f, 2.0f * kPi, 1.0, 1.0f);
    expectFirstOrderAgreement(scene, origin, direction, emitted, 2, 0.02f);
}

// A mirror mesh with interpolated vertex normals: the shading normal turns
// across the triangle, which bends the reflected beam.
TEST(DifferentialsAgainstNeighbours, SmoothShadedMeshMirror) {
    Scene scene;
    TriangleMesh mesh;
    mesh.positions = {Vec3(-2, -2, 0), Vec3(2, -2, 0), Vec3(2, 2, 0), Vec3(-2, 2, 0)};
    mesh.normals = {glm::normalize(Vec3(-0.4f, -0.3f, 1.0f)), glm::normalize(Vec3(0.5f, -0.2f, 1.0f)),
                    glm::normalize(Vec3(0.3f, 0.4f, 1.0f)), glm::normalize(Vec3(-0.2f, 0.5f, 1.0f))};
    mesh.indices = {0, 1, 2, 0, 2, 3};
    addShape(scene, mesh, addMirror(scene));
    addShape(scene, plane(Vec3(0, 0, 3.0f), Vec3(0, 0, -1), 20.0f), addDiffuse(scene));
    const Vec3 origin(-0.3f, 0.2f, 1.5f);
    Vec3 direction;
    const PhotonDifferential emitted = emitTowards(origin, Vec3(0.6f, -0.4f, 0.0f), &direction);
    expectFirstOrderAgreement(scene, origin, direction, emitted, 1, 0.02f);
}

// The shading-normal derivative against the normals of nearby hits.
TEST(Differentials, ShadingNormalDifferentialMatchesNeighbouringHits) {
    Scene scene;
    addShape(scene, Sphere{Vec3(0.0f, 0.0f, 0.0f), 0.7f}, addMirror(scene));
    addShape(scene, Sphere{Vec3(0.0f, 0.0f, 0.0f), 3.0f}, addMirror(scene), true);
    TriangleMesh smooth;
    smooth.positions = {Vec3(-1, -1, -1.5f), Vec3(1, -1, -1.5f), Vec3(0, 1, -1.4f)};
    smooth.normals = {glm::normalize(Vec3(-0.5f, -0.3f, 1.0f)), glm::normalize(Vec3(0.4f, -0.2f, 1.0f)),
                      glm::normalize(Vec3(0.0f, 0.6f, 1.0f))};
    smooth.indices = {0, 1, 2};
    addShape(scene, smooth, addMirror(scene));
    TriangleMesh flat = smooth;
    flat.normals.clear();
    for (Vec3& p : flat.positions) p.z -= 0.5f;
    addShape(scene, flat, addMirror(scene));
    const RayQuery rays(scene);

    struct Probe {
        Vec3 origin, target;
        std::uint32_t shape;
    };
    const std::vector<Probe> probes = {
        {Vec3(0.3f, 0.2f, 2.0f), Vec3(0.2f, 0.1f, 0.0f), 0},    // outside of the small sphere
        {Vec3(0.0f, 0.0f, 1.0f), Vec3(1.0f, 2.0f, 2.0f), 1},    // inside of the flipped sphere
        {Vec3(0.1f, -0.2f, -0.75f), Vec3(0.05f, -0.3f, -2.0f), 2},  // smooth triangle, below the small sphere
        {Vec3(0.1f, -0.2f, -1.7f), Vec3(0.05f, -0.3f, -2.5f), 3},   // flat triangle, below the smooth one
    };
    for (const Probe& probe : probes) {
        SCOPED_TRACE(probe.shape);
        const Vec3 origin = probe.origin;
        const Ray ray{origin, glm::normalize(probe.target - origin), kInfinity};
        const Hit hit = rays.intersect(ray);
        ASSERT_TRUE(hit.valid());
        ASSERT_EQ(hit.shape, probe.shape);
        const SurfacePoint sp = rays.surface(ray, hit);
        Vec3 b1, b2;
        frisvadBasis(sp.ng, &b1, &b2);
        for (const Vec3& tangent : {b1, b2, glm::normalize(b1 + 0.5f * b2)}) {
            const float eps = 1e-3f;
            const Ray neighbour{origin, glm::normalize(sp.p + eps * tangent - origin), kInfinity};
            const Hit nearHit = rays.intersect(neighbour);
            ASSERT_EQ(nearHit.shape, probe.shape);
            const SurfacePoint nearSp = rays.surface(neighbour, nearHit);
            const Vec3 dp = nearSp.p - sp.p;
            const Vec3 predicted = rays.shadingNormalDifferential(ray, hit, dp);
            const Vec3 actual = nearSp.ns - sp.ns;
            if (probe.shape == 3) {
                EXPECT_EQ(predicted, Vec3(0.0f));
                continue;
            }
            EXPECT_GT(glm::length(actual), 1e-4f);
            EXPECT_LT(glm::length(predicted - actual), 0.02f * glm::length(actual));
        }
    }
}

}  // namespace
}  // namespace fg
