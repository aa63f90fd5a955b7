// The eye pass: its direct film against the path tracer, and the eye vertices
// it stores behind specular chains.
#include "engine/shading/bsdf.h"
#include "engine/core/error.h"
#include "engine/shading/light.h"
#include "engine/buffers/photon_buffers.h"
#include "engine/accel/ray_query.h"
#include "engine/scene/scene.h"
#include "engine/scene/scene_loader.h"
#include "passes/passes.h"
#include "tests/support/pass_helpers.h"
#include "tests/support/render_helpers.h"

#include <glm/gtc/matrix_transform.hpp>
#include <gtest/gtest.h>

#include <algorithm>

namespace fg {
namespace {

FilmSettings boxFilm(int w, int h) {
    FilmSettings f;
    f.width = w;
    f.height = h;
    return f;
}

const Pipeline kEyeOnly{"eye-only", "", {{"eye", "eye", {}, {}, 0}}, {"direct"}};

// The eye vertex's direct light is the path tracer's last vertex: on a scene
// without specular surfaces, `direct` and pt with max_depth = 1 estimate the
// same image (different random streams). The camera is turned away from the
// luminaire: the jittered coverage of its bright edges would dominate the
// noise of every sum below.
TEST(EyePass, DirectFilmMatchesPathTracerWithOneBounceOnCornellBox) {
    Scene scene = loadScene(std::string(FLUXGRAPH_SOURCE_DIR) + "/data/cornell-box/cornell-box.toml");
    scene.camera.target = Vec3(278.0f, 245.0f, 0.0f);
    scene.camera.fovYDegrees = 28.0f;
    const int w = 32, h = 32;
    const auto pt = test::renderPipeline(scene, "pt", {{"pt.spp", std::int64_t{128}}, {"pt.max_depth", std::int64_t{1}}},
                                         boxFilm(w, h));
    const BufferHandle direct = test::runPipeline(scene, kEyeOnly, passRegistry(), {{"eye.spp", std::int64_t{128}}},
                                                  boxFilm(w, h), "direct");
    const std::vector<Rgb> eye = test::bufferAs<Film>(direct).resolve();
    ASSERT_EQ(eye.size(), pt.pixels.size());

    glm::dvec3 sumEye(0.0), sumPt(0.0);
    for (std::size_t i = 0; i < eye.size(); ++i) {
        EXPECT_LT(luminance(eye[i]), 2.0f) << "the luminaire is out of view";
        sumEye += glm::dvec3(eye[i]);
        sumPt += glm::dvec3(pt.pixels[i]);
    }
    // Observed spread over seeds: 0.4 %.
    for (int c = 0; c < 3; ++c) EXPECT_NEAR(sumEye[c] / sumPt[c], 1.0, 0.015) << "channel " << c;
    // 8x8 blocks (8192 samples each); dim blocks (shadows) are held to the mean block's scale.
    const double meanBlock = luminance(Rgb(sumPt / 16.0));
    for (int by = 0; by < h; by += 8) {
        for (int bx = 0; bx < w; bx += 8) {
            double a = 0.0, b = 0.0;
            for (int y = by; y < by + 8; ++y) {
                for (int x = bx; x < bx + 8; ++x) {
                    a += luminance(eye[static_cast<std::size_t>(y * w + x)]);
                    b += luminance(pt.at(x, y));
                }
            }
            EXPECT_NEAR(a, b, 0.05 * std::max(b, meanBlock)) << "block " << bx << "," << by;
        }
    }
}

// Camera looking down at a mirror floor; the mirror shows a diffuse ceiling
// lit by a point light between the two.
struct MirrorScene {
    Scene scene;
    float mirrorReflectance = 0.8f;
    float albedo = 0.6f;
    Vec3 light{0.5f, 0.0f, 2.0f};
    float intensity = 5.0f;

