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

}  // namespace
}  // namespace fg
