// The built-in registry: the one table of registered passes, and the built-in
// pipelines, parsed from passes/pipelines/*.toml (embedded in the binary at
// build time). The program installs it; the engine never looks it up itself.
#include "passes/passes.h"

#include "engine/core/job.h"

namespace fg {

const std::vector<std::pair<std::string, std::string>>& embeddedPipelineFiles();

const Registry& builtinRegistry() {
    static const Registry registry = [] {
        Registry r;
        r.passes = {
            pathTracerPass(), photonPass(),  eyePass(),          eyeIndexPass(),
            photonIndexPass(), gatherPass(), gatherGlobalPass(), splatPass(),
            volumeEyePass(),   photonRadiusPass(), photonBvhPass(), beamQueryPass(), lightTracePass(),
            emStatsPass(),     emFitPass(),  pemFitPass(),       gmmPyramidPass(),   gmmBbhPass(),   gmmRenderPass(),
            gmmSplatPass(),
            filmNoisePass(),   compositePass(),
            rayBandwidthPass(), splatIndexPass(), raySplatPass(), radianceIntegratePass(), radianceCachePass(),
            cacheSelectPass(),
            cacheUpdatePass(), importonPass(), environmentUpdatePass(),
            finalGatherSplatPass(), finalGatherPass(),
            bdptPass(),
        };
        for (const auto& [file, text] : embeddedPipelineFiles()) r.pipelines.push_back(parsePipelineFile(text, file));
        return r;
    }();
    return registry;
}

const std::vector<PassRegistration>& passRegistry() { return builtinRegistry().passes; }
const PassRegistration* findPass(const std::string& name) { return builtinRegistry().findPass(name); }
const std::vector<Pipeline>& builtinPipelines() { return builtinRegistry().pipelines; }
const Pipeline* findPipeline(const std::string& name) { return builtinRegistry().findPipeline(name); }

}  // namespace fg
