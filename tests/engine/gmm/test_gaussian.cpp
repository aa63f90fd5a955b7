// The Gaussian arithmetic of Jakob et al. 2011 against independent
// computations: the corrected line integral of Eqs. 16-17 against adaptive
// quadrature of the density, the closed-form cell average <log g>_A (Eq. 7)
// against the average over the cell's points, the closed-form KL divergence
// (Eq. 11) against Monte Carlo, and the merge of Eqs. 12-14 against the
// moments it must conserve.
#include "engine/gmm/gaussian.h"
#include "engine/gmm/segment_batch.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <random>
#include <span>
#include <vector>

namespace fg::gmm {
namespace {

// A random rotation (QR of a Gaussian matrix via Gram-Schmidt).
Mat3d randomRotation(std::mt19937_64& rng) {
    std::normal_distribution<double> normal;
    Vec3d a(normal(rng), normal(rng), normal(rng)), b(normal(rng), normal(rng), normal(rng));
    a = glm::normalize(a);
    b = glm::normalize(b - glm::dot(a, b) * a);
    return Mat3d(a, b, glm::cross(a, b));
}

Sym3 covarianceFrom(const Mat3d& rotation, const Vec3d& eigenvalues) {
    const Mat3d m = rotation * Mat3d(eigenvalues.x, 0, 0, 0, eigenvalues.y, 0, 0, 0, eigenvalues.z) *
                    glm::transpose(rotation);
    return Sym3{{m[0][0], m[1][0], m[2][0], m[1][1], m[2][1], m[2][2]}};
}

Gaussian randomGaussian(std::mt19937_64& rng, double minEigen, double maxEigen) {
    std::uniform_real_distribution<double> logEigen(std::log(minEigen), std::log(maxEigen));
    std::uniform_real_distribution<double> position(-1.0, 1.0);
    const Vec3d eigen(std::exp(logEigen(rng)), std::exp(logEigen(rng)), std::exp(logEigen(rng)));
    return Gaussian(Vec3d(position(rng), position(rng), position(rng)), covarianceFrom(randomRotation(rng), eigen));
}

// Direct evaluation of Eq. 5 from the covariance (inverse and determinant by
// GLM), independent of the Cholesky factors under test.
double directDensity(const Gaussian& g, const Vec3d& x) {
    const Mat3d sigma = g.covariance.toMat3();
    const Vec3d d = x - g.mean;
    const double q = glm::dot(d, glm::inverse(sigma) * d);
    return std::exp(-0.5 * q) / (std::pow(2.0 * M_PI, 1.5) * std::sqrt(glm::determinant(sigma)));
}

// Composite Simpson over the part of [a, b] where g(x + t w) e^{-sigma t} is not
// negligible: the integrand is e^{quadratic in t}, so its maximum over [a, b]
// and its local width bound that part.
double quadrature(const Gaussian& g, const Vec3d& x, const Vec3d& w, double sigmaT, double a, double b) {
    const Mat3d precision = glm::inverse(g.covariance.toMat3());
    const double c2 = 0.5 * glm::dot(w, precision * w);
    const double c3 = glm::dot(w, precision * (x - g.mean)) + sigmaT;
    const double peak = -c3 / (2.0 * c2);
    const double top = std::clamp(peak, a, std::isinf(b) ? peak + 1.0 : b);
    const double slope = std::abs(2.0 * c2 * (top - peak) + 0.0);
    const double width = std::min(1.0 / std::sqrt(2.0 * c2), slope > 0.0 ? 1.0 / slope : 1e300);
    const double lo = std::max(a, top - 60.0 * width);
    const double hi = std::min(b, top + 60.0 * width);
    const double normaliser = 1.0 / (std::pow(2.0 * M_PI, 1.5) * std::sqrt(glm::determinant(g.covariance.toMat3())));
    const int n = 200000;
    const double h = (hi - lo) / n;
    double sum = 0.0;
    for (int i = 0; i <= n; ++i) {
        const double t = lo + i * h;
        const double weight = (i == 0 || i == n) ? 1.0 : (i % 2 ? 4.0 : 2.0);
        const Vec3d d = x + t * w - g.mean;
        sum += weight * normaliser * std::exp(-0.5 * glm::dot(d, precision * d) - sigmaT * t);
    }
    return sum * h / 3.0;
}

struct SegmentCase {
    Gaussian gaussian;
    Vec3d origin, direction;
    double a, b;
};

// Segments placed relative to where the ray passes the mean: wholly before
// it, through it, wholly behind it, and to infinity.
std::vector<SegmentCase> segmentCases(std::mt19937_64& rng, double minEigen, double maxEigen) {
    std::vector<SegmentCase> cases;
    std::normal_distribution<double> normal;
    for (int i = 0; i < 6; ++i) {
        const Gaussian g = randomGaussian(rng, minEigen, maxEigen);
        const Vec3d w = glm::normalize(Vec3d(normal(rng), normal(rng), normal(rng)));
        // A line at Mahalanobis distance 0.7 from the mean: the quadratic form
        // of the precision restricted to offsets across the ray sets the scale.
        const Sym3& p = g.factors.precision;
        const Vec3d pw = p * w;
        const double wpw = glm::dot(w, pw);
        Vec3d offset(normal(rng), normal(rng), normal(rng));
        const double across = p.quadratic(offset) - glm::dot(pw, offset) * glm::dot(pw, offset) / wpw;
        offset *= 0.7 / std::sqrt(across);
        const Vec3d origin = g.mean - 3.0 * w + offset;
        // Where the density along the line peaks, and its standard deviation there.
        const double centre = 3.0 - glm::dot(pw, offset) / wpw;
        const double spread = 1.0 / std::sqrt(wpw);
        cases.push_back({g, origin, w, centre - 6.0 * spread, centre - 2.5 * spread});  // before
        cases.push_back({g, origin, w, centre - 0.5 * spread, centre + 1.5 * spread});  // through
        cases.push_back({g, origin, w, centre + 2.0 * spread, centre + 4.0 * spread});  // behind
        cases.push_back({g, origin, w, centre - 1.0 * spread, std::numeric_limits<double>::infinity()});
    }
    return cases;
}

void expectSegmentIntegralsMatchQuadrature(double minEigen, double maxEigen, std::uint64_t seed) {
    std::mt19937_64 rng(seed);
    for (const SegmentCase& c : segmentCases(rng, minEigen, maxEigen)) {
        for (const double sigmaT : {0.0, 0.1, 1.0, 10.0}) {
            const double closed = segmentIntegral(c.gaussian, c.origin, c.direction, sigmaT, c.a, c.b);
            const double reference = quadrature(c.gaussian, c.origin, c.direction, sigmaT, c.a, c.b);
            ASSERT_GT(reference, 0.0);
            EXPECT_NEAR(closed / reference, 1.0, 1e-5)
                << "a " << c.a << " b " << c.b << " sigma_t " << sigmaT << " closed " << closed << " quadrature "
                << reference;
        }
    }
}

TEST(GmmSegmentIntegral, MatchesQuadratureForRandomGaussians) {
    expectSegmentIntegralsMatchQuadrature(0.01, 0.5, 11);
}

TEST(GmmSegmentIntegral, MatchesQuadratureForNeedleThinGaussians) {
    // Eigenvalues down to 1e-8: the ray crosses a needle or a sheet.
    expectSegmentIntegralsMatchQuadrature(1e-8, 0.2, 12);
}

TEST(GmmSegmentIntegral, TailsNeitherOverflowNorCancel) {
    // A thin Gaussian the ray passes far from: every erf argument is deep in one
    // tail, where erf(b) - erf(a) in doubles is 0 and e^{C3^2/4C2} overflows.
    const Gaussian g(Vec3d(0.0), Sym3{{1e-4, 0, 0, 1e-4, 0, 1e-4}});
    const Vec3d origin(-5.0, 0.02, 0.0), w(1.0, 0.0, 0.0);
    for (const double sigmaT : {0.0, 10.0}) {
        const double behind = segmentIntegral(g, origin, w, sigmaT, 5.3, 5.4);
        const double before = segmentIntegral(g, origin, w, sigmaT, 4.6, 4.7);
        EXPECT_NEAR(behind / quadrature(g, origin, w, sigmaT, 5.3, 5.4), 1.0, 1e-5);
        EXPECT_NEAR(before / quadrature(g, origin, w, sigmaT, 4.6, 4.7), 1.0, 1e-5);
    }
    // Along the whole line without extinction: the 2D marginal density at the
    // ray's perpendicular offset, exp(-r^2 / 2s) / (2 pi s).
    const double whole = segmentIntegral(g, origin, w, 0.0, -1e3, std::numeric_limits<double>::infinity());
    EXPECT_NEAR(whole / (std::exp(-0.0004 / 2e-4) / (2.0 * M_PI * 1e-4)), 1.0, 1e-10);
}

// The renderer's three-channel form shares the sigma_t-free terms and copies
// equal channels: it must give exactly the scalar integral per channel, for
// grey and coloured extinction, on every case above (random and needle-thin).
TEST(GmmSegmentIntegral, RgbFormEqualsThreeScalarIntegralsExactly) {
    std::mt19937_64 rng(13);
    std::vector<SegmentCase> cases = segmentCases(rng, 0.01, 0.5);
    for (const SegmentCase& c : segmentCases(rng, 1e-8, 0.2)) cases.push_back(c);
    for (const SegmentCase& c : cases) {
        const SegmentGaussian compact(c.gaussian);
        for (const Vec3d sigmaT : {Vec3d(0.0), Vec3d(1.0), Vec3d(0.1, 1.0, 10.0), Vec3d(2.0, 2.0, 0.5)}) {
            const Vec3d rgb = segmentIntegralRgb(compact, c.origin, c.direction, sigmaT, c.a, c.b);
            for (int channel = 0; channel < 3; ++channel) {
                const double scalar = segmentIntegral(c.gaussian, c.origin, c.direction, sigmaT[channel], c.a, c.b);
                ASSERT_EQ(rgb[channel], scalar) << "channel " << channel << " a " << c.a << " b " << c.b;
            }
        }
    }
}

// The truncated form skips a Gaussian only where the segment stays outside
// its ellipsoid m(x) <= r^2, and elsewhere gives the untruncated integral
// (within 1e-5 of quadrature, as the plain form). The
// closest approach of [a, b] to the mean, in Mahalanobis distance, is found
// here from GLM's inverse of the covariance and the peak of m clamped to
// [a, b], independent of the code under test.
TEST(GmmSegmentIntegral, TruncatedFormSkipsExactlyTheSegmentsOutsideTheEllipsoid) {
    std::mt19937_64 rng(14);
    std::vector<SegmentCase> cases = segmentCases(rng, 0.01, 0.5);
    for (const SegmentCase& c : segmentCases(rng, 1e-8, 0.2)) cases.push_back(c);
    int skipped = 0, kept = 0;
    for (const SegmentCase& c : cases) {
        const SegmentGaussian compact(c.gaussian);
        const Mat3d precision = glm::inverse(c.gaussian.covariance.toMat3());
        const auto m = [&](double t) {
            const Vec3d r = c.origin + t * c.direction - c.gaussian.mean;
            return glm::dot(r, precision * r);
        };
        const double peak = -glm::dot(c.direction, precision * (c.origin - c.gaussian.mean)) /
                            glm::dot(c.direction, precision * c.direction);
        const double closest = m(std::clamp(peak, c.a, c.b));
        for (const double radius : {0.3, 1.0, 2.0, 4.0}) {
            const Vec3d sigmaT(0.0, 1.0, 10.0);
            Vec3d truncated(-1.0);
            const bool hit = truncatedSegmentIntegralRgb(compact, radius * radius, c.origin, c.direction, sigmaT, c.a,
                                                         c.b, truncated);
            if (std::abs(closest - radius * radius) < 1e-9 * radius * radius) continue;  // grazing
            EXPECT_EQ(hit, closest < radius * radius) << "closest m " << closest << " r^2 " << radius * radius;
            if (!hit) {
                EXPECT_EQ(truncated, Vec3d(-1.0));
                ++skipped;
                continue;
            }
            ++kept;
            // Rounding apart (the exponent C3^2 / 4 C2 - C1 cancels for needle-thin
            // Gaussians, 1e-8 relative here), the untruncated integral.
            const Vec3d full = segmentIntegralRgb(compact, c.origin, c.direction, sigmaT, c.a, c.b);
            for (int channel = 0; channel < 3; ++channel) {
                EXPECT_NEAR(truncated[channel], full[channel], 1e-6 * full[channel]);
                const double reference = quadrature(c.gaussian, c.origin, c.direction, sigmaT[channel], c.a, c.b);
                EXPECT_NEAR(truncated[channel] / reference, 1.0, 1e-5);
            }
        }
    }
    // Both outcomes occur, so neither branch goes untested.
    EXPECT_GT(skipped, 10);
    EXPECT_GT(kept, 10);
}

// The renderer's batched form (segment_batch.h: polynomial exp and erf, two
// Gaussians at a time) against the library-based form, one Gaussian at a
// time (batches of one and two, so both lanes are checked) and many at once
// in one sum: the same ellipsoid decisions, values within 1e-6 relative and
// within 1e-5 of quadrature.
TEST(GmmSegmentIntegral, BatchedFormMatchesTheLibraryForm) {
    std::mt19937_64 rng(15);
    std::vector<SegmentCase> cases = segmentCases(rng, 0.01, 0.5);
    for (const SegmentCase& c : segmentCases(rng, 1e-8, 0.2)) cases.push_back(c);
    SegmentBatch batch;
    int compared = 0;
    for (const SegmentCase& c : cases) {
        const SegmentGaussian compact(c.gaussian);
        // The batch integrates over [0, length] from its origin: move the
        // origin to a, and e^{-sigma_t a} is the factor from there to there.
        const Vec3d start = c.origin + c.a * c.direction;
        const double length = c.b - c.a;
        for (const Vec3d sigmaT : {Vec3d(0.0), Vec3d(1.0), Vec3d(0.1, 1.0, 10.0), Vec3d(2.0, 2.0, 0.5)}) {
            const Vec3d full = segmentIntegralRgb(compact, c.origin, c.direction, sigmaT, c.a, c.b);
            for (const int copies : {1, 2}) {
                batch.begin(start, c.direction, length);
                for (int k = 0; k < copies; ++k) batch.add(compact, Vec3d(1.0));
                const Vec3d batched = batch.sum(sigmaT) / static_cast<double>(copies);
                for (int channel = 0; channel < 3; ++channel) {
                    const double expected = full[channel] * std::exp(sigmaT[channel] * c.a);
                    EXPECT_NEAR(batched[channel], expected, 1e-6 * expected)
                        << "channel " << channel << " a " << c.a << " b " << c.b;
                    ++compared;
                }
            }
            const double reference = quadrature(c.gaussian, start, c.direction, sigmaT.z, 0.0, length);
            batch.begin(start, c.direction, length);
            batch.add(compact, Vec3d(1.0));
            EXPECT_NEAR(batch.sum(sigmaT).z / reference, 1.0, 1e-5);
        }
    }
    EXPECT_GT(compared, 500);
}

// Many Gaussians along one segment, some missed by it: addTruncated keeps
// exactly those truncatedSegmentIntegralRgb evaluates, and the sum of power
// times integral over them matches, on finite and infinite segments.
TEST(GmmSegmentIntegral, BatchedSumKeepsWhatTheTruncatedFormKeeps) {
    std::mt19937_64 rng(16);
    std::uniform_real_distribution<double> unit(0.0, 1.0);
    std::vector<Gaussian> gaussians;
    for (int i = 0; i < 301; ++i) gaussians.push_back(randomGaussian(rng, 0.001, 0.05));
    const Vec3d origin(-1.5, 0.05, -0.02);
    const Vec3d w = glm::normalize(Vec3d(1.0, 0.1, 0.05));
    SegmentBatch batch;
    int kept = 0, skipped = 0;
    for (const double length : {2.0, 2.7, std::numeric_limits<double>::infinity()}) {
        for (const Vec3d sigmaT : {Vec3d(0.5), Vec3d(0.0, 0.3, 3.0)}) {
            batch.begin(origin, w, length);
            Vec3d expected(0.0), magnitude(0.0);
            for (const Gaussian& g : gaussians) {
                const SegmentGaussian compact(g);
                const Vec3d power(unit(rng), unit(rng), unit(rng));
                Vec3d integral(0.0);
                const bool hit = truncatedSegmentIntegralRgb(compact, 16.0, origin, w, sigmaT, 0.0, length, integral);
                ASSERT_EQ(batch.addTruncated(compact, 16.0, power), hit);
                (hit ? kept : skipped) += 1;
                if (hit) {
                    expected += power * integral;
                    magnitude += glm::abs(power * integral);
                }
            }
            const Vec3d total = batch.sum(sigmaT);
            for (int channel = 0; channel < 3; ++channel)
                EXPECT_NEAR(total[channel], expected[channel], 1e-6 * magnitude[channel]) << "channel " << channel;
        }
    }
    EXPECT_GT(kept, 100);
    EXPECT_GT(skipped, 100);
}

// addAll tests and keeps two records at a time: every lane, an odd count's
// last one and repeated indices give the rows, counts and sums of the same
// records added one at a time, bit for bit, with and without truncation.
TEST(GmmSegmentIntegral, PairedAddAllEqualsOneAtATime) {
    std::mt19937_64 rng(17);
    std::uniform_real_distribution<double> unit(0.0, 1.0);
    std::vector<PackedGaussian> records;
    std::vector<SegmentGaussian> compact;
    for (int i = 0; i < 300; ++i) {
        compact.emplace_back(randomGaussian(rng, 0.001, 0.05));
        records.emplace_back(compact.back(), 16.0, Vec3d(unit(rng), unit(rng), unit(rng)));
    }
    std::vector<std::uint32_t> indices;
    for (int i = 0; i < 301; ++i) indices.push_back(static_cast<std::uint32_t>(rng() % records.size()));
    const Vec3d origin(-1.5, 0.05, -0.02);
    const Vec3d w = glm::normalize(Vec3d(1.0, 0.1, 0.05));
    SegmentBatch paired, single;
    int keptAndSkipped[2] = {0, 0};
    for (const bool truncate : {true, false}) {
        for (const double length : {2.7, std::numeric_limits<double>::infinity()}) {
            for (const std::size_t count : {indices.size(), std::size_t{1}, std::size_t{2}, std::size_t{300}}) {
                const std::span<const std::uint32_t> some(indices.data(), count);
                paired.begin(origin, w, length);
                single.begin(origin, w, length);
                const std::size_t kept = paired.addAll(records, some, truncate);
                std::size_t keptSingly = 0;
                for (const std::uint32_t j : some) {
                    const Vec3d power(records[j].powerRed, records[j].powerGreen, records[j].powerBlue);
                    if (truncate) {
                        const bool hit = single.addTruncated(compact[j], 16.0, power);
                        keptSingly += hit ? 1 : 0;
                        ++keptAndSkipped[hit ? 0 : 1];
                    } else {
                        single.add(compact[j], power);
                        ++keptSingly;
                    }
                }
                ASSERT_EQ(kept, keptSingly);
                ASSERT_EQ(paired.size(), single.size());
                const Vec3d sigmaT(0.3);
                const Vec3d a = paired.sum(sigmaT), b = single.sum(sigmaT);
                for (int channel = 0; channel < 3; ++channel) EXPECT_EQ(a[channel], b[channel]);
            }
        }
    }
    EXPECT_GT(keptAndSkipped[0], 50);
    EXPECT_GT(keptAndSkipped[1], 50);
}

TEST(GmmGaussian, FactorsMatchDirectInverseAndDeterminant) {
    std::mt19937_64 rng(3);
    for (int i = 0; i < 20; ++i) {
        const Gaussian g = randomGaussian(rng, 1e-3, 2.0);
        ASSERT_TRUE(g.factors.valid);
        const Vec3d x(0.3, -0.2, 0.5);
        EXPECT_NEAR(g.density(x) / directDensity(g, x), 1.0, 1e-10);
        const Mat3d inverse = glm::inverse(g.covariance.toMat3());
        for (int r = 0; r < 3; ++r)
            for (int c = 0; c < 3; ++c)
                EXPECT_NEAR(g.factors.precision(r, c), inverse[c][r], 1e-9 * std::abs(inverse[r][r]));
    }
    EXPECT_FALSE(factorise(Sym3{{1, 0, 0, 1, 0, -1e-9}}).valid);
    EXPECT_FALSE(factorise(Sym3{{1, 1, 0, 1, 0, 1}}).valid);  // singular
}

TEST(GmmGaussian, LargestEigenvalueOfRotatedDiagonal) {
    std::mt19937_64 rng(4);
    for (int i = 0; i < 20; ++i) {
        const Vec3d eigen(0.1 + i, 0.05, 3.0 + 0.01 * i);
        const Sym3 s = covarianceFrom(randomRotation(rng), eigen);
        EXPECT_NEAR(s.largestEigenvalue(), std::max({eigen.x, eigen.y, eigen.z}), 1e-12 * (1.0 + i));
    }
}

TEST(GmmGaussian, CellAverageOfLogDensityIsClosedForm) {
    std::mt19937_64 rng(5);
    std::normal_distribution<double> normal;
    for (int trial = 0; trial < 10; ++trial) {
        const Gaussian g = randomGaussian(rng, 0.01, 1.0);
        std::vector<Vec3d> points(37 + trial);
        const Vec3d centre(normal(rng), normal(rng), normal(rng));
        for (Vec3d& p : points) p = centre + 0.2 * Vec3d(normal(rng), normal(rng), normal(rng));
        Vec3d mean(0.0);
        for (const Vec3d& p : points) mean += p;
        mean /= static_cast<double>(points.size());
        Sym3 covariance;
        for (const Vec3d& p : points) covariance += Sym3::outer(p - mean);
        covariance = covariance * (1.0 / static_cast<double>(points.size()));
        double average = 0.0;
        for (const Vec3d& p : points) average += g.logDensity(p);
        average /= static_cast<double>(points.size());
        EXPECT_NEAR(g.expectedLogDensity(mean, covariance), average, 1e-10 * std::max(1.0, std::abs(average)));
    }
}

TEST(GmmGaussian, KlDivergenceMatchesMonteCarlo) {
    std::mt19937_64 rng(6);
    std::normal_distribution<double> normal;
    for (int trial = 0; trial < 4; ++trial) {
        const Gaussian a = randomGaussian(rng, 0.1, 1.0);
        Gaussian b = randomGaussian(rng, 0.1, 1.0);
        b = Gaussian(a.mean + 0.3 * (b.mean - a.mean), b.covariance);
        const int n = 1000000;
        double sum = 0.0, sumSq = 0.0;
        const Sym3& l = a.factors.cholesky;
        for (int i = 0; i < n; ++i) {
            const Vec3d z(normal(rng), normal(rng), normal(rng));
            const Vec3d x = a.mean + Vec3d(l.v[0] * z.x, l.v[1] * z.x + l.v[3] * z.y,
                                           l.v[2] * z.x + l.v[4] * z.y + l.v[5] * z.z);
            const double r = a.logDensity(x) - b.logDensity(x);
            sum += r;
            sumSq += r * r;
        }
        const double estimate = sum / n;
        const double standardError = std::sqrt((sumSq / n - estimate * estimate) / n);
        const double closed = klDivergence(a, b);
        // 1 % as the issue asks, and never looser than four standard errors.
        ASSERT_LT(4.0 * standardError, 0.01 * closed);
        EXPECT_NEAR(closed, estimate, 0.01 * closed);
        EXPECT_NEAR(klDivergence(a, a), 0.0, 1e-12);
    }
}

TEST(GmmGaussian, MergeConservesWeightAndMoments) {
    std::mt19937_64 rng(7);
    std::uniform_real_distribution<double> uniform(0.01, 2.0);
    for (int trial = 0; trial < 10; ++trial) {
        const Gaussian ga = randomGaussian(rng, 0.01, 1.0), gb = randomGaussian(rng, 0.01, 1.0);
        const WeightedMoments a{uniform(rng), ga.mean, ga.covariance}, b{uniform(rng), gb.mean, gb.covariance};
        const WeightedMoments m = merge(a, b);
        EXPECT_NEAR(m.weight, a.weight + b.weight, 1e-12);
        const Vec3d first = a.weight * a.mean + b.weight * b.mean;
        for (int i = 0; i < 3; ++i) EXPECT_NEAR(m.weight * m.mean[i], first[i], 1e-9);
        const Sym3 second = (a.covariance + Sym3::outer(a.mean)) * a.weight + (b.covariance + Sym3::outer(b.mean)) * b.weight;
        const Sym3 merged = (m.covariance + Sym3::outer(m.mean)) * m.weight;
        for (std::size_t i = 0; i < 6; ++i) EXPECT_NEAR(merged.v[i], second.v[i], 1e-9);
        EXPECT_TRUE(factorise(m.covariance).valid);
    }
}

}  // namespace
}  // namespace fg::gmm
