// Light sources: point, spot (optionally textured), projector, directional,
// constant and image-based environments, and diffuse area emitters (constant or
// textured radiance) on meshes and spheres.
//
// Next-event estimation follows the solid-angle formulation of pbrt (Pharr,
// Jakob & Humphreys, "Physically Based Rendering", 3rd ed., Sec. 14.2): area
// samples are converted with pdf_omega = pdf_A d^2 / |cos theta_light|, and
// spheres seen from outside are sampled uniformly inside the cone they subtend
// (Shirley, Wang & Zimmerman 1996, "Monte Carlo techniques for direct lighting
// calculations", Sec. 3.2). Photon emission from infinite lights starts on a
// disk of the scene's bounding radius R perpendicular to the photon direction,
// so every such light reports power = pi R^2 * (integral of its radiance over
// the sphere of incoming directions): the flux that crosses the bounding disk.
//
// Conventions fixed here:
// - Spot falloff is Mitsuba 0.5's: full intensity for angles up to beamWidth,
//   then linear *in angle* down to zero at cutoffAngle,
//     f(theta) = (theta_c - theta) / (theta_c - theta_b),   theta_b < theta < theta_c.
//   Its solid-angle integral is 2 pi [1 - (sin theta_c - sin theta_b) / (theta_c - theta_b)]
//   (2 pi (1 - cos theta_c) when the two angles coincide), which is power / I.
// - Environment maps use Mitsuba 3's lat-long layout and lookup: with theta
//   measured from the map's +Y axis and phi = atan2(x, -z) in [0, 2 pi),
//   u = phi / (2 pi) and v = theta / pi. Columns are texel-centred and wrap:
//   column x sits at u = (x + 1/2) / width. Rows are corner-aligned: row y sits
//   at v = y / (height - 1), so the top row is the radiance straight up (+Y) and
//   the bottom row straight down (Mitsuba's envmap evaluates at v (height - 1)).
//   Radiance is bilinear between those texels. The sampling density over (u, v)
//   is piecewise constant on the same bilinear patches (between columns x, x+1
//   and rows y, y+1), proportional to the luminance of the patch integrated
//   over it (the mean of its four corners, exact for a bilinear function) times
//   sin(theta) at the patch centre, so every patch with light is sampled. Its
//   solid-angle density is pdf(u, v) / (2 pi^2 sin theta).
// - An area light on a mesh emits on the side its winding faces (right-hand rule,
//   the orientation ray queries report; flips are already baked into the
//   winding), a sphere outwards unless Shape::flipNormals turns it inwards.
// - emitterSolidAngle (Frisvad et al. 2014, Eq. 6) is the solid angle of the
//   directions a source emits into: 4 pi for point lights and environments,
//   the cutoff cone for spots, 2 pi for a one-sided area light (4 pi two-sided)
//   and 0 for collimated light.
#include "engine/shading/light.h"

#include <array>
#include <cmath>
#include <variant>
#include <vector>

namespace fg {

Rgb Light::emitted(const Vec3&, const Vec3&) const { return Rgb(0.0f); }
Rgb Light::emittedAt(const Vec3& n, const Vec3& w, const Vec2&) const { return emitted(n, w); }
float Light::emissionDirectionPdf(const Vec3&) const { return 0.0f; }
Rgb Light::environment(const Vec3&) const { return Rgb(0.0f); }
void Light::setSceneBounds(const Vec3&, float) {}

namespace {

constexpr float kFourPi = 4.0f * kPi;

// Shared state of the lights whose photons start on the scene's bounding disk.
struct SceneDisk {
    Vec3 center{0.0f};
    float radius = 1.0f;  // until the scene says otherwise

    float area() const { return kPi * radius * radius; }
    // A point on the disk of radius R, perpendicular to `travel`, tangent to the
    // bounding sphere on the side the photon comes from: it starts outside the scene.
    Vec3 sampleOrigin(const Vec3& travel, const Vec2& u) const {
        const Frame frame(travel);
        const Vec2 d = sampleConcentricDisk(u) * radius;
        return center - travel * radius + frame.s * d.x + frame.t * d.y;
    }
};

// ---------------------------------------------------------------------------

class PointLight final : public Light {
public:
    PointLight(const Vec3& position, const Rgb& intensity) : position_(position), intensity_(intensity) {}

    bool isDelta() const override { return true; }
    bool isInfinite() const override { return false; }

    std::optional<LightSample> sampleLi(const Vec3& ref, const Vec2&) const override {
        // One named result for every return, built in the caller's slot (see DiffuseBsdf::sample).
        std::optional<LightSample> s;
        const Vec3 toLight = position_ - ref;
        const float distance2 = glm::dot(toLight, toLight);
        if (!(distance2 > 0.0f) || isBlack(intensity_)) return s;
        s.emplace();
        s->distance = std::sqrt(distance2);
        s->wi = toLight / s->distance;
        s->value = intensity_ / distance2;
        s->pdf = 1.0f;
        s->p = position_;
        return s;
    }
    float pdfLi(const Vec3&, const Vec3&, const Vec3&, const Vec3&) const override { return 0.0f; }
    Rgb power() const override { return kFourPi * intensity_; }
    std::optional<Vec3> position() const override { return position_; }
    float emissionDirectionPdf(const Vec3&) const override { return uniformSpherePdf(); }

