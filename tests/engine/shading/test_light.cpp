#include "engine/shading/light.h"

#include "jobs/random.h"
#include "tests/support/chi2.h"

#include <glm/gtc/matrix_transform.hpp>
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <string>
#include <functional>
#include <optional>
#include <vector>

namespace fg {
namespace {

// ---------------------------------------------------------------------------
// Helpers written independently of the engine's light code.

struct Hit {
    Vec3 p;
    Vec3 n;
};

// Nearest hit of a ray with a triangle mesh (Moller-Trumbore); the normal follows the winding.
std::optional<Hit> intersectMesh(const TriangleMesh& mesh, const Vec3& o, const Vec3& d) {
    std::optional<Hit> best;
    float bestT = 1e30f;
    for (std::size_t t = 0; t + 2 < mesh.indices.size(); t += 3) {
        const Vec3 a = mesh.positions[mesh.indices[t]];
        const Vec3 b = mesh.positions[mesh.indices[t + 1]];
        const Vec3 c = mesh.positions[mesh.indices[t + 2]];
        const Vec3 e1 = b - a, e2 = c - a;
        const Vec3 pv = glm::cross(d, e2);
        const float det = glm::dot(e1, pv);
        if (std::abs(det) < 1e-12f) continue;
        const Vec3 tv = o - a;
        const float u = glm::dot(tv, pv) / det;
        if (u < 0.0f || u > 1.0f) continue;
        const Vec3 qv = glm::cross(tv, e1);
        const float v = glm::dot(d, qv) / det;
        if (v < 0.0f || u + v > 1.0f) continue;
        const float dist = glm::dot(e2, qv) / det;
        if (dist > 0.0f && dist < bestT) {
            bestT = dist;
            best = Hit{o + dist * d, glm::normalize(glm::cross(e1, e2))};
        }
    }
    return best;
}

std::optional<Hit> intersectSphere(const Sphere& s, const Vec3& o, const Vec3& d, bool inwards) {
    const glm::dvec3 oc = glm::dvec3(o) - glm::dvec3(s.center);
    const glm::dvec3 dd(d);
    const double b = glm::dot(oc, dd);
    const double c = glm::dot(oc, oc) - double(s.radius) * s.radius;
    const double disc = b * b - c;
    if (disc < 0.0) return std::nullopt;
    const double root = std::sqrt(disc);
    double t = -b - root;
    if (t <= 0.0) t = -b + root;
    if (t <= 0.0) return std::nullopt;
    const Vec3 p = o + static_cast<float>(t) * d;
    const Vec3 outward = glm::normalize(p - s.center);
    return Hit{p, inwards ? -outward : outward};
}

TriangleMesh transformed(TriangleMesh mesh, const Mat4& m) {
    mesh.transform(m);
    return mesh;
}

Shape meshShape(const TriangleMesh& mesh) {
    Shape s;
    s.geometry = mesh;
    return s;
}

Shape sphereShape(const Vec3& center, float radius, bool inwards = false) {
    Shape s;
    s.geometry = Sphere{center, radius};
    s.flipNormals = inwards;
    return s;
}

struct Estimate {
    Rgb mean{0.0f};
    Rgb stdErr{0.0f};
};

Estimate meanOf(int n, std::uint64_t seed, const std::function<Rgb(jobs::Rng&)>& f) {
    jobs::Rng rng(seed, jobs::streamKey("light-test"), 0);
    glm::dvec3 sum(0.0), sum2(0.0);
    for (int i = 0; i < n; ++i) {
        const glm::dvec3 v(f(rng));
        sum += v;
        sum2 += v * v;
    }
    const glm::dvec3 mean = sum / double(n);
    const glm::dvec3 var = glm::max(sum2 / double(n) - mean * mean, glm::dvec3(0.0));
    return {Rgb(mean), Rgb(glm::sqrt(var / double(n)))};
}

// Irradiance at (ref, normal) by next-event estimation with the light's own sampling.
Estimate irradianceNee(const Light& light, const Vec3& ref, const Vec3& normal, int n, std::uint64_t seed = 1) {
    return meanOf(n, seed, [&](jobs::Rng& rng) {
        const auto s = light.sampleLi(ref, rng.uniform2());
        if (!s) return Rgb(0.0f);
        return s->value * std::max(0.0f, glm::dot(normal, s->wi)) / s->pdf;
    });
}

// Mean irradiance over a one-sided receiver disk measured with emitted photons.
Estimate irradiancePhotons(const Light& light, const Vec3& center, const Vec3& normal, float radius, int n,
                           std::uint64_t seed = 2) {
    const float area = kPi * radius * radius;
    return meanOf(n, seed, [&](jobs::Rng& rng) {
        const Vec2 uPos = rng.uniform2();
        const auto e = light.sampleEmission(uPos, rng.uniform2());
        if (!e) return Rgb(0.0f);
        const float cosIn = glm::dot(e->direction, normal);
        if (cosIn >= 0.0f) return Rgb(0.0f);
        const float t = glm::dot(center - e->origin, normal) / cosIn;
        if (t <= 0.0f) return Rgb(0.0f);
        const Vec3 hit = e->origin + t * e->direction;
        if (glm::length(hit - center) > radius) return Rgb(0.0f);
        return e->flux / area;
    });
}

void expectClose(const Estimate& e, const Rgb& expected, float relTolerance, const std::string& what) {
    for (int c = 0; c < 3; ++c) {
        const float tolerance = 5.0f * e.stdErr[c] + relTolerance * std::abs(expected[c]) + 1e-6f;
        EXPECT_NEAR(e.mean[c], expected[c], tolerance) << what << ", channel " << c << ", std. error " << e.stdErr[c];
    }
}

// Form factor from a differential area to a parallel a x b rectangle with one corner
// straight above it at distance h (standard radiative-transfer tables).
double cornerFormFactor(double a, double b, double h) {
    const double x = a / h, y = b / h;
    const double sx = std::sqrt(1.0 + x * x), sy = std::sqrt(1.0 + y * y);
    return (x / sx * std::atan(y / sx) + y / sy * std::atan(x / sy)) / (2.0 * M_PI);
}

// ---------------------------------------------------------------------------
// Area lights.

TriangleMesh rectangleLightMesh() {
    // [-1, 1] x [-0.5, 0.5] at z = 0, facing +z.
    return transformed(makeRectangleMesh(), glm::scale(Mat4(1.0f), Vec3(1.0f, 0.5f, 1.0f)));
}

TEST(AreaLight, RectangleSamplingMatchesPdfChi2) {
    const TriangleMesh mesh = rectangleLightMesh();
    const auto light = makeAreaLight(meshShape(mesh), Rgb(1.0f));
    const std::vector<Vec3> refs{{0.0f, 0.0f, 1.0f}, {0.7f, -0.3f, 0.4f}, {2.5f, 0.4f, 0.15f}, {-0.2f, 0.1f, 0.05f}};
    for (const Vec3& ref : refs) {
        test::Chi2Config config;
        config.testCount = static_cast<int>(refs.size());
        config.samples = 300'000;
        const auto result = test::chi2SphereTest(
            [&](const Vec2& u) -> std::optional<Vec3> {
                const auto s = light->sampleLi(ref, u);
                if (!s) return std::nullopt;
                return s->wi;
            },
            [&](const Vec3& w) -> double {
                const auto hit = intersectMesh(mesh, ref, w);
                return hit ? light->pdfLi(ref, hit->p, hit->n, w) : 0.0;
            },
            config);
        EXPECT_TRUE(result.passed) << "ref (" << ref.x << ", " << ref.y << ", " << ref.z << "): " << result.message;
    }
}

TEST(AreaLight, SphereSamplingMatchesPdfChi2) {
    const Sphere sphere{Vec3(0.2f, -0.1f, 0.3f), 0.8f};
    struct Case {
        Vec3 ref;
        bool inwards;
    };
    const std::vector<Case> cases{{{0.0f, 0.0f, 3.0f}, false},
                                  {{2.0f, 1.0f, -1.5f}, false},
                                  {{-0.9f, 0.4f, 0.9f}, false},
                                  {{0.1f, 0.2f, 0.1f}, true}};
    for (const Case& c : cases) {
        const auto light = makeAreaLight(sphereShape(sphere.center, sphere.radius, c.inwards), Rgb(1.0f));
        test::Chi2Config config;
        config.testCount = static_cast<int>(cases.size());
        config.samples = 300'000;
        const auto result = test::chi2SphereTest(
            [&](const Vec2& u) -> std::optional<Vec3> {
                const auto s = light->sampleLi(c.ref, u);
                if (!s) return std::nullopt;
                return s->wi;
            },
            [&](const Vec3& w) -> double {
                const auto hit = intersectSphere(sphere, c.ref, w, c.inwards);
                return hit ? light->pdfLi(c.ref, hit->p, hit->n, w) : 0.0;
            },
            config);
        EXPECT_TRUE(result.passed) << "ref (" << c.ref.x << ", " << c.ref.y << ", " << c.ref.z
                                   << "): " << result.message;
    }
}

TEST(AreaLight, PdfLiReproducesSampleLiExactly) {
    const auto rectangle = makeAreaLight(meshShape(rectangleLightMesh()), Rgb(1.0f));
    const auto outer = makeAreaLight(sphereShape(Vec3(0.0f), 1.0f), Rgb(1.0f));
    const auto inner = makeAreaLight(sphereShape(Vec3(0.0f), 1.0f, true), Rgb(1.0f));
    jobs::Rng rng(4, jobs::streamKey("pdf-consistency"), 0);
    for (int i = 0; i < 2000; ++i) {
        const struct {
            const Light* light;
            Vec3 ref;
        } cases[] = {{rectangle.get(), Vec3(0.3f, 0.2f, 0.5f)},
                     {rectangle.get(), Vec3(3.0f, -1.0f, 0.01f)},
                     {outer.get(), Vec3(0.5f, 2.0f, -1.0f)},
                     {inner.get(), Vec3(0.1f, -0.3f, 0.2f)}};
        for (const auto& c : cases) {
            const auto s = c.light->sampleLi(c.ref, rng.uniform2());
            ASSERT_TRUE(s.has_value());
            EXPECT_GT(s->pdf, 0.0f);
            EXPECT_EQ(s->pdf, c.light->pdfLi(c.ref, s->p, s->n, s->wi));
            EXPECT_NEAR(glm::length(s->p - c.ref), s->distance, 1e-5f * s->distance);
            EXPECT_NEAR(glm::dot(s->wi, glm::normalize(s->p - c.ref)), 1.0f, 1e-5f);
            EXPECT_EQ(s->value, Rgb(1.0f));
        }
        // From outside, the sampled point is the visible (nearest) one along wi.
        const Vec3 ref(0.5f, 2.0f, -1.0f);
        const auto s = outer->sampleLi(ref, rng.uniform2());
        ASSERT_TRUE(s.has_value());
        const auto hit = intersectSphere(Sphere{Vec3(0.0f), 1.0f}, ref, s->wi, false);
        ASSERT_TRUE(hit.has_value());
        EXPECT_NEAR(glm::length(hit->p - s->p), 0.0f, 1e-4f);
        EXPECT_NEAR(glm::dot(hit->n, s->n), 1.0f, 1e-4f);
    }
}

TEST(AreaLight, FrontSideOnlyUnlessTwoSided) {
    const Shape rect = meshShape(rectangleLightMesh());
    const auto oneSided = makeAreaLight(rect, Rgb(2.0f));
    const auto twoSided = makeAreaLight(rect, Rgb(2.0f), true);
    const Vec3 behind(0.1f, 0.1f, -0.7f);
    EXPECT_FALSE(oneSided->sampleLi(behind, Vec2(0.3f, 0.6f)).has_value());
    const auto s = twoSided->sampleLi(behind, Vec2(0.3f, 0.6f));
    ASSERT_TRUE(s.has_value());
    EXPECT_EQ(s->value, Rgb(2.0f));

    const Vec3 n(0.0f, 0.0f, 1.0f);
    EXPECT_EQ(oneSided->emitted(n, glm::normalize(Vec3(0.2f, 0.1f, 1.0f))), Rgb(2.0f));
    EXPECT_EQ(oneSided->emitted(n, glm::normalize(Vec3(0.2f, 0.1f, -1.0f))), Rgb(0.0f));
    EXPECT_EQ(twoSided->emitted(n, glm::normalize(Vec3(0.2f, 0.1f, -1.0f))), Rgb(2.0f));

    // A sphere emitting outwards cannot light its own inside; emitting inwards, not its outside.
    EXPECT_FALSE(makeAreaLight(sphereShape(Vec3(0.0f), 1.0f), Rgb(1.0f))->sampleLi(Vec3(0.2f), Vec2(0.4f)));
    EXPECT_FALSE(makeAreaLight(sphereShape(Vec3(0.0f), 1.0f, true), Rgb(1.0f))->sampleLi(Vec3(3.0f), Vec2(0.4f)));
}

TEST(AreaLight, DiskIrradianceOnAxis) {
    const float r = 0.7f, h = 1.3f;
    const TriangleMesh disk = transformed(makeDiskMesh(256), glm::scale(Mat4(1.0f), Vec3(r)));
    const Rgb radiance(1.0f, 2.0f, 0.5f);
    const auto light = makeAreaLight(meshShape(disk), radiance);
    const Estimate e = irradianceNee(*light, Vec3(0.0f, 0.0f, h), Vec3(0.0f, 0.0f, -1.0f), 200'000);
    expectClose(e, radiance * (kPi * r * r / (h * h + r * r)), 2e-3f, "disk light");
}

TEST(AreaLight, RectangleIrradianceOffAxis) {
    // Light [-1, 1] x [-0.5, 0.5] facing +z, lifted to z = 1 and flipped to face down.
    TriangleMesh mesh = rectangleLightMesh();
    mesh.flipNormals();
    mesh.transform(glm::translate(Mat4(1.0f), Vec3(0.0f, 0.0f, 1.0f)));
    const Rgb radiance(3.0f);
    const auto light = makeAreaLight(meshShape(mesh), radiance);
    const Vec3 ref(0.3f, -0.2f, 0.25f);
    const double h = 1.0 - ref.z;
    // The projection of ref splits the rectangle into four rectangles sharing a corner above it.
    double formFactor = 0.0;
    for (double a : {1.0 - ref.x, 1.0 + ref.x})
        for (double b : {0.5 - ref.y, 0.5 + ref.y}) formFactor += cornerFormFactor(a, b, h);
    const Estimate e = irradianceNee(*light, ref, Vec3(0.0f, 0.0f, 1.0f), 200'000);
    expectClose(e, radiance * static_cast<float>(M_PI * formFactor), 2e-3f, "rectangle light");
}

TEST(AreaLight, SphereIrradianceOutsideAndInside) {
    const Vec3 center(0.5f, -0.2f, 0.1f);
    const float r = 0.6f, d = 2.1f;
    const Rgb radiance(1.0f, 0.5f, 2.0f);
    const auto outer = makeAreaLight(sphereShape(center, r), radiance);
    const Vec3 axis = glm::normalize(Vec3(0.3f, 0.9f, -0.2f));
    const Estimate e = irradianceNee(*outer, center + d * axis, -axis, 100'000);
    expectClose(e, radiance * (kPi * r * r / (d * d)), 2e-3f, "sphere seen from outside");

    // Inside a sphere glowing inwards every hemisphere sees radiance L everywhere.
    const auto inner = makeAreaLight(sphereShape(center, r, true), radiance);
    const Estimate inside = irradianceNee(*inner, center + Vec3(0.2f, 0.1f, -0.3f), axis, 200'000);
    expectClose(inside, radiance * kPi, 2e-3f, "inside an inward sphere");
}

TEST(AreaLight, PowerIsIntegratedEmission) {
    const TriangleMesh mesh =
        transformed(makeCubeMesh(), glm::scale(glm::rotate(Mat4(1.0f), 0.4f, Vec3(1.0f, 1.0f, 0.0f)),
                                               Vec3(0.3f, 0.5f, 0.2f)));
    const Rgb radiance(1.0f, 2.0f, 3.0f);
    for (bool twoSided : {false, true}) {
        const auto light = makeAreaLight(meshShape(mesh), radiance, twoSided);
        // Exitance: emitted(n, w) |cos| integrated over the whole sphere of directions, times area.
        const Vec3 n = glm::normalize(Vec3(0.2f, -0.5f, 0.8f));
        const Frame frame(n);
        constexpr int kTheta = 400, kPhi = 64;
        Rgb exitance(0.0f);
        for (int i = 0; i < kTheta; ++i) {
            const float theta = kPi * (static_cast<float>(i) + 0.5f) / kTheta;
            for (int j = 0; j < kPhi; ++j) {
                const float phi = 2.0f * kPi * (static_cast<float>(j) + 0.5f) / kPhi;
                const Vec3 w = frame.toWorld(
                    Vec3(std::sin(theta) * std::cos(phi), std::sin(theta) * std::sin(phi), std::cos(theta)));
                exitance += light->emitted(n, w) * std::abs(std::cos(theta)) * std::sin(theta) *
                            (kPi / kTheta) * (2.0f * kPi / kPhi);
            }
        }
        const Rgb expected = exitance * mesh.area();
        for (int c = 0; c < 3; ++c) EXPECT_NEAR(light->power()[c], expected[c], 1e-3f * expected[c]);

        // Emitted photons carry that power on average.
        const Estimate flux = meanOf(100'000, 9, [&](jobs::Rng& rng) {
            const Vec2 uPos = rng.uniform2();
            const auto e = light->sampleEmission(uPos, rng.uniform2());
            return e ? e->flux : Rgb(0.0f);
        });
        expectClose(flux, expected, 1e-3f, "emission flux");
    }
    const auto sphere = makeAreaLight(sphereShape(Vec3(1.0f), 0.5f), radiance);
    const Rgb sphereExpected = radiance * (kPi * 4.0f * kPi * 0.25f);
    for (int c = 0; c < 3; ++c) EXPECT_NEAR(sphere->power()[c], sphereExpected[c], 1e-4f * sphereExpected[c]);
}

TEST(AreaLight, EmissionDirectionsAreCosineChi2) {
    const TriangleMesh mesh =
        transformed(rectangleLightMesh(), glm::rotate(Mat4(1.0f), 0.9f, glm::normalize(Vec3(1.0f, -2.0f, 0.5f))));
    const Vec3 n =
        glm::normalize(glm::cross(mesh.positions[1] - mesh.positions[0], mesh.positions[2] - mesh.positions[0]));
    for (bool twoSided : {false, true}) {
        const auto light = makeAreaLight(meshShape(mesh), Rgb(1.0f), twoSided);
        test::Chi2Config config;
        config.testCount = 2;
        config.samples = 300'000;
        const auto result = test::chi2SphereTest(
            [&](const Vec2& u) -> std::optional<Vec3> {
                const auto e = light->sampleEmission(Vec2(0.3f, 0.7f), u);
                if (!e) return std::nullopt;
                return e->direction;
            },
            [&](const Vec3& w) -> double {
                const double c = glm::dot(n, w);
                return twoSided ? std::abs(c) / (2.0 * M_PI) : std::max(c, 0.0) / M_PI;
            },
            config);
        EXPECT_TRUE(result.passed) << (twoSided ? "two-sided: " : "one-sided: ") << result.message;
        // The density reported with each photon is the one tested above.
        const auto e = light->sampleEmission(Vec2(0.6f, 0.2f), Vec2(0.3f, 0.8f));
        ASSERT_TRUE(e.has_value());
        const double c = glm::dot(n, e->direction);
        EXPECT_NEAR(e->pdfDirection, twoSided ? std::abs(c) / (2.0 * M_PI) : c / M_PI, 1e-5);
        EXPECT_GT(glm::dot(e->normal, e->direction), 0.0f);
    }
}

TEST(AreaLight, EmissionPositionsAreUniformByArea) {
    TriangleMesh mesh;
    mesh.positions = {{0, 0, 0}, {1, 0, 0}, {0, 2, 0}, {3, 0, 0}, {5, 0, 0}, {3, 6, 0}};
    mesh.indices = {0, 1, 2, 3, 4, 5};  // areas 1 and 6
    const auto light = makeAreaLight(meshShape(mesh), Rgb(1.0f));
    jobs::Rng rng(8, jobs::streamKey("emission-positions"), 0);
    constexpr int kSamples = 140'000;
    int inSecond = 0;
    glm::dvec3 meanSecond(0.0);
    for (int i = 0; i < kSamples; ++i) {
        const Vec2 uPos = rng.uniform2();
        const auto e = light->sampleEmission(uPos, rng.uniform2());
        ASSERT_TRUE(e.has_value());
        EXPECT_FLOAT_EQ(e->pdfPosition, 1.0f / 7.0f);
        EXPECT_FLOAT_EQ(e->emitterArea, 7.0f);
        EXPECT_EQ(e->normal, Vec3(0.0f, 0.0f, 1.0f));
        if (e->origin.x >= 3.0f) {
            ++inSecond;
            meanSecond += glm::dvec3(e->origin);
        }
    }
    const double p = 6.0 / 7.0;
    EXPECT_NEAR(inSecond / double(kSamples), p, 5.0 * std::sqrt(p * (1 - p) / kSamples));
    meanSecond /= double(inSecond);
    EXPECT_NEAR(meanSecond.x, 11.0 / 3.0, 0.01);  // centroid of the second triangle
    EXPECT_NEAR(meanSecond.y, 2.0, 0.01);
}

TEST(AreaLight, PhotonsAgreeWithNextEventEstimation) {
    TriangleMesh mesh = rectangleLightMesh();
    mesh.flipNormals();
    mesh.transform(glm::translate(Mat4(1.0f), Vec3(0.0f, 0.0f, 1.0f)));
    const auto light = makeAreaLight(meshShape(mesh), Rgb(2.0f, 1.0f, 0.5f));
    const Vec3 center(0.3f, 0.1f, 0.0f), normal(0.0f, 0.0f, 1.0f);
    const float radius = 0.4f;
    // Mean irradiance over the receiver disk by NEE at uniformly spread points on it.
    const Estimate nee = meanOf(100'000, 12, [&](jobs::Rng& rng) {
        const Vec2 d = sampleConcentricDisk(rng.uniform2()) * radius;
        const auto s = light->sampleLi(center + Vec3(d, 0.0f), rng.uniform2());
        return s ? s->value * std::max(0.0f, glm::dot(normal, s->wi)) / s->pdf : Rgb(0.0f);
    });
    const Estimate photons = irradiancePhotons(*light, center, normal, radius, 600'000);
    for (int c = 0; c < 3; ++c) {
        const float sigma = std::sqrt(sqr(nee.stdErr[c]) + sqr(photons.stdErr[c]));
        EXPECT_NEAR(photons.mean[c], nee.mean[c], 5.0f * sigma) << "channel " << c;
    }
}

// ---------------------------------------------------------------------------
// Point, spot and directional lights.

TEST(PointLight, IrradianceAndPower) {
    const Vec3 position(1.0f, 2.0f, 3.0f);
    const Rgb intensity(2.0f, 4.0f, 8.0f);
    const auto light = makePointLight(position, intensity);
    EXPECT_TRUE(light->isDelta());
    EXPECT_FALSE(light->isInfinite());
    const Vec3 ref(0.5f, 0.0f, 1.0f), normal = glm::normalize(Vec3(0.1f, 1.0f, 0.4f));
    const auto s = light->sampleLi(ref, Vec2(0.5f));
    ASSERT_TRUE(s.has_value());
    const float d = glm::length(position - ref);
    const float cosTheta = glm::dot(normal, (position - ref) / d);
    const Rgb e = s->value * glm::dot(normal, s->wi) / s->pdf;
    for (int c = 0; c < 3; ++c) EXPECT_NEAR(e[c], intensity[c] * cosTheta / (d * d), 1e-5f * intensity[c]);
    EXPECT_NEAR(s->distance, d, 1e-5f);
    for (int c = 0; c < 3; ++c) EXPECT_NEAR(light->power()[c], 4.0f * kPi * intensity[c], 1e-4f * intensity[c]);

    const Vec3 receiver = position + Vec3(0.0f, 0.0f, -1.5f);
    const Estimate photons = irradiancePhotons(*light, receiver, Vec3(0.0f, 0.0f, 1.0f), 0.3f, 400'000);
    // Mean of I cos / d^2 over the receiver disk: I / (pi rho^2) * solid angle of the disk.
    const double h = 1.5, rho = 0.3;
    const double solidAngle = 2.0 * M_PI * (1.0 - h / std::sqrt(h * h + rho * rho));
    expectClose(photons, intensity * static_cast<float>(solidAngle / (M_PI * rho * rho)), 0.0f, "point photons");
}

// Mitsuba 0.5 spot falloff: 1 up to the beam width, linear in angle to 0 at the cutoff.
double spotFalloffReference(double theta, double cutoff, double beam) {
    if (theta >= cutoff) return 0.0;
    if (theta <= beam) return 1.0;
    return (cutoff - theta) / (cutoff - beam);
}

TEST(SpotLight, FalloffValuesAndPower) {
    const Vec3 position(0.0f, 1.0f, 0.0f), axis = glm::normalize(Vec3(0.3f, -1.0f, 0.2f));
    const Rgb intensity(5.0f, 2.0f, 1.0f);
    const float cutoffDeg = 35.0f, beamDeg = 20.0f;
    const double cutoff = cutoffDeg * M_PI / 180.0, beam = beamDeg * M_PI / 180.0;
    const auto light = makeSpotLight(position, axis, intensity, cutoffDeg, beamDeg);
    const Frame frame(axis);
    for (double thetaDeg : {0.0, 10.0, 19.0, 22.0, 27.5, 33.0, 36.0, 90.0, 150.0}) {
        const double theta = thetaDeg * M_PI / 180.0;
        const Vec3 dir = frame.toWorld(Vec3(std::sin(theta) * 0.6, std::sin(theta) * 0.8, std::cos(theta)));
        const float dist = 2.5f;
        const auto s = light->sampleLi(position + dist * dir, Vec2(0.1f));
        const double f = spotFalloffReference(theta, cutoff, beam);
        if (f == 0.0) {
            EXPECT_FALSE(s.has_value() && !isBlack(s->value)) << thetaDeg;
            continue;
        }
        ASSERT_TRUE(s.has_value()) << thetaDeg;
        EXPECT_EQ(s->pdf, 1.0f);
        for (int c = 0; c < 3; ++c)
            EXPECT_NEAR(s->value[c], intensity[c] * f / (dist * dist), 1e-4 * intensity[c]) << thetaDeg;
    }
    // Power = integral of the intensity over the sphere, measured through sampleLi at unit distance.
    constexpr int kSteps = 20000;
    double integral = 0.0;
    for (int i = 0; i < kSteps; ++i) {
        const double theta = M_PI * (i + 0.5) / kSteps;
        const Vec3 dir = frame.toWorld(Vec3(std::sin(theta), 0.0, std::cos(theta)));
        const auto s = light->sampleLi(position + dir, Vec2(0.5f));
        if (s) integral += s->value.x * std::sin(theta) * (M_PI / kSteps) * 2.0 * M_PI;
    }
    EXPECT_NEAR(light->power().x, integral, 1e-3 * integral);
    EXPECT_NEAR(light->power().y / light->power().x, 0.4f, 1e-5f);
}

TEST(SpotLight, EmissionFollowsFalloffChi2) {
    struct Case {
        float cutoffDeg, beamDeg;
    };
    const std::vector<Case> cases{{40.0f, 25.0f}, {30.0f, 0.0f}, {20.0f, 20.0f}};
    const Vec3 axis = glm::normalize(Vec3(0.3f, 0.2f, -1.0f));
    const Frame frame(axis);
    for (const Case& c : cases) {
        const Rgb intensity(3.0f);
        const auto light = makeSpotLight(Vec3(0.5f), axis, intensity, c.cutoffDeg, c.beamDeg);
        const double cutoff = c.cutoffDeg * M_PI / 180.0, beam = c.beamDeg * M_PI / 180.0;
        // Normalisation of the falloff by independent quadrature.
        constexpr int kSteps = 100000;
        double mass = 0.0;
        for (int i = 0; i < kSteps; ++i) {
            const double theta = cutoff * (i + 0.5) / kSteps;
            mass += spotFalloffReference(theta, cutoff, beam) * std::sin(theta) * cutoff / kSteps * 2.0 * M_PI;
        }
        EXPECT_NEAR(light->power().x, intensity.x * mass, 1e-4 * intensity.x * mass);

        test::Chi2Config config;
        config.testCount = static_cast<int>(cases.size());
        config.samples = 300'000;
        const auto result = test::chi2SphereTest(
            [&](const Vec2& u) -> std::optional<Vec3> {
                const auto e = light->sampleEmission(Vec2(0.5f), u);
                if (!e) return std::nullopt;
                return e->direction;
            },
            [&](const Vec3& w) -> double {
                const double theta = std::acos(std::clamp(double(glm::dot(w, axis)), -1.0, 1.0));
                return spotFalloffReference(theta, cutoff, beam) / mass;
            },
            config);
        EXPECT_TRUE(result.passed) << "cutoff " << c.cutoffDeg << ", beam " << c.beamDeg << ": " << result.message;

        jobs::Rng rng(3, jobs::streamKey("spot-emission"), 0);
        for (int i = 0; i < 1000; ++i) {
            const auto e = light->sampleEmission(rng.uniform2(), rng.uniform2());
            ASSERT_TRUE(e.has_value());
            EXPECT_EQ(e->origin, Vec3(0.5f));
            const double theta = std::acos(std::clamp(double(glm::dot(e->direction, axis)), -1.0, 1.0));
            EXPECT_NEAR(e->pdfDirection, spotFalloffReference(theta, cutoff, beam) / mass, 2e-3 / mass);
            EXPECT_NEAR(e->flux.x, light->power().x, 1e-4f * light->power().x);
        }
    }
}

TEST(DirectionalLight, IrradianceAndPhotons) {
    const Vec3 travel = glm::normalize(Vec3(0.2f, -1.0f, 0.3f));
    const Rgb irradiance(1.0f, 2.0f, 3.0f);
    const auto light = makeDirectionalLight(travel, irradiance);
    EXPECT_TRUE(light->isDelta());
    EXPECT_TRUE(light->isInfinite());
    const Vec3 center(1.0f, 0.5f, -0.5f);
    const float radius = 2.0f;
    light->setSceneBounds(center, radius);

    const Vec3 normal = glm::normalize(Vec3(0.4f, 1.0f, 0.0f));
    const auto s = light->sampleLi(Vec3(0.3f), Vec2(0.2f));
    ASSERT_TRUE(s.has_value());
    EXPECT_EQ(s->pdf, 1.0f);
    EXPECT_GE(s->distance, 1e29f);
    const Rgb e = s->value * glm::dot(normal, s->wi) / s->pdf;
    const float cosTheta = glm::dot(normal, -travel);
    for (int c = 0; c < 3; ++c) EXPECT_NEAR(e[c], irradiance[c] * cosTheta, 1e-5f * irradiance[c]);
    for (int c = 0; c < 3; ++c)
        EXPECT_NEAR(light->power()[c], irradiance[c] * kPi * radius * radius, 1e-4f * irradiance[c]);

    jobs::Rng rng(6, jobs::streamKey("directional"), 0);
    for (int i = 0; i < 1000; ++i) {
        const Vec2 uPos = rng.uniform2();
        const auto photon = light->sampleEmission(uPos, rng.uniform2());
        ASSERT_TRUE(photon.has_value());
        EXPECT_EQ(photon->direction, travel);
        // Starts outside the bounding sphere, upstream of it.
        EXPECT_GE(glm::length(photon->origin - center), radius * (1.0f - 1e-5f));
        EXPECT_LT(glm::dot(photon->origin - center, travel), 0.0f);
    }
    const Estimate photons = irradiancePhotons(*light, center + Vec3(0.3f, -0.2f, 0.1f), normal, 0.6f, 300'000);
    expectClose(photons, irradiance * cosTheta, 0.0f, "directional photons");
}

// ---------------------------------------------------------------------------
// Environments.

TEST(ConstantEnvironment, SamplingIrradianceAndPhotons) {
    const Rgb radiance(0.5f, 1.0f, 2.0f);
    const auto light = makeConstantEnvironment(radiance);
    EXPECT_FALSE(light->isDelta());
    EXPECT_TRUE(light->isInfinite());
    const Vec3 center(0.0f, 1.0f, 0.0f);
    const float radius = 1.5f;
    light->setSceneBounds(center, radius);
    EXPECT_EQ(light->environment(Vec3(0.0f, 0.0f, -1.0f)), radiance);

    test::Chi2Config config;
    config.samples = 200'000;
    const auto result = test::chi2SphereTest(
        [&](const Vec2& u) -> std::optional<Vec3> {
            const auto s = light->sampleLi(Vec3(0.0f), u);
            if (!s) return std::nullopt;
            return s->wi;
        },
        [&](const Vec3& w) -> double { return light->pdfLi(Vec3(0.0f), Vec3(0.0f), Vec3(0.0f), w); }, config);
    EXPECT_TRUE(result.passed) << result.message;
    EXPECT_NEAR(light->pdfLi(Vec3(0.0f), Vec3(0.0f), Vec3(0.0f), Vec3(1, 0, 0)), 1.0 / (4.0 * M_PI), 1e-6);

    const Vec3 normal = glm::normalize(Vec3(0.3f, -0.2f, 0.9f));
    expectClose(irradianceNee(*light, Vec3(0.0f), normal, 200'000), radiance * kPi, 0.0f, "constant environment");
    expectClose(irradiancePhotons(*light, center + Vec3(0.2f, 0.0f, -0.1f), normal, 0.8f, 400'000),
                radiance * kPi, 0.0f, "constant environment photons");
    const Rgb expectedPower = radiance * (4.0f * kPi * kPi * radius * radius);
    for (int c = 0; c < 3; ++c) EXPECT_NEAR(light->power()[c], expectedPower[c], 1e-4f * expectedPower[c]);
}

// 32 x 16 map: a smooth gradient, a black band and a very bright spot.
RgbImage syntheticEnvironment() {
    RgbImage image;
    image.width = 32;
    image.height = 16;
    image.pixels.resize(static_cast<std::size_t>(image.width) * image.height);
    for (int y = 0; y < image.height; ++y)
        for (int x = 0; x < image.width; ++x) {
            Rgb v(0.2f + 0.8f * x / image.width, 0.5f + 0.5f * y / image.height, 1.0f - 0.5f * x / image.width);
            if (x >= 20 && x < 26) v = Rgb(0.0f);
            if (x == 5 && y == 4) v = Rgb(200.0f, 150.0f, 100.0f);
            image.pixels[static_cast<std::size_t>(y) * image.width + x] = v;
        }
    return image;
}

// Rotation taking the map's +Y (up) to world +Z.
Mat3 yUpToZUp() { return Mat3(Vec3(1, 0, 0), Vec3(0, 0, 1), Vec3(0, -1, 0)); }

TEST(EnvironmentMap, SamplingMatchesPdfChi2) {
    // With +Y mapped to +Z, map pixels coincide with groups of chi-square cells, so
    // the piecewise-constant density is integrated exactly by the midpoint rule.
    const auto light = makeEnvironmentMap(syntheticEnvironment(), 1.5f, yUpToZUp());
    test::Chi2Config config;
    config.thetaBins = 32;
    config.phiBins = 64;
    config.samples = 1'000'000;
    config.minRefinement = 0;
    const auto result = test::chi2SphereTest(
        [&](const Vec2& u) -> std::optional<Vec3> {
            const auto s = light->sampleLi(Vec3(0.0f), u);
            if (!s) return std::nullopt;
            return s->wi;
        },
        [&](const Vec3& w) -> double { return light->pdfLi(Vec3(0.0f), Vec3(0.0f), Vec3(0.0f), w); }, config);
    EXPECT_TRUE(result.passed) << result.message;
}

TEST(EnvironmentMap, MitsubaLatLongOrientation) {
    const RgbImage image = syntheticEnvironment();
    const float scale = 2.0f;
    const auto light = makeEnvironmentMap(image, scale);
    const auto pixel = [&](int x, int y) { return image.at(x, y) * scale; };
    // Direction of texel (x, y) as Mitsuba 3 looks it up: u = phi / 2 pi with phi = atan2(x, -z) at the
    // column's centre, u = (x + 1/2) / width; v = theta / pi from +Y with rows on the corners,
    // v = y / (height - 1), so that the first and last rows are the poles.
    for (const auto& [x, y] : std::vector<std::pair<int, int>>{{0, 1}, {5, 4}, {13, 9}, {31, 14}, {22, 7}}) {
        const float phi = 2.0f * kPi * (x + 0.5f) / image.width;
        const float theta = kPi * y / (image.height - 1.0f);
        const Vec3 dir(std::sin(phi) * std::sin(theta), std::cos(theta), -std::cos(phi) * std::sin(theta));
        const Rgb value = light->environment(dir);
        for (int c = 0; c < 3; ++c)
            EXPECT_NEAR(value[c], pixel(x, y)[c], 1e-3f * (1.0f + pixel(x, y)[c])) << x << "," << y;
    }
    // +X is a quarter turn along u and on the horizon: between columns 7, 8 and rows 7, 8.
    const Rgb expected = 0.25f * (pixel(7, 7) + pixel(8, 7) + pixel(7, 8) + pixel(8, 8));
    const Rgb value = light->environment(Vec3(1.0f, 0.0f, 0.0f));
    for (int c = 0; c < 3; ++c) EXPECT_NEAR(value[c], expected[c], 1e-4f * (1.0f + expected[c]));
    // Just off the pole the radiance is the top row's, not a blend with the second row.
    const Vec3 nearPole = glm::normalize(Vec3(0.0f, 1.0f, -1e-4f));  // u = 0: between columns 31 and 0
    const Rgb topRow = 0.5f * (pixel(31, 0) + pixel(0, 0));
    for (int c = 0; c < 3; ++c) EXPECT_NEAR(light->environment(nearPole)[c], topRow[c], 1e-3f * (1.0f + topRow[c]));

    // toWorld rotates the map: what the map holds at +Y appears at world +Z.
    const auto rotated = makeEnvironmentMap(image, scale, yUpToZUp());
    const Vec3 probe = glm::normalize(Vec3(0.3f, 0.5f, -0.4f));
    const Rgb a = light->environment(probe), b = rotated->environment(yUpToZUp() * probe);
    for (int c = 0; c < 3; ++c) EXPECT_NEAR(a[c], b[c], 1e-4f * (1.0f + a[c]));
}

// Importance sampling follows the lookup: a map lit on one row only has light
// in the two bilinear patches around that row's v = y / (height - 1), and every
// sampled direction must land where the lookup sees light (a texel-centred
// sampling grid, (y + 1/2) / height, would put some outside).
TEST(EnvironmentMap, SamplingCoversOnlyWhereTheLookupHasLight) {
    RgbImage image;
    image.width = 8;
    image.height = 16;
    image.pixels.assign(static_cast<std::size_t>(image.width) * image.height, Rgb(0.0f));
    const int litRow = 4;
    for (int x = 0; x < image.width; ++x) image.pixels[static_cast<std::size_t>(litRow) * image.width + x] = Rgb(1.0f + x);
    const auto light = makeEnvironmentMap(image, 1.0f);
    jobs::Rng rng(3, jobs::streamKey("env-support"), 0);
    int above = 0, below = 0;
    constexpr int kSamples = 20'000;
    for (int i = 0; i < kSamples; ++i) {
        const auto s = light->sampleLi(Vec3(0.0f), rng.uniform2());
        ASSERT_TRUE(s.has_value());
        const float v = std::acos(std::clamp(s->wi.y, -1.0f, 1.0f)) / kPi;
        ASSERT_GT(v, (litRow - 1.0f) / (image.height - 1.0f));
        ASSERT_LT(v, (litRow + 1.0f) / (image.height - 1.0f));
        ASSERT_GT(luminance(light->environment(s->wi)), 0.0f) << "v = " << v;
        (v < litRow / (image.height - 1.0f) ? above : below)++;
    }
    // Both patches hold the row's light, weighted by sin(theta) at their centres.
    const double sinAbove = std::sin(M_PI * (litRow - 0.5) / (image.height - 1.0));
    const double sinBelow = std::sin(M_PI * (litRow + 0.5) / (image.height - 1.0));
    const double expectedAbove = sinAbove / (sinAbove + sinBelow);
    EXPECT_NEAR(above / double(kSamples), expectedAbove, 5.0 * std::sqrt(0.25 / kSamples));
    EXPECT_EQ(above + below, kSamples);
}

TEST(EnvironmentMap, IrradiancePowerAndPhotons) {
    const Mat3 toWorld = Mat3(glm::rotate(Mat4(1.0f), 1.1f, glm::normalize(Vec3(0.4f, 1.0f, -0.3f))));
    const float scale = 0.7f;
    const auto light = makeEnvironmentMap(syntheticEnvironment(), scale, toWorld);
    const Vec3 center(0.2f, 0.0f, -0.4f);
    const float radius = 1.2f;
    light->setSceneBounds(center, radius);

    // Reference integrals of environment() by the midpoint rule.
    const Vec3 normal = glm::normalize(Vec3(-0.3f, 0.6f, 0.5f));
    constexpr int kTheta = 800, kPhi = 1600;
    glm::dvec3 irradiance(0.0), radiantIntegral(0.0);
    for (int i = 0; i < kTheta; ++i) {
        const double theta = M_PI * (i + 0.5) / kTheta;
        for (int j = 0; j < kPhi; ++j) {
            const double phi = 2.0 * M_PI * (j + 0.5) / kPhi;
            const Vec3 w(std::sin(theta) * std::cos(phi), std::sin(theta) * std::sin(phi), std::cos(theta));
            const glm::dvec3 l(light->environment(w));
            const double dOmega = std::sin(theta) * (M_PI / kTheta) * (2.0 * M_PI / kPhi);
            radiantIntegral += l * dOmega;
            irradiance += l * std::max(0.0, double(glm::dot(normal, w))) * dOmega;
        }
    }
    expectClose(irradianceNee(*light, Vec3(0.0f), normal, 400'000), Rgb(irradiance), 2e-3f, "environment map NEE");
    const Rgb expectedPower = Rgb(radiantIntegral) * (kPi * radius * radius);
    for (int c = 0; c < 3; ++c) EXPECT_NEAR(light->power()[c], expectedPower[c], 3e-3f * expectedPower[c]);
    expectClose(irradiancePhotons(*light, center + Vec3(0.1f, 0.2f, 0.0f), normal, 0.7f, 600'000), Rgb(irradiance),
                2e-3f, "environment map photons");

    // The density reported by sampleLi is the one pdfLi gives for the returned direction.
    jobs::Rng rng(10, jobs::streamKey("env-pdf"), 0);
    int mismatches = 0;
    for (int i = 0; i < 20000; ++i) {
        const auto s = light->sampleLi(Vec3(1.0f), rng.uniform2());
        ASSERT_TRUE(s.has_value());
        const float pdf = light->pdfLi(Vec3(1.0f), Vec3(0.0f), Vec3(0.0f), s->wi);
        if (std::abs(pdf - s->pdf) > 1e-3f * s->pdf) ++mismatches;
    }
    EXPECT_LE(mismatches, 20);
}

TEST(Light, DefaultsAreBlack) {
    const auto point = makePointLight(Vec3(0.0f), Rgb(1.0f));
    EXPECT_EQ(point->environment(Vec3(0.0f, 0.0f, 1.0f)), Rgb(0.0f));
    EXPECT_EQ(point->emitted(Vec3(0.0f, 0.0f, 1.0f), Vec3(0.0f, 0.0f, 1.0f)), Rgb(0.0f));
    point->setSceneBounds(Vec3(1.0f), 10.0f);
    EXPECT_NEAR(point->power().x, 4.0f * kPi, 1e-5f);
}

}  // namespace
}  // namespace fg
