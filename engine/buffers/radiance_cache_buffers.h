// SoA buffer of the radiance cache records of photon ray splatting (Herzog et
// al. 2007, §8.3, after Gautron et al. 2005): each record is taken at one
// pixel's eye vertex and carries the spherical-harmonic coefficients of the
// light splatted there (world frame, cos θ folded in, as the radiance map of
// photon_ray_buffers.h) and its validity radius R_k, the kernel-weighted
// harmonic mean distance of the photon rays that reached the pixel.
#pragma once

#include "engine/core/codec.h"
#include "engine/core/math.h"
#include "engine/core/pass.h"
#include "engine/core/soa.h"

#include <array>
#include <cstdint>

namespace fg {

// Order-3 SH coefficients of one record, l (l + 1) + m as in passes/prs/sh_radiance.h.
using CacheCoefficientArray = std::array<Rgb, 16>;

FG_SOA_COLUMN(CachePosition, Vec3, "position");          // x_k
FG_SOA_COLUMN(CacheNormal, Vec3, "normal");              // n_k, shading normal
FG_SOA_COLUMN(CacheRadius, float, "radius");             // R_k of the Ward weight
FG_SOA_COLUMN(CachePixel, std::uint32_t, "pixel");       // the pixel the record was taken at
FG_SOA_COLUMN(CacheCoefficients, CacheCoefficientArray, "coefficients");

using CacheRecordBuffer = SoaBuffer<CachePosition, CacheNormal, CacheRadius, CachePixel, CacheCoefficients>;

struct CacheRecords {
    CacheRecordBuffer records;
    float error = 0.0f;  // the ε the records were placed for
    std::size_t bytes() const { return records.bytes(); }
};
template <>
struct BufferTypeName<CacheRecords> {
    static constexpr const char* value = "CacheRecords";
};

// Codec for --save / --import (engine/buffers/photon_ray_codecs.cpp).
BufferCodec cacheRecordsCodec();

}  // namespace fg