    std::optional<EmissionSample> sampleEmission(const Vec2&, const Vec2& uDir) const override {
        EmissionSample e;
        e.origin = position_;
        e.direction = sampleUniformSphere(uDir);
        e.flux = power();
        e.pdfPosition = 1.0f;
        e.pdfDirection = uniformSpherePdf();
        e.emitterArea = 0.0f;
        e.emitterSolidAngle = kFourPi;
        return e;
    }

private:
    Vec3 position_;
    Rgb intensity_;
};

// ---------------------------------------------------------------------------

class SpotLight final : public Light {
public:
    SpotLight(const Vec3& position, const Vec3& direction, const Rgb& intensity, float cutoffDeg, float beamDeg,
              std::shared_ptr<Texture> texture = nullptr, const Mat3& toLocal = Mat3(1.0f))
        : position_(position), frame_(glm::normalize(direction)), intensity_(intensity), texture_(std::move(texture)),
          toLocal_(toLocal) {
        const float cutoff = std::clamp(cutoffDeg, 0.0f, 180.0f);
        cutoff_ = glm::radians(cutoff);
        beam_ = glm::radians(std::clamp(beamDeg, 0.0f, cutoff));
        cosCutoff_ = std::cos(cutoff_);
        cosBeam_ = std::cos(beam_);
        // (sin c - sin b) / (c - b) = cos(mid) sinc(half width): stable as the transition closes.
        const double half = 0.5 * (static_cast<double>(cutoff_) - beam_);
        const double mid = 0.5 * (static_cast<double>(cutoff_) + beam_);
        const double sincHalf = half > 1e-8 ? std::sin(half) / half : 1.0;
        coneMass_ = 1.0 - std::cos(mid) * sincHalf;
        innerMass_ = 1.0 - std::cos(static_cast<double>(beam_));
        uvFactor_ = std::tan(cutoff_);
        power_ = intensity_ * static_cast<float>(2.0 * kPi * coneMass_);
        if (texture_) power_ = intensity_ * texturedConeIntegral();
    }

    bool isDelta() const override { return true; }
    bool isInfinite() const override { return false; }

    float falloff(float cosTheta) const {
        if (cosTheta <= cosCutoff_) return 0.0f;
        if (cosTheta >= cosBeam_) return 1.0f;
        return std::clamp((cutoff_ - std::acos(cosTheta)) / (cutoff_ - beam_), 0.0f, 1.0f);
    }

    std::optional<LightSample> sampleLi(const Vec3& ref, const Vec2&) const override {
        const Vec3 toLight = position_ - ref;
        const float distance2 = glm::dot(toLight, toLight);
        if (!(distance2 > 0.0f)) return std::nullopt;
        LightSample s;
        s.distance = std::sqrt(distance2);
        s.wi = toLight / s.distance;
        const float f = falloff(glm::dot(-s.wi, frame_.n));
        if (f <= 0.0f || isBlack(intensity_)) return std::nullopt;
        s.value = intensity_ * textureFactor(-s.wi) * (f / distance2);
        s.pdf = 1.0f;
        s.p = position_;
        return s;
    }
    float pdfLi(const Vec3&, const Vec3&, const Vec3&, const Vec3&) const override { return 0.0f; }
    Rgb power() const override { return power_; }
    std::optional<Vec3> position() const override { return position_; }
    float emissionDirectionPdf(const Vec3& direction) const override {
        return directionPdf(glm::dot(glm::normalize(direction), frame_.n));
    }

    // Directions are drawn in proportion to the falloff, so every photon of an
    // untextured spot carries the same flux; a texture scales each photon's flux.
    std::optional<EmissionSample> sampleEmission(const Vec2&, const Vec2& uDir) const override {
        if (!(coneMass_ > 0.0)) return std::nullopt;
        const double theta = sampleTheta(uDir.x);
        const float cosT = static_cast<float>(std::cos(theta));
        const float sinT = static_cast<float>(std::sin(theta));
        const float phi = 2.0f * kPi * uDir.y;
        const float pdf = directionPdf(cosT);
        if (!(pdf > 0.0f)) return std::nullopt;
        EmissionSample e;
        e.origin = position_;
        e.direction = frame_.toWorld(Vec3(sinT * std::cos(phi), sinT * std::sin(phi), cosT));
        e.flux = intensity_ * static_cast<float>(2.0 * kPi * coneMass_) * textureFactor(e.direction);
        e.pdfPosition = 1.0f;
        e.pdfDirection = pdf;
        e.emitterArea = 0.0f;
        e.emitterSolidAngle = 2.0f * kPi * (1.0f - cosCutoff_);
        return e;
    }

    // Solid-angle density of sampleEmission's directions, by the cosine to the axis.
    float directionPdf(float cosTheta) const {
        return static_cast<float>(falloff(cosTheta) / (2.0 * kPi * coneMass_));
    }

private:
    // The texture's value in world direction w leaving the light (1 without a texture).
    Rgb textureFactor(const Vec3& w) const {
        if (!texture_) return Rgb(1.0f);
        const Vec3 local = toLocal_ * w;
        if (!(local.z > 0.0f)) return Rgb(0.0f);
        const float scale = 0.5f / (local.z * uvFactor_);
        return texture_->eval(Vec2(0.5f + local.x * scale, 0.5f + local.y * scale));
    }

    // Integral of falloff x texture over the cone by the midpoint rule in
    // (theta, phi): the texture is arbitrary, and power only chooses lights
    // (photon fluxes carry the exact texture value of their direction).
    Rgb texturedConeIntegral() const {
        constexpr int kThetaSteps = 256, kPhiSteps = 512;
        const double dTheta = static_cast<double>(cutoff_) / kThetaSteps, dPhi = 2.0 * kPi / kPhiSteps;
        Rgb sum(0.0f);
        for (int i = 0; i < kThetaSteps; ++i) {
            const double theta = (i + 0.5) * dTheta;
            const float weight = falloff(static_cast<float>(std::cos(theta))) * static_cast<float>(std::sin(theta) * dTheta * dPhi);
            if (!(weight > 0.0f)) continue;
            for (int j = 0; j < kPhiSteps; ++j) {
                const double phi = (j + 0.5) * dPhi;
                const Vec3 local(static_cast<float>(std::sin(theta) * std::cos(phi)),
                                 static_cast<float>(std::sin(theta) * std::sin(phi)), static_cast<float>(std::cos(theta)));
                sum += weight * textureFactor(frame_.toWorld(local));
            }
        }
        return sum;
    }

