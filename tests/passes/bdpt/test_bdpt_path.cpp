// The MIS weights of bidirectional path tracing: for one path, the weights of
// every strategy (s, t) that can produce it sum to one (Veach 1997 §10.2),
// with surfaces, medium vertices, and area, point and environment lights, the
// free-flight densities of thin fog and of a dense chromatic medium included.
#include "passes/bdpt/bdpt_path.h"

#include "engine/accel/ray_query.h"
#include "engine/shading/bsdf.h"
#include "engine/shading/light.h"
#include "engine/scene/scene.h"
#include "jobs/random.h"

#include <glm/gtc/matrix_transform.hpp>
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <vector>

namespace fg {
namespace {

// A diffuse room (a sphere seen from inside) filled with fog around a ball of
// dense chromatic medium behind a null boundary, lit by a disk emitter, a
// point light and a constant environment (which reaches the room through
// nothing: its paths are built by hand along directions).
struct WeightScene {
    Scene scene;
    int wall = -1;
    int disk = -1;
    static constexpr int kFog = 0, kDense = 1;
    const Vec3 ballCentre{0.4f, -0.3f, -0.2f};
    static constexpr float kBallRadius = 0.7f;
    int areaLight = -1, pointLight = -1, environment = -1;

    WeightScene() {
        scene.bsdfs.push_back(makeDiffuse(makeConstantTexture(Rgb(0.6f))));
        Shape room;
        room.geometry = Sphere{Vec3(0.0f), 2.0f};
        room.flipNormals = true;
        room.bsdf = 0;
        scene.shapes.push_back(room);
        wall = 0;
        Shape emitter;
        TriangleMesh mesh = makeDiskMesh(64);
        mesh.transform(glm::translate(Mat4(1.0f), Vec3(0.0f, 1.5f, 0.0f)) *
                       glm::rotate(Mat4(1.0f), kPi / 2.0f, Vec3(1, 0, 0)) * glm::scale(Mat4(1.0f), Vec3(0.4f)));
        emitter.geometry = mesh;
        emitter.bsdf = 0;
        emitter.areaLight = 0;
        scene.lights.push_back(makeAreaLight(emitter, Rgb(5.0f)));
        scene.lightShape.push_back(1);
        scene.shapes.push_back(emitter);
        disk = 1;
        areaLight = 0;
        scene.lights.push_back(makePointLight(Vec3(0.3f, 0.5f, -0.2f), Rgb(4.0f)));
        scene.lightShape.push_back(-1);
        pointLight = 1;
        scene.lights.push_back(makeConstantEnvironment(Rgb(0.7f)));
        scene.lightShape.push_back(-1);
        environment = 2;
        scene.media.emplace_back(Rgb(0.1f), Rgb(0.5f), 0.4f);
        scene.media.emplace_back(Rgb(0.5f, 2.0f, 0.1f), Rgb(3.0f, 6.0f, 1.0f), -0.3f);
        Shape ball;
        ball.geometry = Sphere{ballCentre, kBallRadius};
        ball.interiorMedium = kDense;
        ball.exteriorMedium = kFog;
        scene.shapes.push_back(ball);
        scene.camera.eye = Vec3(0.0f, 0.0f, 1.2f);
        scene.camera.target = Vec3(0.0f, 0.0f, 0.0f);
        scene.camera.fovYDegrees = 60.0f;
        scene.camera.width = 32;
        scene.camera.height = 24;
        scene.finalize();
    }
};

int mediumAt(const WeightScene& ws, const Vec3& p) {
    return glm::length(p - ws.ballCentre) < WeightScene::kBallRadius ? WeightScene::kDense : WeightScene::kFog;
}

// The media along the segment from a to b, found independently of the
// renderer's ray walks: the fog, and the ball where the line crosses it.
FreeFlightSegment segmentMedia(const WeightScene& ws, const BdptVertex& a, const BdptVertex& b) {
    FreeFlightSegment segment;
    if (a.infinite || b.infinite) return segment;
    const Vec3 d = b.p - a.p;
    const float length = glm::length(d);
    const Vec3 dir = d / length;
    const Vec3 oc = a.p - ws.ballCentre;
    const float half = glm::dot(oc, dir);
    const float disc = half * half - (glm::dot(oc, oc) - WeightScene::kBallRadius * WeightScene::kBallRadius);
    const HomogeneousMedium& fog = ws.scene.media[WeightScene::kFog];
    const HomogeneousMedium& dense = ws.scene.media[WeightScene::kDense];
    if (!(disc > 0.0f)) {
        segment.add(fog, length);
        return segment;
    }
    const float enter = std::clamp(-half - std::sqrt(disc), 0.0f, length);
    const float leave = std::clamp(-half + std::sqrt(disc), 0.0f, length);
    if (enter > 0.0f) segment.add(fog, enter);
    if (leave > enter) segment.add(dense, leave - enter);
    if (length > leave) segment.add(fog, length - leave);
    return segment;
}

BdptVertex wallVertex(const Vec3& direction, int shape) {
    BdptVertex v;
    v.kind = BdptVertexKind::Surface;
    v.p = 2.0f * direction;
    v.ng = v.ns = -direction;  // the room's normals face inwards
    v.shape = static_cast<std::uint32_t>(shape);
    v.medium = 0;
    return v;
}

// The vertices x_0 (camera) .. x_k (on the light) of one path, and the light.
struct FullPath {
    std::vector<BdptVertex> x;
    int light = -1;
    bool deltaLight = false;
};

// Vertices of the camera subpath (first t of x) or the light subpath (last s
// of x, reversed), with the densities a random walk would have stored.
std::vector<BdptVertex> subpath(const WeightScene& ws, const BdptScene& bs, const FullPath& path, int count, bool fromLight) {
    const int k = static_cast<int>(path.x.size()) - 1;
    std::vector<BdptVertex> v;
    for (int i = 0; i < count; ++i) v.push_back(path.x[static_cast<std::size_t>(fromLight ? k - i : i)]);
    if (fromLight && count > 0) {
        v[0].kind = BdptVertexKind::Light;
        v[0].light = path.light;
        v[0].shape = Hit::kNoShape;
    }
    for (int i = 1; i < count; ++i) v[static_cast<std::size_t>(i)].wo = bdptDirection(v[static_cast<std::size_t>(i)], v[static_cast<std::size_t>(i - 1)]);
    for (int i = 1; i < count; ++i) {
        auto& before = v[static_cast<std::size_t>(i - 1)];
        auto& vi = v[static_cast<std::size_t>(i)];
        const FreeFlightSegment segment = segmentMedia(ws, before, vi);
        vi.pdfFwd = bdptPdf(bs, i >= 2 ? &v[static_cast<std::size_t>(i - 2)] : nullptr, before, vi) *
                    bdptDistancePdf(segment, before, vi, true);
        vi.distancePdfRev = bdptDistancePdf(segment, before, vi, false);
    }
    for (int i = 0; i < count; ++i) {
        auto& vi = v[static_cast<std::size_t>(i)];
        if (i == 0) vi.pdfFwd = fromLight ? bdptPdfLightOrigin(bs, vi) : 1.0f;
        // Set by the walk once vertex i + 2 exists; the weight overwrites the last two.
        vi.pdfRev = i + 2 < count ? bdptPdf(bs, &v[static_cast<std::size_t>(i + 2)], v[static_cast<std::size_t>(i + 1)], vi) *
                                        v[static_cast<std::size_t>(i + 1)].distancePdfRev
                                  : -1.0f;
    }
    return v;
}

// Sum of the weights of every strategy the renderer uses for this path.
float weightSum(const WeightScene& ws, const BdptScene& bs, const FullPath& path, MisHeuristic heuristic) {
    const int vertices = static_cast<int>(path.x.size());
    float sum = 0.0f;
    for (int t = 1; t <= vertices; ++t) {
        const int s = vertices - t;
        if (s == 0 && path.deltaLight) continue;          // a point light is never hit
        if (s == 1 && t == 1 && path.deltaLight) continue;  // nor seen directly
        auto camera = subpath(ws, bs, path, t, false);
        auto light = subpath(ws, bs, path, s, true);
        if (s == 0) {
            // The camera subpath ends on the emitter.
            camera.back().light = path.light;
        }
        const BdptVertex* sampled = s == 1 ? &light[0] : nullptr;
        const FreeFlightSegment connection =
            s > 0 ? segmentMedia(ws, camera.back(), light.back()) : FreeFlightSegment();
        sum += bdptMisWeight(bs, light, camera, sampled, s, t, heuristic, connection);
    }
    return sum;
}

TEST(BdptMis, WeightsOfAllStrategiesSumToOne) {
    WeightScene ws;
    const RayQuery rays(ws.scene);
    const BdptScene bs(ws.scene, rays, ws.scene.camera);
    jobs::Rng rng(3, 5, 7);
    int checked = 0, inDense = 0;
    for (int trial = 0; trial < 600; ++trial) {
        FullPath path;
        BdptVertex camera;
        camera.kind = BdptVertexKind::Camera;
        camera.p = ws.scene.camera.eye;
        camera.medium = 0;
        path.x.push_back(camera);
        // The first vertex along a camera ray through a random raster position.
        const Vec2 raster = rng.uniform2() * Vec2(32.0f, 24.0f);
        const Vec3 first = ws.scene.camera.generateRay(raster).direction;
        const int middle = static_cast<int>(rng.uniformIndex(5));
        for (int i = 0; i < middle; ++i) {
            const bool inMedium = rng.uniform() < 0.4f;
            if (inMedium) {
                BdptVertex m;
                m.kind = BdptVertexKind::Medium;
                m.p = (i == 0 ? camera.p + (0.2f + rng.uniform()) * first
                              : Vec3(rng.uniform() - 0.5f, rng.uniform() - 0.5f, rng.uniform() - 0.5f) * 1.5f);
                m.medium = mediumAt(ws, m.p);
                inDense += m.medium == WeightScene::kDense ? 1 : 0;
                path.x.push_back(m);
            } else {
                Vec3 direction = i == 0 ? glm::normalize(camera.p + 3.0f * first) : glm::normalize(Vec3(rng.uniform() - 0.5f, rng.uniform() - 0.5f, rng.uniform() - 0.5f));
                path.x.push_back(wallVertex(direction, ws.wall));
            }
        }
        const std::uint32_t lightKind = rng.uniformIndex(3);
        BdptVertex end;
        if (lightKind == 0) {
            const auto emission = ws.scene.lights[static_cast<std::size_t>(ws.areaLight)]->sampleEmission(rng.uniform2(), rng.uniform2());
            ASSERT_TRUE(emission);
            end.kind = BdptVertexKind::Surface;
            end.p = emission->origin;
            end.ng = end.ns = emission->normal;
            end.shape = static_cast<std::uint32_t>(ws.disk);
            path.light = ws.areaLight;
        } else if (lightKind == 1) {
            end.kind = BdptVertexKind::Light;
            end.p = *ws.scene.lights[static_cast<std::size_t>(ws.pointLight)]->position();
            path.light = ws.pointLight;
            path.deltaLight = true;
        } else {
            end.kind = BdptVertexKind::Light;
            end.infinite = true;
            end.p = glm::normalize(Vec3(rng.uniform() - 0.5f, rng.uniform() - 0.5f, rng.uniform() - 0.5f));
            path.light = ws.environment;
        }
        end.light = path.light;
        path.x.push_back(end);
        if (!(bs.cameraDirectionPdf(bdptDirection(path.x[0], path.x[1])) > 0.0f)) continue;
        if (path.deltaLight && middle == 0) continue;  // no strategy renders a point light seen directly
        ++checked;
        for (MisHeuristic h : {MisHeuristic::Balance, MisHeuristic::Power}) {
            EXPECT_NEAR(weightSum(ws, bs, path, h), 1.0f, 2e-4f)
                << "trial " << trial << ", " << path.x.size() << " vertices, light kind " << lightKind;
        }
    }
    EXPECT_GT(checked, 400);
    EXPECT_GT(inDense, 50);
}

// A pool: a diffuse floor at y = 0 under a flat water surface at y = 1
// (IOR 1.33 below, normals up), a downward-facing disk lamp at y = 4 and a
// camera under the water looking down. Light reaches the floor only through
// the refraction, so a path camera -> floor -> surface -> lamp is made by two
// strategies alone: s = 0 (the camera path's ray from the floor refracts into
// the lamp) and t = 1 (the light path refracts onto the floor, which is
// connected to the camera); the refracting vertex is no connection's end.
struct PoolScene {
    Scene scene;
    static constexpr int kFloor = 0, kSurface = 1, kLamp = 2;
    static constexpr float kEta = 1.33f;
    static constexpr float kLampHeight = 4.0f, kLampRadius = 1.0f;

