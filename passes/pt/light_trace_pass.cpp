// Light tracing (`light_trace`): every stored photon is connected to the
// pinhole camera, the t = 1 strategy of bidirectional path tracing (Veach 1997,
// §10.2; the particle tracing of Dutré, Lafortune and Willems 1993). No density
// estimation is involved, so the image is an unbiased estimate of what the
// camera sees of the photons' surfaces: the reference for light that a path
// tracer cannot reach, such as caustics under collimated or point light seen
// on a diffuse surface (L S+ D E), which photon differential splatting and
// standard photon mapping (Frisvad et al. 2014, §4.1) are judged against.
//
// A photon of flux Phi_p at x_p, arriving from w_i and seen along w_o, adds to
// the pixel j whose filter reaches its raster position r_p
//
//   I_j += Phi_p f_r(x_p, w_i, w_o) G(x_p) w(r_p - c_j) / W,
//   G(x_p) = (H / (2 tan(fov_y / 2)))^2 |n_g . w_o| / (d^2 cos^3 theta_c),
//
// G being the raster area per unit of surface area at x_p (the solid angle
// |n_g . w_o| / d^2 per area, 1 / cos^3 theta_c image-plane area per solid angle
// at angle theta_c off the viewing axis, (H / (2 tan))^2 raster area per image
// plane area at unit distance), w the film's filter and W its integral: a
// pixel's value is the filter-weighted average of the radiance over the image,
// as the path tracer's pixels are (for a box filter of half-width 1/2, the
// radiance averaged over the pixel).
//
// Visibility and the surface's BSDF come from a ray from the camera towards
// x_p: the photon is seen only if that ray's first hit lies at x_p, or if the
// surfaces before it have null events (null boundaries, thindielectric), whose
// transmittance then scales the contribution. Photons
// the camera sees only through specular surfaces (L ... D S+ E) cannot be
// connected and are missing from the image, as is emission seen directly; the
// image holds exactly the light of the photon maps it is given (all surface
// light with the photon pass's store = "surface" and store_direct = true, the
// caustics alone with store = "caustic"). Participating media are not
// supported (the connection would need their transmittance).
//
// Photons arrive in batches, all of them streamed (nothing is stored). Block b
// of every batch adds into per-pixel accumulator b, and the accumulators are
// merged in block order at the end, so the image is the same for any thread
// count.
#include "passes/passes.h"

#include "engine/core/error.h"
#include "engine/image/film.h"
#include "engine/buffers/photon_buffers.h"
#include "engine/accel/ray_query.h"
#include "engine/scene/scene.h"
#include "jobs/parallel.h"

#include <algorithm>
#include <cmath>

