// The one table of registered passes and the built-in pipelines.
#include "passes/passes.h"

namespace fg {

const std::vector<PassRegistration>& passRegistry() {
    static const std::vector<PassRegistration> registry = {
        pathTracerPass(), photonPass(),  eyePass(),          eyeIndexPass(),
        photonIndexPass(), gatherPass(), gatherGlobalPass(), splatPass(),
    };
    return registry;
}

// Standard photon mapping: eye vertices and photon maps are made independently,
// each map gets its own index, and one gather adds both maps' estimates to the
// direct film.
Pipeline spmPipeline() {
    return {"spm",
            "standard photon mapping: eye vertices + caustic and global photon maps, k-nearest gathering",
            {
                {"eye", "eye", {}, {}, 0},
                {"photon", "photon", {}, {}, 0},
                {"caustic_index", "photon_index", {{"photons", "caustic_photons"}}, {{"index", "caustic_index"}}, 0},
                {"global_index", "photon_index", {{"photons", "global_photons"}}, {{"index", "global_index"}}, 0},
                {"gather", "gather", {}, {}, 0},
            },
            {"image"}};
}

// Photon differential splatting: caustic photons are splatted onto the indexed
// eye vertices; the rest of the indirect light comes from gathering the global
// map, added on top of the splatted film.
Pipeline pdsPipeline() {
    return {"pds",
            "photon differential splatting for caustics + global photon map gathering for other indirect light",
            {
                {"eye", "eye", {}, {}, 0},
                {"photon", "photon", {}, {}, 0},
                {"eye_index", "eye_index", {}, {}, 0},
                {"global_index", "photon_index", {{"photons", "global_photons"}}, {{"index", "global_index"}}, 0},
                {"splat", "splat", {}, {{"image", "direct_caustics"}}, 0},
                {"gather", "gather_global", {{"base", "direct_caustics"}}, {}, 0},
            },
            {"image"}};
}

const std::vector<Pipeline>& builtinPipelines() {
    static const std::vector<Pipeline> pipelines = {
        {"pt", "reference path tracer: surfaces and homogeneous media, NEE + MIS", {{"pt", "pt", {}, {}, 0}}, {"image"}},
        spmPipeline(),
        pdsPipeline(),
    };
    return pipelines;
}

const PassRegistration* findPass(const std::string& name) {
    for (const auto& r : passRegistry())
        if (r.spec.name == name) return &r;
    return nullptr;
}

const Pipeline* findPipeline(const std::string& name) {
    for (const auto& p : builtinPipelines())
        if (p.name == name) return &p;
    return nullptr;
}

}  // namespace fg
