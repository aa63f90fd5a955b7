// EM statistics pass (`em_stats`): the partition family of Jakob et al. 2011
// §5.1 — a balanced kd-tree over the volume photons, a leaf once a subtree
// holds fewer than 5 photons, every node holding count, mean, centred scatter
// (doubles), summed RGB power, box and split (engine/gmm/em_tree.h). Any cut
// through it is a partition for accelerated EM (§3.6); the photons themselves
// are not needed afterwards, so the map is freed once the tree is built.
#include "passes/passes.h"

#include "engine/buffers/photon_buffers.h"
#include "engine/gmm/em_tree.h"
#include "passes/pem/pem_common.h"
#include "jobs/work_context.h"

namespace fg {

namespace {

class EmStatsPass final : public Pass {
public:
    void run(PassContext& ctx) override {
        const VolumePhotonMap& map = ctx.input<VolumePhotonMap>("photons");
        EmTree& tree = ctx.createOutput<EmTree>("tree");
        const std::int64_t start = jobs::wallNanos();
        tree.build(map.photons.column<PhotonPosition>(), map.photons.column<PhotonPower>(),
                   static_cast<std::uint32_t>(ctx.params().getInt("leaf_size")));
        ctx.addItems(static_cast<std::int64_t>(map.photons.size()));
        ctx.addCounter("photons", static_cast<std::int64_t>(map.photons.size()));
        ctx.addCounter("nodes", static_cast<std::int64_t>(tree.size()));
        ctx.addCounter("build_us", (jobs::wallNanos() - start) / 1000);
    }
};

}  // namespace

PassRegistration emStatsPass() {
    PassSpec spec;
    spec.name = "em_stats";
    spec.doc = "Balanced kd-tree over volume photons with per-node count, mean, centred scatter, power, box and "
               "split: the partitions of accelerated EM (Jakob et al. 2011 §5.1)";
    spec.inputs = {{"photons", "VolumePhotonMap", "the volume photons (photon pass, volume_photons = 128 k)"}};
    spec.outputs = {{"tree", "EmTree", "statistics kd-tree; any cut is a partition"}};
    spec.params = {
        {"leaf_size", ParamType::Int, std::int64_t{4}, 1, 64, {},
         "largest photon count of a leaf (the paper: a leaf below 5 photons)"},
    };
    return {spec, [] { return std::make_unique<EmStatsPass>(); }, refuseAnisotropicMedia};
}

}  // namespace fg
