// Pass scheduler. Validation happens entirely in ExecutionPlan::build so that a
// job with a mistake fails in milliseconds with one line, before any scene is
// loaded or pixel traced. Execution maps the plan onto a jobs::TaskGraph.
#include "engine/core/scheduler.h"

#include "engine/core/error.h"
#include "engine/core/interrupt.h"
#include "jobs/parallel.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <limits>
#include <memory>
#include <mutex>
#include <set>
#include <sstream>

namespace fg {

namespace {

// Serial (non-chunk) CPU time of pass bodies that finished on this thread.
thread_local std::int64_t tPassSerialCpu = 0;

std::string slotBuffer(const std::map<std::string, std::string>& bindings, const std::string& slot) {
    const auto it = bindings.find(slot);
    return it == bindings.end() ? slot : it->second;
}

// Splits "file:line" back for InputError; messages keep the source text as given.
[[noreturn]] void fail(const std::string& source, const std::string& message) {
    throw InputError(source + ": " + message);
}

ParamValue convertSetting(const ParamSpec& spec, const ParamSetting& setting, const std::string& instance) {
    const std::string where = "parameter '" + instance + "." + spec.name + "'";
    const ParamValue& v = setting.value;
    switch (spec.type) {
    case ParamType::Int: {
        // The range is checked on the number as written, before any conversion:
        // casting a double beyond the int64 range is undefined.
        double number = 0.0;
        if (const auto* i = std::get_if<std::int64_t>(&v)) {
            number = static_cast<double>(*i);
        } else if (const auto* d = std::get_if<double>(&v); d && std::isfinite(*d) && std::floor(*d) == *d) {
            number = *d;
        } else {
            fail(setting.source, where + " must be an integer, got " + toString(v));
        }
        constexpr double kInt64Limit = 9.2e18;
        if (number < spec.minValue || number > spec.maxValue || std::abs(number) > kInt64Limit)
            fail(setting.source, where + " = " + toString(v) + " is outside its valid range " + describeRange(spec));
        if (const auto* i = std::get_if<std::int64_t>(&v)) return *i;
        return static_cast<std::int64_t>(number);
    }
    case ParamType::Float: {
        double value = 0.0;
        if (const auto* i = std::get_if<std::int64_t>(&v)) {
            value = static_cast<double>(*i);
        } else if (const auto* d = std::get_if<double>(&v)) {
            value = *d;
        } else {
            fail(setting.source, where + " must be a number, got " + toString(v));
        }
        if (!std::isfinite(value) || value < spec.minValue || value > spec.maxValue)
            fail(setting.source, where + " = " + toString(v) + " is outside its valid range " + describeRange(spec));
        return value;
    }
    case ParamType::Bool:
        if (const auto* b = std::get_if<bool>(&v)) return *b;
        fail(setting.source, where + " must be true or false, got " + toString(v));
    case ParamType::String: {
        const auto* s = std::get_if<std::string>(&v);
        if (!s) fail(setting.source, where + " must be a string, got " + toString(v));
        if (!spec.choices.empty() && std::find(spec.choices.begin(), spec.choices.end(), *s) == spec.choices.end()) {
            std::string allowed;
            for (const auto& c : spec.choices) allowed += (allowed.empty() ? "" : ", ") + c;
            fail(setting.source, where + " = \"" + *s + "\" is not one of: " + allowed);
        }
        return *s;
    }
    }
    return v;
}

}  // namespace

namespace {

// All slots of a pass that read a buffer: inputs, then in-out slots.
std::vector<const SlotSpec*> readSlots(const PassSpec& spec) {
    std::vector<const SlotSpec*> slots;
    for (const SlotSpec& s : spec.inputs) slots.push_back(&s);
    for (const SlotSpec& s : spec.inouts) slots.push_back(&s);
    return slots;
}
// All slots that make a buffer version: outputs, then in-out slots.
std::vector<const SlotSpec*> writeSlots(const PassSpec& spec) {
    std::vector<const SlotSpec*> slots;
    for (const SlotSpec& s : spec.outputs) slots.push_back(&s);
    for (const SlotSpec& s : spec.inouts) slots.push_back(&s);
    return slots;
}
bool isInout(const PassSpec& spec, const std::string& slot) {
    return std::any_of(spec.inouts.begin(), spec.inouts.end(), [&](const SlotSpec& s) { return s.name == slot; });
}

// Turns the pipeline's declaration into a flat list of pass instances whose
// bindings name buffer versions (see scheduler.h). Block iterations are
// instances of their own: "block[i].name".
class Unroller {
public:
    Unroller(const Pipeline& pipeline, const std::vector<PassRegistration>& registry, const std::string& origin,
             const BufferFiles& files)
        : pipeline_(pipeline), registry_(registry), origin_(origin), files_(files) {}

    std::vector<PlannedPass> passes;
    std::vector<PlannedBlock> blocks;
    std::map<std::string, std::string> current;                    // name -> current version
    std::map<std::string, std::pair<std::string, std::string>> imports;  // version -> (type, path)
    std::map<std::string, std::vector<int>> readersOf;             // version -> passes reading it
    std::map<std::string, std::vector<int>> extraDependencies;     // instance -> passes it must follow

    void run() {
        // Imports come first: every later read of the name resolves to the file.
        for (const auto& [name, path] : files_.imports) {
            current[name] = name;
            imports[name] = {"", path};
        }
        std::set<std::string> templateNames;
        const auto claimName = [&](const PipelineNode& node) {
            if (!templateNames.insert(node.instance).second)
                fail(sourceOf(node), "pass instance '" + node.instance + "' appears twice in pipeline '" + pipeline_.name + "'");
        };
        for (const PipelineNode& node : pipeline_.nodes) claimName(node);
        for (const RepeatBlock& block : pipeline_.blocks)
            for (const PipelineNode& node : block.nodes) claimName(node);

        for (std::size_t i = 0; i <= pipeline_.nodes.size(); ++i) {
            for (std::size_t b = 0; b < pipeline_.blocks.size(); ++b)
                if (pipeline_.blocks[b].position == i) unrollBlock(pipeline_.blocks[b], static_cast<int>(b));
            if (i < pipeline_.nodes.size()) addInstance(pipeline_.nodes[i], pipeline_.nodes[i].instance, -1, -1, "");
        }
    }

    std::string sourceOf(const PipelineNode& node) const {
        return node.sourceLine > 0 ? origin_ + ":" + std::to_string(node.sourceLine) : origin_;
    }

private:
    const PassRegistration* registrationOf(const PipelineNode& node) const {
        const auto it = std::find_if(registry_.begin(), registry_.end(),
                                     [&](const PassRegistration& r) { return r.spec.name == node.pass; });
        if (it != registry_.end()) return &*it;
        std::string known;
        for (const auto& r : registry_) known += (known.empty() ? "" : ", ") + r.spec.name;
        fail(sourceOf(node), "unknown pass '" + node.pass + "' (registered passes: " + known + ")");
    }

