// The window room (data/window-room/, written by tools/make_geometry.py): a
// closed room lit by a sky with a small sun only through a gap between two
// curtains behind a thin glass pane. Its guiding benchmark (tools/guiding_report.py)
// means something only if the scene is what it claims: closed but for the
// window, and sunlit through the gap onto the floor.
#include "engine/accel/ray_query.h"
#include "engine/core/job.h"
#include "engine/scene/scene_loader.h"
#include "engine/shading/bsdf.h"
#include "engine/shading/light.h"
#include "tests/support/cli_helpers.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <string>

namespace fg {
namespace {

const std::string kScene = test::sourcePath("data/window-room/window-room.xml");

// Inside of the room and the window opening in its wall x = -3 (tools/make_geometry.py, WINDOW_ROOM).
constexpr float kRoomX = 3.0f, kRoomY = 3.0f, kRoomZ = 2.0f;
constexpr float kOpeningZ0 = -0.9f, kOpeningZ1 = 0.9f, kOpeningY0 = 0.8f, kOpeningY1 = 2.4f;

struct Trace {
    bool escaped = false;     // left the scene
    int glassCrossings = 0;   // null events passed on the way
    Vec3 firstGlassPoint{0.0f};
    Vec3 end{0.0f};           // the opaque surface hit, if it did not escape
};

// Follows a ray through surfaces with null events (the pane) to the first opaque one.
Trace follow(const Scene& scene, const RayQuery& rays, Ray ray) {
    Trace trace;
    for (int crossing = 0; crossing < 16; ++crossing) {
        const Hit hit = rays.intersect(ray);
        if (!hit.valid()) {
            trace.escaped = true;
            return trace;
        }
        const SurfacePoint sp = rays.surface(ray, hit);
        const Bsdf& bsdf = *scene.bsdfs[static_cast<std::size_t>(scene.shapes[hit.shape].bsdf)];
        if (!bsdf.hasNullLobe()) {
            trace.end = sp.p;
            return trace;
        }
        if (trace.glassCrossings++ == 0) trace.firstGlassPoint = sp.p;
        ray.origin = offsetRayOrigin(sp.p, sp.ng, ray.direction);
    }
    ADD_FAILURE() << "more than 16 null crossings";
    return trace;
}

Vec3 sphereDirection(float u, float v) {
    const float z = 1.0f - 2.0f * u, r = std::sqrt(std::max(0.0f, 1.0f - z * z)), phi = 2.0f * kPi * v;
    return {r * std::cos(phi), z, r * std::sin(phi)};
}

TEST(WindowRoom, LoadsWithASkyAndAThinPane) {
    const Scene scene = loadScene(kScene);
    ASSERT_EQ(scene.lights.size(), 1u);
    EXPECT_TRUE(scene.lights[0]->isInfinite());
    EXPECT_FALSE(scene.lights[0]->isDelta());
    int null = 0, diffuse = 0;
    for (const Shape& shape : scene.shapes) {
        const Bsdf& bsdf = *scene.bsdfs[static_cast<std::size_t>(shape.bsdf)];
        if (bsdf.hasNullLobe()) ++null;
        else if (bsdf.lobes() == (BsdfLobe::Diffuse | BsdfLobe::Reflection)) ++diffuse;
    }
    EXPECT_EQ(null, 1) << "one glass pane";
    EXPECT_EQ(diffuse + null, static_cast<int>(scene.shapes.size())) << "everything else diffuse";
}

// From points spread over the room's free air, rays in all directions: every
// ray that leaves the scene crossed the pane first, inside the window opening,
// so the only light that enters comes through the window.
TEST(WindowRoom, ClosedButForTheWindow) {
    const Scene scene = loadScene(kScene);
    const RayQuery rays(scene);
    int escaped = 0, total = 0;
    for (const Vec3 origin : {Vec3(0.0f, 1.5f, 0.0f), Vec3(2.5f, 2.5f, -1.5f), Vec3(-2.5f, 0.3f, -1.5f),
                              Vec3(-2.0f, 2.8f, 1.0f), Vec3(1.5f, 1.2f, 1.8f), Vec3(-2.9f, 1.5f, 0.0f)}) {
        for (int i = 0; i < 64; ++i) {
            for (int j = 0; j < 64; ++j) {
                const Trace t = follow(scene, rays, Ray{origin, sphereDirection((i + 0.5f) / 64, (j + 0.5f) / 64)});
                ++total;
                if (!t.escaped) {
                    EXPECT_LE(std::abs(t.end.x), kRoomX + 0.2f);
                    EXPECT_LE(std::abs(t.end.z), kRoomZ + 0.2f);
                    continue;
                }
                ++escaped;
                ASSERT_EQ(t.glassCrossings, 1) << "escaped without crossing the pane";
                EXPECT_NEAR(t.firstGlassPoint.x, -kRoomX - 0.05f, 1e-3f);
                EXPECT_GE(t.firstGlassPoint.z, kOpeningZ0 - 1e-3f);
                EXPECT_LE(t.firstGlassPoint.z, kOpeningZ1 + 1e-3f);
                EXPECT_GE(t.firstGlassPoint.y, kOpeningY0 - 1e-3f);
                EXPECT_LE(t.firstGlassPoint.y, kOpeningY1 + 1e-3f);
            }
        }
    }
    // The gap is narrow: only the point just behind it sees much of the sky.
    EXPECT_GT(escaped, 0);
    EXPECT_LT(escaped, total / 20);
}

// The sky's brightest direction (the sun) reaches a narrow streak of the floor
// through the gap and the pane, and the camera sees part of it.
TEST(WindowRoom, SunLightsAFloorStreakThroughTheGap) {
    const Scene scene = loadScene(kScene);
    const RayQuery rays(scene);
    const Light& sky = *scene.lights[0];
    Vec3 sun(0.0f);
    float brightest = 0.0f;
    for (int i = 0; i < 256; ++i) {
        for (int j = 0; j < 512; ++j) {
            const Vec3 d = sphereDirection((i + 0.5f) / 256, (j + 0.5f) / 512);
            const float y = luminance(sky.environment(d));
            if (y > brightest) brightest = y, sun = d;
        }
    }
    ASSERT_GT(sun.y, 0.0f) << "the sun is above the horizon";
    // The sun outshines the zenith sky by orders of magnitude.
    EXPECT_GT(brightest, 1000.0f * luminance(sky.environment(Vec3(0.0f, 1.0f, 0.0f))));

    int lit = 0, floorPoints = 0, litSeen = 0;
    const int n = 240;
    for (int i = 0; i < n; ++i) {
        for (int k = 0; k < n * 2 / 3; ++k) {
            const Vec3 p(-kRoomX + 2.0f * kRoomX * (i + 0.5f) / n, 1e-3f, -kRoomZ + 2.0f * kRoomZ * (k + 0.5f) / (n * 2 / 3));
            ++floorPoints;
            const Trace t = follow(scene, rays, Ray{p, sun});
            if (!t.escaped) continue;
            ++lit;
            EXPECT_EQ(t.glassCrossings, 1);
            EXPECT_LT(std::abs(t.firstGlassPoint.z), 0.5f) << "through the gap, near z = 0";
            const Vec3 toCamera = scene.camera.eye - p;
            if (!rays.occluded(Ray{p, glm::normalize(toCamera), glm::length(toCamera)})) ++litSeen;
        }
    }
    EXPECT_GT(lit, floorPoints / 500) << "a streak, not nothing";
    EXPECT_LT(lit, floorPoints / 20) << "a streak, not the whole floor";
    EXPECT_GT(litSeen, lit / 2) << "the camera sees most of the streak";
}

// `fluxgraph validate` accepts the scene's jobs.
TEST(WindowRoom, JobsValidate) {
    const auto dir = test::scratchDirectory("window_room");
    for (const char* job : {"pt.toml", "guided-pt.toml", "quality-pt.toml"}) {
        const test::CommandResult r = test::runFluxgraph(dir, {"validate", test::sourcePath(std::string("data/window-room/") + job)});
        EXPECT_EQ(r.exitCode, 0) << job << ": " << r.err;
    }
}

// guided-pt.toml spells out the built-in guided-pt pipeline with 3 training
// passes (a job cannot change a built-in pipeline's repeat count), so that it
// shows what tools/guiding_report.py runs; a copy left behind when the
// pipeline changes (as when guided environment emission, Vorba et al. 2014
// §4.4, was added to it) would silently measure something else.
TEST(WindowRoom, GuidedJobSpellsOutTheBuiltInPipeline) {
    const auto pipelineLines = [](const std::string& text) {
        std::string out;
        std::size_t start = text.find("[pipeline]");
        EXPECT_NE(start, std::string::npos);
        if (start == std::string::npos) return out;
        std::size_t pos = start;
        while (pos < text.size()) {
            const std::size_t end = std::min(text.find('\n', pos), text.size());
            const std::string line = text.substr(pos, end - pos);
            pos = end + 1;
            // Its name, its description and the training count are the job's own.
            if (line.empty() || line[0] == '#' || line.rfind("name = \"guided-pt", 0) == 0 || line.rfind("doc =", 0) == 0 ||
                line.rfind("count =", 0) == 0)
                continue;
            out += line + "\n";
        }
        return out;
    };
    const std::string job = test::readText(test::sourcePath("data/window-room/guided-pt.toml"));
    const std::string builtIn = test::readText(test::sourcePath("passes/pipelines/guided-pt.toml"));
    EXPECT_EQ(pipelineLines(job), pipelineLines(builtIn));
    EXPECT_NE(job.find("count = 3\n"), std::string::npos);
}

}  // namespace
}  // namespace fg
