// Importons (Vorba et al. 2014, §4.1, Fig. 2a, f): the vertices of camera
// paths, the adjoint of photons. Their density and weights represent incident
// importance W_in, as photons represent incident radiance (§4.2). They are
// stored where a guided camera path looks the radiance cache up, so the same
// points serve as the query points at which the radiance cache creates its
// records (§4.1: records are made where guided paths request them).
#pragma once

#include "engine/core/math.h"
#include "engine/core/pass.h"
#include "engine/core/soa.h"

#include <cstdint>

namespace fg {

FG_SOA_COLUMN(ImportonPosition, Vec3, "position");
FG_SOA_COLUMN(ImportonIncident, Vec3, "incident");  // unit direction towards where the importon came from
FG_SOA_COLUMN(ImportonWeight, float, "weight");     // scalar importance weight (mean of the path throughput)
FG_SOA_COLUMN(ImportonNormal, Vec3, "normal");      // shading normal, on the side the importon arrived from
// Scattering events before this one: 0 is the camera's first hit (direct
// importance, which importance training skips as radiance training skips
// direct photons); the radiance cache's query points include it.
FG_SOA_COLUMN(ImportonBounces, std::uint16_t, "bounces");

using ImportonBuffer = SoaBuffer<ImportonPosition, ImportonIncident, ImportonWeight, ImportonNormal, ImportonBounces>;

struct ImportonMap {
    ImportonBuffer importons;
    std::uint64_t paths = 0;  // camera paths traced to make this map
    std::size_t bytes() const { return importons.bytes(); }
};
template <>
struct BufferTypeName<ImportonMap> {
    static constexpr const char* value = "ImportonMap";
};

// Importons that leave the scene (Vorba et al. 2014, §4.4, Fig. 6a): where a
// camera path's ray escapes to the environment. They train the environment
// sampler (environment_guide.h), which learns from them which directions and
// which lines through the scene photons from an environment light should take.
FG_SOA_COLUMN(ExitPosition, Vec3, "position");    // where the ray crosses the scene's bounding sphere
FG_SOA_COLUMN(ExitDirection, Vec3, "direction");  // unit direction it leaves in (towards the environment)
FG_SOA_COLUMN(ExitWeight, float, "weight");       // as ImportonWeight: path throughput mean / paths
FG_SOA_COLUMN(ExitBounces, std::uint16_t, "bounces");  // scattering events before it left

using ImportonExitBuffer = SoaBuffer<ExitPosition, ExitDirection, ExitWeight, ExitBounces>;

struct ImportonExits {
    ImportonExitBuffer exits;
    std::uint64_t paths = 0;  // camera paths traced to make them
    std::size_t bytes() const { return exits.bytes(); }
};
template <>
struct BufferTypeName<ImportonExits> {
    static constexpr const char* value = "ImportonExits";
};

}  // namespace fg
