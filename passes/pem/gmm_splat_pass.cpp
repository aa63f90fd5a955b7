// Gaussian mixture splat pass (`gmm_splat`): Jakob et al. 2011 §8.1, their GPU
// preview of one pyramid level, on the CPU. Every node of the chosen level of
// the Gaussian pyramid (§6; the nodes at or below the level whose parent is
// above it, as gmm_render's mode = level) is truncated to the ellipsoid of
// §7.1, Mahalanobis radius r_j with Phi_j P(chi_3 > r_j) = delta W / k as in
// gmm_bbh, and projected to the screen rectangle that bounds it (per screen
// axis, the two planes through the eye tangent to the ellipsoid). Every pixel
// of the rectangle whose centre ray meets the ellipsoid (the elliptical splat
// of §8.1) adds Eq. 15,
//   1/4 pi Phi_j int_0^b g_j(x + t w) e^{-sigma_t t} dt,
// with Eqs. 16-17 in corrected form (engine/gmm/gaussian.h). As in the paper,
// surfaces are ignored, b = infinity; with `depth_clip` b is the first surface
// along the ray. x is where the centre ray enters a scattering medium: the
// camera, when it sits in one, or else the first crossing of index-matched
// (null) boundaries into one; an opaque or specular surface before any such
// medium leaves the pixel black. The film is cut into tiles, and each tile
// sums its splats in pyramid order, pixel by pixel, so the image depends
// neither on the thread count nor on the tile size. Writes the `volume` layer
// (a film from black, as gmm_render) and the AOV query_gaussians; `frames`
// repeats the whole frame (pixel rays, rectangles, tiles) for timing, and the
// counter frame_ns is its mean wall time, so frames/s = 1e9 / frame_ns (the
// level's nodes, Gaussians and radii, which do not depend on the view, are
// prepared once). An orthographic camera's splats cover the whole film (the
// ray test still picks the pixels).
#include "passes/passes.h"

#include "passes/common/path_vertex.h"
#include "passes/pem/pem_common.h"
#include "engine/accel/ray_query.h"
#include "engine/core/error.h"
#include "engine/image/film.h"
#include "engine/scene/scene.h"
#include "jobs/parallel.h"
#include "jobs/work_context.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <string>

