// SoA buffers of the beam radiance estimate (Jarosz, Zwicker & Jensen 2008;
// Jakob et al. 2011 §3.2): the per-photon kernel radii of the pilot density
// estimate, and the camera-ray segments through participating media that the
// beam query integrates over.
#pragma once

#include "engine/core/math.h"
#include "engine/core/pass.h"
#include "engine/core/soa.h"

#include <cstdint>

namespace fg {

FG_SOA_COLUMN(PhotonRadius, float, "radius");  // kernel radius r_i of photon i, scene units
using PhotonRadiusBuffer = SoaBuffer<PhotonRadius>;

// One radius per photon of a map, in the map's photon order.
struct PhotonRadii {
    PhotonRadiusBuffer radii;
    std::uint32_t neighbours = 0;  // k of the pilot estimate
    float scale = 1.0f;            // r_i = scale * distance to the k-th nearest other photon
    std::size_t bytes() const { return radii.bytes(); }
};
template <>
struct BufferTypeName<PhotonRadii> {
    static constexpr const char* value = "PhotonRadii";
};

// A camera-ray segment inside one medium: the points origin + t direction,
// t in [tNear, tFar]. Segments of one straight leg of a camera path (e.g. a
// ray crossing several index-matched boundaries) share its origin, so tNear is
// the distance from the leg's start. The throughput is the camera path's
// weight at tNear: 1/spp times specular weights times the transmittance of the
// media crossed before; within the segment the medium's own transmittance
// from tNear applies.
FG_SOA_COLUMN(SegmentOrigin, Vec3, "origin");
FG_SOA_COLUMN(SegmentDirection, Vec3, "direction");  // unit length
FG_SOA_COLUMN(SegmentTNear, float, "t_near");
FG_SOA_COLUMN(SegmentTFar, float, "t_far");          // may be kInfinity (ray escaped)
FG_SOA_COLUMN(SegmentMedium, std::int32_t, "medium"); // index into Scene::media
FG_SOA_COLUMN(SegmentPixel, std::uint32_t, "pixel");
FG_SOA_COLUMN(SegmentThroughput, Rgb, "throughput");

using SegmentBuffer = SoaBuffer<SegmentOrigin, SegmentDirection, SegmentTNear, SegmentTFar, SegmentMedium,
                                SegmentPixel, SegmentThroughput>;

// Segments in (pixel, sample, order along the path) order.
struct EyeSegments {
    SegmentBuffer segments;
    int samplesPerPixel = 1;
    std::size_t bytes() const { return segments.bytes(); }
};
template <>
struct BufferTypeName<EyeSegments> {
    static constexpr const char* value = "EyeSegments";
};

}  // namespace fg