namespace fg {

namespace {

// Bytes of per-block pixel accumulators the pass may hold at once.
constexpr std::size_t kAccumulatorBudget = std::size_t{256} << 20;
// Relative distance within which the camera ray's first hit counts as the photon's position.
constexpr float kSameHitTolerance = 1e-3f;
// Null-event surfaces a camera connection may cross; only degenerate geometry needs more.
constexpr int kMaxConnectionCrossings = 64;

struct ConnectAccumulator {
    std::vector<Rgb> pixels;
    std::int64_t connected = 0;
    std::int64_t occluded = 0;
    std::int64_t outsideView = 0;
};

// Integral of the film's filter over its support, by the midpoint rule (exact
// for a box whose edges fall between the grid's midpoints).
double filterIntegral(const FilmSettings& film) {
    constexpr int kSteps = 512;
    const double radius = film.filterRadius;
    const double step = 2.0 * radius / kSteps;
    const PixelFilter filter(film);
    double sum = 0.0;
    for (int i = 0; i < kSteps; ++i) {
        const float dx = static_cast<float>(-radius + (i + 0.5) * step);
        for (int j = 0; j < kSteps; ++j) {
            const float dy = static_cast<float>(-radius + (j + 0.5) * step);
            sum += filter(dx, dy);
        }
    }
    return sum * step * step;
}

class LightTracePass final : public Pass {
public:
    void consumeBatch(PassContext& ctx, const std::string& slot) override {
        if (slot != "caustic_photons" && slot != "global_photons") return;
        const PhotonMap& map = ctx.input<PhotonMap>(slot);
        if (plannedPaths_ == 0) plannedPaths_ = map.emitted;
        tracedPaths_ = map.emitted;
        if (map.photons.empty()) return;
        prepare(ctx);
        const Scene& scene = ctx.scene();
        const RayQuery& rays = ctx.rays();
        const FilmSettings& film = ctx.filmSettings();
        const auto position = map.photons.column<PhotonPosition>();
        const auto incident = map.photons.column<PhotonIncident>();
        const auto power = map.photons.column<PhotonPower>();
        const auto photonClass = map.photons.column<PhotonClassColumn>();
        const std::ptrdiff_t width = film.width, height = film.height;
        const float reach = film.filterRadius;
        const PixelFilter filter(film);

        jobs::parallelForBlocks(position.size(), blocks_.size(), [&](std::size_t block, jobs::IndexRange range) {
            ConnectAccumulator& acc = blocks_[block];
            if (acc.pixels.empty()) acc.pixels.assign(static_cast<std::size_t>(width * height), Rgb(0.0f));
            for (std::size_t p = range.begin; p != range.end; ++p) {
                if (photonClass[p] & PhotonClass::Volume) continue;
                const Vec3 x = position[p];
                Vec2 raster;
                const float depth = glm::dot(x - camera_.eye, forward_);
                if (!camera_.project(x, &raster) || depth < camera_.nearClip || depth > camera_.farClip ||
                    !(raster.x > -reach && raster.x < static_cast<float>(width) + reach && raster.y > -reach &&
                      raster.y < static_cast<float>(height) + reach)) {
                    ++acc.outsideView;
                    continue;
                }
                const Vec3 toPhoton = x - camera_.eye;
                const float distance = glm::length(toPhoton);
                if (!(distance > 0.0f)) continue;
                const float cosCamera = depth / distance;
                // As the camera's own rays, the visibility ray starts on the near plane.
                Ray ray;
                ray.direction = toPhoton / distance;
                const float tNear = camera_.nearClip / cosCamera;
                ray.origin = camera_.eye + tNear * ray.direction;
                float rayLength = distance - tNear;
                ray.tMax = rayLength + kSameHitTolerance * distance * 2.0f + kRayEpsilon;
                Hit hit = rays.intersect(ray);
                // Surfaces with null events in front of the photon (a thin glass pane, a
                // null boundary) let the connection through with their transmittance; a
                // mask lets 1 - opacity through, as for shadow rays.
                Rgb transmittance(1.0f);
                for (int crossing = 0; crossing < kMaxConnectionCrossings && hit.valid() &&
                                       hit.t < rayLength - kSameHitTolerance * distance - kRayEpsilon && !isBlack(transmittance);
                     ++crossing) {
                    const SurfacePoint blocker = rays.surface(ray, hit);
                    const int blockerBsdf = scene.shapes[blocker.shape].bsdf;
                    const Bsdf* bsdf = blockerBsdf >= 0 ? scene.bsdfs[static_cast<std::size_t>(blockerBsdf)].get() : nullptr;
                    if (bsdf && !bsdf->hasNullLobe() && !bsdf->hasOpacity()) break;
                    if (bsdf) {
                        transmittance *= bsdf->hasOpacity()
                                             ? Rgb(1.0f - bsdf->opacity(blocker.texturePoint()))
                                             : bsdf->nullTransmission(Frame(blocker.ns).toLocal(ray.direction), blocker.texturePoint());
                    }
                    const Vec3 origin = offsetRayOrigin(blocker.p, blocker.ng, ray.direction);
                    const float advanced = glm::dot(origin - ray.origin, ray.direction);
                    ray.origin = origin;
                    rayLength -= advanced;
                    ray.tMax -= advanced;
                    hit = rays.intersect(ray);
                }
                if (!hit.valid() || isBlack(transmittance) ||
                    std::abs(hit.t - rayLength) > kSameHitTolerance * distance + kRayEpsilon) {
                    ++acc.occluded;
                    continue;
                }
                const SurfacePoint surface = rays.surface(ray, hit);
                const int bsdfIndex = scene.shapes[surface.shape].bsdf;
                if (bsdfIndex < 0) continue;
                const Vec3 wo = -ray.direction;
                const Vec3 wi = incident[p];
                const Frame frame(surface.ns);
                const Vec3 woLocal = frame.toLocal(wo), wiLocal = frame.toLocal(wi);
                // Shading normals must not let light through the geometric surface, on either side.
                if (!(std::abs(wiLocal.z) > 1e-6f) || glm::dot(wi, surface.ng) * wiLocal.z <= 0.0f ||
                    glm::dot(wo, surface.ng) * woLocal.z <= 0.0f)
                    continue;
                // Bsdf::eval holds |cos theta_i|; the photon's flux already does.
                const Rgb brdf = scene.bsdfs[static_cast<std::size_t>(bsdfIndex)]->eval(
                                     woLocal, wiLocal, surface.texturePoint(), TransportMode::Radiance) /
                                 std::abs(wiLocal.z);
                const float rasterPerArea =
                    rasterPerImagePlane_ * std::abs(glm::dot(surface.ng, wo)) / (sqr(distance) * cosCamera * sqr(cosCamera));
                const Rgb value = power[p] * brdf * transmittance * (rasterPerArea / filterIntegral_);
                if (!isFinite(value) || isBlack(value)) continue;
                ++acc.connected;
                const std::ptrdiff_t x0 = std::max<std::ptrdiff_t>(0, static_cast<std::ptrdiff_t>(std::floor(raster.x - reach)));
                const std::ptrdiff_t x1 = std::min<std::ptrdiff_t>(width - 1, static_cast<std::ptrdiff_t>(std::floor(raster.x + reach)));
                const std::ptrdiff_t y0 = std::max<std::ptrdiff_t>(0, static_cast<std::ptrdiff_t>(std::floor(raster.y - reach)));
                const std::ptrdiff_t y1 = std::min<std::ptrdiff_t>(height - 1, static_cast<std::ptrdiff_t>(std::floor(raster.y + reach)));
                for (std::ptrdiff_t py = y0; py <= y1; ++py)
                    for (std::ptrdiff_t px = x0; px <= x1; ++px) {
                        const float weight = filter(raster.x - (static_cast<float>(px) + 0.5f),
                                                    raster.y - (static_cast<float>(py) + 0.5f));
                        if (weight != 0.0f) acc.pixels[static_cast<std::size_t>(py * width + px)] += weight * value;
                    }
            }
        });
        ctx.addItems(static_cast<std::int64_t>(position.size()));
    }