namespace fg {

namespace {

constexpr std::size_t kPixelGrain = 256;
constexpr std::size_t kSplatGrain = 64;
// Null boundaries crossed before a pixel's ray gives up looking for a medium.
constexpr int kMaxNullCrossings = 1024;

// What Eq. 15 needs of one pixel's centre ray.
struct PixelRay {
    glm::dvec3 start{0.0}, direction{0.0, 0.0, 1.0}, sigmaT{0.0};
    double length = std::numeric_limits<double>::infinity();
    // Transmittance up to `start` (non-scattering media before it); black: the
    // ray meets no scattering medium.
    Rgb weight{0.0f};
};

// A node of the level with its truncated ellipsoid and the pixels it may cover.
struct Splat {
    std::uint32_t node = 0;
    double radiusSquared = 0.0;
    int x0 = 0, y0 = 0, x1 = -1, y1 = -1;  // inclusive; empty when x1 < x0
};

// ceil(log2 k): the levels above the leaves of a pyramid over k Gaussians (Alg. 3).
std::int64_t pyramidLevels(std::int64_t k) {
    std::int64_t levels = 0;
    while ((std::int64_t{1} << levels) < k) ++levels;
    return levels;
}

bool scattering(const Scene& scene, int medium) {
    return medium >= 0 && !isBlack(scene.media[static_cast<std::size_t>(medium)].sigmaS());
}

PixelRay pixelRay(const Scene& scene, const Camera& camera, const RayQuery* rays, int x, int y, bool depthClip) {
    Ray ray = camera.generateRay(Vec2(static_cast<float>(x) + 0.5f, static_cast<float>(y) + 0.5f));
    ray.direction = glm::normalize(ray.direction);
    PixelRay out;
    int medium = camera.medium;
    Rgb weight(1.0f);
    for (int crossings = 0; !scattering(scene, medium); ++crossings) {
        if (!rays || crossings > kMaxNullCrossings) return out;
        const Hit hit = rays->intersect(ray);
        if (medium >= 0) {
            const HomogeneousMedium& crossed = scene.media[static_cast<std::size_t>(medium)];
            weight *= segmentTransmittance(crossed, hit.valid() ? hit.t : kInfinity);
        }
        if (!hit.valid() || isBlack(weight)) return out;
        const Shape& shape = scene.shapes[hit.shape];
        const Bsdf* bsdf = shape.bsdf >= 0 ? scene.bsdfs[static_cast<std::size_t>(shape.bsdf)].get() : nullptr;
        if (bsdf && !bsdf->isNull()) return out;
        const SurfacePoint sp = rays->surface(ray, hit);
        medium = mediumAfterCrossing(shape, sp.ng, ray.direction, medium);
        ray.origin = offsetRayOrigin(sp.p, sp.ng, ray.direction);
    }
    if (depthClip) {
        const Hit hit = rays->intersect(ray);
        if (hit.valid()) out.length = static_cast<double>(hit.t);
    }
    out.start = glm::dvec3(ray.origin);
    out.direction = glm::dvec3(ray.direction);
    out.sigmaT = glm::dvec3(scene.media[static_cast<std::size_t>(medium)].sigmaT());
    out.weight = weight;
    return out;
}

// The perspective camera's screen in the frame of its own rays: a point q
// (relative to the eye) lies at raster x = (right.q / forward.q / rightScale + 1) w / 2
// and raster y = (1 - up.q / forward.q / upScale) h / 2.
struct Screen {
    glm::dvec3 eye{0.0}, forward{0.0}, right{0.0}, up{0.0};
    double rightScale = 1.0, upScale = 1.0;
    int width = 0, height = 0;
    bool perspective = false;

