// Eye vertices as the eye passes produce them: one record per camera sample,
// traced in parallel, then appended to the EyeVertices SoA buffer in sample
// order so the buffer is identical for any thread count. Shared by the eye
// pass (surfaces) and the volume eye pass (media).
#pragma once

#include "engine/core/math.h"
#include "engine/core/pass.h"
#include "engine/buffers/photon_buffers.h"
#include "jobs/parallel.h"

#include <cstdint>
#include <vector>

namespace fg {

struct EyeRecord {
    Vec3 position{0.0f};
    Vec3 normal{0.0f};
    Vec3 geometricNormal{0.0f};
    Vec3 outgoing{0.0f};
    Vec2 uv{0.0f};
    Rgb throughput{0.0f};
    std::uint32_t bsdf = 0;
    bool valid = false;
};

// Appends the valid records of one wave (samples of pixels firstPixel, ...,
// samplesPerPixel per pixel) to `out`; `slot` is scratch space kept between waves.
inline void appendEyeVertices(const std::vector<EyeRecord>& records, std::size_t firstPixel,
                              std::size_t samplesPerPixel, EyeVertexBuffer& out, std::vector<std::size_t>& slot,
                              PassContext& ctx) {
    const std::size_t count = records.size();
    slot.resize(count);
    std::size_t stored = out.size();
    const std::size_t before = stored;
    for (std::size_t i = 0; i < count; ++i) {
        slot[i] = stored;
        if (records[i].valid) ++stored;
    }
    out.resize(stored);
    const auto position = out.column<EyePosition>();
    const auto normal = out.column<EyeNormal>();
    const auto geometricNormal = out.column<EyeGeometricNormal>();
    const auto outgoing = out.column<EyeOutgoing>();
    const auto bsdf = out.column<EyeBsdf>();
    const auto uv = out.column<EyeUv>();
    const auto throughput = out.column<EyeThroughput>();
    const auto pixelOf = out.column<EyePixel>();
    jobs::parallelFor(count, 4096, [&](std::size_t i) {
        const EyeRecord& r = records[i];
        if (!r.valid) return;
        const std::size_t v = slot[i];
        position[v] = r.position;
        normal[v] = r.normal;
        geometricNormal[v] = r.geometricNormal;
        outgoing[v] = r.outgoing;
        bsdf[v] = r.bsdf;
        uv[v] = r.uv;
        throughput[v] = r.throughput;
        pixelOf[v] = static_cast<std::uint32_t>(firstPixel + i / samplesPerPixel);
    });
    ctx.addCounter("eye_vertices", static_cast<std::int64_t>(stored - before));
}

}  // namespace fg
