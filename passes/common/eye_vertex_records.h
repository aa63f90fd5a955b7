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

// A camera sample's eye vertex; the pixel column is filled on appending.
struct EyeRecord : EyeVertexBuffer::Record {
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
    jobs::parallelFor(count, 4096, [&](std::size_t i) {
        if (!records[i].valid) return;
        EyeVertexBuffer::Record vertex = records[i];
        vertex.get<EyePixel>() = static_cast<std::uint32_t>(firstPixel + i / samplesPerPixel);
        out.set(slot[i], vertex);
    });
    ctx.addCounter("eye_vertices", static_cast<std::int64_t>(stored - before));
}

}  // namespace fg