    explicit Screen(const Camera& camera) : eye(camera.eye), width(camera.width), height(camera.height) {
        perspective = !camera.orthographic;
        const auto centreRay = [&](float x, float y) {
            return glm::normalize(glm::dvec3(camera.generateRay(Vec2(x, y)).direction));
        };
        const float w = static_cast<float>(width), h = static_cast<float>(height);
        forward = centreRay(0.5f * w, 0.5f * h);
        const glm::dvec3 rightEdge = centreRay(w, 0.5f * h), topEdge = centreRay(0.5f * w, 0.0f);
        const glm::dvec3 toRight = rightEdge / glm::dot(rightEdge, forward) - forward;
        const glm::dvec3 toTop = topEdge / glm::dot(topEdge, forward) - forward;
        rightScale = glm::length(toRight);
        upScale = glm::length(toTop);
        right = toRight / rightScale;
        up = toTop / upScale;
    }
};

// The range of (axis . q) / (forward . q) over the ellipsoid
// (q - d)^T Sigma^-1 (q - d) <= r^2 (q relative to the eye). The plane
// (axis - u forward) . q = 0 through the eye touches the ellipsoid where its
// support function vanishes: (axis . d - u forward . d)^2 = r^2 (axis - u forward)^T Sigma (axis - u forward),
// a quadratic A u^2 - 2 B u + C = 0 whose roots bound the range. False when the
// ellipsoid reaches behind the eye's plane (forward . d <= r sqrt(forward^T Sigma forward)),
// where the projection is unbounded.
bool tangentRange(const glm::dvec3& axis, const glm::dvec3& forward, const glm::dvec3& d, const gmm::Sym3& sigma,
                  double radiusSquared, double& lo, double& hi) {
    const glm::dvec3 sigmaForward = sigma * forward;
    const double axisD = glm::dot(axis, d), forwardD = glm::dot(forward, d);
    const double a = forwardD * forwardD - radiusSquared * glm::dot(forward, sigmaForward);
    if (!(forwardD > 0.0 && a > 0.0)) return false;
    const double b = axisD * forwardD - radiusSquared * glm::dot(axis, sigmaForward);
    const double c = axisD * axisD - radiusSquared * glm::dot(axis, sigma * axis);
    const double root = std::sqrt(std::max(0.0, b * b - a * c));
    lo = (b - root) / a;
    hi = (b + root) / a;
    return true;
}

// Pixels whose centres lie in the raster interval [from, to], widened by a
// pixel against the rounding of the camera's float rays; clamped to [0, size).
void pixelSpan(double from, double to, int size, int& first, int& last) {
    const double lo = std::clamp(std::ceil(from - 1.5), 0.0, static_cast<double>(size));
    const double hi = std::clamp(std::floor(to + 0.5), -1.0, static_cast<double>(size - 1));
    first = static_cast<int>(lo);
    last = static_cast<int>(hi);
}

void setRectangle(const Screen& screen, const glm::dvec3& mean, const gmm::Sym3& sigma, Splat& splat) {
    splat.x0 = 0;
    splat.y0 = 0;
    splat.x1 = screen.width - 1;
    splat.y1 = screen.height - 1;
    if (!screen.perspective) return;  // the whole film; the ray test still picks the covered pixels
    const glm::dvec3 d = mean - screen.eye;
    double uLo = 0.0, uHi = 0.0, vLo = 0.0, vHi = 0.0;
    if (!tangentRange(screen.right, screen.forward, d, sigma, splat.radiusSquared, uLo, uHi) ||
        !tangentRange(screen.up, screen.forward, d, sigma, splat.radiusSquared, vLo, vHi))
        return;
    const double halfWidth = 0.5 * screen.width, halfHeight = 0.5 * screen.height;
    pixelSpan((uLo / screen.rightScale + 1.0) * halfWidth, (uHi / screen.rightScale + 1.0) * halfWidth, screen.width,
              splat.x0, splat.x1);
    pixelSpan((1.0 - vHi / screen.upScale) * halfHeight, (1.0 - vLo / screen.upScale) * halfHeight, screen.height,
              splat.y0, splat.y1);
}

// Whether start + t direction, t in [0, length], meets the ellipsoid
// (x - mu)^T Sigma^-1 (x - mu) <= r^2.
bool meetsEllipsoid(const gmm::SegmentGaussian& g, double radiusSquared, const PixelRay& ray) {
    const glm::dvec3 q = ray.start - g.mean;
    const glm::dvec3 precisionW = g.precision * ray.direction;
    const double a = glm::dot(ray.direction, precisionW);
    const double b = glm::dot(q, precisionW);
    const double c = g.precision.quadratic(q) - radiusSquared;
    const double discriminant = b * b - a * c;
    if (discriminant < 0.0 || !(a > 0.0)) return false;
    const double root = std::sqrt(discriminant);
    return (-b + root) / a >= 0.0 && (-b - root) / a <= ray.length;
}

struct FrameCounts {
    std::int64_t pixelsTested = 0, gaussiansEvaluated = 0;
};

// What does not depend on the view: the level's nodes in pyramid
// (depth-first) order, their Gaussians as Eq. 16 reads them, their powers
// and truncation radii.
struct Level {
    std::vector<Splat> splats;
    std::vector<gmm::SegmentGaussian> gaussians;
    std::vector<glm::dvec3> means, powers;
    std::vector<gmm::Sym3> covariances;