    // A fresh version name for a write of `name` with the given prefix.
    std::string newVersion(const std::string& name, const std::string& prefix) {
        std::string version = prefix + name;
        for (int k = 2; taken_.count(version); ++k) version = prefix + name + "@" + std::to_string(k);
        taken_.insert(version);
        return version;
    }

    void addInstance(const PipelineNode& node, const std::string& instance, int block, int iteration,
                     const std::string& prefix, const std::set<std::string>* producedLater = nullptr,
                     const std::map<std::string, std::string>* skipFrom = nullptr) {
        PlannedPass planned;
        planned.registration = registrationOf(node);
        const PassSpec& spec = planned.registration->spec;
        planned.node = node;
        planned.node.instance = instance;
        planned.node.inputBindings.clear();
        planned.node.outputBindings.clear();
        planned.paramsKey = node.instance;
        planned.source = sourceOf(node);
        planned.block = block;
        planned.iteration = iteration;
        const int index = static_cast<int>(passes.size());
        for (const auto& [slot, buffer] : node.inputBindings) {
            (void)buffer;
            // Named init-captures: clang before 16 cannot capture structured bindings.
            const bool known = std::any_of(spec.inputs.begin(), spec.inputs.end(), [&name = slot](const SlotSpec& s) { return s.name == name; }) ||
                               isInout(spec, slot);
            if (!known) fail(planned.source, "pass '" + node.instance + "' has no input slot '" + slot + "'");
        }
        for (const auto& [slot, buffer] : node.outputBindings) {
            (void)buffer;
            if (std::none_of(spec.outputs.begin(), spec.outputs.end(),
                             [&name = slot](const SlotSpec& s) { return s.name == name; }))
                fail(planned.source, "pass '" + node.instance + "' has no output slot '" + slot + "'");
        }
        for (const SlotSpec* in : readSlots(spec)) {
            const std::string name = slotBuffer(node.inputBindings, in->name);
            const auto it = current.find(name);
            std::string version;
            if (it != current.end()) {
                version = it->second;
            } else if (producedLater && producedLater->count(name)) {
                const RepeatBlock& repeat = pipeline_.blocks[static_cast<std::size_t>(block)];
                if (!in->optional && repeat.carry.count(name)) {
                    fail(planned.source, "pass '" + node.instance + "' in repeat block '" + repeat.name + "' reads '" + name +
                                             "', which iteration 0 has nothing to carry in for: make or import it before "
                                             "the block, or read it through an optional input");
                }
                if (!in->optional)
                    fail(planned.source, "pass '" + node.instance + "' in repeat block '" + repeat.name + "' reads '" + name +
                                             "' before the block produces it; declare carry = { " + name + " = \"" + name +
                                             "\" } to read the previous iteration's");
            } else {
                version = name;  // produced later at top level (order-free), or by no one: checked below
            }
            if (!version.empty()) readersOf[version].push_back(index);
            planned.node.inputBindings[in->name] = version;
        }
        for (const SlotSpec* out : writeSlots(spec)) {
            const bool inout = isInout(spec, out->name);
            const std::string name = inout ? slotBuffer(node.inputBindings, out->name) : slotBuffer(node.outputBindings, out->name);
            std::string version;
            if (inout) {
                const std::string old = planned.node.inputBindings[out->name];
                if (old.empty()) fail(planned.source, "in-out slot '" + out->name + "' of pass '" + node.instance + "' has no buffer '" + name + "' to update");
                // In place: every reader of the old version declared so far runs first.
                for (int reader : readersOf[old])
                    if (reader != index) extraDependencies[instance].push_back(reader);
                version = newVersion(name, prefix);
            } else if (prefix.empty() && files_.imports.count(name)) {
                // The file stands in for this producer's output: its own goes nowhere,
                // and the pass is culled unless another output is needed.
                version = newVersion(name + "~replaced-by-import", prefix);
                imports[name].first = out->type;
            } else if (prefix.empty()) {
                version = name;  // a second plain producer is reported by the single-producer check
                taken_.insert(version);
            } else {
                version = newVersion(name, prefix);
            }
            planned.node.outputBindings[out->name] = version;
            if (inout || !prefix.empty() || !files_.imports.count(name)) current[name] = version;
            if (skipFrom) {
                const auto previous = skipFrom->find(name);
                if (previous != skipFrom->end()) planned.skipAliases[out->name] = previous->second;
            }
        }
        passes.push_back(std::move(planned));
    }

    void unrollBlock(const RepeatBlock& block, int blockIndex) {
        const std::string where = block.sourceLine > 0 ? origin_ + ":" + std::to_string(block.sourceLine) : origin_;
        if (block.nodes.empty()) fail(where, "repeat block '" + block.name + "' has no passes");
        std::set<std::string> produced;
        for (const PipelineNode& node : block.nodes) {
            const PassSpec& spec = registrationOf(node)->spec;
            for (const SlotSpec& out : spec.outputs) produced.insert(slotBuffer(node.outputBindings, out.name));
            for (const SlotSpec& io : spec.inouts) produced.insert(slotBuffer(node.inputBindings, io.name));
        }
        for (const auto& [readName, producedName] : block.carry) {
            if (!produced.count(producedName))
                fail(where, "repeat block '" + block.name + "' carries '" + producedName + "', which none of its passes produces");
        }
        PlannedBlock planned;
        planned.name = block.name;
        planned.count = block.count;
        planned.seconds = block.seconds;
        if (!block.until.empty()) {
            const auto dot = block.until.find('.');
            if (dot == std::string::npos)
                fail(where, "repeat block '" + block.name + "': until = \"" + block.until + "\" must be \"instance.signal\"");
            planned.untilInstance = block.until.substr(0, dot);
            planned.untilSignal = block.until.substr(dot + 1);
            const auto node = std::find_if(block.nodes.begin(), block.nodes.end(),
                                           [&](const PipelineNode& n) { return n.instance == planned.untilInstance; });
            if (node == block.nodes.end())
                fail(where, "repeat block '" + block.name + "': until names '" + planned.untilInstance + "', which is not a pass of the block");
            const auto& signals = registrationOf(*node)->spec.signals;
            if (std::find(signals.begin(), signals.end(), planned.untilSignal) == signals.end()) {
                std::string known;
                for (const auto& s : signals) known += (known.empty() ? "" : ", ") + s;
                fail(where, "repeat block '" + block.name + "': until names signal '" + planned.untilSignal + "', which pass '" + node->pass + "' does not raise" +
                                " (it raises: " + (known.empty() ? "none" : known) + ")");
            }
        }
        std::map<std::string, std::string> endOfPrevious;  // produced name -> version after the previous iteration
        for (int i = 0; i < block.count; ++i) {
            const std::string prefix = block.name + "[" + std::to_string(i) + "].";
            if (i > 0) {
                for (const auto& [readName, producedName] : block.carry) current[readName] = endOfPrevious.at(producedName);
            }
            // Names the block produces are not visible inside an iteration until made
            // in it (or carried): a read before that is an error, or absent if optional.
            std::map<std::string, std::string> hidden;
            for (const std::string& name : produced) {
                if (block.carry.count(name) && i > 0) continue;
                const auto it = current.find(name);
                if (it != current.end() && !block.carry.count(name)) {
                    hidden[name] = it->second;
                    current.erase(it);
                }
            }
            std::vector<int> members;
            for (const PipelineNode& node : block.nodes) {
                members.push_back(static_cast<int>(passes.size()));
                addInstance(node, prefix + node.instance, blockIndex, i, prefix, &produced, i > 0 ? &endOfPrevious : nullptr);
            }
            for (const auto& [name, version] : hidden)
                if (!current.count(name)) current[name] = version;
            for (const std::string& name : produced) endOfPrevious[name] = current.at(name);
            planned.iterationPasses.push_back(std::move(members));
        }
        blocks.push_back(std::move(planned));
    }

