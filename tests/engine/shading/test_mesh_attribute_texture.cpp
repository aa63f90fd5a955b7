// The mesh_attribute texture on a mesh built in code: a face attribute is one
// value over each triangle, a vertex attribute is interpolated with the hit's
// barycentrics, one channel is grey, scale multiplies, and a lookup without a
// mesh (or of a name the mesh lacks) is black. Also blendbsdf weighted by one.
#include "engine/scene/shape.h"
#include "engine/shading/bsdf.h"
#include "engine/shading/bsdf_adapters.h"
#include "engine/shading/mesh_attribute_texture.h"

#include <gtest/gtest.h>

#include <string>

namespace fg {
namespace {

void expectNear(const Rgb& a, const Rgb& b, float tolerance, const std::string& what) {
    for (int c = 0; c < 3; ++c) EXPECT_NEAR(a[c], b[c], tolerance) << what << " component " << c;
}

// The unit square as two triangles, (0 1 2) and (0 2 3).
TriangleMesh squareWithAttributes() {
    TriangleMesh mesh;
    mesh.positions = {{0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0}};
    mesh.indices = {0, 1, 2, 0, 2, 3};
    mesh.attributes.push_back({"vertex_color", 3, {1, 0, 0, 0, 1, 0, 0, 0, 1, 1, 1, 1}});
    mesh.attributes.push_back({"face_color", 3, {0.2f, 0.4f, 0.6f, 0.9f, 0.8f, 0.7f}});
    mesh.attributes.push_back({"face_weight", 1, {0.25f, 0.75f}});
    return mesh;
}

TEST(MeshAttributeTexture, FaceValueIsConstantOverEachTriangle) {
    const TriangleMesh mesh = squareWithAttributes();
    const auto texture = makeMeshAttributeTexture("face_color");
    for (const Vec2 barycentric : {Vec2(0.0f), Vec2(0.2f, 0.3f), Vec2(0.5f, 0.5f), Vec2(0.0f, 1.0f)}) {
        expectNear(texture->evalAt(TexturePoint(Vec2(0.0f), &mesh, 0, barycentric)), Rgb(0.2f, 0.4f, 0.6f), 0.0f, "triangle 0");
        expectNear(texture->evalAt(TexturePoint(Vec2(0.0f), &mesh, 1, barycentric)), Rgb(0.9f, 0.8f, 0.7f), 0.0f, "triangle 1");
    }
    // One channel reads as grey.
    const auto weight = makeMeshAttributeTexture("face_weight");
    expectNear(weight->evalAt(TexturePoint(Vec2(0.0f), &mesh, 1, Vec2(0.3f))), Rgb(0.75f), 0.0f, "face_weight");
    EXPECT_NEAR(weight->evalScalar(TexturePoint(Vec2(0.0f), &mesh, 0, Vec2(0.3f))), 0.25f, 1e-6f);
}

TEST(MeshAttributeTexture, VertexValueIsInterpolatedWithTheBarycentrics) {
    const TriangleMesh mesh = squareWithAttributes();
    const auto texture = makeMeshAttributeTexture("vertex_color", 2.0f);
    // At the corners: the vertex's own value (times scale).
    expectNear(texture->evalAt(TexturePoint(Vec2(0.0f), &mesh, 0, Vec2(0.0f, 0.0f))), Rgb(2, 0, 0), 1e-6f, "vertex 0");
    expectNear(texture->evalAt(TexturePoint(Vec2(0.0f), &mesh, 0, Vec2(1.0f, 0.0f))), Rgb(0, 2, 0), 1e-6f, "vertex 1");
    expectNear(texture->evalAt(TexturePoint(Vec2(0.0f), &mesh, 1, Vec2(0.0f, 1.0f))), Rgb(2, 2, 2), 1e-6f, "vertex 3");
    // Inside: b0 v0 + b1 v1 + b2 v2 of the triangle's own corners.
    expectNear(texture->evalAt(TexturePoint(Vec2(0.0f), &mesh, 0, Vec2(0.2f, 0.3f))), 2.0f * Rgb(0.5f, 0.2f, 0.3f), 1e-6f,
               "triangle 0");
    expectNear(texture->evalAt(TexturePoint(Vec2(0.0f), &mesh, 1, Vec2(0.2f, 0.3f))), 2.0f * Rgb(0.8f, 0.3f, 0.5f), 1e-6f,
               "triangle 1");
}

TEST(MeshAttributeTexture, WithoutTheMeshOrTheAttributeItIsBlack) {
    const TriangleMesh mesh = squareWithAttributes();
    expectNear(makeMeshAttributeTexture("vertex_color")->evalAt(Vec2(0.5f)), Rgb(0.0f), 0.0f, "no mesh");
    expectNear(makeMeshAttributeTexture("vertex_normal")->evalAt(TexturePoint(Vec2(0.0f), &mesh, 0, Vec2(0.2f))), Rgb(0.0f),
               0.0f, "missing attribute");
}

TEST(MeshAttributeTexture, DiffuseAndBlendReadItThroughTheirLookupPoint) {
    const TriangleMesh mesh = squareWithAttributes();
    const Vec3 up(0.0f, 0.0f, 1.0f);
    const auto red = makeDiffuse(makeConstantTexture(Rgb(1, 0, 0)));
    const auto blue = makeDiffuse(makeConstantTexture(Rgb(0, 0, 1)));
    const auto blend = makeBlend(red, blue, makeMeshAttributeTexture("face_weight"));
    const auto coloured = makeDiffuse(makeMeshAttributeTexture("face_color"));
    for (std::uint32_t triangle : {0u, 1u}) {
        const TexturePoint at(Vec2(0.0f), &mesh, triangle, Vec2(0.1f, 0.2f));
        const float w = mesh.attributes[2].values[triangle];
        const Rgb expected = ((1.0f - w) * Rgb(1, 0, 0) + w * Rgb(0, 0, 1)) * kInvPi;
        expectNear(blend->eval(up, up, at, TransportMode::Radiance), expected, 1e-6f, "blend eval");
        ASSERT_TRUE(blend->constantReflectance(at).has_value());
        expectNear(*blend->constantReflectance(at), expected, 1e-6f, "blend constant reflectance");
        const float* c = &mesh.attributes[1].values[3 * triangle];
        expectNear(coloured->eval(up, up, at, TransportMode::Radiance), Rgb(c[0], c[1], c[2]) * kInvPi, 1e-6f, "diffuse");
    }
}

// A sample of the blend carries the blend's own value over its own density,
// whichever material drew it, and the two are chosen with 1 - w and w.
TEST(MeshAttributeTexture, BlendSamplesAreTheMixturesValueOverItsDensity) {
    const TriangleMesh mesh = squareWithAttributes();
    const auto diffuse = makeDiffuse(makeConstantTexture(Rgb(0.8f)));
    const auto glossy = makeRoughConductor(*conductorPreset("Au"), 0.3f);
    const auto blend = makeBlend(diffuse, glossy, makeMeshAttributeTexture("face_weight"));
    const TexturePoint at(Vec2(0.0f), &mesh, 0, Vec2(0.1f, 0.2f));
    const Vec3 wo = glm::normalize(Vec3(0.3f, -0.2f, 0.9f));
    int samples = 0;
    for (int i = 0; i < 64; ++i) {
        const float uLobe = (static_cast<float>(i) + 0.5f) / 64.0f;
        const Vec2 u(static_cast<float>((i * 37) % 64) / 64.0f + 0.004f, static_cast<float>((i * 11) % 64) / 64.0f + 0.007f);
        const std::optional<BsdfSample> s = blend->sample(wo, at, uLobe, u, TransportMode::Radiance);
        if (!s) continue;
        ++samples;
        EXPECT_NEAR(s->pdf, blend->pdf(wo, s->wi, at), 1e-4f * s->pdf);
        expectNear(s->weight * s->pdf, blend->eval(wo, s->wi, at, TransportMode::Radiance), 1e-4f, "weight * pdf");
    }
    EXPECT_GT(samples, 48);
}

}  // namespace
}  // namespace fg
