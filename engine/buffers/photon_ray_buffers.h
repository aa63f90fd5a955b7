// SoA buffer of photon rays for photon ray splatting (Herzog et al. 2007):
// every segment x_i -> x_{i+1} of every photon path, with the bounded path
// density p~ of Eq. 7 and, once the ray_bandwidth pass has run, the conical
// frustum of §6 (initial bandwidth h_0 and its growth dh per unit length).
#pragma once

#include "engine/accel/splat_kdtree.h"
#include "engine/core/codec.h"
#include "engine/core/math.h"
#include "engine/core/pass.h"
#include "engine/core/soa.h"

#include <array>
#include <cstdint>
#include <tuple>
#include <utility>

namespace fg {

// Classes of photon rays, by the vertex they leave (index into PhotonRays::countPerClass).
namespace PhotonRayClass {
inline constexpr std::uint8_t Direct = 0;   // leaves the light (x_0)
inline constexpr std::uint8_t Caustic = 1;  // leaves a specular vertex reached through specular events only
inline constexpr std::uint8_t Global = 2;   // leaves a vertex after at least one non-specular event
inline constexpr std::size_t Count = 3;
}  // namespace PhotonRayClass

FG_SOA_COLUMN(RayOrigin, Vec3, "origin");             // x_i
FG_SOA_COLUMN(RayDirection, Vec3, "direction");       // unit, x_i -> x_{i+1}
FG_SOA_COLUMN(RayLength, float, "length");            // |x_{i+1} - x_i|; escaping rays clipped to the scene box
FG_SOA_COLUMN(RayPower, Rgb, "power");                // flux carried along the segment, divided by the emitted count
FG_SOA_COLUMN(RayH0, float, "h0");                    // min(h(x_i), h(x_{i+1})), §6
FG_SOA_COLUMN(RayDh, float, "dh");                    // max(0, h(x_{i+1}) - h(x_i)) / length, §6
FG_SOA_COLUMN(RayDensity, float, "density");          // p~(x_{i+1} | x_i) of Eq. 7
FG_SOA_COLUMN(RayOriginDensity, float, "origin_density");  // p~(x_i | x_{i-1}), 0 for rays leaving the light
FG_SOA_COLUMN(RayClassColumn, std::uint8_t, "class");  // PhotonRayClass
FG_SOA_COLUMN(RayOriginNormal, Vec3, "origin_normal");  // geometric normal at x_i on its outgoing side; zero if none
FG_SOA_COLUMN(RayEndNormal, Vec3, "end_normal");        // geometric normal at x_{i+1} facing the ray; zero if it escaped
FG_SOA_COLUMN(RayPath, std::uint64_t, "path");          // photon path index (rays of a path are consecutive)
FG_SOA_COLUMN(RayVertex, std::uint16_t, "vertex");      // i

using PhotonRayBuffer = SoaBuffer<RayOrigin, RayDirection, RayLength, RayPower, RayH0, RayDh, RayDensity, RayOriginDensity,
                                  RayClassColumn, RayOriginNormal, RayEndNormal, RayPath, RayVertex>;

struct PhotonRays {
    PhotonRayBuffer rays;
    std::uint64_t emitted = 0;  // photon paths emitted
    float clampDistance = 0.0f;  // D~ of Eq. 7
    // Set by ray_bandwidth: stored rays per class (M of Eq. 8), the pilot's
    // normalisation w and scene scale mu_C, and whether h_0 and dh are filled.
    std::array<std::uint64_t, PhotonRayClass::Count> countPerClass{};
    double normalisation = 0.0;  // w
    double sceneScale = 0.0;     // mu_C
    bool hasBandwidths = false;
    std::size_t bytes() const { return rays.bytes(); }
};
template <>
struct BufferTypeName<PhotonRays> {
    static constexpr const char* value = "PhotonRays";
};

// The rays as the splat passes read them (ray_splat, fg_splat): ray_bandwidth's
// output in 5D kd order, every ray with its bandwidth, without the columns
// only Eq. 8 needs (the densities, the path index and the vertex number):
// 73 bytes a ray instead of 91, the largest buffer of the prs pipelines.
using SplatRayBuffer = SoaBuffer<RayOrigin, RayDirection, RayLength, RayPower, RayH0, RayDh, RayClassColumn,
                                 RayOriginNormal, RayEndNormal>;

// Bytes a splat ray takes, what memory figures per ray count.
inline constexpr std::size_t kSplatRayBytes =
    4 * sizeof(Vec3) + sizeof(Rgb) + 3 * sizeof(float) + sizeof(std::uint8_t);

struct SplatRays {
    SplatRayBuffer rays;
    std::uint64_t emitted = 0;   // photon paths emitted
    float clampDistance = 0.0f;  // D~ of Eq. 7
    std::array<std::uint64_t, PhotonRayClass::Count> countPerClass{};  // M of Eq. 8 per class
    double normalisation = 0.0;  // w
    double sceneScale = 0.0;     // mu_C
    std::size_t bytes() const { return rays.bytes(); }
};
template <>
struct BufferTypeName<SplatRays> {
    static constexpr const char* value = "SplatRays";
};

// The radiance map of §5/§8.1 for the glossy eye vertices: per vertex the
// spherical-harmonic coefficients (order 3, world frame, cos θ folded in;
// passes/prs/sh_radiance.h) of the light the photon rays splatted onto it,
// one Rgb column per coefficient, the sum of the kernel weights and the sum of
// the kernel weights over the distance to each ray's origin x_i, so that
// weight_sum / inverse_distance_sum is the kernel-weighted harmonic mean
// distance of the light's sources (Ward et al. 1988; §3 and §8.3 size the
// radiance cache records by it).
FG_SOA_COLUMN(MapVertex, std::uint32_t, "vertex");  // index into the eye vertices
FG_SOA_COLUMN(MapSh0, Rgb, "sh0");
FG_SOA_COLUMN(MapSh1, Rgb, "sh1");
FG_SOA_COLUMN(MapSh2, Rgb, "sh2");
FG_SOA_COLUMN(MapSh3, Rgb, "sh3");
FG_SOA_COLUMN(MapSh4, Rgb, "sh4");
FG_SOA_COLUMN(MapSh5, Rgb, "sh5");
FG_SOA_COLUMN(MapSh6, Rgb, "sh6");
FG_SOA_COLUMN(MapSh7, Rgb, "sh7");
FG_SOA_COLUMN(MapSh8, Rgb, "sh8");
FG_SOA_COLUMN(MapSh9, Rgb, "sh9");
FG_SOA_COLUMN(MapSh10, Rgb, "sh10");
FG_SOA_COLUMN(MapSh11, Rgb, "sh11");
FG_SOA_COLUMN(MapSh12, Rgb, "sh12");
FG_SOA_COLUMN(MapSh13, Rgb, "sh13");
FG_SOA_COLUMN(MapSh14, Rgb, "sh14");
FG_SOA_COLUMN(MapSh15, Rgb, "sh15");
FG_SOA_COLUMN(MapWeightSum, float, "weight_sum");  // sum of K_R(d_perp) |cos theta| over the splats
FG_SOA_COLUMN(MapInverseDistanceSum, float, "inverse_distance_sum");  // sum of K_R |cos theta| / |x - x_i|

using RadianceMapBuffer = SoaBuffer<MapVertex, MapSh0, MapSh1, MapSh2, MapSh3, MapSh4, MapSh5, MapSh6, MapSh7, MapSh8,
                                    MapSh9, MapSh10, MapSh11, MapSh12, MapSh13, MapSh14, MapSh15, MapWeightSum,
                                    MapInverseDistanceSum>;

// The 16 coefficient columns of a radiance map, indexed like sh::Coefficients.
template <class Buffer>
auto radianceMapShColumns(Buffer& map) {
    return [&map]<std::size_t... K>(std::index_sequence<K...>) {
        using Tags = std::tuple<MapSh0, MapSh1, MapSh2, MapSh3, MapSh4, MapSh5, MapSh6, MapSh7, MapSh8, MapSh9, MapSh10,
                                MapSh11, MapSh12, MapSh13, MapSh14, MapSh15>;
        using Span = decltype(map.template column<MapSh0>());
        return std::array<Span, 16>{map.template column<std::tuple_element_t<K, Tags>>()...};
    }(std::make_index_sequence<16>{});
}

struct RadianceMap {
    RadianceMapBuffer vertices;
    std::size_t bytes() const { return vertices.bytes(); }
};
template <>
struct BufferTypeName<RadianceMap> {
    static constexpr const char* value = "RadianceMap";
};

// The splat kd-tree over the eye vertices (§7.1), in the eye buffer's index space.
struct SplatIndex {
    SplatKdTree tree;
    std::size_t bytes() const { return tree.bytes(); }
};
template <>
struct BufferTypeName<SplatIndex> {
    static constexpr const char* value = "SplatIndex";
};

// Codecs for --save / --import (engine/buffers/photon_ray_codecs.cpp).
BufferCodec photonRaysCodec();
BufferCodec splatRaysCodec();
BufferCodec splatIndexCodec();
BufferCodec radianceMapCodec();

}  // namespace fg
