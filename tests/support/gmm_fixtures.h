// Hand-made directional mixtures for the guiding tests.
#pragma once

#include "engine/guiding/directional_gmm.h"

#include <gtest/gtest.h>

#include <vector>

namespace fg::test {

inline GmmComponent gmmComponent(float weight, Vec2 mean, float xx, float xy, float yy) {
    GmmComponent c;
    c.weight = weight;
    c.mean = mean;
    c.covXX = xx;
    c.covXY = xy;
    c.covYY = yy;
    return c;
}

// The given components, the rest of the mixture's slots empty; fails the test
// if the covariances are not positive definite.
inline DirectionalGmm gmmMixture(const std::vector<GmmComponent>& parts) {
    DirectionalGmm gmm;
    for (GmmComponent& c : gmm.components) c.weight = 0.0f;
    for (std::size_t j = 0; j < parts.size(); ++j) gmm.components[j] = parts[j];
    EXPECT_TRUE(gmm.finalize());
    return gmm;
}

}  // namespace fg::test