    // Unnormalised cumulative mass of f(theta) sin(theta) on [0, theta].
    double cumulative(double theta) const {
        if (theta <= beam_) return 1.0 - std::cos(theta);
        const double width = static_cast<double>(cutoff_) - beam_;
        return innerMass_ + (width * std::cos(static_cast<double>(beam_)) + std::sin(static_cast<double>(beam_)) -
                             (cutoff_ - theta) * std::cos(theta) - std::sin(theta)) /
                                width;
    }

    // Inverts the cumulative: closed form in the flat core, safeguarded Newton on the ramp.
    double sampleTheta(float u) const {
        const double target = static_cast<double>(u) * coneMass_;
        if (target <= innerMass_ || cutoff_ <= beam_) return std::acos(std::clamp(1.0 - target, -1.0, 1.0));
        const double width = static_cast<double>(cutoff_) - beam_;
        double lo = beam_, hi = cutoff_, theta = 0.5 * (lo + hi);
        for (int i = 0; i < 64; ++i) {
            const double g = cumulative(theta) - target;
            if (g > 0.0) hi = theta;
            else lo = theta;
            const double slope = (cutoff_ - theta) * std::sin(theta) / width;
            double next = slope > 0.0 ? theta - g / slope : 0.5 * (lo + hi);
            if (!(next > lo && next < hi)) next = 0.5 * (lo + hi);
            if (std::abs(next - theta) < 1e-12) return next;
            theta = next;
        }
        return theta;
    }

    Vec3 position_;
    Frame frame_;
    Rgb intensity_;
    float cutoff_ = 0.0f, beam_ = 0.0f, cosCutoff_ = 1.0f, cosBeam_ = 1.0f;
    double coneMass_ = 0.0;   // integral of f over the sphere / (2 pi)
    double innerMass_ = 0.0;  // the part of it inside the full-intensity core
    std::shared_ptr<Texture> texture_;  // optional
    Mat3 toLocal_;                      // world to the texture's frame (the spot's to_world inverted)
    float uvFactor_ = 1.0f;             // tan(cutoff): the cone's edge reaches uv = 0 and 1 on the axes
    Rgb power_{0.0f};
};

// ---------------------------------------------------------------------------

// Mitsuba's projector. In the light's frame (+z forward) the virtual image plane
// z = 1 spans x in [-a, a], y in [-b, b] with a = tan(fov_x / 2) and b = a * height
// / width; uv = (1/2 - x / (2a), 1/2 - y / (2b)), so u = 0 is the +x edge (the
// image's left, as for Mitsuba's cameras) and v = 0 the top (+y). Mitsuba scales
// the texture so that the irradiance on that plane is pi * scale * E(uv) (its
// projector divides by the camera importance, which carries a 1/pi); derived:
// a plane element dA at z = 1 subtends d(omega) = cos^3(theta) dA, so the
// intensity is I(omega) = pi * scale * E(uv) / cos^3(theta), the irradiance it
// gives a point at distance d is I / d^2 = pi * scale * E / (z^2 cos(theta))
// with z = d cos(theta) the point's depth, and the power is pi * scale * 4ab *
// mean(E). Photons pick uv from a piecewise-constant density over the texture's
// pixel grid (each pixel weighted by the largest luminance among itself and its
// eight neighbours, so that bilinear lookups between pixel centres never fall
// where the density is zero) and carry flux pi * scale * 4ab * E(uv) / pdf(uv).
class ProjectorLight final : public Light {
public:
    ProjectorLight(const Mat4& toWorld, std::shared_ptr<Texture> irradiance, int width, int height, float tanHalfFovX,
                   float scale)
        : position_(Vec3(toWorld[3])), toWorld_(Mat3(toWorld)), toLocal_(glm::transpose(Mat3(toWorld))),
          irradiance_(std::move(irradiance)), scale_(scale) {
        width = std::max(1, width);
        height = std::max(1, height);
        halfWidth_ = tanHalfFovX;
        halfHeight_ = tanHalfFovX * static_cast<float>(height) / static_cast<float>(width);
        planeArea_ = 4.0f * halfWidth_ * halfHeight_;
        std::vector<float> centre(static_cast<std::size_t>(width) * height);
        for (int y = 0; y < height; ++y)
            for (int x = 0; x < width; ++x) {
                const Vec2 uv((static_cast<float>(x) + 0.5f) / static_cast<float>(width),
                              (static_cast<float>(y) + 0.5f) / static_cast<float>(height));
                centre[static_cast<std::size_t>(y) * width + x] = std::max(0.0f, luminance(irradiance_->eval(uv)));
            }
        std::vector<float> weights(centre.size(), 0.0f);
        for (int y = 0; y < height; ++y)
            for (int x = 0; x < width; ++x) {
                float w = 0.0f;
                for (int dy = -1; dy <= 1; ++dy)
                    for (int dx = -1; dx <= 1; ++dx) {
                        const int nx = (x + dx + width) % width, ny = (y + dy + height) % height;
                        w = std::max(w, centre[static_cast<std::size_t>(ny) * width + nx]);
                    }
                weights[static_cast<std::size_t>(y) * width + x] = w;
            }
        distribution_ = Distribution2D(weights, width, height);
        // Solid angle of the frustum: a rectangular pyramid with half-extents a, b at unit depth.
        const double a = halfWidth_, b = halfHeight_;
        solidAngle_ = static_cast<float>(4.0 * std::asin(a * b / std::sqrt((1.0 + a * a) * (1.0 + b * b))));
    }

    bool isDelta() const override { return true; }
    bool isInfinite() const override { return false; }
    std::optional<Vec3> position() const override { return position_; }

