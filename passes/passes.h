// Registrations of the passes defined in passes/, collected by passes/registry.cpp.
#pragma once

#include "engine/pass.h"

namespace fg {

PassRegistration pathTracerPass();
PassRegistration photonPass();

}  // namespace fg
