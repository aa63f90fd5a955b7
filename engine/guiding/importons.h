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

}  // namespace fg
