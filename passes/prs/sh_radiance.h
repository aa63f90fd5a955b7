// The spherical-harmonic radiance map of photon ray splatting (Herzog et al.
// 2007, §5 and §8.1): at a glossy eye vertex the splatted photon rays are
// projected onto real spherical harmonics up to order 3 (16 coefficients) in
// the world frame, with the vertex's cos θ folded in, i.e. the coefficients
// of E(ω) = Σ_i Φ_i K_R(d_⊥,i) |cos θ_i| δ(ω − ω_i), the incident radiance
// times the cosine (the projection of a sum of deltas is exact: c_lm = Σ_i w_i
// Y_lm(ω_i)). §8.1 integrates against the BRDF by rotating the coefficients
// into the vertex frame (z = n, x towards the outgoing direction, so that
// ω_o has φ = 0) and taking the dot product with a table
//   F_lm(θ_o) = ∫_{H+} f_s(ω, ω_o) Y_lm(ω) dω,
// precomputed per material over θ_o, so that L_o = Σ_lm c'_lm F_lm(θ_o).
// A Lambertian vertex needs one coefficient: L_o = (ρ/π) ∫ E = (ρ/π) c_00 2√π.
//
// Rotation: a rotated band-l function stays in band l, so the 16 rotated
// coefficients are recovered exactly (to rounding) by least squares from the
// rotated function's values at 32 fixed directions (a spherical Fibonacci
// set): c' = P · [Σ_k c_k Y_k(Mᵀ d_j)]_j with P = (AᵀA)⁻¹Aᵀ, A_jk = Y_k(d_j).
// It replaces the paper's (unspecified) rotation with one that needs no
// Wigner recurrences; 32 directions keep AᵀA well conditioned.
#pragma once

#include "engine/core/math.h"
#include "engine/shading/bsdf.h"

#include <array>
#include <cmath>
#include <vector>

namespace fg::sh {

inline constexpr int kBands = 4;          // l = 0..3
inline constexpr int kCoefficients = 16;  // (l + 1)^2 up to l = 3
inline constexpr int kRotationDirections = 32;

template <class T>
using Coefficients = std::array<T, kCoefficients>;

// Index of Y_lm: l (l + 1) + m.
constexpr int index(int l, int m) { return l * (l + 1) + m; }

// The real, orthonormal spherical harmonics up to l = 3 at unit direction w
// (Sloan, "Stupid spherical harmonics tricks", 2008, Appendix A2, without the
// Condon-Shortley sign): m < 0 are the sin(|m| φ) harmonics, m > 0 the cos.
inline void evaluate(const Vec3& w, float* y) {
    const float x = w.x, yy = w.y, z = w.z;
    y[0] = 0.282094791773878f;
    y[1] = 0.488602511902920f * yy;
    y[2] = 0.488602511902920f * z;
    y[3] = 0.488602511902920f * x;
    y[4] = 1.092548430592079f * x * yy;
    y[5] = 1.092548430592079f * yy * z;
    y[6] = 0.315391565252520f * (3.0f * z * z - 1.0f);
    y[7] = 1.092548430592079f * x * z;
    y[8] = 0.546274215296040f * (x * x - yy * yy);
    y[9] = 0.590043589926644f * yy * (3.0f * x * x - yy * yy);
    y[10] = 2.890611442640554f * x * yy * z;
    y[11] = 0.457045799464466f * yy * (5.0f * z * z - 1.0f);
    y[12] = 0.373176332590115f * z * (5.0f * z * z - 3.0f);
    y[13] = 0.457045799464466f * x * (5.0f * z * z - 1.0f);
    y[14] = 1.445305721320277f * z * (x * x - yy * yy);
    y[15] = 0.590043589926644f * x * (x * x - 3.0f * yy * yy);
}

// ∫ E over the sphere from the coefficients of E: only c_00 contributes,
// ∫ Y_00 = 4π / (2√π) = 2√π.
template <class T>
T integral(const Coefficients<T>& c) {
    return c[0] * 3.544907701811032f;
}

// The rotation of coefficients into a frame (see the header comment).
class Rotator {
public:
    static const Rotator& instance() {
        static const Rotator rotator;
        return rotator;
    }

