// Registrations of the passes defined in passes/, collected by passes/registry.cpp
// into the built-in registry that fluxgraph's main installs.
#pragma once

#include "engine/core/pass.h"

namespace fg {

PassRegistration pathTracerPass();
PassRegistration photonPass();
PassRegistration eyePass();
PassRegistration eyeIndexPass();
PassRegistration photonIndexPass();
PassRegistration gatherPass();
PassRegistration gatherGlobalPass();
PassRegistration splatPass();
PassRegistration volumeEyePass();
PassRegistration photonRadiusPass();
PassRegistration photonBvhPass();
PassRegistration beamQueryPass();
PassRegistration emStatsPass();
PassRegistration emFitPass();
PassRegistration pemFitPass();
PassRegistration gmmPyramidPass();
PassRegistration gmmBbhPass();
PassRegistration gmmRenderPass();
PassRegistration gmmSplatPass();
PassRegistration lightTracePass();
PassRegistration bdptPass();
PassRegistration filmNoisePass();
PassRegistration compositePass();
PassRegistration rayBandwidthPass();
PassRegistration splatIndexPass();
PassRegistration raySplatPass();
PassRegistration cacheUpdatePass();
PassRegistration importonPass();
PassRegistration environmentUpdatePass();
PassRegistration radianceIntegratePass();
PassRegistration radianceCachePass();
PassRegistration cacheSelectPass();
PassRegistration finalGatherSplatPass();
PassRegistration finalGatherPass();

// The passes and the pipelines of passes/pipelines/*.toml.
const Registry& builtinRegistry();
// Look-ups in the built-in registry.
const std::vector<PassRegistration>& passRegistry();
const PassRegistration* findPass(const std::string& name);
const std::vector<Pipeline>& builtinPipelines();
const Pipeline* findPipeline(const std::string& name);

}  // namespace fg
