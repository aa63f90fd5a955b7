// Registrations of the passes defined in passes/, collected by passes/registry.cpp.
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
PassRegistration lightTracePass();
PassRegistration compositePass();
PassRegistration compositeSurfacePass();

// The photon-mapping pipelines as data.
Pipeline spmPipeline();
Pipeline pdsPipeline();
Pipeline brePipeline();
Pipeline ltPipeline();

}  // namespace fg
