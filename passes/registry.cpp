// The one table of registered passes and the built-in pipelines.
#include "passes/passes.h"

namespace fg {

const std::vector<PassRegistration>& passRegistry() {
    static const std::vector<PassRegistration> registry = {
        pathTracerPass(), photonPass(),  eyePass(),          eyeIndexPass(),
        photonIndexPass(), gatherPass(), gatherGlobalPass(), splatPass(),
        volumeEyePass(),   photonRadiusPass(), photonBvhPass(), beamQueryPass(), lightTracePass(),
        compositePass(),   compositeSurfacePass(),
    };
    return registry;
}

// Standard photon mapping: eye vertices and photon maps are made independently,
// each map gets its own index, one gather writes each map's estimates as its
// own layer (`caustic`, `global`), and the composite adds them to the direct
// light.
Pipeline spmPipeline() {
    return {"spm",
            "standard photon mapping: eye vertices + caustic and global photon maps, k-nearest gathering",
            {
                {"eye", "eye", {}, {}, 0},
                {"photon", "photon", {}, {}, 0},
                {"caustic_index", "photon_index", {{"photons", "caustic_photons"}}, {{"index", "caustic_index"}}, 0},
                {"global_index", "photon_index", {{"photons", "global_photons"}}, {{"index", "global_index"}}, 0},
                {"gather", "gather", {}, {}, 0},
                {"composite", "composite_surface", {}, {}, 0},
            },
            {"image"}};
}

// Photon differential splatting: caustic photons are splatted onto the indexed
// eye vertices; the rest of the indirect light comes from gathering the global
// map; each writes its own layer and the composite adds both to the direct
// light. The caustic map is streamed: the
// splat runs inside the photon pass's task and takes each batch as it is
// traced (so the photon pass starts once the eye index is built), and no map
// of all caustic photons exists (Frisvad et al. 2014, §2).
Pipeline pdsPipeline() {
    return {"pds",
            "photon differential splatting for caustics + global photon map gathering for other indirect light",
            {
                {"eye", "eye", {}, {}, 0},
                {"photon", "photon", {}, {}, 0},
                {"eye_index", "eye_index", {}, {}, 0},
                {"global_index", "photon_index", {{"photons", "global_photons"}}, {{"index", "global_index"}}, 0},
                {"splat", "splat", {}, {}, 0},
                {"gather", "gather_global", {}, {}, 0},
                {"composite", "composite_surface", {{"caustic", "caustics"}}, {}, 0},
            },
            {"image"}};
}

// Volumetric photon mapping with the beam radiance estimate (Jarosz et al.
// 2008; the baseline of Jakob et al. 2011): camera segments through the media
// and the surface vertices behind them, in parallel with photon tracing; the
// surface part is standard photon mapping (direct light + caustic and global
// photon gathering), the media part the beam query over the volume photons'
// kernel spheres (pilot radii, then a BVH). Each writes its own layer and the
// composite sums them, so the beam query runs alongside the surface gather.
Pipeline brePipeline() {
    return {"bre",
            "volumetric photon mapping: beam radiance estimate over volume photons (pilot radii + sphere BVH) for "
            "media, standard photon mapping for surfaces",
            {
                {"volume_eye", "volume_eye", {}, {}, 0},
                {"photon", "photon", {}, {}, 0},
                {"caustic_index", "photon_index", {{"photons", "caustic_photons"}}, {{"index", "caustic_index"}}, 0},
                {"global_index", "photon_index", {{"photons", "global_photons"}}, {{"index", "global_index"}}, 0},
                {"gather", "gather", {}, {}, 0},
                {"photon_radius", "photon_radius", {{"photons", "volume_photons"}}, {{"radii", "photon_radii"}}, 0},
                {"photon_bvh", "photon_bvh", {{"photons", "volume_photons"}, {"radii", "photon_radii"}},
                 {{"bvh", "photon_bvh"}}, 0},
                {"beam_query", "beam_query", {{"photons", "volume_photons"}, {"bvh", "photon_bvh"}}, {}, 0},
                {"composite", "composite", {}, {}, 0},
            },
            {"image"}};
}

// Light tracing: the photons, streamed batch by batch, each connected to the
// camera. Which light the image holds is the photon pass's `store`: the
// unbiased reference for caustics under delta lights (store = "caustic").
Pipeline ltPipeline() {
    return {"lt",
            "light tracing: every photon connected to the camera; unbiased images of light seen directly on surfaces "
            "(e.g. caustics of collimated or point lights, which pt cannot reach)",
            {
                {"photon", "photon", {}, {}, 0},
                {"light_trace", "light_trace", {}, {}, 0},
            },
            {"image"}};
}

const std::vector<Pipeline>& builtinPipelines() {
    static const std::vector<Pipeline> pipelines = {
        {"pt", "reference path tracer: surfaces and homogeneous media, NEE + MIS", {{"pt", "pt", {}, {}, 0}}, {"image"}},
        spmPipeline(),
        pdsPipeline(),
        brePipeline(),
        ltPipeline(),
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