    // Coefficients of g(ω) = f(toLocalᵀ ω) (f expressed in the frame whose
    // rows are toLocal's: local = toLocal · world), from f's coefficients.
    template <class T>
    Coefficients<T> rotate(const Coefficients<T>& world, const Vec3& xAxis, const Vec3& yAxis, const Vec3& zAxis) const {
        std::array<T, kRotationDirections> values;
        float y[kCoefficients];
        for (int j = 0; j < kRotationDirections; ++j) {
            const Vec3& d = directions_[static_cast<std::size_t>(j)];
            evaluate(d.x * xAxis + d.y * yAxis + d.z * zAxis, y);
            T v = world[0] * y[0];
            for (int k = 1; k < kCoefficients; ++k) v += world[static_cast<std::size_t>(k)] * y[k];
            values[static_cast<std::size_t>(j)] = v;
        }
        Coefficients<T> local;
        for (int k = 0; k < kCoefficients; ++k) {
            const auto& row = pinv_[static_cast<std::size_t>(k)];
            T v = values[0] * row[0];
            for (int j = 1; j < kRotationDirections; ++j) v += values[static_cast<std::size_t>(j)] * row[static_cast<std::size_t>(j)];
            local[static_cast<std::size_t>(k)] = v;
        }
        return local;
    }

private:
    Rotator() {
        const double golden = kPi * (3.0 - std::sqrt(5.0));
        double a[kRotationDirections][kCoefficients];
        for (int j = 0; j < kRotationDirections; ++j) {
            const double z = 1.0 - (2.0 * j + 1.0) / kRotationDirections;
            const double r = std::sqrt(std::max(0.0, 1.0 - z * z)), phi = golden * j;
            directions_[static_cast<std::size_t>(j)] =
                Vec3(static_cast<float>(r * std::cos(phi)), static_cast<float>(r * std::sin(phi)), static_cast<float>(z));
            float y[kCoefficients];
            evaluate(directions_[static_cast<std::size_t>(j)], y);
            for (int k = 0; k < kCoefficients; ++k) a[j][k] = y[k];
        }
        // (AᵀA)⁻¹ by Gauss-Jordan with partial pivoting, then P = (AᵀA)⁻¹ Aᵀ.
        double m[kCoefficients][2 * kCoefficients] = {};
        for (int r = 0; r < kCoefficients; ++r) {
            for (int c = 0; c < kCoefficients; ++c)
                for (int j = 0; j < kRotationDirections; ++j) m[r][c] += a[j][r] * a[j][c];
            m[r][kCoefficients + r] = 1.0;
        }
        for (int c = 0; c < kCoefficients; ++c) {
            int pivot = c;
            for (int r = c + 1; r < kCoefficients; ++r)
                if (std::abs(m[r][c]) > std::abs(m[pivot][c])) pivot = r;
            for (int k = 0; k < 2 * kCoefficients; ++k) std::swap(m[c][k], m[pivot][k]);
            const double inv = 1.0 / m[c][c];
            for (int k = 0; k < 2 * kCoefficients; ++k) m[c][k] *= inv;
            for (int r = 0; r < kCoefficients; ++r) {
                if (r == c) continue;
                const double f = m[r][c];
                for (int k = 0; k < 2 * kCoefficients; ++k) m[r][k] -= f * m[c][k];
            }
        }
        for (int k = 0; k < kCoefficients; ++k)
            for (int j = 0; j < kRotationDirections; ++j) {
                double v = 0.0;
                for (int c = 0; c < kCoefficients; ++c) v += m[k][kCoefficients + c] * a[j][c];
                pinv_[static_cast<std::size_t>(k)][static_cast<std::size_t>(j)] = static_cast<float>(v);
            }
    }