    const Pipeline& pipeline_;
    const std::vector<PassRegistration>& registry_;
    std::string origin_;
    const BufferFiles& files_;
    std::set<std::string> taken_;
};

}  // namespace

ExecutionPlan ExecutionPlan::build(const Pipeline& pipeline, const JobParams& params, const std::string& origin) {
    return build(pipeline, params, origin, installedRegistry().passes);
}

ExecutionPlan ExecutionPlan::build(const Pipeline& pipeline, const JobParams& params, const std::string& origin,
                                   const std::vector<PassRegistration>& registry, const BufferFiles& files) {
    ExecutionPlan plan;
    plan.pipeline_ = pipeline;

    Unroller unroller(pipeline, registry, origin, files);
    unroller.run();
    plan.passes_ = std::move(unroller.passes);
    plan.blocks_ = std::move(unroller.blocks);

    // Parameters are known and valid; [passes.X] tables name a pass. A block's
    // parameters apply to every iteration, so each is checked once.
    std::set<std::string> paramsKeys;
    std::map<std::string, PassParams> checkedParams;
    for (PlannedPass& planned : plan.passes_) {
        paramsKeys.insert(planned.paramsKey);
        if (const auto done = checkedParams.find(planned.paramsKey); done != checkedParams.end()) {
            planned.params = done->second;
            continue;
        }
        const PassSpec& spec = planned.registration->spec;
        for (const ParamSpec& p : spec.params) planned.params.set(p.name, p.defaultValue);
        if (const auto it = params.values.find(planned.paramsKey); it != params.values.end()) {
            for (const auto& [key, setting] : it->second) {
                const auto found = std::find_if(spec.params.begin(), spec.params.end(),
                                                [&name = key](const ParamSpec& p) { return p.name == name; });
                if (found == spec.params.end()) {
                    std::string known;
                    for (const auto& p : spec.params) known += (known.empty() ? "" : ", ") + p.name;
                    fail(setting.source, "unknown parameter '" + key + "' for pass '" + planned.paramsKey +
                                             "' (" + spec.name + " takes: " + known + ")");
                }
                planned.params.set(key, convertSetting(*found, setting, planned.paramsKey));
            }
        }
        checkedParams[planned.paramsKey] = planned.params;
    }
    for (const auto& [instance, table] : params.values) {
        if (!paramsKeys.count(instance)) {
            const auto src = params.tableSource.find(instance);
            fail(src != params.tableSource.end() ? src->second : origin,
                 "[passes." + instance + "] names no pass of pipeline '" + pipeline.name + "'");
        }
    }

    // Every version has exactly one producer; every bound input has a producer of the same type.
    std::map<std::string, std::string> bufferType;
    for (std::size_t i = 0; i < plan.passes_.size(); ++i) {
        const PlannedPass& p = plan.passes_[i];
        for (const SlotSpec* out : writeSlots(p.registration->spec)) {
            const std::string buffer = p.node.outputBindings.at(out->name);
            if (plan.producer_.count(buffer)) {
                fail(p.source, "buffer '" + buffer + "' is produced by both '" +
                                   plan.passes_[static_cast<std::size_t>(plan.producer_[buffer])].node.instance + "' and '" +
                                   p.node.instance + "'");
            }
            plan.producer_[buffer] = static_cast<int>(i);
            bufferType[buffer] = out->type;
        }
    }
    for (PlannedPass& p : plan.passes_) {
        for (const SlotSpec* in : readSlots(p.registration->spec)) {
            std::string& buffer = p.node.inputBindings[in->name];
            if (buffer.empty()) continue;  // an optional input left absent
            if (const auto imported = unroller.imports.find(buffer); imported != unroller.imports.end()) {
                auto& [type, path] = imported->second;
                if (!type.empty() && type != in->type) {
                    fail(files.sources.count(buffer) ? files.sources.at(buffer) : origin,
                         "imported buffer '" + buffer + "' is read as " + in->type + " by '" + p.node.instance +
                             "' but is a " + type + " elsewhere in the pipeline");
                }
                type = in->type;
                continue;
            }
            const auto it = plan.producer_.find(buffer);
            if (it == plan.producer_.end()) {
                if (in->optional) {
                    buffer.clear();
                    continue;
                }
                fail(p.source, "input '" + in->name + "' (" + in->type + ") of pass '" + p.node.instance +
                                   "' reads buffer '" + buffer + "', which no pass produces");
            }
            if (bufferType[buffer] != in->type) {
                fail(p.source, "input '" + in->name + "' of pass '" + p.node.instance + "' expects " + in->type +
                                   " but buffer '" + buffer + "' is " + bufferType[buffer] + " (from '" +
                                   plan.passes_[static_cast<std::size_t>(it->second)].node.instance + "')");
            }
            if (std::find(p.dependencies.begin(), p.dependencies.end(), it->second) == p.dependencies.end())
                p.dependencies.push_back(it->second);
        }
        for (int d : unroller.extraDependencies[p.node.instance])
            if (std::find(p.dependencies.begin(), p.dependencies.end(), d) == p.dependencies.end()) p.dependencies.push_back(d);
    }
    // A block that may end early decides after each iteration: the next one waits for all of it.
    for (const PlannedBlock& block : plan.blocks_) {
        if (!block.canExitEarly()) continue;
        for (std::size_t it = 1; it < block.iterationPasses.size(); ++it)
            for (int later : block.iterationPasses[it])
                for (int earlier : block.iterationPasses[it - 1]) {
                    auto& deps = plan.passes_[static_cast<std::size_t>(later)].dependencies;
                    if (std::find(deps.begin(), deps.end(), earlier) == deps.end()) deps.push_back(earlier);
                }
    }
    for (const auto& [name, version] : unroller.current) plan.finalVersion_[name] = version;
    for (const auto& [version, typeAndPath] : unroller.imports) {
        if (typeAndPath.first.empty())
            fail(files.sources.count(version) ? files.sources.at(version) : origin,
                 "imported buffer '" + version + "' is neither made nor read by any pass of pipeline '" + pipeline.name + "'");
        plan.imports_[version] = typeAndPath;
    }
    const auto producedOrImported = [&](const std::string& version) {
        return plan.producer_.count(version) || plan.imports_.count(version);
    };
    for (const std::string& result : pipeline.results) {
        if (!producedOrImported(plan.finalVersion(result)))
            fail(origin, "pipeline '" + pipeline.name + "' promises result '" + result + "' but no pass produces it");
    }
    for (const auto& [name, path] : files.saves) {
        const std::string version = plan.finalVersion(name);
        if (!plan.producer_.count(version))
            fail(files.sources.count(name) ? files.sources.at(name) : origin,
                 "cannot save '" + name + "': no pass of pipeline '" + pipeline.name + "' produces it");
        plan.saves_[version] = path;
    }

    // Topological order (Kahn); whatever remains sits on a cycle.
    const std::size_t n = plan.passes_.size();
    std::vector<int> indegree(n, 0);
    for (std::size_t i = 0; i < n; ++i) indegree[i] = static_cast<int>(plan.passes_[i].dependencies.size());
    std::vector<int> ready;
    for (std::size_t i = 0; i < n; ++i)
        if (indegree[i] == 0) ready.push_back(static_cast<int>(i));
    while (!ready.empty()) {
        const int current = ready.front();
        ready.erase(ready.begin());
        plan.order_.push_back(current);
        for (std::size_t j = 0; j < n; ++j) {
            const auto& deps = plan.passes_[j].dependencies;
            if (std::find(deps.begin(), deps.end(), current) != deps.end() && --indegree[j] == 0)
                ready.push_back(static_cast<int>(j));
        }
    }
    if (plan.order_.size() != n) {
        // What Kahn leaves over is the cycles plus everything downstream of them;
        // peel off passes that feed no other leftover pass to name only the cycles.
        std::vector<bool> onCycle(n);
        for (std::size_t i = 0; i < n; ++i) onCycle[i] = indegree[i] > 0;
        for (bool peeled = true; peeled;) {
            peeled = false;
            for (std::size_t i = 0; i < n; ++i) {
                if (!onCycle[i]) continue;
                bool feedsLeftover = false;
                for (std::size_t j = 0; j < n && !feedsLeftover; ++j) {
                    const auto& deps = plan.passes_[j].dependencies;
                    feedsLeftover =
                        onCycle[j] && std::find(deps.begin(), deps.end(), static_cast<int>(i)) != deps.end();
                }
                if (!feedsLeftover) {
                    onCycle[i] = false;
                    peeled = true;
                }
            }
        }
        std::string cycle;
        for (std::size_t i = 0; i < n; ++i)
            if (onCycle[i]) cycle += (cycle.empty() ? "" : ", ") + plan.passes_[i].node.instance;
        fail(origin, "pipeline '" + pipeline.name + "' has a dependency cycle through passes: " + cycle);
    }

    // Cull passes that do not contribute to any result.
    std::vector<int> roots;
    for (const std::string& result : pipeline.results)
        if (const auto it = plan.producer_.find(plan.finalVersion(result)); it != plan.producer_.end()) roots.push_back(it->second);
    for (const auto& [version, path] : plan.saves_) roots.push_back(plan.producer_.at(version));
    // A block's stopping condition is computed in every iteration, whether or
    // not its outputs are read later.
    for (const PlannedBlock& block : plan.blocks_)
        for (const auto& members : block.iterationPasses)
            for (int member : members)
                if (plan.passes_[static_cast<std::size_t>(member)].paramsKey == block.untilInstance) roots.push_back(member);
    plan.cullAllBut(roots);
    if (pipeline.streamBatches) plan.chooseStreams();
    return plan;
}

void ExecutionPlan::cullAllBut(std::vector<int> roots) {
    std::vector<bool> needed(passes_.size(), false);
    while (!roots.empty()) {
        const int i = roots.back();
        roots.pop_back();
        if (needed[static_cast<std::size_t>(i)]) continue;
        needed[static_cast<std::size_t>(i)] = true;
        const PlannedPass& p = passes_[static_cast<std::size_t>(i)];
        for (int d : p.dependencies) roots.push_back(d);
        // Were its iteration skipped, its outputs would take the previous iteration's.
        if (p.block >= 0 && blocks_[static_cast<std::size_t>(p.block)].canExitEarly())
            for (const auto& [slot, source] : p.skipAliases) roots.push_back(producer_.at(source));
    }
    for (std::size_t i = 0; i < passes_.size(); ++i) passes_[i].culled = !needed[i];
}

ExecutionPlan ExecutionPlan::producing(const std::vector<std::string>& versions) const {
    ExecutionPlan plan = *this;
    plan.pipeline_.results.clear();
    plan.saves_.clear();
    std::vector<int> roots;
    for (const std::string& version : versions) {
        if (imports_.count(version)) continue;
        const auto it = producer_.find(version);
        if (it == producer_.end())
            throw InputError(pipeline_.file.empty() ? pipeline_.name : pipeline_.file,
                             0, "no pass of pipeline '" + pipeline_.name + "' makes buffer '" + version + "'");
        plan.saves_[version] = "";
        roots.push_back(it->second);
    }
    // Stopping conditions decide whether the iterations before the last needed
    // pass run at all, so they stay; those of later iterations do not matter.
    const int lastNeeded = roots.empty() ? -1 : *std::max_element(roots.begin(), roots.end());
    for (const PlannedBlock& block : blocks_)
        for (const auto& members : block.iterationPasses)
            for (int member : members)
                if (member < lastNeeded && passes_[static_cast<std::size_t>(member)].paramsKey == block.untilInstance)
                    roots.push_back(member);
    plan.cullAllBut(roots);
    for (PlannedPass& p : plan.passes_) {
        p.streamHost = -1;
        p.streamedOutputs.clear();
    }
    if (plan.pipeline_.streamBatches) plan.chooseStreams();
    return plan;
}

std::string ExecutionPlan::finalVersion(const std::string& name) const {
    const auto it = finalVersion_.find(name);
    return it == finalVersion_.end() ? name : it->second;
}

bool ExecutionPlan::streamed(const std::string& buffer) const {
    const auto it = producer_.find(buffer);
    if (it == producer_.end()) return false;
    const PlannedPass& p = passes_[static_cast<std::size_t>(it->second)];
    for (const std::string& slot : p.streamedOutputs)
        if (slotBuffer(p.node.outputBindings, slot) == buffer) return true;
    return false;
}

// Tasks after fusing stream readers into their producers' tasks must still
// form a DAG: a reader whose other inputs come from downstream of the
// producer cannot run inside it.
bool ExecutionPlan::fusedTasksAcyclic() const {
    const std::size_t n = passes_.size();
    const auto task = [&](std::size_t i) {
        return passes_[i].streamHost >= 0 ? static_cast<std::size_t>(passes_[i].streamHost) : i;
    };
    std::vector<std::set<std::size_t>> successors(n);
    std::vector<int> indegree(n, 0);
    for (std::size_t i = 0; i < n; ++i) {
        if (passes_[i].culled) continue;
        for (int d : passes_[i].dependencies) {
            const std::size_t from = task(static_cast<std::size_t>(d)), to = task(i);
            if (from != to && successors[from].insert(to).second) ++indegree[to];
        }
    }
    std::vector<std::size_t> ready;
    std::size_t tasks = 0, visited = 0;
    for (std::size_t i = 0; i < n; ++i) {
        if (passes_[i].culled || task(i) != i) continue;
        ++tasks;
        if (indegree[i] == 0) ready.push_back(i);
    }
    while (!ready.empty()) {
        const std::size_t t = ready.back();
        ready.pop_back();
        ++visited;
        for (std::size_t s : successors[t])
            if (--indegree[s] == 0) ready.push_back(s);
    }
    return visited == tasks;
}

void ExecutionPlan::chooseStreams() {
    for (int i : order_) {
        PlannedPass& producer = passes_[static_cast<std::size_t>(i)];
        if (producer.culled || producer.streamHost >= 0) continue;
        for (const SlotSpec& out : producer.registration->spec.outputs) {
            if (!out.streamable) continue;
            const std::string buffer = slotBuffer(producer.node.outputBindings, out.name);
            const bool isResult = std::any_of(pipeline_.results.begin(), pipeline_.results.end(),
                                              [&](const std::string& r) { return finalVersion(r) == buffer; });
            if (isResult || saves_.count(buffer)) continue;
            std::vector<std::size_t> readers;
            bool allStreamable = true;
            for (std::size_t j = 0; j < passes_.size(); ++j) {
                const PlannedPass& reader = passes_[j];
                if (reader.culled) continue;
                for (const SlotSpec& in : reader.registration->spec.inputs) {
                    if (slotBuffer(reader.node.inputBindings, in.name) != buffer) continue;
                    if (readers.empty() || readers.back() != j) readers.push_back(j);
                    allStreamable = allStreamable && in.streamable;
                }
            }
            // A reader that streams its own outputs, or is already fed by another producer, stays separate.
            const bool hostable = std::all_of(readers.begin(), readers.end(), [&](std::size_t j) {
                const PlannedPass& reader = passes_[j];
                return (reader.streamHost < 0 || reader.streamHost == i) && reader.streamedOutputs.empty();
            });
            if (readers.empty() || !allStreamable || !hostable) continue;
            std::vector<int> previousHosts;
            for (std::size_t j : readers) {
                previousHosts.push_back(passes_[j].streamHost);
                passes_[j].streamHost = i;
            }
            if (fusedTasksAcyclic()) {
                producer.streamedOutputs.push_back(out.name);
            } else {
                for (std::size_t k = 0; k < readers.size(); ++k) passes_[readers[k]].streamHost = previousHosts[k];
            }
        }
    }
}

std::string ExecutionPlan::toDot(bool unroll) const {
    // Folded, every iteration of a block is drawn as its first: one box per block
    // pass inside a cluster labelled with the count; edges between iterations
    // (carried buffers) become edges inside the cluster.
    const auto shown = [&](const PlannedPass& p) {
        if (unroll || p.block < 0) return p.node.instance;
        return blocks_[static_cast<std::size_t>(p.block)].name + "." + p.paramsKey;
    };
    const auto bufferLabel = [&](const std::string& version) {
        if (unroll) return version;
        const auto dot = version.find("].");
        return dot == std::string::npos ? version : version.substr(dot + 2);
    };
    std::ostringstream dot;
    dot << "digraph \"" << pipeline_.name << "\" {\n  rankdir=LR;\n  node [shape=box, fontname=\"Helvetica\"];\n";
    std::set<std::string> drawn;
    const auto drawNode = [&](const PlannedPass& p) {
        const std::string id = shown(p);
        if (!drawn.insert(id).second) return;
        dot << "  \"" << id << "\" [label=\"" << (unroll || p.block < 0 ? p.node.instance : p.paramsKey);
        if (p.paramsKey != p.node.pass) dot << "\\n(" << p.node.pass << ")";
        dot << "\"" << (p.culled ? ", style=dashed, color=gray" : "") << "];\n";
    };
    for (const PlannedPass& p : passes_)
        if (p.block < 0 || unroll) drawNode(p);
    for (std::size_t b = 0; b < blocks_.size() && !unroll; ++b) {
        const PlannedBlock& block = blocks_[b];
        dot << "  subgraph \"cluster_" << block.name << "\" {\n    label=\"repeat " << block.name << " x " << block.count;
        if (!block.untilSignal.empty()) dot << ", until " << block.untilInstance << "." << block.untilSignal;
        if (block.seconds > 0) dot << ", at most " << block.seconds << " s";
        dot << "\";\n  ";
        for (int i : block.iterationPasses.front()) drawNode(passes_[static_cast<std::size_t>(i)]);
        dot << "  }\n";
    }
    std::set<std::string> edges;
    for (const PlannedPass& p : passes_) {
        for (const auto& [slot, buffer] : p.node.inputBindings) {
            if (buffer.empty()) continue;
            std::string from;
            if (imports_.count(buffer)) {
                from = "import:" + buffer;
                if (drawn.insert(from).second)
                    dot << "  \"" << from << "\" [shape=folder, label=\"" << buffer << "\\n" << imports_.at(buffer).second << "\"];\n";
            } else {
                from = shown(passes_[static_cast<std::size_t>(producer_.at(buffer))]);
            }
            const bool isStreamed = streamed(buffer);
            std::ostringstream edge;
            edge << "  \"" << from << "\" -> \"" << shown(p) << "\" [label=\"" << bufferLabel(buffer) << " : "
                 << (imports_.count(buffer) ? imports_.at(buffer).first : bufferTypeOf(buffer)) << (isStreamed ? " (batches)" : "") << "\""
                 << (isStreamed ? ", style=bold" : "") << "];\n";
            if (edges.insert(edge.str()).second) dot << edge.str();
        }
    }
    for (const std::string& result : pipeline_.results) {
        const std::string version = finalVersion(result);
        dot << "  \"result:" << result << "\" [shape=note];\n";
        if (producer_.count(version))
            dot << "  \"" << shown(passes_[static_cast<std::size_t>(producer_.at(version))]) << "\" -> \"result:" << result << "\";\n";
    }
    for (const auto& [version, path] : saves_) {
        dot << "  \"save:" << version << "\" [shape=folder, label=\"" << path << "\"];\n";
        dot << "  \"" << shown(passes_[static_cast<std::size_t>(producer_.at(version))]) << "\" -> \"save:" << version << "\";\n";
    }
    dot << "}\n";
    return dot.str();
}

std::string ExecutionPlan::bufferTypeOf(const std::string& version) const {
    const auto it = producer_.find(version);
    if (it == producer_.end()) return imports_.count(version) ? imports_.at(version).first : "";
    const PlannedPass& p = passes_[static_cast<std::size_t>(it->second)];
    for (const auto& [slot, bound] : p.node.outputBindings) {
        if (bound != version) continue;
        for (const SlotSpec* out : writeSlots(p.registration->spec))
            if (out->name == slot) return out->type;
    }
    return "";
}

// Books wall time, and this thread's CPU time less the chunks it ran (booked
// to their own passes) and less nested timed bodies.
void timePass(PassTiming& timing, const std::string& label, const std::function<void()>& body) {
    const std::int64_t wall0 = jobs::wallNanos();
    const std::int64_t cpu0 = jobs::threadCpuNanos();
    const std::int64_t chunkCpu0 = jobs::chunkCpuOnThisThread();
    const std::int64_t nestedCpu0 = tPassSerialCpu;
    {
        jobs::ScopedContext scope(&timing.work);
        body();
    }
    const std::int64_t wall1 = jobs::wallNanos();
    const std::int64_t serialCpu =
        (jobs::threadCpuNanos() - cpu0) - (jobs::chunkCpuOnThisThread() - chunkCpu0) - (tPassSerialCpu - nestedCpu0);
    tPassSerialCpu += serialCpu;
    timing.serialCpuNs += serialCpu;
    timing.wallNs += wall1 - wall0;
    if (timing.firstStartNs < 0) timing.firstStartNs = wall0;
    if (jobs::TraceRecorder::instance().enabled())
        jobs::TraceRecorder::instance().record({label, "pass", jobs::threadSlot(), wall0, wall1, 0});
}

RunResult execute(const ExecutionPlan& plan, const Scene& scene, const RayQuery& rays, const RunOptions& options) {
    return execute(plan, scene, &rays, options);
}

namespace {

// One pass instance while it runs: its context, its time so far (possibly in
// several pieces: the batches it consumed inside its producer's task, then its
// own run) and the stand-in handles its streamed inputs point at.
struct PassRun {
    std::unique_ptr<Pass> instance;
    std::unique_ptr<PassContext> ctx;
    std::map<std::string, BufferHandle*> inputs, outputs;
    std::map<std::string, BufferHandle> streamedInputs;  // slot -> handle holding the current batch
    PassTiming timing;
    std::int64_t batchWallNs = 0;  // wall time of readers' batches run inside this pass
    std::size_t largestBatchBytes = 0;
    std::int64_t batches = 0;
};

// A failed allocation inside a pass is the job asking for more than the
// machine has (preflight estimates only what it can foresee): the user's
// problem to fix, so an InputError naming the pass, not an internal error.
template <class Body>
void timed(PassRun& run, const std::string& label, Body&& body) {
    try {
        timePass(run.timing, label, body);
    } catch (const std::bad_alloc&) {
        throw InputError("pass '" + label +
                         "' ran out of memory; lower its sizes (film, photons, batch_size, wave_size) or free memory");
    }
}

}  // namespace

RunResult execute(const ExecutionPlan& plan, const Scene& scene, const RayQuery* rays, const RunOptions& options) {
    const auto& passes = plan.passes();
    const std::size_t n = passes.size();

    // Buffer versions and how many live passes still have to read each.
    std::map<std::string, BufferHandle> buffers;
    std::map<std::string, std::atomic<int>> readers;
    std::set<std::string> kept;  // results and saved versions: never freed by the run
    for (const std::string& r : plan.pipeline().results) kept.insert(plan.finalVersion(r));
    for (const auto& [version, path] : plan.saves()) kept.insert(version);
    for (const PlannedPass& p : passes) {
        if (p.culled) continue;
        for (const SlotSpec* out : writeSlots(p.registration->spec)) buffers[p.node.outputBindings.at(out->name)].type = out->type;
    }
    for (const auto& [version, typeAndPath] : plan.imports()) {
        const auto it = options.imported.find(version);
        if (it == options.imported.end()) throw std::logic_error("imported buffer '" + version + "' was not loaded");
        buffers[version] = it->second;
    }
    for (const PlannedPass& p : passes) {
        if (p.culled) continue;
        for (const SlotSpec* in : readSlots(p.registration->spec)) {
            const std::string& version = p.node.inputBindings.at(in->name);
            if (!version.empty()) ++readers[version];
        }
        // The version an output would take if the iteration were skipped is held
        // until the pass has run or been skipped.
        if (p.block >= 0 && plan.blocks()[static_cast<std::size_t>(p.block)].canExitEarly())
            for (const auto& [slot, source] : p.skipAliases) ++readers[source];
    }
    std::mutex bufferMutex;  // guards freeing against concurrent lookups

    // Readers each pass hosts (streams), in topological order.
    std::vector<std::vector<std::size_t>> hosted(n);
    for (int i : plan.topologicalOrder()) {
        const PlannedPass& p = passes[static_cast<std::size_t>(i)];
        if (!p.culled && p.streamHost >= 0) hosted[static_cast<std::size_t>(p.streamHost)].push_back(static_cast<std::size_t>(i));
    }

    // Early exit of repeat blocks. Iteration j + 1 waits for all of iteration j
    // (plan edges), so the first of its passes to start sees the final state.
    struct BlockState {
        std::atomic<int> stopAfter{std::numeric_limits<int>::max()};
        std::atomic<std::int64_t> startNs{-1};
        std::unique_ptr<std::once_flag[]> decided;
        std::once_flag aliased;
        std::atomic<bool> interrupted{false};
        // Live passes of each iteration not yet finished: an iteration is a unit of work.
        std::unique_ptr<std::atomic<int>[]> unfinished;
    };
    std::vector<BlockState> blockStates(plan.blocks().size());
    for (std::size_t b = 0; b < plan.blocks().size(); ++b) {
        const PlannedBlock& block = plan.blocks()[b];
        blockStates[b].decided = std::make_unique<std::once_flag[]>(static_cast<std::size_t>(block.count));
        blockStates[b].unfinished = std::make_unique<std::atomic<int>[]>(static_cast<std::size_t>(block.count));
        for (std::size_t it = 0; it < block.iterationPasses.size(); ++it) {
            int live = 0;
            for (int member : block.iterationPasses[it]) live += passes[static_cast<std::size_t>(member)].culled ? 0 : 1;
            blockStates[b].unfinished[it].store(live);
        }
    }
    const std::int64_t runStart = jobs::wallNanos();
    // Whether pass i belongs to an iteration the block no longer runs. The first
    // time that is so, every later iteration's outputs take the versions of the
    // last iteration that ran, before any skipped reader can free them.
    const auto skipped = [&](std::size_t i) {
        const PlannedPass& p = passes[i];
        if (p.block < 0) return false;
        const PlannedBlock& block = plan.blocks()[static_cast<std::size_t>(p.block)];
        BlockState& state = blockStates[static_cast<std::size_t>(p.block)];
        if (p.iteration == 0) {
            std::int64_t unset = -1;
            state.startNs.compare_exchange_strong(unset, jobs::wallNanos());
            return false;
        }
        std::call_once(state.decided[static_cast<std::size_t>(p.iteration)], [&] {
            if (stopRequested() && p.iteration <= state.stopAfter.load()) {
                state.stopAfter.store(std::min(state.stopAfter.load(), p.iteration - 1));
                state.interrupted = true;
            }
            if (block.seconds > 0.0 && p.iteration <= state.stopAfter.load() &&
                1e-9 * static_cast<double>(jobs::wallNanos() - state.startNs.load()) >= block.seconds)
                state.stopAfter.store(std::min(state.stopAfter.load(), p.iteration - 1));
        });
        if (p.iteration <= state.stopAfter.load()) return false;
        std::call_once(state.aliased, [&] {
            std::lock_guard lock(bufferMutex);
            for (std::size_t it = static_cast<std::size_t>(p.iteration); it < block.iterationPasses.size(); ++it) {
                for (int member : block.iterationPasses[it]) {
                    const PlannedPass& m = passes[static_cast<std::size_t>(member)];
                    if (m.culled) continue;
                    for (const auto& [slot, from] : m.skipAliases) {
                        BufferHandle& target = buffers.at(m.node.outputBindings.at(slot));
                        const BufferHandle& source = buffers.at(from);
                        target.data = source.data;
                        target.bytes = source.bytes;
                    }
                }
            }
        });
        return true;
    };

    RunResult result;
    std::vector<PassStats> stats(n);
    std::vector<bool> ran(n, false);
    std::set<std::string> savedVersions;
    std::vector<PassRun> runs(n);

    const auto prepare = [&](std::size_t i) {
        const PlannedPass& pass = passes[i];
        PassRun& run = runs[i];
        {
            std::lock_guard lock(bufferMutex);
            for (const SlotSpec& in : pass.registration->spec.inputs) {
                const std::string& buffer = pass.node.inputBindings.at(in.name);
                if (buffer.empty()) {
                    run.inputs[in.name] = nullptr;
                } else if (plan.streamed(buffer)) {
                    BufferHandle& standIn = run.streamedInputs[in.name];
                    standIn.type = in.type;
                    run.inputs[in.name] = &standIn;
                } else {
                    run.inputs[in.name] = &buffers.at(buffer);
                }
            }
            for (const SlotSpec* out : writeSlots(pass.registration->spec))
                run.outputs[out->name] = &buffers.at(pass.node.outputBindings.at(out->name));
            // In place: the new version starts as the old one's storage.
            for (const SlotSpec& io : pass.registration->spec.inouts) {
                const BufferHandle& old = buffers.at(pass.node.inputBindings.at(io.name));
                BufferHandle& next = *run.outputs[io.name];
                next.data = old.data;
                next.bytes = old.bytes;
            }
        }
        run.ctx = std::make_unique<PassContext>(scene, rays, options.film, options.seed, pass.params, run.inputs,
                                                run.outputs, pass.node.instance);
        run.ctx->setIteration(pass.iteration);
        run.ctx->setStoppable(pass.block < 0);
        run.ctx->setDeclaredSignals(pass.registration->spec.signals);
        if (options.progress) run.ctx->setProgressSink(options.progress);
        run.timing.work.label = pass.node.instance;
        run.instance = pass.registration->create();
    };
    // Stored inputs a pass could also read in batches arrive as one batch (for a
    // hosted reader, once its host has run: the host may have produced them).
    const auto consumeStored = [&](std::size_t i) {
        const PlannedPass& pass = passes[i];
        PassRun& run = runs[i];
        for (const SlotSpec& in : pass.registration->spec.inputs) {
            const std::string& buffer = pass.node.inputBindings.at(in.name);
            if (in.streamable && !buffer.empty() && !plan.streamed(buffer))
                timed(run, pass.node.instance, [&] { run.instance->consumeBatch(*run.ctx, in.name); });
        }
    };
    // Every input this pass was the last reader of is freed.
    const auto releaseInputs = [&](std::size_t i) {
        const PlannedPass& pass = passes[i];
        std::lock_guard lock(bufferMutex);
        for (const SlotSpec* in : readSlots(pass.registration->spec)) {
            const std::string& buffer = pass.node.inputBindings.at(in->name);
            if (buffer.empty()) continue;
            if (--readers[buffer] == 0 && !kept.count(buffer)) buffers[buffer].data.reset();
        }
        if (pass.block >= 0 && plan.blocks()[static_cast<std::size_t>(pass.block)].canExitEarly())
            for (const auto& [slot, source] : pass.skipAliases)
                if (--readers[source] == 0 && !kept.count(source)) buffers[source].data.reset();
        // Outputs nobody reads (side outputs of a needed pass) go at once.
        for (const SlotSpec* out : writeSlots(pass.registration->spec)) {
            const std::string& buffer = pass.node.outputBindings.at(out->name);
            if (readers[buffer] == 0 && !kept.count(buffer)) buffers[buffer].data.reset();
        }
    };

    const auto finish = [&](std::size_t i) {
        const PlannedPass& pass = passes[i];
        PassRun& run = runs[i];
        PassStats& s = stats[i];
        ran[i] = true;
        s.instance = pass.node.instance;
        s.pass = pass.node.pass;
        if (pass.block >= 0) {
            s.block = plan.blocks()[static_cast<std::size_t>(pass.block)].name;
            s.blockPass = pass.paramsKey;
        }
        s.startSeconds = 1e-9 * static_cast<double>(run.timing.firstStartNs - runStart);
        s.wallSeconds = 1e-9 * static_cast<double>(run.timing.wallNs - run.batchWallNs);
        s.cpuSeconds = run.timing.cpuSeconds();
        s.items = run.ctx->items();
        s.counters = run.ctx->counters();
        s.batchesEmitted = run.batches;
        s.outputBytes = run.largestBatchBytes;
        s.partial = run.ctx->partial();
        for (const auto& [slot, handle] : run.outputs) {
            if (std::find(pass.streamedOutputs.begin(), pass.streamedOutputs.end(), slot) != pass.streamedOutputs.end())
                continue;
            if (!handle->data)
                throw std::logic_error("pass '" + pass.node.instance + "' did not produce its output '" + slot + "'");
            s.outputBytes += handle->bytes ? handle->bytes() : 0;
        }
        if (pass.block >= 0) {
            const PlannedBlock& block = plan.blocks()[static_cast<std::size_t>(pass.block)];
            if (!block.untilSignal.empty() && pass.paramsKey == block.untilInstance && run.ctx->signalled(block.untilSignal)) {
                std::atomic<int>& stopAfter = blockStates[static_cast<std::size_t>(pass.block)].stopAfter;
                int previous = stopAfter.load();
                while (pass.iteration < previous && !stopAfter.compare_exchange_weak(previous, pass.iteration)) {
                }
            }
        }
        run.ctx.reset();
        run.instance.reset();
        if (pass.block >= 0 &&
            --blockStates[static_cast<std::size_t>(pass.block)].unfinished[static_cast<std::size_t>(pass.iteration)] == 0)
            noteCompletedUnit();
        if (options.save) {
            for (const auto& [slot, handle] : run.outputs) {
                const auto saved = plan.saves().find(pass.node.outputBindings.at(slot));
                if (saved != plan.saves().end()) {
                    options.save(saved->first, saved->second, *handle);
                    std::lock_guard lock(bufferMutex);
                    savedVersions.insert(saved->first);
                }
            }
        }
        releaseInputs(i);
    };

    jobs::TaskGraph graph;
    std::vector<int> taskOf(n, -1);
    for (std::size_t i = 0; i < n; ++i) {
        const PlannedPass& p = passes[i];
        if (p.culled || p.streamHost >= 0) continue;
        taskOf[i] = graph.addTask([&, i] {
            const PlannedPass& pass = passes[i];
            if (skipped(i)) {
                releaseInputs(i);
                for (std::size_t reader : hosted[i]) releaseInputs(reader);
                return;
            }
            for (std::size_t reader : hosted[i]) prepare(reader);
            prepare(i);
            consumeStored(i);
            PassRun& run = runs[i];
            if (!pass.streamedOutputs.empty()) {
                run.ctx->setBatchSink(pass.streamedOutputs, [&, i](const std::string& slot, std::shared_ptr<void> batch,
                                                                   std::size_t bytes) {
                    PassRun& producer = runs[i];
                    const std::string& buffer = passes[i].node.outputBindings.at(slot);
                    const std::int64_t wall0 = jobs::wallNanos();
                    if (options.batchTap) options.batchTap(buffer, batch, bytes);
                    bool wanted = false;
                    for (std::size_t j : hosted[i]) {
                        const PlannedPass& reader = passes[j];
                        for (const SlotSpec& in : reader.registration->spec.inputs) {
                            if (reader.node.inputBindings.at(in.name) != buffer) continue;
                            if (!runs[j].ctx->wantsMoreBatches(in.name)) continue;
                            BufferHandle& standIn = runs[j].streamedInputs.at(in.name);
                            standIn.data = batch;
                            timed(runs[j], reader.node.instance, [&] { runs[j].instance->consumeBatch(*runs[j].ctx, in.name); });
                            standIn.data.reset();
                            wanted = wanted || runs[j].ctx->wantsMoreBatches(in.name);
                        }
                    }
                    producer.batchWallNs += jobs::wallNanos() - wall0;
                    producer.largestBatchBytes = std::max(producer.largestBatchBytes, bytes);
                    ++producer.batches;
                    return wanted;
                });
            }
            timed(run, pass.node.instance, [&] { run.instance->run(*run.ctx); });
            finish(i);
            for (std::size_t reader : hosted[i]) {
                consumeStored(reader);
                timed(runs[reader], passes[reader].node.instance, [&] { runs[reader].instance->run(*runs[reader].ctx); });
                finish(reader);
            }
        });
    }
    for (std::size_t i = 0; i < n; ++i)
        if (passes[i].streamHost >= 0 && !passes[i].culled) taskOf[i] = taskOf[static_cast<std::size_t>(passes[i].streamHost)];
    std::set<std::pair<int, int>> edges;
    for (std::size_t i = 0; i < n; ++i) {
        if (taskOf[i] < 0) continue;
        for (int d : passes[i].dependencies) {
            const int from = taskOf[static_cast<std::size_t>(d)], to = taskOf[i];
            if (from != to && edges.insert({from, to}).second) graph.addEdge(from, to);
        }
    }
    graph.run();
    // Versions made by skipped iterations hold what the last iteration run made.
    if (options.save) {
        for (const auto& [version, path] : plan.saves())
            if (!savedVersions.count(version) && buffers.at(version).data) options.save(version, path, buffers.at(version));
    }
    result.wallSeconds = 1e-9 * static_cast<double>(jobs::wallNanos() - runStart);
    for (int i : plan.topologicalOrder())
        if (ran[static_cast<std::size_t>(i)]) result.stats.push_back(stats[static_cast<std::size_t>(i)]);
    for (std::size_t b = 0; b < plan.blocks().size(); ++b) {
        const int stopAfter = blockStates[b].stopAfter.load();
        const int iterations = stopAfter == std::numeric_limits<int>::max() ? plan.blocks()[b].count : stopAfter + 1;
        result.iterations[plan.blocks()[b].name] = iterations;
        if (blockStates[b].interrupted)
            result.partial.push_back(plan.blocks()[b].name + ": " + std::to_string(iterations) + " of " +
                                     std::to_string(plan.blocks()[b].count) + " iterations");
    }
    for (const PassStats& s : result.stats)
        if (!s.partial.empty()) result.partial.push_back(s.partial);
    for (const std::string& r : plan.pipeline().results) result.results[r] = buffers.at(plan.finalVersion(r));
    return result;
}

}  // namespace fg