    void run(PassContext& ctx) override {
        prepare(ctx);  // refuses media even when no photon arrived
        Film& image = ctx.createOutput<Film>("image", ctx.filmSettings());
        ConnectAccumulator total;
        total.pixels.assign(image.pixelCount(), Rgb(0.0f));
        for (const ConnectAccumulator& part : blocks_) {
            for (std::size_t i = 0; i < part.pixels.size(); ++i) total.pixels[i] += part.pixels[i];
            total.connected += part.connected;
            total.occluded += part.occluded;
            total.outsideView += part.outsideView;
        }
        // Batches streamed before an interrupt carry powers for the planned
        // count of paths; fewer were traced (the last, empty batch says how many).
        const float plannedPerTraced = tracedPaths_ > 0 && tracedPaths_ < plannedPaths_
                                       ? static_cast<float>(static_cast<double>(plannedPaths_) /
                                                            static_cast<double>(tracedPaths_))
                                       : 1.0f;
        image.addToPixels(total.pixels, plannedPerTraced);
        ctx.addCounter("connected_photons", total.connected);
        ctx.addCounter("occluded_photons", total.occluded);
        ctx.addCounter("photons_outside_view", total.outsideView);
    }

private:
    void prepare(PassContext& ctx) {
        if (!blocks_.empty()) return;
        const Scene& scene = ctx.scene();
        if (!scene.media.empty() || scene.camera.medium >= 0) {
            throw InputError("pass '" + ctx.instanceName() + "': " + scene.sourcePath +
                             " has participating media, which light tracing does not support (it would need their "
                             "transmittance); render it with pt");
        }
        if (scene.camera.orthographic) {
            // Its rays share one direction, so a light path meets it with probability zero.
            throw InputError("pass '" + ctx.instanceName() + "': " + scene.sourcePath +
                             " has an orthographic camera, which light tracing cannot connect to; render it with pt");
        }
        const FilmSettings& film = ctx.filmSettings();
        camera_ = scene.camera;
        camera_.width = film.width;
        camera_.height = film.height;
        forward_ = glm::normalize(camera_.target - camera_.eye);
        const float tanHalfFovY = std::tan(0.5f * camera_.fovYDegrees * kPi / 180.0f);
        rasterPerImagePlane_ = sqr(static_cast<float>(film.height) / (2.0f * tanHalfFovY));
        filterIntegral_ = static_cast<float>(filterIntegral(film));
        const std::size_t blockBytes =
            std::max<std::size_t>(1, static_cast<std::size_t>(film.width) * film.height * sizeof(Rgb));
        blocks_.resize(std::clamp<std::size_t>(kAccumulatorBudget / blockBytes, 1, 64));
    }

