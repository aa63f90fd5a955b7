#pragma once
// Russian roulette shared by every path tracer (pt, importon, photon, bdpt
// subpaths), so that they all end paths by the same rule.
#include "engine/core/math.h"
#include "jobs/random.h"

#include <algorithm>

namespace fg {

// `m` is the largest component of the path's throughput relative to its start
// (w_i / w_i* in Vorba et al. 2014 §4.5). A path is not threatened while m is
// at least `threshold`; below it, it survives with probability
// min(m / threshold, 0.95) and its throughput is divided by that probability.
// threshold = 1 is the classic throughput roulette. §4.5 uses threshold
// w_t = 1e-5: guided sampling sends many particles of small weight into
// important regions on purpose, and a roulette on the bare weight would end
// most of them and multiply the few survivors into spiky noise (§7). The
// kill probability keeps a 5 % floor so that a path whose weight never
// drops still ends.
inline bool rouletteSurvives(float m, float threshold, jobs::Rng& rng, Rgb& throughput) {
    if (m >= threshold) return true;
    const float q = std::max(0.05f, 1.0f - m / threshold);
    if (rng.uniform() < q) return false;
    throughput /= 1.0f - q;
    return true;
}

}  // namespace fg
