// Photon index pass (`photon_index`): builds the neighbour structure over a
// photon map's positions that the gather pass queries for the k nearest
// photons (Jensen 1996). One instance per map. Photons of class Direct only are
// left out unless asked for: the eye pass estimates direct light by next-event
// estimation, and counting them among the k neighbours would shrink the
// bandwidth for light that is never added.
#include "passes/passes.h"
#include "passes/caustics/photon_estimate.h"

#include "engine/buffers/photon_buffers.h"
#include "engine/accel/point_index.h"

namespace fg {

namespace {

class PhotonIndexPass final : public Pass {
public:
    void run(PassContext& ctx) override {
        const PhotonMap& map = ctx.input<PhotonMap>("photons");
        const bool includeDirect = ctx.params().getBool("include_direct");
        const auto positions = map.photons.column<PhotonPosition>();
        const auto classes = map.photons.column<PhotonClassColumn>();
        std::vector<std::uint32_t> ids;
        ids.reserve(positions.size());
        for (std::size_t i = 0; i < positions.size(); ++i)
            if (includeDirect || countsAsIndirect(classes[i])) ids.push_back(static_cast<std::uint32_t>(i));

        PointIndex& index = ctx.createOutput<PointIndex>("index");
        if (ids.size() == positions.size())
            index.build(positions);
        else
            index.build(positions, std::move(ids));
        ctx.addItems(static_cast<std::int64_t>(index.size()));
        ctx.addCounter("indexed_photons", static_cast<std::int64_t>(index.size()));
    }
};

}  // namespace

PassRegistration photonIndexPass() {
    PassSpec spec;
    spec.name = "photon_index";
    spec.doc = "Neighbour-search structure over a photon map's positions (for k-nearest-photon gathering)";
    spec.inputs = {{"photons", "PhotonMap", "the photons to index"}};
    spec.outputs = {{"index", "PointIndex", "search structure over the photons; reports photon indices"}};
    spec.params = {
        {"include_direct", ParamType::Bool, false, 0, 0, {},
         "also index photons of class Direct (already counted by the eye pass's next-event estimation)"},
    };
    return {spec, [] { return std::make_unique<PhotonIndexPass>(); }};
}

}  // namespace fg