    MirrorScene() {
        Shape mirror;
        TriangleMesh floor = makeRectangleMesh();
        floor.transform(glm::scale(Mat4(1.0f), Vec3(20.0f)));
        mirror.geometry = floor;
        scene.bsdfs.push_back(makeConductor(*conductorPreset("none"), Rgb(mirrorReflectance)));
        mirror.bsdf = 0;
        scene.shapes.push_back(mirror);

        Shape ceiling;
        TriangleMesh top = makeRectangleMesh();
        top.transform(glm::translate(Mat4(1.0f), Vec3(0, 0, 3)) * glm::rotate(Mat4(1.0f), kPi, Vec3(1, 0, 0)) *
                      glm::scale(Mat4(1.0f), Vec3(20.0f)));
        ceiling.geometry = top;
        scene.bsdfs.push_back(makeDiffuse(makeConstantTexture(Rgb(albedo))));
        ceiling.bsdf = 1;
        scene.shapes.push_back(ceiling);

        scene.lights.push_back(makePointLight(light, Rgb(intensity)));
        scene.lightShape.push_back(-1);
        scene.camera.eye = Vec3(0.0f, 0.0f, 1.0f);
        scene.camera.target = Vec3(0.0f, 0.0f, 0.0f);
        scene.camera.up = Vec3(0.0f, 1.0f, 0.0f);
        scene.camera.fovYDegrees = 4.0f;
        scene.finalize();
    }
};

TEST(EyePass, StoresVerticesBehindSpecularChains) {
    const MirrorScene m;
    const RayQuery rays(m.scene);
    const int spp = 3;
    const FilmSettings film = boxFilm(9, 7);
    auto out = test::runPass(eyePass(), m.scene, &rays, film, {}, {{"spp", std::int64_t{spp}}});
    const EyeVertices& eye = test::bufferAs<EyeVertices>(out.at("eye_vertices"));
    EXPECT_EQ(eye.samplesPerPixel, spp);
    const auto& v = eye.vertices;
    // Every sample sees the ceiling in the mirror: one vertex per sample, in sample order.
    ASSERT_EQ(v.size(), static_cast<std::size_t>(film.width * film.height * spp));
    for (std::size_t i = 0; i < v.size(); ++i) {
        EXPECT_EQ(v.column<EyePixel>()[i], i / spp);
        EXPECT_NEAR(v.column<EyePosition>()[i].z, 3.0f, 1e-4f);
        EXPECT_EQ(v.column<EyeBsdf>()[i], 1u);
        EXPECT_NEAR(v.column<EyeOutgoing>()[i].z, -1.0f, 0.01f);  // back down towards the mirror
        EXPECT_NEAR(v.column<EyeNormal>()[i].z, -1.0f, 1e-5f);
        const Rgb t = v.column<EyeThroughput>()[i];
        EXPECT_NEAR(t.x, m.mirrorReflectance / spp, 1e-5f);
        EXPECT_NEAR(t.y, m.mirrorReflectance / spp, 1e-5f);
        // The mirrored position: the camera ray reflected at z = 0 travels 3 more units up.
        const Vec2 xy(v.column<EyePosition>()[i].x, v.column<EyePosition>()[i].y);
        EXPECT_LT(glm::length(xy), 4.0f * std::tan(glm::radians(4.0f)));
    }

    // Direct light at the centre: the mirror's reflectance times the ceiling's
    // radiance rho/pi * I cos / d^2 (the light's reflection in the mirror is a
    // caustic, not direct light).
    const Vec3 centre(0.0f, 0.0f, 3.0f);
    const Vec3 toLight = m.light - centre;
    const float d2 = glm::dot(toLight, toLight);
    const float cosine = -toLight.z / std::sqrt(d2);  // the ceiling faces down
    const float expected = m.mirrorReflectance * m.albedo * kInvPi * m.intensity * cosine / d2;
    const std::vector<Rgb> direct = test::bufferAs<Film>(out.at("direct")).resolve();
    const Rgb mid = direct[static_cast<std::size_t>(3 * film.width + 4)];
    EXPECT_NEAR(mid.y, expected, 0.02f * expected);

    // Without specular bounces nothing diffuse is seen: no vertices, no light.
    out = test::runPass(eyePass(), m.scene, &rays, film, {}, {{"spp", std::int64_t{spp}}, {"max_specular_depth", std::int64_t{0}}});
    EXPECT_EQ(test::bufferAs<EyeVertices>(out.at("eye_vertices")).vertices.size(), 0u);
    for (const Rgb& p : test::bufferAs<Film>(out.at("direct")).resolve()) EXPECT_EQ(p, Rgb(0.0f));
}

// direct_light = false leaves the film black and nothing else changes: the
// vertices (positions, weights, everything the photon passes read) are the
// ones stored with direct light on, so caustic-only images and full images
// are made from the same eye samples. Gold ring: a directly lit floor, seen
// directly and in the ring's mirror reflection.
TEST(EyePass, WithoutDirectLightTheFilmIsBlackAndTheVerticesAreUnchanged) {
    const Scene scene = loadScene(std::string(FLUXGRAPH_SOURCE_DIR) + "/data/gold-ring/gold-ring.toml");
    const RayQuery rays(scene);
    const FilmSettings film = boxFilm(24, 24);
    const auto render = [&](bool directLight) {
        return test::runPass(eyePass(), scene, &rays, film, {},
                             {{"spp", std::int64_t{3}}, {"direct_light", directLight}}, 7);
    };
    const auto lit = render(true);
    const auto dark = render(false);

    const std::vector<Rgb> litFilm = test::bufferAs<Film>(lit.at("direct")).resolve();
    const std::vector<Rgb> darkFilm = test::bufferAs<Film>(dark.at("direct")).resolve();
    ASSERT_EQ(darkFilm.size(), litFilm.size());
    std::size_t litPixels = 0;
    for (std::size_t i = 0; i < litFilm.size(); ++i) {
        EXPECT_EQ(darkFilm[i], Rgb(0.0f)) << "pixel " << i;
        litPixels += luminance(litFilm[i]) > 0.0f ? 1 : 0;
    }
    EXPECT_GT(litPixels, litFilm.size() / 2) << "the floor is directly lit";

    const auto& a = test::bufferAs<EyeVertices>(lit.at("eye_vertices"));
    const auto& b = test::bufferAs<EyeVertices>(dark.at("eye_vertices"));
    EXPECT_EQ(a.samplesPerPixel, b.samplesPerPixel);
    ASSERT_EQ(a.vertices.size(), b.vertices.size());
    ASSERT_GT(a.vertices.size(), static_cast<std::size_t>(film.width * film.height));
    const auto same = [](auto columnA, auto columnB) {
        return std::equal(columnA.begin(), columnA.end(), columnB.begin(), columnB.end());
    };
    const EyeVertexBuffer& va = a.vertices;
    const EyeVertexBuffer& vb = b.vertices;
    EXPECT_TRUE(same(va.column<EyePosition>(), vb.column<EyePosition>()));
    EXPECT_TRUE(same(va.column<EyeNormal>(), vb.column<EyeNormal>()));
    EXPECT_TRUE(same(va.column<EyeGeometricNormal>(), vb.column<EyeGeometricNormal>()));
    EXPECT_TRUE(same(va.column<EyeOutgoing>(), vb.column<EyeOutgoing>()));
    EXPECT_TRUE(same(va.column<EyeUv>(), vb.column<EyeUv>()));
    EXPECT_TRUE(same(va.column<EyeThroughput>(), vb.column<EyeThroughput>()));
    EXPECT_TRUE(same(va.column<EyeBsdf>(), vb.column<EyeBsdf>()));
    EXPECT_TRUE(same(va.column<EyePixel>(), vb.column<EyePixel>()));
    // Some vertices lie behind the gold mirror (throughput below the 1/spp of a directly seen floor).
    const auto throughput = va.column<EyeThroughput>();
    EXPECT_TRUE(std::any_of(throughput.begin(), throughput.end(),
                            [](const Rgb& t) { return t.z < 0.99f / 3.0f; }));
}

TEST(EyePass, DeterministicForAnyThreadCountAndRejectsMedia) {
    const Scene scene = loadScene(std::string(FLUXGRAPH_SOURCE_DIR) + "/data/cornell-box/cornell-box.toml");
    const FilmSettings film = boxFilm(12, 12);
    const auto run = [&](int threads) {
        return test::runPipeline(scene, kEyeOnly, passRegistry(), {{"eye.spp", std::int64_t{4}}}, film, "direct", 3,
                                 threads);
    };
    const std::vector<Rgb> a = test::bufferAs<Film>(run(1)).resolve();
    const std::vector<Rgb> b = test::bufferAs<Film>(run(2)).resolve();
    EXPECT_EQ(a, b);
    // Nearly every sample sees a diffuse surface through the open front (the
    // image corners look past the box); no chains, so the weight is 1/spp.
    const RayQuery rays(scene);
    const auto out = test::runPass(eyePass(), scene, &rays, film, {}, {{"spp", std::int64_t{4}}});
    const auto& vertices = test::bufferAs<EyeVertices>(out.at("eye_vertices")).vertices;
    EXPECT_GT(vertices.size(), 12u * 12u * 4u * 9u / 10u);
    EXPECT_LE(vertices.size(), 12u * 12u * 4u);
    for (const Rgb& t : vertices.column<EyeThroughput>()) EXPECT_EQ(t, Rgb(0.25f));
    const auto pixels = vertices.column<EyePixel>();
    EXPECT_TRUE(std::is_sorted(pixels.begin(), pixels.end()));

    Scene withMedium = scene;
    withMedium.media.emplace_back(Rgb(0.1f), Rgb(0.1f), 0.0f);
    const RayQuery mediumRays(withMedium);
    EXPECT_THROW(test::runPass(eyePass(), withMedium, &mediumRays, film, {}), InputError);
}

}  // namespace
}  // namespace fg
