// An equirectangular sky (the layout of engine/shading/light.cpp: +Y up,
// column x at φ = 2π (x + 1/2) / width, row y at θ = π y / (height − 1)) of
// radiance 1 with a small sun: the pixels whose direction lies within
// `sunDegrees` of `towardsSun` hold `sunRadiance`. A real sky's sun is
// 0.5–2° across and holds most of its power; guided environment emission
// (Vorba et al. 2014, §4.4) has to find it within a bitmap cell of ~9°.
#pragma once

#include "engine/core/math.h"

#include <cmath>
#include <vector>

namespace fg::test {

inline std::vector<Rgb> sunSkyPixels(int width, int height, const Vec3& towardsSun, float sunDegrees,
                                     float sunRadiance) {
    const Vec3 sun = glm::normalize(towardsSun);
    const float cosSun = std::cos(sunDegrees * kPi / 180.0f);
    std::vector<Rgb> pixels;
    pixels.reserve(static_cast<std::size_t>(width) * height);
    for (int y = 0; y < height; ++y) {
        const float theta = kPi * static_cast<float>(y) / static_cast<float>(height - 1);
        for (int x = 0; x < width; ++x) {
            const float phi = 2.0f * kPi * (static_cast<float>(x) + 0.5f) / static_cast<float>(width);
            const Vec3 d(std::sin(phi) * std::sin(theta), std::cos(theta), -std::cos(phi) * std::sin(theta));
            pixels.push_back(glm::dot(d, sun) >= cosSun ? Rgb(sunRadiance) : Rgb(0.6f, 0.8f, 1.0f));
        }
    }
    return pixels;
}

}  // namespace fg::test