    std::optional<LightSample> sampleLi(const Vec3& ref, const Vec2&) const override {
        const Vec3 toRef = ref - position_;
        const float distance = glm::length(toRef);
        if (!(distance > 0.0f)) return std::nullopt;
        const Vec3 local = toLocal_ * toRef;
        Vec2 uv;
        if (!localToUv(local, &uv)) return std::nullopt;
        const Rgb e = irradiance_->eval(uv);
        if (isBlack(e)) return std::nullopt;
        const float cosTheta = local.z / distance;
        LightSample s;
        s.distance = distance;
        s.wi = -toRef / distance;
        s.value = e * (kPi * scale_ / (local.z * local.z * cosTheta));
        s.pdf = 1.0f;
        s.p = position_;
        return s;
    }
    float pdfLi(const Vec3&, const Vec3&, const Vec3&, const Vec3&) const override { return 0.0f; }
    Rgb power() const override { return irradiance_->mean() * (kPi * scale_ * planeArea_); }

    std::optional<EmissionSample> sampleEmission(const Vec2&, const Vec2& uDir) const override {
        float pdfUv = 0.0f;
        const Vec2 uv = distribution_.sample(uDir, &pdfUv);
        if (!(pdfUv > 0.0f)) return std::nullopt;
        const Vec3 onPlane((1.0f - 2.0f * uv.x) * halfWidth_, (1.0f - 2.0f * uv.y) * halfHeight_, 1.0f);
        const Vec3 local = glm::normalize(onPlane);
        const float cos3 = local.z * local.z * local.z;
        EmissionSample e;
        e.origin = position_;
        e.direction = glm::normalize(toWorld_ * local);
        e.pdfPosition = 1.0f;
        e.pdfDirection = pdfUv / (planeArea_ * cos3);
        e.flux = irradiance_->eval(uv) * (kPi * scale_ * planeArea_ / pdfUv);
        e.emitterArea = 0.0f;
        e.emitterSolidAngle = solidAngle_;
        return e;
    }

    float emissionDirectionPdf(const Vec3& direction) const override {
        const Vec3 local = toLocal_ * direction;
        Vec2 uv;
        if (!localToUv(local, &uv)) return 0.0f;
        const float cosTheta = local.z / glm::length(local);
        return distribution_.pdf(uv) / (planeArea_ * cosTheta * cosTheta * cosTheta);
    }

private:
    bool localToUv(const Vec3& local, Vec2* uv) const {
        if (!(local.z > 0.0f)) return false;
        const float x = local.x / local.z, y = local.y / local.z;
        *uv = Vec2(0.5f - 0.5f * x / halfWidth_, 0.5f - 0.5f * y / halfHeight_);
        return uv->x >= 0.0f && uv->x <= 1.0f && uv->y >= 0.0f && uv->y <= 1.0f;
    }

    Vec3 position_;
    Mat3 toWorld_, toLocal_;  // a rotation: its inverse is its transpose
    std::shared_ptr<Texture> irradiance_;
    float scale_;
    float halfWidth_ = 1.0f, halfHeight_ = 1.0f, planeArea_ = 4.0f, solidAngle_ = 0.0f;
    Distribution2D distribution_;
};

// ---------------------------------------------------------------------------

class DirectionalLight final : public Light {
public:
    DirectionalLight(const Vec3& direction, const Rgb& irradiance)
        : direction_(glm::normalize(direction)), irradiance_(irradiance) {}

    bool isDelta() const override { return true; }
    bool isInfinite() const override { return true; }

    std::optional<LightSample> sampleLi(const Vec3&, const Vec2&) const override {
        if (isBlack(irradiance_)) return std::nullopt;
        LightSample s;
        s.wi = -direction_;
        s.distance = kInfinity;
        s.value = irradiance_;
        s.pdf = 1.0f;
        return s;
    }
    float pdfLi(const Vec3&, const Vec3&, const Vec3&, const Vec3&) const override { return 0.0f; }
    Rgb power() const override { return irradiance_ * disk_.area(); }
    void setSceneBounds(const Vec3& center, float radius) override { disk_ = {center, radius}; }

    std::optional<EmissionSample> sampleEmission(const Vec2& uPos, const Vec2&) const override {
        if (!(disk_.radius > 0.0f)) return std::nullopt;
        EmissionSample e;
        e.origin = disk_.sampleOrigin(direction_, uPos);
        e.direction = direction_;
        e.normal = direction_;
        e.flux = power();
        e.pdfPosition = 1.0f / disk_.area();
        e.pdfDirection = 1.0f;
        e.emitterArea = disk_.area();
        e.emitterSolidAngle = 0.0f;
        return e;
    }

private:
    Vec3 direction_;
    Rgb irradiance_;
    SceneDisk disk_;
};

// ---------------------------------------------------------------------------

class ConstantEnvironment final : public Light {
public:
    explicit ConstantEnvironment(const Rgb& radiance) : radiance_(radiance) {}

    bool isDelta() const override { return false; }
    bool isInfinite() const override { return true; }

    // Uniform over the sphere: the reference point's normal is not known here.
    std::optional<LightSample> sampleLi(const Vec3&, const Vec2& u) const override {
        LightSample s;
        s.wi = sampleUniformSphere(u);
        s.distance = kInfinity;
        s.value = radiance_;
        s.pdf = uniformSpherePdf();
        return s;
    }
    float pdfLi(const Vec3&, const Vec3&, const Vec3&, const Vec3&) const override { return uniformSpherePdf(); }
    Rgb environment(const Vec3&) const override { return radiance_; }
    // pi R^2 * (4 pi L): equivalently the irradiance pi L on every element of the bounding sphere's 4 pi R^2.
    Rgb power() const override { return radiance_ * (kFourPi * disk_.area()); }
    void setSceneBounds(const Vec3& center, float radius) override { disk_ = {center, radius}; }

