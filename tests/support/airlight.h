// Single scattering from a point light in an infinite homogeneous isotropic
// medium along a camera ray segment (the airlight integral): the closed form
// that the path tracer and the volumetric photon pipelines are checked against.
#pragma once

#include <cmath>

namespace fg::test {

// F(u, v) = int_0^v exp(-u tan xi) dxi by composite Simpson on a fine grid.
inline double airlightF(double u, double v) {
    const int n = 20000;
    const double hstep = v / n;
    double sum = 0.0;
    for (int i = 0; i <= n; ++i) {
        const double w = (i == 0 || i == n) ? 1.0 : (i % 2 ? 4.0 : 2.0);
        sum += w * std::exp(-u * std::tan(i * hstep));
    }
    return sum * hstep / 3.0;
}

// Single scattering along a ray segment [0, T] in a homogeneous isotropic
// medium from a point light of intensity I at perpendicular distance h whose
// foot is at distance delta along the ray (substituting t - delta = h tan(theta),
// xi = pi/4 + theta/2):
//   L = sigma_s I e^{-sigma_t delta} / (2 pi h) [F(sigma_t h, xi_b) - F(sigma_t h, xi_a)],
// theta_a = atan(-delta / h), theta_b = atan((T - delta) / h).
inline double airlight(double sigmaS, double sigmaT, double I, double h, double delta, double T) {
    const double thetaA = std::atan(-delta / h), thetaB = std::atan((T - delta) / h);
    const double xiA = M_PI / 4 + thetaA / 2, xiB = M_PI / 4 + thetaB / 2;
    const double u = sigmaT * h;
    return sigmaS * I * std::exp(-sigmaT * delta) / (2.0 * M_PI * h) * (airlightF(u, xiB) - airlightF(u, xiA));
}

}  // namespace fg::test
