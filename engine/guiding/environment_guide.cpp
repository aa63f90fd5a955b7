// Guided environment emission's model (Vorba et al. 2014, §4.4); see the header.
#include "engine/guiding/environment_guide.h"

#include "engine/scene/scene.h"
#include "engine/shading/light.h"

#include <algorithm>
#include <cmath>
#include <vector>

namespace fg {

Vec2 squareToUnitDisk(const Vec2& s) {
    // squareToHemisphere lifts the concentric disk point d to d sqrt(2 − |d|²),
    // z = 1 − |d|²; undoing the lift gives the disk point of the same map.
    const Vec3 h = squareToHemisphere(s);
    const float r2 = std::clamp(1.0f - h.z, 0.0f, 1.0f);
    const float lift = std::sqrt(2.0f - r2);
    return {h.x / lift, h.y / lift};
}

Vec2 unitDiskToSquare(const Vec2& d) {
    float r2 = d.x * d.x + d.y * d.y;
    Vec2 p = d;
    if (r2 > 1.0f) {
        p /= std::sqrt(r2);
        r2 = 1.0f;
    }
    const float lift = std::sqrt(2.0f - r2);
    return *hemisphereToSquare(Vec3(p.x * lift, p.y * lift, 1.0f - r2));
}

bool EnvironmentGuide::guides() const {
    if (cellCount() == 0 || cells.size() != cellCount()) return false;
    for (const float d : cells.column<EnvCellDensity>())
        if (d > 0.0f) return true;
    return false;
}

std::uint32_t EnvironmentGuide::cellOf(const Vec3& w) const {
    const float z = std::clamp(w.z, -1.0f, 1.0f);
    const auto row = std::min(rows - 1, static_cast<std::uint32_t>(std::max(0.0f, (1.0f - z) * 0.5f * rows)));
    float phi = std::atan2(w.y, w.x);
    if (phi < 0.0f) phi += 2.0f * kPi;
    const auto column = std::min(columns - 1, static_cast<std::uint32_t>(std::max(0.0f, phi * kInv2Pi * columns)));
    return row * columns + column;
}

Vec3 EnvironmentGuide::directionInCell(std::uint32_t cell, const Vec2& u) const {
    const std::uint32_t row = cell / columns, column = cell % columns;
    const float z = std::clamp(1.0f - 2.0f * (static_cast<float>(row) + u.x) / static_cast<float>(rows), -1.0f, 1.0f);
    const float phi = 2.0f * kPi * (static_cast<float>(column) + u.y) / static_cast<float>(columns);
    const float sinTheta = std::sqrt(std::max(0.0f, 1.0f - z * z));
    return {sinTheta * std::cos(phi), sinTheta * std::sin(phi), z};
}

Vec3 EnvironmentGuide::cellCentre(std::uint32_t cell) const { return directionInCell(cell, Vec2(0.5f)); }

Frame EnvironmentGuide::diskFrame(std::uint32_t cell, const Vec3& w) const {
    const Vec3 a = cellCentre(cell);
    const Frame base(a);
    // The rotation about a × w taking a to w (Rodrigues' formula written
    // without the axis): v -> v − ((a + w)·v) / (1 + a·w) (a + w) + 2 (a·v) w.
    // Within a cell a·w is far from −1.
    const Vec3 sum = a + w;
    const float denominator = 1.0f + glm::dot(a, w);
    const auto rotate = [&](const Vec3& v) {
        return v - (glm::dot(sum, v) / denominator) * sum + 2.0f * glm::dot(a, v) * w;
    };
    Frame f;
    f.n = w;
    f.s = rotate(base.s);
    f.t = rotate(base.t);
    return f;
}

Vec2 EnvironmentGuide::diskPoint(std::uint32_t cell, const Vec3& w, const Vec3& x) const {
    const Frame f = diskFrame(cell, w);
    const Vec3 o = x - center;
    return Vec2(glm::dot(o, f.s), glm::dot(o, f.t)) / radius;
}

Vec3 EnvironmentGuide::diskOrigin(std::uint32_t cell, const Vec3& w, const Vec2& d) const {
    const Frame f = diskFrame(cell, w);
    return center + radius * (w + f.s * d.x + f.t * d.y);
}

const DirectionalGmm* EnvironmentGuide::diskMixture(std::uint32_t cell) const {
    if (cells.column<EnvCellFitted>()[cell] == 0) return nullptr;
    const DirectionalGmm& gmm = cells.column<EnvCellMixture>()[cell];
    return gmm.usable() ? &gmm : nullptr;
}

float environmentPositionPdf(const DirectionalGmm* gmm, float gamma, const Vec2& unitDisk, float radius) {
    const float uniform = 1.0f / (kPi * radius * radius);
    if (!gmm) return uniform;
    const Vec2 s = unitDiskToSquare(unitDisk);
    // Square density -> unit disk (÷ π) -> disk of radius R (÷ R²).
    const float guided = gmm->pdfSquare(s) / (kSquareToUnitDiskJacobian * radius * radius);
    return gamma * guided + (1.0f - gamma) * uniform;
}

bool isEnvironmentEmitter(const Light& light) { return light.isInfinite() && !light.isDelta(); }

bool hasEnvironmentEmitter(const Scene& scene) {
    return std::any_of(scene.lights.begin(), scene.lights.end(),
                       [](const auto& light) { return isEnvironmentEmitter(*light); });
}

EnvironmentSampler::EnvironmentSampler(const EnvironmentGuide& guide, const Light& light)
    : guide_(&guide), light_(&light) {
    if (!guide.guides()) return;
    const auto density = guide.cells.column<EnvCellDensity>();
    std::vector<float> weights(guide.cellCount());
    const std::size_t patchCount = light.samplingPatchCount();
    if (patchCount > 0) {
        // Patches are counted in 32 bits, as cells are; a map with more than
        // 2^32 patches would not fit in memory anyway.
        patched_ = true;
        patchCell_.resize(patchCount);
        std::vector<float> mass(patchCount);
        std::vector<Vec3> centres(patchCount);
        light.samplingPatchCentres(centres);
        std::vector<std::uint32_t> counts(guide.cellCount() + 1, 0);
        for (std::size_t k = 0; k < patchCount; ++k) {
            mass[k] = light.samplingPatchMass(k);
            patchCell_[k] = guide.cellOf(centres[k]);
            if (mass[k] > 0.0f) ++counts[patchCell_[k] + 1];
        }
        for (std::size_t c = 0; c < guide.cellCount(); ++c) counts[c + 1] += counts[c];
        patchStart_ = counts;
        patches_.resize(counts.back());
        for (std::size_t k = 0; k < patchCount; ++k)
            if (mass[k] > 0.0f) patches_[counts[patchCell_[k]]++] = static_cast<std::uint32_t>(k);
        withinCell_.resize(guide.cellCount());
        std::vector<float> cellMasses;
        for (std::uint32_t c = 0; c < guide.cellCount(); ++c) {
            if (!(density[c] > 0.0f) || patchStart_[c] == patchStart_[c + 1]) continue;
            cellMasses.clear();
            for (std::uint32_t i = patchStart_[c]; i < patchStart_[c + 1]; ++i) cellMasses.push_back(mass[patches_[i]]);
            withinCell_[c] = Distribution1D(cellMasses);
            weights[c] = density[c] * withinCell_[c].total();
        }
    } else {
        for (std::uint32_t c = 0; c < guide.cellCount(); ++c) {
            if (!(density[c] > 0.0f)) continue;
            float emitted = 0.0f;
            for (const Vec2 u : {Vec2(0.25f, 0.25f), Vec2(0.75f, 0.25f), Vec2(0.25f, 0.75f), Vec2(0.75f, 0.75f)})
                emitted += 0.25f * std::max(0.0f, luminance(light.environment(guide.directionInCell(c, u))));
            weights[c] = density[c] * emitted;
        }
    }
    double total = 0.0;
    for (const float w : weights) total += w;
    if (!(total > 0.0) || !std::isfinite(total)) return;
    cells_ = Distribution1D(weights);
    usable_ = true;
}

std::optional<Vec3> EnvironmentSampler::sample(const Vec2& u, float* pdf) const {
    float pmf = 0.0f, uRemapped = 0.0f;
    const auto cell = static_cast<std::uint32_t>(cells_.sampleDiscrete(u.x, &pmf, &uRemapped));
    if (!patched_) {
        if (pdf) *pdf = pmf / guide_->cellSolidAngle();
        return guide_->directionInCell(cell, Vec2(uRemapped, u.y));
    }
    // The cell takes u.x and the patch u.y, and what each leaves over places
    // the direction within the patch: both axes keep about as many bits.
    float vRemapped = 0.0f;
    const std::size_t index = withinCell_[cell].sampleDiscrete(u.y, nullptr, &vRemapped);
    const std::optional<Vec3> w =
        light_->sampleInSamplingPatch(patches_[patchStart_[cell] + index], Vec2(uRemapped, vRemapped));
    if (w && pdf) *pdf = this->pdf(*w);
    return w;
}

float EnvironmentSampler::pdf(const Vec3& towardsLight) const {
    if (!usable_) return 0.0f;
    if (!patched_) return cells_.discretePmf(guide_->cellOf(towardsLight)) / guide_->cellSolidAngle();
    return pdf(towardsLight, light_->pdfLi(guide_->center, Vec3(0.0f), Vec3(0.0f), towardsLight));
}

float EnvironmentSampler::pdf(const Vec3& towardsLight, float lightPdf) const {
    if (!usable_) return 0.0f;
    if (!patched_) return cells_.discretePmf(guide_->cellOf(towardsLight)) / guide_->cellSolidAngle();
    const std::uint32_t cell = patchCell_[light_->samplingPatchOf(towardsLight)];
    const float cellMass = withinCell_[cell].size() > 0 ? withinCell_[cell].total() : 0.0f;
    if (!(cellMass > 0.0f)) return 0.0f;
    return cells_.discretePmf(cell) / cellMass * lightPdf;
}

}  // namespace fg
