// The one table of registered passes and the built-in pipelines.
#include "passes/passes.h"

namespace fg {

const std::vector<PassRegistration>& passRegistry() {
    static const std::vector<PassRegistration> registry = {
        pathTracerPass(),
    };
    return registry;
}

const std::vector<Pipeline>& builtinPipelines() {
    static const std::vector<Pipeline> pipelines = {
        {"pt", "reference path tracer: surfaces and homogeneous media, NEE + MIS", {{"pt", "pt", {}, {}, 0}}, {"image"}},
    };
    return pipelines;
}

}  // namespace fg
