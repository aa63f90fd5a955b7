// Pass parameters and the context a running pass sees. The registry look-ups
// live in passes/registry.cpp, next to the table, so that the scheduler links
// without pulling in every registered pass.
#include "engine/core/pass.h"

#include "engine/core/interrupt.h"
#include "engine/scene/scene.h"
#include "jobs/random.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <sstream>
#include <stdexcept>

namespace fg {

std::string toString(ParamType type) {
    switch (type) {
    case ParamType::Int: return "int";
    case ParamType::Float: return "float";
    case ParamType::Bool: return "bool";
    case ParamType::String: return "string";
    }
    return "?";
}

std::string toString(const ParamValue& value) {
    std::ostringstream out;
    std::visit(
        [&](const auto& v) {
            using T = std::decay_t<decltype(v)>;
            if constexpr (std::is_same_v<T, bool>) out << (v ? "true" : "false");
            else if constexpr (std::is_same_v<T, std::string>) out << '"' << v << '"';
            else out << v;
        },
        value);
    return out.str();
}

namespace {
void writeBound(std::ostream& out, double bound) {
    if (std::abs(bound) < 1e15 && std::floor(bound) == bound) out << static_cast<std::int64_t>(bound);
    else out << bound;
}
}  // namespace

std::string describeRange(const ParamSpec& spec) {
    std::ostringstream out;
    out << '[';
    writeBound(out, spec.minValue);
    out << ", ";
    writeBound(out, spec.maxValue);
    out << ']';
    return out.str();
}

const ParamValue& PassParams::at(const std::string& name) const {
    const auto it = values_.find(name);
    if (it == values_.end()) throw std::logic_error("pass asked for undeclared parameter '" + name + "'");
    return it->second;
}
std::int64_t PassParams::getInt(const std::string& name) const { return std::get<std::int64_t>(at(name)); }
double PassParams::getFloat(const std::string& name) const { return std::get<double>(at(name)); }
bool PassParams::getBool(const std::string& name) const { return std::get<bool>(at(name)); }
const std::string& PassParams::getString(const std::string& name) const { return std::get<std::string>(at(name)); }

PassContext::PassContext(const Scene& scene, const RayQuery& rays, const FilmSettings& film, std::uint64_t seed,
                         const PassParams& params, std::map<std::string, BufferHandle*> inputs,
                         std::map<std::string, BufferHandle*> outputs, std::string instanceName)
    : PassContext(scene, &rays, film, seed, params, std::move(inputs), std::move(outputs), std::move(instanceName)) {}

PassContext::PassContext(const Scene& scene, const RayQuery* rays, const FilmSettings& film, std::uint64_t seed,
                         const PassParams& params, std::map<std::string, BufferHandle*> inputs,
                         std::map<std::string, BufferHandle*> outputs, std::string instanceName)
    : scene_(scene), rays_(rays), film_(film), seed_(seed), params_(params), inputs_(std::move(inputs)),
      outputs_(std::move(outputs)), instance_(std::move(instanceName)) {}

const RayQuery& PassContext::rays() const {
    if (!rays_) throw std::logic_error("pass '" + instance_ + "' traces rays, but the run has no ray queries");
    return *rays_;
}

Camera PassContext::filmCamera() const {
    Camera camera = scene_.camera;
    camera.width = film_.width;
    camera.height = film_.height;
    return camera;
}

void PassContext::reportProgress(double fraction) const {
    if (progress_) progress_(instance_, fraction);
}

bool PassContext::streamed(const std::string& outputSlot) const {
    return std::find(streamedOutputs_.begin(), streamedOutputs_.end(), outputSlot) != streamedOutputs_.end();
}

bool PassContext::emitErased(const std::string& slot, std::shared_ptr<void> batch, std::size_t bytes) {
    if (!batchSink_) throw std::logic_error("pass '" + instance_ + "' emitted a batch, but nothing reads its batches");
    return batchSink_(slot, std::move(batch), bytes);
}

bool PassContext::stopRequested() const { return stoppable_ && fg::stopRequested(); }

void PassContext::completedUnit() const { noteCompletedUnit(); }

std::uint64_t PassContext::streamKey() const { return jobs::streamKey(instance_); }

void PassContext::signal(const std::string& name) {
    if (std::find(declaredSignals_.begin(), declaredSignals_.end(), name) == declaredSignals_.end())
        throw std::logic_error("pass '" + instance_ + "' raised undeclared signal '" + name + "'");
    if (!signalled(name)) signals_.push_back(name);
}

const PassRegistration* Registry::findPass(const std::string& name) const {
    for (const auto& r : passes)
        if (r.spec.name == name) return &r;
    return nullptr;
}

const Pipeline* Registry::findPipeline(const std::string& name) const {
    for (const auto& p : pipelines)
        if (p.name == name) return &p;
    return nullptr;
}

namespace {
std::atomic<const Registry*> gInstalledRegistry{nullptr};
}

void installRegistry(const Registry* registry) { gInstalledRegistry.store(registry); }

const Registry& installedRegistry() {
    const Registry* registry = gInstalledRegistry.load();
    if (!registry) throw std::logic_error("no pass registry installed (fg::installRegistry)");
    return *registry;
}

BufferHandle* PassContext::checked(const std::map<std::string, BufferHandle*>& slots, const std::string& slot,
                                   const char* type, const char* kind) {
    const auto it = slots.find(slot);
    if (it == slots.end()) throw std::logic_error(std::string("pass used undeclared ") + kind + " '" + slot + "'");
    if (!it->second) throw std::logic_error(std::string("optional ") + kind + " '" + slot + "' is not bound in this run");
    if (it->second->type != type) {
        throw std::logic_error(std::string(kind) + " '" + slot + "' is " + it->second->type + ", not " + type);
    }
    return it->second;
}

}  // namespace fg
