// The `light_trace` pass (pipeline `lt`) against images with known answers: a diffuse floor lit
// by a point light directly and through a perfect vertical mirror (the
// caustic is the direct light of the mirror image source), seen by a tilted
// camera through box and Gaussian pixel filters; identical images for one and
// two threads; the near clip plane; scenes with media refused.
#include "engine/shading/bsdf.h"
#include "engine/core/error.h"
#include "engine/shading/light.h"
#include "engine/scene/scene.h"
#include "engine/shading/texture.h"
#include "tests/support/render_helpers.h"

#include <glm/gtc/matrix_transform.hpp>
#include <gtest/gtest.h>

#include <cmath>
#include <functional>

namespace fg {
namespace {

const Rgb kFloorAlbedo(0.7f, 0.5f, 0.3f);
const Vec3 kLight(0.0f, 0.0f, 1.0f);
const Vec3 kMirrorImage(2.0f, 0.0f, 1.0f);  // the light reflected in the mirror x = 1
constexpr float kIntensity = 2.0f;

// Floor z = 0 (x in [-4, 1], y in [-4, 4]), a perfect mirror x = 1 facing -x
// (z in [0, 4]), the point light at height 1, and a camera that sees only the
// floor, tilted so that neither the floor's cosine nor the camera's is constant.
Scene mirrorScene() {
    Scene scene;
    scene.bsdfs.push_back(makeDiffuse(makeConstantTexture(kFloorAlbedo)));
    scene.bsdfs.push_back(makeConductor(*conductorPreset("none")));
    Shape floor;
    TriangleMesh floorMesh = makeRectangleMesh();
    floorMesh.transform(glm::translate(Mat4(1.0f), Vec3(-1.5f, 0, 0)) * glm::scale(Mat4(1.0f), Vec3(2.5f, 4.0f, 1.0f)));
    floor.geometry = floorMesh;
    floor.bsdf = 0;
    scene.shapes.push_back(floor);
    Shape mirror;
    TriangleMesh mirrorMesh = makeRectangleMesh();
    mirrorMesh.transform(glm::translate(Mat4(1.0f), Vec3(1.0f, 0.0f, 2.0f)) *
                         glm::rotate(Mat4(1.0f), -0.5f * kPi, Vec3(0, 1, 0)) *
                         glm::scale(Mat4(1.0f), Vec3(2.0f, 4.0f, 1.0f)));
    mirror.geometry = mirrorMesh;
    mirror.bsdf = 1;
    scene.shapes.push_back(mirror);
    scene.lights.push_back(makePointLight(kLight, Rgb(kIntensity)));
    scene.lightShape.push_back(-1);
    scene.camera.eye = Vec3(-0.6f, 0.3f, 2.5f);
    scene.camera.target = Vec3(-0.4f, 0.0f, 0.0f);
    scene.camera.up = Vec3(0.0f, 1.0f, 0.0f);
    scene.camera.fovYDegrees = 40.0f;
    scene.finalize();
    return scene;
}

// Radiance of the floor at (x, y) from a point source of kIntensity at `source` (height 1).
double floorRadiance(const Vec3& source, double x, double y, int channel) {
    const double r2 = sqr(x - source.x) + sqr(y - source.y) + sqr(source.z);
    return kFloorAlbedo[channel] / M_PI * kIntensity * source.z / (r2 * std::sqrt(r2));
}

// Expected pixel values: the radiance of the floor point each raster position
// sees, weighted by the film's filter around the pixel centre (1/8-pixel grid).
std::vector<Rgb> expectedImage(const Scene& scene, const FilmSettings& film,
                               const std::function<double(double, double, int)>& radiance) {
    Camera camera = scene.camera;
    camera.width = film.width;
    camera.height = film.height;
    const int perPixel = 8;
    const int reach = static_cast<int>(std::ceil(film.filterRadius * perPixel));
    const PixelFilter filter(film);
    std::vector<Rgb> image;
    for (int py = 0; py < film.height; ++py)
        for (int px = 0; px < film.width; ++px) {
            glm::dvec3 sum(0.0);
            double weights = 0.0;
            for (int i = -reach; i < reach; ++i)
                for (int j = -reach; j < reach; ++j) {
                    const float dx = (i + 0.5f) / perPixel, dy = (j + 0.5f) / perPixel;
                    const float w = filter(dx, dy);
                    if (w == 0.0f) continue;
                    const Ray ray = camera.generateRay(Vec2(px + 0.5f + dx, py + 0.5f + dy));
                    const float t = -ray.origin.z / ray.direction.z;
                    const Vec3 hit = ray.origin + t * ray.direction;
                    for (int c = 0; c < 3; ++c) sum[c] += w * radiance(hit.x, hit.y, c);
                    weights += w;
                }
            image.push_back(Rgb(sum / weights));
        }
    return image;
}

void expectMatches(const test::RenderedImage& rendered, const std::vector<Rgb>& expected, double pixelTolerance,
                   const std::string& what) {
    ASSERT_EQ(rendered.pixels.size(), expected.size());
    glm::dvec3 renderedSum(0.0), expectedSum(0.0);
    for (std::size_t i = 0; i < expected.size(); ++i) {
        for (int c = 0; c < 3; ++c) {
            ASSERT_GT(expected[i][c], 0.0f);
            EXPECT_NEAR(rendered.pixels[i][c] / expected[i][c], 1.0, pixelTolerance)
                << what << ", pixel " << i << ", channel " << c;
        }
        renderedSum += glm::dvec3(rendered.pixels[i]);
        expectedSum += glm::dvec3(expected[i]);
    }
    // Hundreds of pixels: the mean's noise is a tenth of a pixel's.
    for (int c = 0; c < 3; ++c) EXPECT_NEAR(renderedSum[c] / expectedSum[c], 1.0, 0.012) << what << ", channel " << c;
}

FilmSettings filmWith(FilterKind filter) {
    FilmSettings film;
    film.width = 12;
    film.height = 12;
    film.filter = filter;
    if (filter == FilterKind::Gaussian) {
        film.filterRadius = 1.5f;
        film.gaussianSigma = 0.5f;
    }
    return film;
}

// Direct photons only (paths end at their first event): about 2000 reach each
// pixel, a relative standard deviation near 2 %.
TEST(LightTrace, DirectLightOfAPointSourceMatchesTheAnalyticImage) {
    const Scene scene = mirrorScene();
    const std::map<std::string, ParamValue> params = {{"photon.photons", std::int64_t{4000000}},
                                                      {"photon.store", std::string("global")},
                                                      {"photon.store_direct", true},
                                                      {"photon.max_depth", std::int64_t{1}},
                                                      {"photon.differentials", false}};
    for (FilterKind filter : {FilterKind::Box, FilterKind::Gaussian}) {
        const FilmSettings film = filmWith(filter);
        const test::RenderedImage image = test::renderPipeline(scene, "lt", params, film);
        const auto direct = [](double x, double y, int c) { return floorRadiance(kLight, x, y, c); };
        expectMatches(image, expectedImage(scene, film, direct), 0.12,
                      filter == FilterKind::Box ? "box filter" : "Gaussian filter");
    }
}

// Caustic photons (L S D) only: the image is the mirror image source's direct light.
TEST(LightTrace, MirrorCausticMatchesTheImageSource) {
    const Scene scene = mirrorScene();
    const std::map<std::string, ParamValue> params = {{"photon.photons", std::int64_t{12000000}},
                                                      {"photon.store", std::string("caustic")},
                                                      {"photon.caustic_only_paths", true},
                                                      {"photon.differentials", false}};
    const FilmSettings film = filmWith(FilterKind::Box);
    const test::RenderedImage image = test::renderPipeline(scene, "lt", params, film);
    const auto caustic = [](double x, double y, int c) { return floorRadiance(kMirrorImage, x, y, c); };
    expectMatches(image, expectedImage(scene, film, caustic), 0.15, "mirror caustic");
}

TEST(LightTrace, ImageIsIdenticalForOneAndTwoThreads) {
    const Scene scene = mirrorScene();
    const std::map<std::string, ParamValue> params = {{"photon.photons", std::int64_t{300000}},
                                                      {"photon.batch_size", std::int64_t{40000}}};
    const FilmSettings film = filmWith(FilterKind::Gaussian);
    const test::RenderedImage one = test::renderPipeline(scene, "lt", params, film, 3, 1);
    const test::RenderedImage two = test::renderPipeline(scene, "lt", params, film, 3, 2);
    ASSERT_EQ(one.pixels.size(), two.pixels.size());
    EXPECT_GT(luminance(one.mean()), 0.0f);
    for (std::size_t i = 0; i < one.pixels.size(); ++i)
        for (int c = 0; c < 3; ++c) ASSERT_EQ(one.pixels[i][c], two.pixels[i][c]) << "pixel " << i;
}

// Geometry between the eye and the near clip plane is not seen, as by the
// camera's own rays: a sheet over the whole view just in front of the lens hides
// the floor, unless the near plane lies beyond it.
TEST(LightTrace, GeometryBeforeTheNearPlaneIsIgnored) {
    const std::map<std::string, ParamValue> params = {{"photon.photons", std::int64_t{200000}},
                                                      {"photon.store", std::string("global")},
                                                      {"photon.store_direct", true},
                                                      {"photon.max_depth", std::int64_t{1}}};
    const FilmSettings film = filmWith(FilterKind::Box);
    const Scene open = mirrorScene();
    Scene covered = mirrorScene();
    Shape sheet;
    TriangleMesh sheetMesh = makeRectangleMesh();
    sheetMesh.transform(glm::translate(Mat4(1.0f), Vec3(-0.6f, 0.3f, 2.45f)) * glm::scale(Mat4(1.0f), Vec3(1.0f)));
    sheet.geometry = sheetMesh;
    sheet.bsdf = 0;
    covered.shapes.push_back(sheet);
    covered.finalize();
    const test::RenderedImage reference = test::renderPipeline(open, "lt", params, film);
    EXPECT_EQ(luminance(test::renderPipeline(covered, "lt", params, film).mean()), 0.0f);
    covered.camera.nearClip = 0.1f;
    const test::RenderedImage clipped = test::renderPipeline(covered, "lt", params, film);
    ASSERT_GT(luminance(reference.mean()), 0.0f);
    for (std::size_t i = 0; i < reference.pixels.size(); ++i)
        for (int c = 0; c < 3; ++c)
            EXPECT_NEAR(clipped.pixels[i][c], reference.pixels[i][c], 1e-5f * reference.pixels[i][c]) << "pixel " << i;
}

TEST(LightTrace, ScenesWithMediaAreRefused) {
    Scene scene = mirrorScene();
    scene.media.emplace_back(Rgb(0.1f), Rgb(0.1f), 0.0f);
    const std::map<std::string, ParamValue> params = {{"photon.photons", std::int64_t{1000}}};
    EXPECT_THROW(test::renderPipeline(scene, "lt", params, filmWith(FilterKind::Box)), InputError);
}

}  // namespace
}  // namespace fg