    std::optional<EmissionSample> sampleEmission(const Vec2& uPos, const Vec2& uDir) const override {
        if (!(disk_.radius > 0.0f)) return std::nullopt;
        const Vec3 towardsLight = sampleUniformSphere(uDir);
        EmissionSample e;
        e.direction = -towardsLight;
        e.origin = disk_.sampleOrigin(e.direction, uPos);
        e.normal = e.direction;
        e.flux = power();
        e.pdfPosition = 1.0f / disk_.area();
        e.pdfDirection = uniformSpherePdf();
        e.emitterArea = disk_.area();
        e.emitterSolidAngle = kFourPi;
        return e;
    }

private:
    Rgb radiance_;
    SceneDisk disk_;
};

// ---------------------------------------------------------------------------

class EnvironmentMap final : public Light {
public:
    EnvironmentMap(const RgbImage& image, float scale, const Mat3& toWorld)
        : image_(image), scale_(scale), toWorld_(toWorld), toLocal_(glm::inverse(toWorld)) {
        if (image_.width <= 0 || image_.height <= 0 ||
            image_.pixels.size() != static_cast<std::size_t>(image_.width) * static_cast<std::size_t>(image_.height)) {
            image_ = RgbImage{1, 1, {Rgb(0.0f)}};
        }
        const int w = image_.width, h = image_.height;
        // Bilinear patches: w between columns (wrapping), h - 1 between rows (one for a single row).
        patchRows_ = std::max(1, h - 1);
        std::vector<float> weights(static_cast<std::size_t>(w) * patchRows_);
        Rgb radiantIntegral(0.0f);  // integral of L over the sphere of directions
        for (int y = 0; y < patchRows_; ++y) {
            const float theta0 = kPi * static_cast<float>(y) / static_cast<float>(patchRows_);
            const float theta1 = kPi * static_cast<float>(y + 1) / static_cast<float>(patchRows_);
            const float sinCentre = std::sin(0.5f * (theta0 + theta1));
            const float patchSolidAngle = 2.0f * kPi / static_cast<float>(w) * (std::cos(theta0) - std::cos(theta1));
            for (int x = 0; x < w; ++x) {
                const Rgb mean =
                    0.25f * scale_ * (texel(x, y) + texel(x + 1, y) + texel(x, y + 1) + texel(x + 1, y + 1));
                weights[static_cast<std::size_t>(y) * w + x] = std::max(0.0f, luminance(mean)) * sinCentre;
                radiantIntegral += mean * patchSolidAngle;
            }
        }
        radiantIntegral_ = radiantIntegral;
        distribution_ = Distribution2D(weights, w, patchRows_);
    }

    bool isDelta() const override { return false; }
    bool isInfinite() const override { return true; }

    std::optional<LightSample> sampleLi(const Vec3&, const Vec2& u) const override {
        float pdf = 0.0f;
        Vec3 wi;
        Vec2 uv;
        if (!sampleDirection(u, &wi, &uv, &pdf)) return std::nullopt;
        LightSample s;
        s.wi = wi;
        s.distance = kInfinity;
        s.value = lookup(uv);
        s.pdf = pdf;
        return s;
    }

    float pdfLi(const Vec3&, const Vec3&, const Vec3&, const Vec3& wi) const override {
        const Vec3 local = glm::normalize(toLocal_ * wi);
        const float sinTheta = std::sqrt(local.x * local.x + local.z * local.z);
        if (!(sinTheta > 0.0f)) return 0.0f;
        return distribution_.pdf(uvToPatchSpace(localToUv(local))) / (2.0f * kPi * kPi * sinTheta);
    }

    Rgb environment(const Vec3& dir) const override { return lookup(localToUv(glm::normalize(toLocal_ * dir))); }
    Rgb power() const override { return radiantIntegral_ * disk_.area(); }
    void setSceneBounds(const Vec3& center, float radius) override { disk_ = {center, radius}; }

    std::optional<EmissionSample> sampleEmission(const Vec2& uPos, const Vec2& uDir) const override {
        if (!(disk_.radius > 0.0f)) return std::nullopt;
        float pdf = 0.0f;
        Vec3 towardsLight;
        Vec2 uv;
        if (!sampleDirection(uDir, &towardsLight, &uv, &pdf)) return std::nullopt;
        EmissionSample e;
        e.direction = -towardsLight;
        e.origin = disk_.sampleOrigin(e.direction, uPos);
        e.normal = e.direction;
        e.pdfPosition = 1.0f / disk_.area();
        e.pdfDirection = pdf;
        e.flux = lookup(uv) / (e.pdfPosition * pdf);
        e.emitterArea = disk_.area();
        e.emitterSolidAngle = kFourPi;
        return e;
    }

    std::size_t samplingPatchCount() const override {
        return static_cast<std::size_t>(image_.width) * static_cast<std::size_t>(patchRows_);
    }

    // The density pdfLi reads is constant over the patch (Distribution2D), so
    // its mass is that density times the patch's share of the (u, v) square.
    float samplingPatchMass(std::size_t patch) const override {
        const Vec2 centre = patchCentre(patch);
        return distribution_.pdf(centre) / static_cast<float>(samplingPatchCount());
    }

    void samplingPatchCentres(std::span<Vec3> centres) const override {
        const auto w = static_cast<std::size_t>(image_.width);
        std::vector<float> sinPhi(w), cosPhi(w);
        for (std::size_t x = 0; x < w; ++x) {
            const float phi = 2.0f * kPi * patchSpaceToUv(patchCentre(x)).x;
            sinPhi[x] = std::sin(phi);
            cosPhi[x] = std::cos(phi);
        }
        for (std::size_t y = 0; y < static_cast<std::size_t>(patchRows_); ++y) {
            const float theta = kPi * patchCentre(y * w).y;
            const float sinTheta = std::sin(theta), cosTheta = std::cos(theta);
            for (std::size_t x = 0; x < w; ++x)
                centres[y * w + x] =
                    glm::normalize(toWorld_ * Vec3(sinPhi[x] * sinTheta, cosTheta, -cosPhi[x] * sinTheta));
        }
    }

