// Splat index (`splat_index`): the kd-tree over eye vertices of photon ray
// splatting, Herzog et al. 2007, §7.1 (sliding-midpoint splits, leaves below
// 16 vertices or 0.1 % of the scene diagonal, backface-culling nodes with a
// reference normal and C_max = sin δ). The tree itself: engine/accel/splat_kdtree.h.
#include "passes/passes.h"

#include "engine/buffers/photon_buffers.h"
#include "engine/buffers/photon_ray_buffers.h"
#include "engine/scene/scene.h"

namespace fg {

namespace {

class SplatIndexPass final : public Pass {
public:
    void run(PassContext& ctx) override {
        const EyeVertices& eye = ctx.input<EyeVertices>("eye_vertices");
        const Scene& scene = ctx.scene();
        SplatKdTreeOptions options;
        options.maxLeafSize = static_cast<std::uint32_t>(ctx.params().getInt("leaf_size"));
        options.minCellDiagonal = static_cast<float>(ctx.params().getFloat("min_leaf_extent")) *
                                  glm::length(scene.boundsMax - scene.boundsMin);
        options.maxCullDeviationDegrees = static_cast<float>(ctx.params().getFloat("cull_max_deviation"));
        SplatIndex& index = ctx.createOutput<SplatIndex>("splat_index");
        index.tree.build(eye.vertices.column<EyePosition>(), eye.vertices.column<EyeNormal>(), options);
        ctx.addItems(static_cast<std::int64_t>(index.tree.size()));
        ctx.addCounter("nodes", static_cast<std::int64_t>(index.tree.nodes().size()));
    }
};

}  // namespace

PassRegistration splatIndexPass() {
    PassSpec spec;
    spec.name = "splat_index";
    spec.doc = "Splat kd-tree over the eye vertices with backface-culling nodes (Herzog et al. 2007, §7.1)";
    spec.inputs = {{"eye_vertices", "EyeVertices", "the vertices photon rays splat to"}};
    spec.outputs = {{"splat_index", "SplatIndex", "kd-tree over the eye vertices' positions and shading normals"}};
    spec.params = {
        {"leaf_size", ParamType::Int, std::int64_t{16}, 1, 1 << 20, {}, "nodes with fewer vertices become leaves"},
        {"min_leaf_extent", ParamType::Float, 0.001, 0.0, 1.0, {},
         "cells whose diagonal is below this fraction of the scene diagonal become leaves"},
        {"cull_max_deviation", ParamType::Float, 45.0, 0.0, 90.0, {},
         "degrees: a backface-culling node tops each largest subtree whose normals deviate at most this much "
         "from their mean (0 = none)"},
    };
    return {spec, [] { return std::make_unique<SplatIndexPass>(); }};
}

}  // namespace fg