    std::array<Vec3, kRotationDirections> directions_;
    std::array<std::array<float, kRotationDirections>, kCoefficients> pinv_;
};

// The vertex frame of §8.1: z = n, x along the part of w_o perpendicular to n
// (any perpendicular when w_o is along n, where an isotropic BRDF's table has
// no φ dependence).
struct VertexFrame {
    Vec3 x, y, z;
    float cosThetaO;
};
inline VertexFrame vertexFrame(const Vec3& n, const Vec3& wo) {
    VertexFrame f;
    f.z = n;
    f.cosThetaO = glm::dot(wo, n);
    Vec3 t = wo - f.cosThetaO * n;
    if (glm::dot(t, t) < 1e-12f) t = std::abs(n.x) < 0.9f ? glm::cross(n, Vec3(1, 0, 0)) : glm::cross(n, Vec3(0, 1, 0));
    f.x = glm::normalize(t);
    f.y = glm::cross(f.z, f.x);
    return f;
}

// F_lm(θ_o) of one isotropic material on a grid of θ_o, linearly interpolated.
// f_s = eval / |cos θ_i| (Bsdf::eval carries the cosine, folded into the map).
// Midpoint quadrature in (θ, φ) over the upper hemisphere; fine enough for
// GGX or Beckmann lobes down to α ≈ 0.1 (narrower lobes need more points).
class BrdfTable {
public:
    BrdfTable() = default;
    BrdfTable(const Bsdf& bsdf, const Vec2& uv, int thetaOSteps = 32, int quadratureTheta = 96, int quadraturePhi = 192)
        : steps_(thetaOSteps) {
        rows_.resize(static_cast<std::size_t>(steps_) + 1);
        const double dTheta = 0.5 * kPi / quadratureTheta, dPhi = 2.0 * kPi / quadraturePhi;
        std::vector<Vec3> dirs;
        std::vector<double> dArea;
        std::vector<std::array<float, kCoefficients>> ys;
        for (int i = 0; i < quadratureTheta; ++i) {
            const double theta = (i + 0.5) * dTheta;
            for (int j = 0; j < quadraturePhi; ++j) {
                const double phi = (j + 0.5) * dPhi;
                const Vec3 w(static_cast<float>(std::sin(theta) * std::cos(phi)),
                             static_cast<float>(std::sin(theta) * std::sin(phi)), static_cast<float>(std::cos(theta)));
                dirs.push_back(w);
                dArea.push_back(std::sin(theta) * dTheta * dPhi);
                std::array<float, kCoefficients> y;
                evaluate(w, y.data());
                ys.push_back(y);
            }
        }
        for (int s = 0; s <= steps_; ++s) {
            const double thetaO = std::min(0.5 * kPi * s / steps_, 0.5 * kPi - 1e-3);
            const Vec3 wo(static_cast<float>(std::sin(thetaO)), 0.0f, static_cast<float>(std::cos(thetaO)));
            std::array<std::array<double, 3>, kCoefficients> acc{};
            for (std::size_t q = 0; q < dirs.size(); ++q) {
                const Rgb f = bsdf.eval(wo, dirs[q], uv, TransportMode::Radiance) / dirs[q].z;
                for (int k = 0; k < kCoefficients; ++k)
                    for (int c = 0; c < 3; ++c) acc[static_cast<std::size_t>(k)][static_cast<std::size_t>(c)] += f[c] * ys[q][static_cast<std::size_t>(k)] * dArea[q];
            }
            for (int k = 0; k < kCoefficients; ++k)
                rows_[static_cast<std::size_t>(s)][static_cast<std::size_t>(k)] =
                    Rgb(static_cast<float>(acc[static_cast<std::size_t>(k)][0]), static_cast<float>(acc[static_cast<std::size_t>(k)][1]),
                        static_cast<float>(acc[static_cast<std::size_t>(k)][2]));
        }
    }

    bool empty() const { return rows_.empty(); }

    // L_o = Σ c'_lm F_lm(θ_o) for coefficients already in the vertex frame.
    Rgb integrate(const Coefficients<Rgb>& local, float cosThetaO) const {
        const float theta = std::acos(std::clamp(cosThetaO, 0.0f, 1.0f));
        const float u = std::clamp(theta / (0.5f * kPi) * static_cast<float>(steps_), 0.0f, static_cast<float>(steps_));
        const int i = std::min(static_cast<int>(u), steps_ - 1);
        const float t = u - static_cast<float>(i);
        Rgb sum(0.0f);
        for (int k = 0; k < kCoefficients; ++k) {
            const Rgb f = (1.0f - t) * rows_[static_cast<std::size_t>(i)][static_cast<std::size_t>(k)] +
                          t * rows_[static_cast<std::size_t>(i) + 1][static_cast<std::size_t>(k)];
            sum += f * local[static_cast<std::size_t>(k)];
        }
        return sum;
    }

private:
    int steps_ = 0;
    std::vector<Coefficients<Rgb>> rows_;
};

}  // namespace fg::sh