    std::size_t samplingPatchOf(const Vec3& towardsLight) const override {
        const Vec2 s = uvToPatchSpace(localToUv(glm::normalize(toLocal_ * towardsLight)));
        // The row and column Distribution2D::pdf reads.
        const auto w = static_cast<std::size_t>(image_.width), h = static_cast<std::size_t>(patchRows_);
        const std::size_t row = std::min(h - 1, static_cast<std::size_t>(std::max(0.0f, s.y) * static_cast<float>(h)));
        const std::size_t column = std::min(w - 1, static_cast<std::size_t>(std::max(0.0f, s.x) * static_cast<float>(w)));
        return row * w + column;
    }

    // Uniform over the patch in (u, v), as Distribution2D samples within it, so
    // the solid-angle density is p_L's (constant in (u, v)) over the patch's mass.
    std::optional<Vec3> sampleInSamplingPatch(std::size_t patch, const Vec2& u) const override {
        const auto w = static_cast<std::size_t>(image_.width);
        const Vec2 s(std::min((static_cast<float>(patch % w) + u.x) / static_cast<float>(w), 0x1.fffffep-1f),
                     std::min((static_cast<float>(patch / w) + u.y) / static_cast<float>(patchRows_), 0x1.fffffep-1f));
        const Vec3 local = uvToLocal(patchSpaceToUv(s));
        if (!(std::sqrt(local.x * local.x + local.z * local.z) > 0.0f)) return std::nullopt;
        return glm::normalize(toWorld_ * local);
    }

private:
    Vec2 patchCentre(std::size_t patch) const {
        const auto w = static_cast<std::size_t>(image_.width);
        return {(static_cast<float>(patch % w) + 0.5f) / static_cast<float>(w),
                (static_cast<float>(patch / w) + 0.5f) / static_cast<float>(patchRows_)};
    }

    Vec2 patchSpaceToUv(Vec2 s) const {
        s.x += 0.5f / static_cast<float>(image_.width);
        if (s.x >= 1.0f) s.x -= 1.0f;
        return s;
    }

    static Vec3 uvToLocal(const Vec2& uv) {
        const float theta = kPi * uv.y, phi = 2.0f * kPi * uv.x;
        const float sinTheta = std::sin(theta);
        return {std::sin(phi) * sinTheta, std::cos(theta), -std::cos(phi) * sinTheta};
    }

    const Rgb& texel(int x, int y) const {
        x %= image_.width;
        if (x < 0) x += image_.width;
        return image_.at(x, std::clamp(y, 0, image_.height - 1));
    }

    Rgb lookup(const Vec2& uv) const {
        const float fx = uv.x * static_cast<float>(image_.width) - 0.5f;
        const float fy = uv.y * static_cast<float>(image_.height - 1);
        const float x0 = std::floor(fx), y0 = std::floor(fy);
        const float tx = fx - x0, ty = fy - y0;
        const int ix = static_cast<int>(x0), iy = static_cast<int>(y0);
        const Rgb top = (1.0f - tx) * texel(ix, iy) + tx * texel(ix + 1, iy);
        const Rgb bottom = (1.0f - tx) * texel(ix, iy + 1) + tx * texel(ix + 1, iy + 1);
        return ((1.0f - ty) * top + ty * bottom) * scale_;
    }

    static Vec2 localToUv(const Vec3& d) {
        float phi = std::atan2(d.x, -d.z);
        if (phi < 0.0f) phi += 2.0f * kPi;
        const float u = std::min(phi * kInv2Pi, 0x1.fffffep-1f);
        const float v = std::min(std::acos(std::clamp(d.y, -1.0f, 1.0f)) * kInvPi, 0x1.fffffep-1f);
        return {u, v};
    }

    // Patch space: u shifted by half a column, so that patch x starts at column x's centre.
    Vec2 uvToPatchSpace(const Vec2& uv) const {
        float s = uv.x - 0.5f / static_cast<float>(image_.width);
        if (s < 0.0f) s += 1.0f;
        return {std::min(s, 0x1.fffffep-1f), uv.y};
    }

    bool sampleDirection(const Vec2& u, Vec3* wi, Vec2* uv, float* pdf) const {
        float pdfUv = 0.0f;
        *uv = patchSpaceToUv(distribution_.sample(u, &pdfUv));
        const float sinTheta = std::sin(kPi * uv->y);
        if (!(pdfUv > 0.0f) || !(sinTheta > 0.0f)) return false;
        *wi = glm::normalize(toWorld_ * uvToLocal(*uv));
        *pdf = pdfUv / (2.0f * kPi * kPi * sinTheta);
        return true;
    }