    Camera camera_;
    Vec3 forward_{0.0f};
    float rasterPerImagePlane_ = 0.0f;
    float filterIntegral_ = 1.0f;
    std::vector<ConnectAccumulator> blocks_;
    // The photon paths the powers of the first and of the last batch were
    // divided by: they differ when an interrupt cut the photon pass short.
    std::uint64_t plannedPaths_ = 0, tracedPaths_ = 0;
};

}  // namespace

PassRegistration lightTracePass() {
    PassSpec spec;
    spec.name = "light_trace";
    spec.doc = "Light tracing: connects every photon to the camera (unbiased, no density estimation); the reference "
               "for light seen directly on surfaces that a path tracer cannot reach, such as caustics of delta lights";
    spec.inputs = {
        {"caustic_photons", "PhotonMap", "caustic photons (L S+ D) to connect (read in batches)", true},
        {"global_photons", "PhotonMap", "other surface photons to connect (read in batches)", true},
    };
    spec.outputs = {{"image", "Film", "the photons' light as the camera sees it directly"}};
    const auto preflight = [](const PreflightContext& pf) {
        if (!pf.scene.media.empty() || pf.scene.camera.medium >= 0) {
            throw InputError("pass '" + pf.instance + "': " + pf.scene.sourcePath +
                             " has participating media, which light tracing does not support (it would need their "
                             "transmittance); render it with pt");
        }
    };
    // The film, the summed image and the per-block accumulators (as many as
    // fit kAccumulatorBudget, at least one, at most 64).
    const auto memory = [](const PreflightContext& pf) {
        const std::uint64_t image =
            multiplyBytes(static_cast<std::uint64_t>(pf.film.width) * static_cast<std::uint64_t>(pf.film.height), sizeof(Rgb));
        const std::uint64_t blocks = std::clamp<std::uint64_t>(kAccumulatorBudget / std::max<std::uint64_t>(image, 1), 1, 64);
        return MemoryEstimate{addBytes(addBytes(filmBytes(pf.film), image), multiplyBytes(image, blocks)),
                              "film " + std::to_string(pf.film.width) + " x " + std::to_string(pf.film.height) + " and " +
                                  std::to_string(blocks) + " connection accumulators",
                              {}};
    };
    return {spec, [] { return std::make_unique<LightTracePass>(); }, preflight, memory};
}

}  // namespace fg