    PoolScene() {
        scene.bsdfs.push_back(makeDiffuse(makeConstantTexture(Rgb(0.8f))));
        scene.bsdfs.push_back(makeDielectric(kEta));
        const Mat4 faceUp = glm::rotate(Mat4(1.0f), -kPi / 2.0f, Vec3(1, 0, 0));
        Shape floor;
        TriangleMesh floorMesh = makeRectangleMesh();
        floorMesh.transform(glm::scale(Mat4(1.0f), Vec3(3.0f)) * faceUp);
        floor.geometry = floorMesh;
        floor.bsdf = 0;
        scene.shapes.push_back(floor);
        Shape surface;
        TriangleMesh surfaceMesh = makeRectangleMesh();
        surfaceMesh.transform(glm::translate(Mat4(1.0f), Vec3(0.0f, 1.0f, 0.0f)) * glm::scale(Mat4(1.0f), Vec3(3.0f)) * faceUp);
        surface.geometry = surfaceMesh;
        surface.bsdf = 1;
        scene.shapes.push_back(surface);
        Shape lamp;
        TriangleMesh lampMesh = makeDiskMesh(64);
        lampMesh.transform(glm::translate(Mat4(1.0f), Vec3(0.0f, kLampHeight, 0.0f)) *
                           glm::rotate(Mat4(1.0f), kPi / 2.0f, Vec3(1, 0, 0)) * glm::scale(Mat4(1.0f), Vec3(kLampRadius)));
        lamp.geometry = lampMesh;
        lamp.bsdf = 0;
        lamp.areaLight = 0;
        scene.lights.push_back(makeAreaLight(lamp, Rgb(10.0f)));
        scene.lightShape.push_back(kLamp);
        scene.shapes.push_back(lamp);
        scene.camera.eye = Vec3(0.0f, 0.85f, 0.0f);
        // Tilted, so that the camera's area density, and with it the best weights, vary over the floor.
        scene.camera.target = Vec3(0.5f, 0.0f, 0.0f);
        scene.camera.up = Vec3(0.0f, 0.0f, -1.0f);
        scene.camera.fovYDegrees = 90.0f;
        scene.camera.width = scene.camera.height = 64;
        scene.finalize();
    }
};

BdptVertex poolVertex(const Vec3& p, int shape, const Vec3& normal) {
    BdptVertex v;
    v.kind = BdptVertexKind::Surface;
    v.p = p;
    v.ng = v.ns = normal;
    v.shape = static_cast<std::uint32_t>(shape);
    return v;
}

// Where a ray from the floor point x1 up through the surface point x2 meets
// the lamp's plane, by Snell's law in double precision (independent of the BSDF code).
glm::dvec3 refractToLampPlane(const glm::dvec3& x1, const glm::dvec3& x2) {
    const glm::dvec3 d = glm::normalize(x2 - x1);
    const glm::dvec3 n(0.0, 1.0, 0.0);
    const double r = static_cast<double>(PoolScene::kEta);  // water over air
    const double c = glm::dot(d, n);
    const glm::dvec3 up = r * d + (std::sqrt(1.0 - r * r * (1.0 - c * c)) - r * c) * n;
    return x2 + ((static_cast<double>(PoolScene::kLampHeight) - x2.y) / up.y) * up;
}

// One path x0 (camera) .. x3 (lamp) through the surface, as both subpaths store it.
struct PoolPath {
    std::vector<BdptVertex> camera;  // z0 camera, z1 floor, z2 surface (specular), z3 lamp
    std::vector<BdptVertex> light;   // y0 lamp, y1 surface (specular), y2 floor
};

// Traces the path backwards from a lamp point through a surface point with
// the dielectric's own refraction; false when the floor point is outside the image.
bool makePoolPath(const PoolScene& ps, const BdptScene& bs, const Vec3& x3, const Vec3& x2, PoolPath& path) {
    const Bsdf& water = *ps.scene.bsdfs[PoolScene::kSurface];
    const Frame frame(Vec3(0.0f, 1.0f, 0.0f));
    const Vec3 toLamp = glm::normalize(x3 - x2);
    // Transmission: a lobe sample beyond the Fresnel reflectance.
    const auto down = water.sample(frame.toLocal(toLamp), TexturePoint{Vec2(0.0f)}, 0.9999f, Vec2(0.5f), TransportMode::Importance);
    if (!down || !(down->lobe & BsdfLobe::Transmission)) return false;
    const Vec3 toFloor = frame.toWorld(down->wi);
    const Vec3 x1 = x2 + (-x2.y / toFloor.y) * toFloor;
    const Vec3 eye = ps.scene.camera.eye;
    if (!(bs.cameraDirectionPdf(glm::normalize(x1 - eye)) > 0.0f)) return false;

    const Vec3 up(0.0f, 1.0f, 0.0f), lampNormal(0.0f, -1.0f, 0.0f);
    std::vector<BdptVertex>& z = path.camera;
    z.assign(4, BdptVertex());
    z[0].kind = BdptVertexKind::Camera;
    z[0].p = eye;
    z[1] = poolVertex(x1, PoolScene::kFloor, up);
    z[2] = poolVertex(x2, PoolScene::kSurface, up);
    z[3] = poolVertex(x3, PoolScene::kLamp, lampNormal);
    z[3].light = 0;
    for (std::size_t i = 1; i < 4; ++i) z[i].wo = bdptDirection(z[i], z[i - 1]);
    z[2].delta = true;
    const auto up2 = water.sample(frame.toLocal(z[2].wo), TexturePoint{Vec2(0.0f)}, 0.9999f, Vec2(0.5f), TransportMode::Radiance);
    if (!up2 || glm::length(frame.toWorld(up2->wi) - toLamp) > 1e-4f) return false;
    const BdptSpecularPdfs cameraSpecular = bdptSpecularPdfs(frame.toLocal(z[2].wo), up2->wi, up2->eta);
    z[0].pdfFwd = 1.0f;
    z[1].pdfFwd = bdptPdf(bs, nullptr, z[0], z[1]);
    z[2].pdfFwd = bdptPdf(bs, &z[0], z[1], z[2]);
    z[3].pdfFwd = bdptConvertDensity(cameraSpecular.forward, z[2], z[3]);
    z[0].pdfRev = bdptPdf(bs, &z[2], z[1], z[0]);
    z[1].pdfRev = bdptConvertDensity(cameraSpecular.reverse, z[2], z[1]);
    z[2].pdfRev = z[3].pdfRev = -1.0f;  // the weight sets them

    std::vector<BdptVertex>& y = path.light;
    y.assign(3, BdptVertex());
    y[0].kind = BdptVertexKind::Light;
    y[0].p = x3;
    y[0].ng = lampNormal;
    y[0].light = 0;
    y[1] = poolVertex(x2, PoolScene::kSurface, up);
    y[2] = poolVertex(x1, PoolScene::kFloor, up);
    for (std::size_t i = 1; i < 3; ++i) y[i].wo = bdptDirection(y[i], y[i - 1]);
    y[1].delta = true;
    const BdptSpecularPdfs lightSpecular = bdptSpecularPdfs(frame.toLocal(toLamp), down->wi, down->eta);
    y[0].pdfFwd = bdptPdfLightOrigin(bs, y[0]);
    y[1].pdfFwd = bdptPdf(bs, nullptr, y[0], y[1]);
    y[2].pdfFwd = bdptConvertDensity(lightSpecular.forward, y[1], y[2]);
    y[0].pdfRev = bdptConvertDensity(lightSpecular.reverse, y[1], y[0]);
    y[1].pdfRev = y[2].pdfRev = -1.0f;
    return true;
}

// Densities of the two strategies in one measure, dA(x1) dA(x2) (x3 follows
// from them by the refraction): the camera path samples x1 and x2; the light
// path samples x3 and x2, its density carried over to x1 by the Jacobian
// |dA(x3) / dA(x1)| at fixed x2, by central differences of Snell's law.
struct StrategyDensities {
    double camera = 0.0;  // s = 0, t = 4
    double light = 0.0;   // s = 3, t = 1
};

StrategyDensities poolDensities(const PoolPath& path) {
    const glm::dvec3 x1(path.camera[1].p), x2(path.camera[2].p);
    const double h = 1e-4;
    const auto lampAt = [&](double dx, double dz) { return refractToLampPlane(x1 + glm::dvec3(dx, 0.0, dz), x2); };
    const glm::dvec3 ddx = (lampAt(h, 0.0) - lampAt(-h, 0.0)) / (2.0 * h);
    const glm::dvec3 ddz = (lampAt(0.0, h) - lampAt(0.0, -h)) / (2.0 * h);
    const double jacobian = std::abs(ddx.x * ddz.z - ddx.z * ddz.x);  // both planes horizontal
    StrategyDensities d;
    d.camera = static_cast<double>(path.camera[1].pdfFwd) * path.camera[2].pdfFwd;
    d.light = static_cast<double>(path.light[0].pdfFwd) * path.light[1].pdfFwd * jacobian;
    return d;
}

// Random lamp and surface points whose refracted path lands on the floor in view.
template <typename Check>
int forPoolPaths(const PoolScene& ps, const BdptScene& bs, Check check) {
    jobs::Rng rng(11, 13, 17);
    int checked = 0;
    for (int trial = 0; trial < 200; ++trial) {
        const Vec2 u = rng.uniform2();
        const float radius = PoolScene::kLampRadius * std::sqrt(u.x), phi = 2.0f * kPi * u.y;
        const Vec3 x3(radius * std::cos(phi), PoolScene::kLampHeight, radius * std::sin(phi));
        const Vec2 v = rng.uniform2();
        const Vec3 x2(1.6f * (v.x - 0.5f), 1.0f, 1.6f * (v.y - 0.5f));
        PoolPath path;
        if (!makePoolPath(ps, bs, x3, x2, path)) continue;
        ++checked;
        check(path, trial);
    }
    return checked;
}

// The densities of a vertex from the side that did not sample it, as the
// other subpath stores them, must be the densities that subpath samples it
// with: across the refraction they hold the Dirac factor of opposite
// directions, which must be the same factor for the weights to compare like with like.
TEST(BdptMis, SpecularReverseDensitiesMatchTheOtherSubpath) {
    PoolScene ps;
    const RayQuery rays(ps.scene);
    const BdptScene bs(ps.scene, rays, ps.scene.camera);
    const int checked = forPoolPaths(ps, bs, [](const PoolPath& path, int trial) {
        // The floor point, sampled by the light path through the refraction.
        EXPECT_NEAR(path.camera[1].pdfRev, path.light[2].pdfFwd, 1e-4f * path.light[2].pdfFwd) << "trial " << trial;
        // The lamp point, sampled by the camera path through the refraction.
        EXPECT_NEAR(path.camera[3].pdfFwd, path.light[0].pdfRev, 1e-4f * path.light[0].pdfRev) << "trial " << trial;
        EXPECT_GT(path.camera[1].pdfRev, 0.0f) << "trial " << trial;
        EXPECT_GT(path.camera[3].pdfFwd, 0.0f) << "trial " << trial;
    });
    EXPECT_GT(checked, 100);
}

// Through a refraction the weights of the two strategies must be the
// heuristics of their true densities (Veach §9.2: p_i / sum_j p_j, or its
// squares), which account for how the refraction maps the floor onto the
// lamp (distances on either side, the cosines and eta^2): the Dirac factors
// do not cancel to 1 unless they are expressed in the same measure.
TEST(BdptMis, WeightsThroughARefractionFollowTheTrueDensities) {
    PoolScene ps;
    const RayQuery rays(ps.scene);
    const BdptScene bs(ps.scene, rays, ps.scene.camera);
    double smallest = kInfinity, largest = 0.0;
    const int checked = forPoolPaths(ps, bs, [&](const PoolPath& path, int trial) {
        const StrategyDensities d = poolDensities(path);
        const double ratio = d.light / d.camera;
        // Closed form for flat, horizontal floor, surface and lamp: the
        // lamp's cosine-weighted emission through the refraction reaches the
        // floor with eta^2 times the density with which the floor's diffuse
        // sampling reaches the surface, so the ratio is eta^2 p(x3) / p_camera(x1).
        const double closedForm = static_cast<double>(PoolScene::kEta) * PoolScene::kEta * path.light[0].pdfFwd / path.camera[1].pdfFwd;
        EXPECT_NEAR(ratio, closedForm, 1e-3 * closedForm) << "trial " << trial;
        smallest = std::min(smallest, ratio);
        largest = std::max(largest, ratio);
        for (MisHeuristic h : {MisHeuristic::Balance, MisHeuristic::Power}) {
            const float cameraWeight = bdptMisWeight(bs, {}, path.camera, nullptr, 0, 4, h);
            const float lightWeight =
                bdptMisWeight(bs, path.light, std::span<const BdptVertex>(path.camera).first(1), nullptr, 3, 1, h);
            EXPECT_NEAR(cameraWeight + lightWeight, 1.0f, 1e-4f) << "trial " << trial;
            const double r = h == MisHeuristic::Power ? ratio * ratio : ratio;
            EXPECT_NEAR(lightWeight, r / (1.0 + r), 2e-3) << "trial " << trial << ", density ratio " << ratio;
            EXPECT_NEAR(cameraWeight, 1.0 / (1.0 + r), 2e-3) << "trial " << trial << ", density ratio " << ratio;
        }
    });
    EXPECT_GT(checked, 100);
    // The geometry must give the check something to discriminate.
    EXPECT_LT(smallest, largest * 0.8) << "density ratios " << smallest << " to " << largest;
}

}  // namespace
}  // namespace fg