    RgbImage image_;
    float scale_;
    Mat3 toWorld_, toLocal_;
    int patchRows_ = 1;
    Distribution2D distribution_;
    Rgb radiantIntegral_{0.0f};
    SceneDisk disk_;
};

// ---------------------------------------------------------------------------

class AreaLight final : public Light {
public:
    AreaLight(const Shape& shape, const Rgb& radiance, bool twoSided, std::shared_ptr<Texture> texture = nullptr)
        : radiance_(radiance), twoSided_(twoSided), texture_(std::move(texture)) {
        if (const auto* sphere = std::get_if<Sphere>(&shape.geometry)) {
            sphere_ = *sphere;
            isSphere_ = true;
            inwards_ = shape.flipNormals;
            area_ = 4.0f * kPi * sphere_.radius * sphere_.radius;
        } else {
            const TriangleMesh mesh = shape.worldMesh();
            std::vector<float> areas;
            double total = 0.0;
            for (std::size_t t = 0; t + 2 < mesh.indices.size(); t += 3) {
                Triangle tri{mesh.positions[mesh.indices[t]], mesh.positions[mesh.indices[t + 1]],
                             mesh.positions[mesh.indices[t + 2]], Vec3(0.0f)};
                // As ray queries report uv: the mesh's coordinates, else the barycentrics.
                if (mesh.uvs.empty()) {
                    tri.uvA = Vec2(0.0f, 0.0f), tri.uvB = Vec2(1.0f, 0.0f), tri.uvC = Vec2(0.0f, 1.0f);
                } else {
                    tri.uvA = mesh.uvs[mesh.indices[t]], tri.uvB = mesh.uvs[mesh.indices[t + 1]];
                    tri.uvC = mesh.uvs[mesh.indices[t + 2]];
                }
                const Vec3 cross = glm::cross(tri.b - tri.a, tri.c - tri.a);
                const float twiceArea = glm::length(cross);
                // Degenerate triangles keep zero weight and are never chosen.
                if (twiceArea > 0.0f) tri.n = cross / twiceArea;
                areas.push_back(0.5f * twiceArea);
                total += 0.5 * twiceArea;
                triangles_.push_back(tri);
            }
            area_ = static_cast<float>(total);
            if (!triangles_.empty()) triangleChoice_ = Distribution1D(areas);
        }
    }

    bool isDelta() const override { return false; }
    bool isInfinite() const override { return false; }

    std::optional<LightSample> sampleLi(const Vec3& ref, const Vec2& u) const override {
        if (!(area_ > 0.0f)) return std::nullopt;
        LightSample s;
        Vec2 uv(0.0f);
        if (isSphere_ && isOutside(ref)) {
            // Uniform in the cone of directions the sphere subtends.
            const Vec3 toCenter = sphere_.center - ref;
            const float distance2 = glm::dot(toCenter, toCenter);
            const float distance = std::sqrt(distance2);
            const float oneMinusCosMax = coneOneMinusCos(distance2);
            const float oneMinusCos = u.x * oneMinusCosMax;
            const float cosT = 1.0f - oneMinusCos;
            const float sin2T = oneMinusCos * (2.0f - oneMinusCos);
            const float sinT = safeSqrt(sin2T);
            const float phi = 2.0f * kPi * u.y;
            const Frame frame(toCenter / distance);
            const Vec3 w = frame.toWorld(Vec3(sinT * std::cos(phi), sinT * std::sin(phi), cosT));
            const float r2 = sphere_.radius * sphere_.radius;
            const float tHit = distance * cosT - safeSqrt(r2 - distance2 * sin2T);
            const Vec3 outward = glm::normalize(ref + tHit * w - sphere_.center);
            s.p = sphere_.center + sphere_.radius * outward;
            s.n = inwards_ ? -outward : outward;
            uv = sphereUv(outward);
            s.pdf = conePdf(oneMinusCosMax);
            // From outside only the outer side is visible.
            if (inwards_ && !twoSided_) return std::nullopt;
        } else {
            const ShapeSample point = sampleArea(u);
            s.p = point.p;
            s.n = point.n;
            uv = point.uv;
            s.pdf = solidAnglePdf(ref, s.p, s.n);
            if (!facesTowards(s.n, ref - s.p)) return std::nullopt;
        }
        const Vec3 toLight = s.p - ref;
        s.distance = glm::length(toLight);
        if (!(s.distance > 0.0f) || !(s.pdf > 0.0f) || !std::isfinite(s.pdf)) return std::nullopt;
        s.wi = toLight / s.distance;
        s.value = radianceAt(uv);
        return s;
    }

    float pdfLi(const Vec3& ref, const Vec3& p, const Vec3& n, const Vec3&) const override {
        if (!(area_ > 0.0f)) return 0.0f;
        if (isSphere_ && isOutside(ref)) {
            const Vec3 toCenter = sphere_.center - ref;
            return conePdf(coneOneMinusCos(glm::dot(toCenter, toCenter)));
        }
        const float pdf = solidAnglePdf(ref, p, n);
        return std::isfinite(pdf) ? pdf : 0.0f;
    }

    Rgb emitted(const Vec3& n, const Vec3& w) const override {
        return facesTowards(n, w) ? radiance_ : Rgb(0.0f);
    }
    Rgb emittedAt(const Vec3& n, const Vec3& w, const Vec2& uv) const override {
        return facesTowards(n, w) ? radianceAt(uv) : Rgb(0.0f);
    }
    // With a texture, its mean stands for the area average: power only chooses
    // lights, and photons carry the texture value where they start.
    Rgb power() const override { return radiance_ * (kPi * area_ * (twoSided_ ? 2.0f : 1.0f)); }

    std::optional<EmissionSample> sampleEmission(const Vec2& uPos, const Vec2& uDir) const override {
        if (!(area_ > 0.0f)) return std::nullopt;
        const ShapeSample point = sampleArea(uPos);
        Vec3 side = point.n;
        Vec2 u = uDir;
        if (twoSided_) {
            // The first coordinate picks the side and is stretched back to [0, 1).
            if (u.x < 0.5f) {
                u.x = 2.0f * u.x;
            } else {
                u.x = 2.0f * u.x - 1.0f;
                side = -side;
            }
        }
        const Vec3 local = sampleCosineHemisphere(u);
        if (!(local.z > 0.0f)) return std::nullopt;
        EmissionSample e;
        e.origin = point.p;
        e.normal = side;
        e.direction = Frame(side).toWorld(local);
        e.pdfPosition = point.pdfArea;
        e.pdfDirection = cosineHemispherePdf(local.z) * (twoSided_ ? 0.5f : 1.0f);
        // L cos / (pdfPosition pdfDirection), with the cosine cancelled exactly.
        e.flux = radianceAt(point.uv) * (kPi * area_ * (twoSided_ ? 2.0f : 1.0f));
        e.emitterArea = area_;
        e.emitterSolidAngle = twoSided_ ? kFourPi : 2.0f * kPi;
        return e;
    }

private:
    struct Triangle {
        Vec3 a, b, c, n;
        Vec2 uvA{0.0f}, uvB{0.0f}, uvC{0.0f};
    };

