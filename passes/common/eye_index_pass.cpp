// Eye index pass (`eye_index`): the eye path map of photon differential
// splatting (Frisvad et al. 2014 §3.3): a neighbour-search structure over the
// eye vertices' positions, queried once per photon for the vertices its
// footprint may cover.
#include "passes/passes.h"

#include "engine/buffers/photon_buffers.h"
#include "engine/accel/point_index.h"

namespace fg {

namespace {

class EyeIndexPass final : public Pass {
public:
    void run(PassContext& ctx) override {
        const EyeVertices& eye = ctx.input<EyeVertices>("eye_vertices");
        PointIndex& index = ctx.createOutput<PointIndex>("eye_index");
        index.build(eye.vertices.column<EyePosition>());
        ctx.addItems(static_cast<std::int64_t>(index.size()));
    }
};

}  // namespace

PassRegistration eyeIndexPass() {
    PassSpec spec;
    spec.name = "eye_index";
    spec.doc = "Neighbour-search structure over the eye vertices (the eye path map splatting queries)";
    spec.inputs = {{"eye_vertices", "EyeVertices", "the vertices to index"}};
    spec.outputs = {{"eye_index", "PointIndex", "search structure over the eye vertices; reports vertex indices"}};
    return {spec, [] { return std::make_unique<EyeIndexPass>(); }};
}

}  // namespace fg
