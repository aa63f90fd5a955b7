// SoA buffers of the photon-based pipelines: photons (surface events, with
// optional photon differentials, Frisvad et al. 2014 §3), volume photons
// (scattering events in media, Jensen & Christensen 1998) and eye-path
// vertices (the first non-specular vertex of each camera path, Frisvad et al.
// 2014 §3.3, Herzog et al. 2007). All are declared once, column by column, on
// SoaBuffer.
#pragma once

#include "engine/core/math.h"
#include "engine/core/pass.h"
#include "engine/core/soa.h"

#include <cstdint>

namespace fg {

namespace PhotonClass {
inline constexpr std::uint8_t Direct = 1u << 0;   // L D: light is covered by next-event estimation
inline constexpr std::uint8_t Caustic = 1u << 1;  // L S+ D
inline constexpr std::uint8_t Global = 1u << 2;   // L (S|D)* D (S|D)* D: at least one diffuse bounce before
inline constexpr std::uint8_t Volume = 1u << 3;   // scattering event in a medium (added by the volume issue)
}  // namespace PhotonClass

FG_SOA_COLUMN(PhotonPosition, Vec3, "position");
FG_SOA_COLUMN(PhotonIncident, Vec3, "incident");  // unit direction towards where the photon came from
FG_SOA_COLUMN(PhotonPower, Rgb, "power");         // flux carried, already divided by the emitted count
FG_SOA_COLUMN(PhotonNormal, Vec3, "normal");      // shading normal at the event (zero in media)
FG_SOA_COLUMN(PhotonClassColumn, std::uint8_t, "class");
FG_SOA_COLUMN(PhotonDu, Vec3, "dudx");  // positional photon differential D_u x' at the event (Eq. 7)
FG_SOA_COLUMN(PhotonDv, Vec3, "dvdx");  // D_v x'

using PhotonBuffer =
    SoaBuffer<PhotonPosition, PhotonIncident, PhotonPower, PhotonNormal, PhotonClassColumn, PhotonDu, PhotonDv>;

// A set of stored photons and what is needed to interpret them.
struct PhotonMap {
    PhotonBuffer photons;
    std::uint64_t emitted = 0;            // photon paths emitted to make this map
    std::uint64_t collapsedFootprints = 0;  // discarded: zero-area differential footprint (Eq. 12 singular)
    bool hasDifferentials = false;
    std::size_t bytes() const { return photons.bytes(); }
};
template <>
struct BufferTypeName<PhotonMap> {
    static constexpr const char* value = "PhotonMap";
};

// Volume photons have no surface: no normal and no footprint (their paths
// have left the specular chain that differentials follow). 37 bytes per
// photon instead of a PhotonBuffer's 73.
using VolumePhotonBuffer = SoaBuffer<PhotonPosition, PhotonIncident, PhotonPower, PhotonClassColumn>;

struct VolumePhotonMap {
    VolumePhotonBuffer photons;
    std::uint64_t emitted = 0;  // photon paths emitted to make this map
    std::size_t bytes() const { return photons.bytes(); }
};
template <>
struct BufferTypeName<VolumePhotonMap> {
    static constexpr const char* value = "VolumePhotonMap";
};

FG_SOA_COLUMN(EyePosition, Vec3, "position");
FG_SOA_COLUMN(EyeNormal, Vec3, "normal");        // shading normal
FG_SOA_COLUMN(EyeGeometricNormal, Vec3, "ng");
FG_SOA_COLUMN(EyeOutgoing, Vec3, "wo");          // unit direction towards the camera side of the path
FG_SOA_COLUMN(EyeBsdf, std::uint32_t, "bsdf");   // index into Scene::bsdfs
FG_SOA_COLUMN(EyeUv, Vec2, "uv");
FG_SOA_COLUMN(EyeThroughput, Rgb, "throughput"); // importance weight incl. 1/spp and specular chain
FG_SOA_COLUMN(EyePixel, std::uint32_t, "pixel");

using EyeVertexBuffer =
    SoaBuffer<EyePosition, EyeNormal, EyeGeometricNormal, EyeOutgoing, EyeBsdf, EyeUv, EyeThroughput, EyePixel>;

struct EyeVertices {
    EyeVertexBuffer vertices;
    int samplesPerPixel = 1;
    std::size_t bytes() const { return vertices.bytes(); }
};
template <>
struct BufferTypeName<EyeVertices> {
    static constexpr const char* value = "EyeVertices";
};

}  // namespace fg