    Rgb radianceAt(const Vec2& uv) const { return texture_ ? texture_->eval(uv) : radiance_; }
    // Mitsuba's sphere parametrisation, as ray queries report it.
    Vec2 sphereUv(const Vec3& outward) const {
        const Vec3 local = sphere_.worldToObject * outward;
        float phi = std::atan2(local.y, local.x);
        if (phi < 0.0f) phi += 2.0f * kPi;
        return Vec2(phi * kInv2Pi, std::acos(std::clamp(local.z, -1.0f, 1.0f)) * kInvPi);
    }

    bool facesTowards(const Vec3& n, const Vec3& w) const { return twoSided_ || glm::dot(n, w) > 0.0f; }
    bool isOutside(const Vec3& ref) const {
        const Vec3 d = ref - sphere_.center;
        return glm::dot(d, d) > sphere_.radius * sphere_.radius;
    }
    // 1 - cos(theta_max) of the cone a sphere subtends, without cancellation for small cones.
    float coneOneMinusCos(float distance2) const {
        const float sin2Max = std::min(1.0f, sphere_.radius * sphere_.radius / distance2);
        return sin2Max / (1.0f + safeSqrt(1.0f - sin2Max));
    }
    static float conePdf(float oneMinusCosMax) { return 1.0f / (2.0f * kPi * oneMinusCosMax); }

    // Uniform by area over the whole shape.
    ShapeSample sampleArea(const Vec2& u) const {
        ShapeSample s;
        s.pdfArea = 1.0f / area_;
        if (isSphere_) {
            const Vec3 outward = sampleUniformSphere(u);
            s.p = sphere_.center + sphere_.radius * outward;
            s.n = inwards_ ? -outward : outward;
            s.uv = sphereUv(outward);
            return s;
        }
        float uTriangle = 0.0f;
        const Triangle& tri = triangles_[triangleChoice_.sampleDiscrete(u.x, nullptr, &uTriangle)];
        const Vec2 b = sampleUniformTriangle(Vec2(uTriangle, u.y));
        s.p = (1.0f - b.x - b.y) * tri.a + b.x * tri.b + b.y * tri.c;
        s.uv = (1.0f - b.x - b.y) * tri.uvA + b.x * tri.uvB + b.y * tri.uvC;
        s.n = tri.n;
        return s;
    }

    // Area density 1 / A converted to solid angle at ref.
    float solidAnglePdf(const Vec3& ref, const Vec3& p, const Vec3& n) const {
        const Vec3 d = p - ref;
        const float distance2 = glm::dot(d, d);
        const float cosLight = std::abs(glm::dot(n, d)) / std::sqrt(distance2);
        return distance2 / (cosLight * area_);
    }

    Rgb radiance_;
    bool twoSided_;
    std::shared_ptr<Texture> texture_;  // optional; replaces radiance_ where set
    bool isSphere_ = false;
    bool inwards_ = false;
    Sphere sphere_;
    std::vector<Triangle> triangles_;
    Distribution1D triangleChoice_;
    float area_ = 0.0f;
};

}  // namespace

std::shared_ptr<Light> makePointLight(const Vec3& position, const Rgb& intensity) {
    return std::make_shared<PointLight>(position, intensity);
}

std::shared_ptr<Light> makeSpotLight(const Vec3& position, const Vec3& direction, const Rgb& intensity,
                                     float cutoffAngleDeg, float beamWidthDeg) {
    return std::make_shared<SpotLight>(position, direction, intensity, cutoffAngleDeg, beamWidthDeg);
}

std::shared_ptr<Light> makeTexturedSpotLight(const Mat4& toWorld, const Rgb& intensity, float cutoffAngleDeg,
                                             float beamWidthDeg, std::shared_ptr<Texture> texture) {
    const Mat3 linear(toWorld);
    return std::make_shared<SpotLight>(Vec3(toWorld[3]), glm::normalize(linear[2]), intensity, cutoffAngleDeg,
                                       beamWidthDeg, std::move(texture), glm::inverse(linear));
}

std::shared_ptr<Light> makeProjectorLight(const Mat4& toWorld, std::shared_ptr<Texture> irradiance, int width,
                                          int height, float tanHalfFovX, float scale) {
    return std::make_shared<ProjectorLight>(toWorld, std::move(irradiance), width, height, tanHalfFovX, scale);
}

std::shared_ptr<Light> makeDirectionalLight(const Vec3& direction, const Rgb& irradiance) {
    return std::make_shared<DirectionalLight>(direction, irradiance);
}

std::shared_ptr<Light> makeConstantEnvironment(const Rgb& radiance) {
    return std::make_shared<ConstantEnvironment>(radiance);
}

std::shared_ptr<Light> makeEnvironmentMap(const RgbImage& image, float scale, const Mat3& toWorld) {
    return std::make_shared<EnvironmentMap>(image, scale, toWorld);
}

std::shared_ptr<Light> makeAreaLight(const Shape& shape, const Rgb& radiance, bool twoSided) {
    return std::make_shared<AreaLight>(shape, radiance, twoSided);
}

std::shared_ptr<Light> makeTexturedAreaLight(const Shape& shape, std::shared_ptr<Texture> radiance, bool twoSided) {
    const Rgb mean = radiance->mean();
    return std::make_shared<AreaLight>(shape, mean, twoSided, std::move(radiance));
}

}  // namespace fg
