// The one table of registered passes and the built-in pipelines.
#include "passes/passes.h"

namespace fg {

const std::vector<PassRegistration>& passRegistry() {
    static const std::vector<PassRegistration> registry = {
        pathTracerPass(),
        photonPass(),
    };
    return registry;
}

const std::vector<Pipeline>& builtinPipelines() {
    static const std::vector<Pipeline> pipelines = {
        {"pt", "reference path tracer: surfaces and homogeneous media, NEE + MIS", {{"pt", "pt", {}, {}, 0}}, {"image"}},
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