    Level(const GmmPyramidBuffer& nodes, std::uint32_t level, double delta) {
        if (nodes.empty()) return;
        const auto right = nodes.column<GmmRight>();
        const auto nodeLevel = nodes.column<GmmLevel>();
        std::vector<std::uint32_t> stack{0};
        while (!stack.empty()) {
            const std::uint32_t j = stack.back();
            stack.pop_back();
            if (right[j] == kNoGmmNode || nodeLevel[j] <= level) {
                splats.push_back({j, 0.0, 0, 0, -1, -1});
                continue;
            }
            stack.push_back(right[j]);
            stack.push_back(j + 1);
        }
        const auto power = nodes.column<GmmPower>();
        const double allowed = delta * energy(power[0]) / static_cast<double>((nodes.size() + 1) / 2);
        gaussians.resize(splats.size());
        means.resize(splats.size());
        powers.resize(splats.size());
        covariances.resize(splats.size());
        jobs::parallelFor(splats.size(), kSplatGrain, [&](std::size_t s) {
            const std::uint32_t j = splats[s].node;
            gaussians[s] = gmm::SegmentGaussian(gaussianAt(nodes, j));
            means[s] = nodes.column<GmmMean>()[j];
            covariances[s] = nodes.column<GmmCovariance>()[j];
            powers[s] = power[j];
            const double e = energy(power[j]);
            const double r = e > 0.0 ? gmm::truncationRadius(allowed / e) : 0.0;
            splats[s].radiusSquared = r * r;
        });
    }
};

class GmmSplatPass final : public Pass {
public:
    void run(PassContext& ctx) override {
        const Scene& scene = ctx.scene();
        const GmmPyramid& pyramid = ctx.input<GmmPyramid>("pyramid");
        const PassParams& params = ctx.params();
        const auto levelIndex = static_cast<std::uint32_t>(params.getInt("level"));
        const bool depthClip = params.getBool("depth_clip");
        const auto tile = static_cast<int>(params.getInt("tile"));
        const std::int64_t frames = params.getInt("frames");
        if (!pyramid.nodes.empty() && levelIndex > pyramid.levels) {
            throw InputError("pass '" + ctx.instanceName() + "': level " + std::to_string(levelIndex) +
                             " does not exist: the fitted pyramid has levels 0 (the leaves) to " +
                             std::to_string(pyramid.levels));
        }
        Level level(pyramid.nodes, levelIndex, params.getFloat("delta"));

        const Camera camera = ctx.filmCamera();
        const bool needsRays = depthClip || !scattering(scene, camera.medium);
        const RayQuery* rays = needsRays ? &ctx.rays() : nullptr;

        std::vector<Rgb> radiance;
        std::vector<float> gaussiansPerPixel;
        FrameCounts counts;
        const std::int64_t start = jobs::wallNanos();
        for (std::int64_t frame = 0; frame < frames; ++frame)
            counts = renderFrame(scene, camera, rays, level, depthClip, tile, radiance, gaussiansPerPixel);
        const std::int64_t elapsed = jobs::wallNanos() - start;

        Film& image = ctx.createOutput<Film>("volume", ctx.filmSettings());
        image.aov("query_gaussians") = gaussiansPerPixel;
        image.addToPixels(radiance, 1.0f);
        ctx.addItems(frames);
        ctx.addCounter("frames", frames);
        ctx.addCounter("frame_ns", elapsed / frames);
        ctx.addCounter("splats", static_cast<std::int64_t>(level.splats.size()));
        ctx.addCounter("splat_pixels", counts.pixelsTested);
        ctx.addCounter("gaussians_evaluated", counts.gaussiansEvaluated);
    }

private:
    // One view of the level: the pixels' rays, the splats' rectangles, their
    // tiles, and Eq. 15 per covered pixel.
    static FrameCounts renderFrame(const Scene& scene, const Camera& camera, const RayQuery* rays, Level& level,
                                   bool depthClip, int tile, std::vector<Rgb>& radiance,
                                   std::vector<float>& gaussiansPerPixel) {
        const int width = camera.width, height = camera.height;
        const std::size_t pixelCount = static_cast<std::size_t>(width) * static_cast<std::size_t>(height);
        radiance.assign(pixelCount, Rgb(0.0f));
        gaussiansPerPixel.assign(pixelCount, 0.0f);
        FrameCounts counts;
        std::vector<Splat>& splats = level.splats;
        if (splats.empty() || pixelCount == 0) return counts;

        std::vector<PixelRay> pixelRays(pixelCount);
        jobs::parallelFor(pixelCount, kPixelGrain, [&](std::size_t p) {
            pixelRays[p] = pixelRay(scene, camera, rays, static_cast<int>(p % static_cast<std::size_t>(width)),
                                    static_cast<int>(p / static_cast<std::size_t>(width)), depthClip);
        });

        const Screen screen(camera);
        jobs::parallelFor(splats.size(), kSplatGrain, [&](std::size_t s) {
            if (splats[s].radiusSquared > 0.0) setRectangle(screen, level.means[s], level.covariances[s], splats[s]);
        });

        // Each tile's splats in pyramid order (compressed rows).
        const int tilesX = (width + tile - 1) / tile, tilesY = (height + tile - 1) / tile;
        const auto rowMajor = [](int x, int y, int rowLength) {
            return static_cast<std::size_t>(y) * static_cast<std::size_t>(rowLength) + static_cast<std::size_t>(x);
        };
        const std::size_t tileCount = rowMajor(0, tilesY, tilesX);
        std::vector<std::size_t> rowStart(tileCount + 1, 0);
        const auto forTilesOf = [&](const Splat& splat, auto&& body) {
            if (splat.x1 < splat.x0 || splat.y1 < splat.y0) return;
            for (int ty = splat.y0 / tile; ty <= splat.y1 / tile; ++ty)
                for (int tx = splat.x0 / tile; tx <= splat.x1 / tile; ++tx)
                    body(rowMajor(tx, ty, tilesX));
        };
        for (const Splat& splat : splats) forTilesOf(splat, [&](std::size_t t) { ++rowStart[t + 1]; });
        for (std::size_t t = 0; t < tileCount; ++t) rowStart[t + 1] += rowStart[t];
        std::vector<std::uint32_t> tileSplats(rowStart[tileCount]);
        std::vector<std::size_t> fill(rowStart.begin(), rowStart.end() - 1);
        for (std::size_t s = 0; s < splats.size(); ++s)
            forTilesOf(splats[s], [&](std::size_t t) { tileSplats[fill[t]++] = static_cast<std::uint32_t>(s); });

        std::vector<FrameCounts> perTile(tileCount);
        const double inverseFourPi = 1.0 / (4.0 * M_PI);
        jobs::parallelForChunks(tileCount, 1, [&](jobs::IndexRange range) {
            std::vector<glm::dvec3> sum;
            std::vector<float> evaluated;
            for (std::size_t t = range.begin; t != range.end; ++t) {
                const int tx0 = static_cast<int>(t % static_cast<std::size_t>(tilesX)) * tile;
                const int ty0 = static_cast<int>(t / static_cast<std::size_t>(tilesX)) * tile;
                const int tx1 = std::min(width, tx0 + tile) - 1, ty1 = std::min(height, ty0 + tile) - 1;
                const int rowLength = tx1 - tx0 + 1;
                sum.assign(rowMajor(0, ty1 - ty0 + 1, rowLength), glm::dvec3(0.0));
                evaluated.assign(sum.size(), 0.0f);
                FrameCounts& tileCounts = perTile[t];
                for (std::size_t e = rowStart[t]; e != rowStart[t + 1]; ++e) {
                    const std::uint32_t s = tileSplats[e];
                    const Splat& splat = splats[s];
                    const gmm::SegmentGaussian& g = level.gaussians[s];
                    const glm::dvec3& splatPower = level.powers[s];
                    for (int y = std::max(ty0, splat.y0); y <= std::min(ty1, splat.y1); ++y) {
                        for (int x = std::max(tx0, splat.x0); x <= std::min(tx1, splat.x1); ++x) {
                            const PixelRay& ray = pixelRays[rowMajor(x, y, width)];
                            if (isBlack(ray.weight)) continue;
                            ++tileCounts.pixelsTested;
                            if (!meetsEllipsoid(g, splat.radiusSquared, ray)) continue;
                            ++tileCounts.gaussiansEvaluated;
                            const std::size_t local = rowMajor(x - tx0, y - ty0, rowLength);
                            sum[local] += splatPower * gmm::segmentIntegralRgb(g, ray.start, ray.direction, ray.sigmaT,
                                                                               0.0, ray.length);
                            evaluated[local] += 1.0f;
                        }
                    }
                }
                for (int y = ty0; y <= ty1; ++y) {
                    for (int x = tx0; x <= tx1; ++x) {
                        const std::size_t p = rowMajor(x, y, width);
                        const std::size_t local = rowMajor(x - tx0, y - ty0, rowLength);
                        const Rgb value = Rgb(sum[local] * inverseFourPi) * pixelRays[p].weight;
                        radiance[p] = isFinite(value) ? value : Rgb(0.0f);
                        gaussiansPerPixel[p] = evaluated[local];
                    }
                }
            }
        });
        for (const FrameCounts& c : perTile) {
            counts.pixelsTested += c.pixelsTested;
            counts.gaussiansEvaluated += c.gaussiansEvaluated;
        }
        return counts;
    }
};

void preflight(const PreflightContext& pf) {
    refuseAnisotropicMedia(pf);
    const PassParams* fit = pf.producerParams ? pf.producerParams("gmm") : nullptr;
    if (!fit || fit->values().count("k") == 0) return;
    const std::int64_t k = fit->getInt("k");
    const std::int64_t levels = pyramidLevels(k);
    const std::int64_t level = pf.params.getInt("level");
    if (level > levels) {
        throw InputError(pf.source + ": pass '" + pf.instance + "': level " + std::to_string(level) +
                         " does not exist: a pyramid over k = " + std::to_string(k) +
                         " Gaussians has levels 0 (the leaves) to " + std::to_string(levels));
    }
}

}  // namespace

PassRegistration gmmSplatPass() {
    PassSpec spec;
    spec.name = "gmm_splat";
    spec.doc = "Media radiance of one Gaussian pyramid level by splatting (Jakob et al. 2011 §8.1 on the CPU): each "
               "truncated ellipsoid projected to a screen rectangle, Eq. 15 along the covered pixel-centre rays to "
               "infinity or to the first surface; tiles summed in pyramid order";
    spec.inputs = {
        {"pyramid", "GmmPyramid", "the Gaussian pyramid (gmm_pyramid)"},
        {"gmm", "GaussianMixture",
         "the mixture the pyramid was built from; only its producer's k is read, by preflight, to refuse a level the "
         "pyramid cannot have", false, true},
    };
    spec.outputs = {{"volume", "Film", "media radiance alone (a film from black); AOV query_gaussians"}};
    spec.params = {
        {"level", ParamType::Int, std::int64_t{0}, 0, 64, {},
         "the pyramid level splatted (0: the leaves; at most ceil(log2 k))"},
        {"depth_clip", ParamType::Bool, false, 0, 0, {},
         "end each pixel's integral at the first surface along its ray (false: surfaces ignored, as the paper)"},
        {"delta", ParamType::Float, 1e-3, 0.0, 1.0, {},
         "truncation: energy outside each splat's ellipsoid <= delta W / k (W total power, k leaves), as gmm_bbh"},
        {"tile", ParamType::Int, std::int64_t{16}, 1, 4096, {},
         "tile side in pixels (the image does not depend on it)"},
        {"frames", ParamType::Int, std::int64_t{1}, 1, 1000000, {},
         "render the frame this many times (timing: counter frame_ns, items = frames)"},
    };
    const auto memory = [](const PreflightContext& pf) {
        const std::uint64_t pixels =
            static_cast<std::uint64_t>(pf.film.width) * static_cast<std::uint64_t>(pf.film.height);
        return MemoryEstimate{addBytes(filmBytes(pf.film, 1), multiplyBytes(pixels, sizeof(PixelRay) + sizeof(Rgb))),
                              "film " + std::to_string(pf.film.width) + " x " + std::to_string(pf.film.height) +
                                  " and a ray per pixel",
                              {}};
    };
    return {spec, [] { return std::make_unique<GmmSplatPass>(); }, preflight, memory};
}

}  // namespace fg
