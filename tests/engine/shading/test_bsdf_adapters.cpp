// Mask, bump map and normal map adapters: the normals they produce against
// hand-derived ones, and chi-square tests of the wrapped materials as the
// tracers use them (sampled around the perturbed normal, seen from the
// unperturbed frame, with the geometric-normal leak check applied).
#include "engine/shading/bsdf_adapters.h"

#include "engine/accel/ray_query.h"
#include "engine/scene/scene.h"
#include "jobs/random.h"
#include "tests/engine/shading/bsdf_test_util.h"
#include "tests/support/chi2.h"

#include <gtest/gtest.h>

#include <functional>
#include <string>

namespace fg {
namespace {

// h(u, v) = a u + b v, the slope a bump map reads.
class RampTexture final : public Texture {
public:
    RampTexture(float a, float b) : a_(a), b_(b) {}
    Rgb eval(const Vec2& uv) const override { return Rgb(a_ * uv.x + b_ * uv.y); }
    Rgb mean() const override { return Rgb(0.5f * (a_ + b_)); }

private:
    float a_, b_;
};

void expectNear(const Vec3& a, const Vec3& b, float tolerance, const std::string& what) {
    for (int c = 0; c < 3; ++c) EXPECT_NEAR(a[c], b[c], tolerance) << what << " component " << c;
}

// A flat patch in the z = 0 plane, parametrised by p = (2 u, 3 v, 0).
ShadingGeometry flatPatch() {
    ShadingGeometry g;
    g.dpdu = Vec3(2, 0, 0);
    g.dpdv = Vec3(0, 3, 0);
    g.ng = Vec3(0, 0, 1);
    g.uv = Vec2(0.3f, 0.6f);
    return g;
}

TEST(BumpMap, NormalOfTheDisplacedSurface) {
    // Displacing p = (2u, 3v, 0) by h = s (a u + b v) along z gives the tangents
    // (2, 0, s a) and (0, 3, s b), whose cross product is (-3 s a, -2 s b, 6).
    const float a = 0.4f, b = -0.7f, scale = 1.5f;
    const auto bump = makeBumpMap(makeDiffuse(makeConstantTexture(Rgb(0.5f))), std::make_shared<RampTexture>(a, b), scale);
    EXPECT_TRUE(bump->perturbsNormal());
    const Vec3 expected = glm::normalize(Vec3(-3.0f * scale * a, -2.0f * scale * b, 6.0f));
    expectNear(bump->perturbedNormal(flatPatch()), expected, 1e-4f, "bump");
    // A flat height field leaves the normal alone.
    const auto flat = makeBumpMap(makeDiffuse(makeConstantTexture(Rgb(0.5f))), makeConstantTexture(Rgb(0.3f)));
    expectNear(flat->perturbedNormal(flatPatch()), Vec3(0, 0, 1), 1e-6f, "flat");
}

TEST(NormalMap, TangentSpaceFollowsDpDu) {
    // Shading frame turned by 90 degrees about z: s = +y. The map's (1, 0, 1) /
    // sqrt(2) (rgb = (1, 0.5, 1)) then leans towards +y in world space.
    ShadingGeometry g = flatPatch();
    g.frame.s = Vec3(0, 1, 0);
    g.frame.t = Vec3(-1, 0, 0);
    g.frame.n = Vec3(0, 0, 1);
    const auto map = makeNormalMap(makeDiffuse(makeConstantTexture(Rgb(0.5f))), makeConstantTexture(Rgb(1.0f, 0.5f, 1.0f)));
    expectNear(map->perturbedNormal(g), glm::normalize(Vec3(0, 1, 1)), 1e-6f, "tilted");
    const auto straight =
        makeNormalMap(makeDiffuse(makeConstantTexture(Rgb(0.5f))), makeConstantTexture(Rgb(0.5f, 0.5f, 1.0f)));
    expectNear(straight->perturbedNormal(g), Vec3(0, 0, 1), 1e-6f, "straight");
    // A normal pointing into the surface is turned to the geometric normal's side.
    const auto inward =
        makeNormalMap(makeDiffuse(makeConstantTexture(Rgb(0.5f))), makeConstantTexture(Rgb(0.5f, 0.5f, 0.2f)));
    EXPECT_GT(inward->perturbedNormal(g).z, 0.0f);
}

TEST(Mask, OpacityComposesAndScatteringIsTheInnerMaterials) {
    const auto inner = makeRoughConductor(*conductorPreset("Cu"), 0.3f);
    const auto mask = makeMask(inner, makeConstantTexture(Rgb(0.4f)));
    const auto nested = makeMask(makeTwoSided(mask), makeConstantTexture(Rgb(0.5f)));
    EXPECT_TRUE(nested->hasOpacity());
    EXPECT_NEAR(mask->opacity(Vec2(0.5f)), 0.4f, 1e-6f);
    EXPECT_NEAR(nested->opacity(Vec2(0.5f)), 0.2f, 1e-6f);
    EXPECT_NEAR(makeMask(inner, makeConstantTexture(Rgb(3.0f)))->opacity(Vec2(0.5f)), 1.0f, 0.0f);
    const Vec3 wo = test::directionFromAngles(40.0f, 10.0f), wi = test::directionFromAngles(35.0f, 200.0f);
    EXPECT_EQ(mask->eval(wo, wi, Vec2(0.5f), TransportMode::Radiance), inner->eval(wo, wi, Vec2(0.5f), TransportMode::Radiance));
    EXPECT_EQ(mask->pdf(wo, wi, Vec2(0.5f)), inner->pdf(wo, wi, Vec2(0.5f)));
    EXPECT_EQ(mask->lobes(), inner->lobes());
}

// The adapter as a tracer sees it: directions in the frame of the unperturbed
// shading normal (+z, geometric normal too), the material evaluated in a frame
// around the perturbed normal, and directions under the geometric surface
// refused (the tracers' leak check).
struct TracerView {
    std::shared_ptr<Bsdf> bsdf;
    Frame perturbed;
    Vec2 uv;

