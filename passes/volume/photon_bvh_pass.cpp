// Photon BVH pass (`photon_bvh`): the bounding-volume hierarchy over the
// photons' kernel spheres that the beam query traverses (engine/accel/photon_bvh.h:
// binned SAH, built in parallel through jobs/, identical for any thread count).
#include "passes/passes.h"

#include "engine/buffers/beam_buffers.h"
#include "engine/buffers/photon_buffers.h"
#include "engine/accel/photon_bvh.h"
#include "jobs/work_context.h"

#include <stdexcept>
#include <string>

namespace fg {

namespace {

class PhotonBvhPass final : public Pass {
public:
    void run(PassContext& ctx) override {
        const VolumePhotonMap& map = ctx.input<VolumePhotonMap>("photons");
        const PhotonRadii& radii = ctx.input<PhotonRadii>("radii");
        const auto positions = map.photons.column<PhotonPosition>();
        const auto r = radii.radii.column<PhotonRadius>();
        if (positions.size() != r.size()) {
            throw std::logic_error("photon_bvh: " + std::to_string(positions.size()) + " photons but " +
                                   std::to_string(r.size()) + " radii");
        }
        PhotonBvh::BuildOptions options;
        options.maxLeafSize = static_cast<std::uint32_t>(ctx.params().getInt("leaf_size"));
        options.bins = static_cast<std::uint32_t>(ctx.params().getInt("bins"));

        PhotonBvh& bvh = ctx.createOutput<PhotonBvh>("bvh");
        const std::int64_t start = jobs::wallNanos();
        bvh.build(positions, r, options);
        const std::int64_t buildNs = jobs::wallNanos() - start;
        ctx.addItems(static_cast<std::int64_t>(positions.size()));
        ctx.addCounter("spheres", static_cast<std::int64_t>(bvh.size()));
        ctx.addCounter("nodes", static_cast<std::int64_t>(bvh.nodeCount()));
        ctx.addCounter("depth", static_cast<std::int64_t>(bvh.depth()));
        ctx.addCounter("build_us", buildNs / 1000);
    }
};

}  // namespace

PassRegistration photonBvhPass() {
    PassSpec spec;
    spec.name = "photon_bvh";
    spec.doc = "Bounding-volume hierarchy (binned SAH, SoA nodes) over the photons' kernel spheres, for beam queries";
    spec.inputs = {
        {"photons", "VolumePhotonMap", "the photons (usually volume_photons)"},
        {"radii", "PhotonRadii", "their kernel radii (photon_radius)"},
    };
    spec.outputs = {{"bvh", "PhotonBvh", "sphere hierarchy; leaves refer back to photon indices"}};
    spec.params = {
        {"leaf_size", ParamType::Int, std::int64_t{PhotonBvhBuildOptions{}.maxLeafSize}, 1, 64, {},
         "largest number of spheres in a leaf (measured best: 16-32)"},
        {"bins", ParamType::Int, std::int64_t{16}, 2, 64, {}, "bins per axis of the binned SAH split search"},
    };
    return {spec, [] { return std::make_unique<PhotonBvhPass>(); }};
}

}  // namespace fg