    std::optional<Vec3> sample(const Vec3& wo, float uLobe, const Vec2& u) const {
        const auto s = bsdf->sample(perturbed.toLocal(wo), uv, uLobe, u, TransportMode::Radiance);
        if (!s || s->isSpecular()) return std::nullopt;
        const Vec3 wi = perturbed.toWorld(s->wi);
        if (wi.z * s->wi.z <= 0.0f) return std::nullopt;
        return wi;
    }
    double pdf(const Vec3& wo, const Vec3& wi) const {
        const Vec3 local = perturbed.toLocal(wi);
        if (wi.z * local.z <= 0.0f) return 0.0;
        return bsdf->pdf(perturbed.toLocal(wo), local, uv);
    }
};

struct AdapterCase {
    std::string name;
    std::function<std::shared_ptr<Bsdf>()> make;
    float woThetaDeg;
};

std::vector<AdapterCase> adapterCases() {
    const auto rough = [] { return makeRoughConductor(*conductorPreset("Au"), 0.3f); };
    const auto diffuse = [] { return makeDiffuse(makeConstantTexture(Rgb(0.7f))); };
    return {
        {"BumpedDiffuse", [=] { return makeBumpMap(diffuse(), std::make_shared<RampTexture>(0.9f, -0.5f)); }, 30.0f},
        {"BumpedRoughConductor", [=] { return makeBumpMap(rough(), std::make_shared<RampTexture>(0.6f, 0.4f)); }, 60.0f},
        {"NormalMappedDiffuse",
         [=] { return makeNormalMap(diffuse(), makeConstantTexture(Rgb(0.85f, 0.35f, 0.8f))); }, 45.0f},
        {"NormalMappedRoughConductor",
         [=] { return makeNormalMap(rough(), makeConstantTexture(Rgb(0.75f, 0.6f, 0.9f))); }, 70.0f},
        {"MaskedTwoSidedRoughConductor",
         [=] { return makeMask(makeTwoSided(makeNormalMap(rough(), makeConstantTexture(Rgb(0.6f, 0.5f, 0.9f)))),
                               makeConstantTexture(Rgb(0.5f))); },
         20.0f},
    };
}

class AdapterChi2 : public ::testing::TestWithParam<AdapterCase> {};

TEST_P(AdapterChi2, SamplingMatchesPdfAroundThePerturbedNormal) {
    const AdapterCase& c = GetParam();
    const std::shared_ptr<Bsdf> bsdf = c.make();
    ShadingGeometry geometry = flatPatch();
    const Vec3 n = bsdf->perturbedNormal(geometry);
    ASSERT_NEAR(glm::length(n), 1.0f, 1e-5f);
    if (bsdf->perturbsNormal()) {
        ASSERT_LT(n.z, 0.999f) << "the case should tilt the normal";
    }
    const TracerView view{bsdf, Frame(n), geometry.uv};
    const Vec3 wo = test::directionFromAngles(c.woThetaDeg, 25.0f);

    test::Chi2Config config;
    config.samples = 400'000;
    config.testCount = static_cast<int>(adapterCases().size());
    config.seed = std::hash<std::string>{}(c.name);
    jobs::Rng lobeRng(config.seed, jobs::streamKey("adapter-chi2-lobe"), 0);
    const test::Chi2Result result = test::chi2SphereTest(
        [&](const Vec2& u) { return view.sample(wo, lobeRng.uniform(), u); },
        [&](const Vec3& wi) { return view.pdf(wo, wi); }, config);
    EXPECT_TRUE(result.passed) << c.name << ": " << result.message;
}

INSTANTIATE_TEST_SUITE_P(BsdfAdapters, AdapterChi2, ::testing::ValuesIn(adapterCases()),
                         [](const ::testing::TestParamInfo<AdapterCase>& param) { return param.param.name; });

// A white Lambertian material around a tilted normal loses what would leave
// through the geometric surface and gains nothing: its albedo seen from the
// tracer stays at most 1 and equals the share of its cosine lobe above z = 0.
TEST(NormalMap, WhiteFurnaceLosesOnlyTheLobeBelowTheSurface) {
    const auto map = makeNormalMap(makeDiffuse(makeConstantTexture(Rgb(1.0f))), makeConstantTexture(Rgb(0.5f, 0.85f, 0.8f)));
    const Vec3 n = map->perturbedNormal(flatPatch());
    const TracerView view{map, Frame(n), Vec2(0.5f)};
    const Vec3 wo = test::directionFromAngles(20.0f, 90.0f);
    jobs::Rng rng(7, jobs::streamKey("normal-map-furnace"), 0);
    constexpr int kSamples = 200'000;
    int kept = 0;
    for (int i = 0; i < kSamples; ++i)
        if (view.sample(wo, rng.uniform(), rng.uniform2())) ++kept;
    // Share of a cosine lobe around n above the plane z = 0, by quadrature.
    double above = 0.0;
    constexpr int kSteps = 400;
    for (int i = 0; i < kSteps; ++i)
        for (int j = 0; j < kSteps; ++j) {
            const Vec3 local = sampleCosineHemisphere(Vec2((i + 0.5f) / kSteps, (j + 0.5f) / kSteps));
            if (Frame(n).toWorld(local).z > 0.0f) above += 1.0;
        }
    above /= kSteps * kSteps;
    EXPECT_LT(above, 0.999);
    EXPECT_NEAR(static_cast<double>(kept) / kSamples, above, 0.005);
}

// The tracers get the perturbed normal from RayQuery::surface, which supplies
// dp/du: tangent-space (1, 0, 1) / sqrt(2) must lean towards increasing u.
TEST(NormalMap, SurfaceLeansTowardsIncreasingU) {
    Scene scene;
    scene.bsdfs.push_back(
        makeNormalMap(makeDiffuse(makeConstantTexture(Rgb(0.5f))), makeConstantTexture(Rgb(1.0f, 0.5f, 1.0f))));
    // A rectangle turned by 90 degrees about z: u increases along +y.
    Shape rectangle;
    TriangleMesh mesh = makeRectangleMesh();
    mesh.transform(Mat4(Vec4(0, 1, 0, 0), Vec4(-1, 0, 0, 0), Vec4(0, 0, 1, 0), Vec4(0, 0, 0, 1)));
    rectangle.geometry = std::move(mesh);
    rectangle.bsdf = 0;
    scene.shapes.push_back(std::move(rectangle));
    // A sphere: u = phi / 2 pi increases anticlockwise about +z.
    Shape sphere;
    sphere.geometry = Sphere{Vec3(10, 0, 0), 1.0f};
    sphere.bsdf = 0;
    scene.shapes.push_back(std::move(sphere));
    scene.finalize();
    RayQuery rays(scene);

    const Ray down{Vec3(0.2f, 0.3f, 5.0f), Vec3(0, 0, -1), kInfinity};
    const Hit onRectangle = rays.intersect(down);
    ASSERT_TRUE(onRectangle.valid());
    const SurfacePoint flat = rays.surface(down, onRectangle);
    expectNear(flat.ng, Vec3(0, 0, 1), 1e-6f, "geometric normal unchanged");
    expectNear(flat.ns, glm::normalize(Vec3(0, 1, 1)), 1e-5f, "rectangle");

    // On the sphere's equator facing -y (phi = 270 degrees) phi grows towards +x.
    const Ray sideways{Vec3(10, -5, 0), Vec3(0, 1, 0), kInfinity};
    const Hit onSphere = rays.intersect(sideways);
    ASSERT_TRUE(onSphere.valid());
    const SurfacePoint round = rays.surface(sideways, onSphere);
    expectNear(round.ng, Vec3(0, -1, 0), 1e-5f, "sphere geometric normal");
    expectNear(round.ns, glm::normalize(Vec3(1, -1, 0)), 1e-4f, "sphere");
}

}  // namespace
}  // namespace fg
