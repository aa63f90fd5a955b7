// Pass scheduler. Validation happens entirely in ExecutionPlan::build so that a
// job with a mistake fails in milliseconds with one line, before any scene is
// loaded or pixel traced. Execution maps the plan onto a jobs::TaskGraph.
#include "engine/core/scheduler.h"

#include "engine/core/error.h"
#include "jobs/parallel.h"

#include <algorithm>
#include <atomic>
#include <cmath>
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

ExecutionPlan ExecutionPlan::build(const Pipeline& pipeline, const JobParams& params, const std::string& origin,
                                   const std::vector<PassRegistration>& registry) {
    ExecutionPlan plan;
    plan.pipeline_ = pipeline;
    const auto nodeSource = [&](const PipelineNode& node) {
        return node.sourceLine > 0 ? origin + ":" + std::to_string(node.sourceLine) : origin;
    };

    // Passes exist, instance names are unique, parameters are known and valid.
    std::set<std::string> instances;
    for (const PipelineNode& node : pipeline.nodes) {
        PlannedPass planned;
        planned.node = node;
        const auto registered = std::find_if(registry.begin(), registry.end(),
                                        [&](const PassRegistration& r) { return r.spec.name == node.pass; });
        planned.registration = registered == registry.end() ? nullptr : &*registered;
        if (!planned.registration) {
            std::string known;
            for (const auto& r : registry) known += (known.empty() ? "" : ", ") + r.spec.name;
            fail(nodeSource(node), "unknown pass '" + node.pass + "' (registered passes: " + known + ")");
        }
        if (!instances.insert(node.instance).second) {
            fail(nodeSource(node), "pass instance '" + node.instance + "' appears twice in pipeline '" +
                                       pipeline.name + "'");
        }
        const PassSpec& spec = planned.registration->spec;
        for (const ParamSpec& p : spec.params) planned.params.set(p.name, p.defaultValue);
        if (const auto it = params.values.find(node.instance); it != params.values.end()) {
            for (const auto& [key, setting] : it->second) {
                const auto found = std::find_if(spec.params.begin(), spec.params.end(),
                                                [&](const ParamSpec& p) { return p.name == key; });
                if (found == spec.params.end()) {
                    std::string known;
                    for (const auto& p : spec.params) known += (known.empty() ? "" : ", ") + p.name;
                    fail(setting.source, "unknown parameter '" + key + "' for pass '" + node.instance +
                                             "' (" + spec.name + " takes: " + known + ")");
                }
                planned.params.set(key, convertSetting(*found, setting, node.instance));
            }
        }
        for (const auto& [slot, buffer] : node.inputBindings) {
            (void)buffer;
            if (std::none_of(spec.inputs.begin(), spec.inputs.end(), [&](const SlotSpec& s) { return s.name == slot; }))
                fail(nodeSource(node), "pass '" + node.instance + "' has no input slot '" + slot + "'");
        }
        for (const auto& [slot, buffer] : node.outputBindings) {
            (void)buffer;
            if (std::none_of(spec.outputs.begin(), spec.outputs.end(), [&](const SlotSpec& s) { return s.name == slot; }))
                fail(nodeSource(node), "pass '" + node.instance + "' has no output slot '" + slot + "'");
        }
        plan.passes_.push_back(std::move(planned));
    }
    for (const auto& [instance, table] : params.values) {
        if (!instances.count(instance)) {
            const auto src = params.tableSource.find(instance);
            fail(src != params.tableSource.end() ? src->second : origin,
                 "[passes." + instance + "] names no pass of pipeline '" + pipeline.name + "'");
        }
    }

    // Every buffer has exactly one producer; every input has a producer of the same type.
    std::map<std::string, std::string> bufferType;
    for (std::size_t i = 0; i < plan.passes_.size(); ++i) {
        const PlannedPass& p = plan.passes_[i];
        for (const SlotSpec& out : p.registration->spec.outputs) {
            const std::string buffer = slotBuffer(p.node.outputBindings, out.name);
            if (plan.producer_.count(buffer)) {
                fail(nodeSource(p.node), "buffer '" + buffer + "' is produced by both '" +
                                             plan.passes_[plan.producer_[buffer]].node.instance + "' and '" +
                                             p.node.instance + "'");
            }
            plan.producer_[buffer] = static_cast<int>(i);
            bufferType[buffer] = out.type;
        }
    }
    for (PlannedPass& p : plan.passes_) {
        for (const SlotSpec& in : p.registration->spec.inputs) {
            const std::string buffer = slotBuffer(p.node.inputBindings, in.name);
            const auto it = plan.producer_.find(buffer);
            if (it == plan.producer_.end()) {
                fail(nodeSource(p.node), "input '" + in.name + "' (" + in.type + ") of pass '" + p.node.instance +
                                             "' reads buffer '" + buffer + "', which no pass produces");
            }
            if (bufferType[buffer] != in.type) {
                fail(nodeSource(p.node), "input '" + in.name + "' of pass '" + p.node.instance + "' expects " +
                                             in.type + " but buffer '" + buffer + "' is " + bufferType[buffer] +
                                             " (from '" + plan.passes_[it->second].node.instance + "')");
            }
            if (std::find(p.dependencies.begin(), p.dependencies.end(), it->second) == p.dependencies.end())
                p.dependencies.push_back(it->second);
        }
    }
    for (const std::string& result : pipeline.results) {
        if (!plan.producer_.count(result))
            fail(origin, "pipeline '" + pipeline.name + "' promises result '" + result + "' but no pass produces it");
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
    std::vector<bool> needed(n, false);
    std::vector<int> stack;
    for (const std::string& result : pipeline.results) stack.push_back(plan.producer_[result]);
    while (!stack.empty()) {
        const int i = stack.back();
        stack.pop_back();
        if (needed[static_cast<std::size_t>(i)]) continue;
        needed[static_cast<std::size_t>(i)] = true;
        for (int d : plan.passes_[static_cast<std::size_t>(i)].dependencies) stack.push_back(d);
    }
    for (std::size_t i = 0; i < n; ++i) plan.passes_[i].culled = !needed[i];
    if (pipeline.streamBatches) plan.chooseStreams();
    return plan;
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
            if (std::find(pipeline_.results.begin(), pipeline_.results.end(), buffer) != pipeline_.results.end())
                continue;
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

std::string ExecutionPlan::toDot() const {
    std::ostringstream dot;
    dot << "digraph \"" << pipeline_.name << "\" {\n  rankdir=LR;\n  node [shape=box, fontname=\"Helvetica\"];\n";
    for (const PlannedPass& p : passes_) {
        dot << "  \"" << p.node.instance << "\" [label=\"" << p.node.instance;
        if (p.node.instance != p.node.pass) dot << "\\n(" << p.node.pass << ")";
        dot << "\"" << (p.culled ? ", style=dashed, color=gray" : "") << "];\n";
    }
    for (const PlannedPass& p : passes_) {
        for (const SlotSpec& in : p.registration->spec.inputs) {
            const std::string buffer = slotBuffer(p.node.inputBindings, in.name);
            const PlannedPass& from = passes_[static_cast<std::size_t>(producer_.at(buffer))];
            const bool isStreamed = streamed(buffer);
            dot << "  \"" << from.node.instance << "\" -> \"" << p.node.instance << "\" [label=\"" << buffer
                << " : " << in.type << (isStreamed ? " (batches)" : "") << "\"" << (isStreamed ? ", style=bold" : "")
                << "];\n";
        }
    }
    for (const std::string& result : pipeline_.results) {
        dot << "  \"result:" << result << "\" [shape=note];\n";
        dot << "  \"" << passes_[static_cast<std::size_t>(producer_.at(result))].node.instance << "\" -> \"result:"
            << result << "\";\n";
    }
    dot << "}\n";
    return dot.str();
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
    jobs::WorkContext work;
    std::int64_t firstStart = -1;
    std::int64_t wallNs = 0;
    std::int64_t serialCpuNs = 0;
    std::int64_t batchWallNs = 0;  // wall time of readers' batches run inside this pass
    std::size_t largestBatchBytes = 0;
    std::int64_t batches = 0;
};

// Runs body() booked to `run`: wall time, and this thread's CPU time less the
// chunks it ran (booked to their own passes) and less nested timed bodies.
template <class Body>
void timed(PassRun& run, const std::string& label, Body&& body) {
    const std::int64_t wall0 = jobs::wallNanos();
    const std::int64_t cpu0 = jobs::threadCpuNanos();
    const std::int64_t chunkCpu0 = jobs::chunkCpuOnThisThread();
    const std::int64_t nestedCpu0 = tPassSerialCpu;
    {
        jobs::ScopedContext scope(&run.work);
        body();
    }
    const std::int64_t wall1 = jobs::wallNanos();
    const std::int64_t serialCpu =
        (jobs::threadCpuNanos() - cpu0) - (jobs::chunkCpuOnThisThread() - chunkCpu0) - (tPassSerialCpu - nestedCpu0);
    tPassSerialCpu += serialCpu;
    run.serialCpuNs += serialCpu;
    run.wallNs += wall1 - wall0;
    if (run.firstStart < 0) run.firstStart = wall0;
    if (jobs::TraceRecorder::instance().enabled())
        jobs::TraceRecorder::instance().record({label, "pass", jobs::threadSlot(), wall0, wall1, 0});
}

}  // namespace

RunResult execute(const ExecutionPlan& plan, const Scene& scene, const RayQuery* rays, const RunOptions& options) {
    const auto& passes = plan.passes();
    const std::size_t n = passes.size();

    // Buffers and how many live passes still have to read each.
    std::map<std::string, BufferHandle> buffers;
    std::map<std::string, std::atomic<int>> readers;
    std::set<std::string> results(plan.pipeline().results.begin(), plan.pipeline().results.end());
    for (const PlannedPass& p : passes) {
        if (p.culled) continue;
        for (const SlotSpec& out : p.registration->spec.outputs)
            buffers[slotBuffer(p.node.outputBindings, out.name)].type = out.type;
    }
    for (const PlannedPass& p : passes) {
        if (p.culled) continue;
        for (const SlotSpec& in : p.registration->spec.inputs) ++readers[slotBuffer(p.node.inputBindings, in.name)];
    }
    std::mutex bufferMutex;  // guards freeing against concurrent lookups

    // Readers each pass hosts (streams), in topological order.
    std::vector<std::vector<std::size_t>> hosted(n);
    for (int i : plan.topologicalOrder()) {
        const PlannedPass& p = passes[static_cast<std::size_t>(i)];
        if (!p.culled && p.streamHost >= 0) hosted[static_cast<std::size_t>(p.streamHost)].push_back(static_cast<std::size_t>(i));
    }

    RunResult result;
    std::vector<PassStats> stats(n);
    std::vector<PassRun> runs(n);
    const std::int64_t runStart = jobs::wallNanos();

    const auto prepare = [&](std::size_t i) {
        const PlannedPass& pass = passes[i];
        PassRun& run = runs[i];
        {
            std::lock_guard lock(bufferMutex);
            for (const SlotSpec& in : pass.registration->spec.inputs) {
                const std::string buffer = slotBuffer(pass.node.inputBindings, in.name);
                if (plan.streamed(buffer)) {
                    BufferHandle& standIn = run.streamedInputs[in.name];
                    standIn.type = in.type;
                    run.inputs[in.name] = &standIn;
                } else {
                    run.inputs[in.name] = &buffers.at(buffer);
                }
            }
            for (const SlotSpec& out : pass.registration->spec.outputs)
                run.outputs[out.name] = &buffers.at(slotBuffer(pass.node.outputBindings, out.name));
        }
        run.ctx = std::make_unique<PassContext>(scene, rays, options.film, options.seed, pass.params, run.inputs,
                                                run.outputs, pass.node.instance);
        if (options.progress) run.ctx->setProgressSink(options.progress);
        run.work.label = pass.node.instance;
        run.instance = pass.registration->create();
    };
    // Stored inputs a pass could also read in batches arrive as one batch (for a
    // hosted reader, once its host has run: the host may have produced them).
    const auto consumeStored = [&](std::size_t i) {
        const PlannedPass& pass = passes[i];
        PassRun& run = runs[i];
        for (const SlotSpec& in : pass.registration->spec.inputs) {
            if (in.streamable && !plan.streamed(slotBuffer(pass.node.inputBindings, in.name)))
                timed(run, pass.node.instance, [&] { run.instance->consumeBatch(*run.ctx, in.name); });
        }
    };

    const auto finish = [&](std::size_t i) {
        const PlannedPass& pass = passes[i];
        PassRun& run = runs[i];
        PassStats& s = stats[i];
        s.instance = pass.node.instance;
        s.pass = pass.node.pass;
        s.startSeconds = 1e-9 * static_cast<double>(run.firstStart - runStart);
        s.wallSeconds = 1e-9 * static_cast<double>(run.wallNs - run.batchWallNs);
        s.cpuSeconds = 1e-9 * static_cast<double>(run.serialCpuNs + run.work.chunkCpuNs.load());
        s.items = run.ctx->items();
        s.counters = run.ctx->counters();
        s.batchesEmitted = run.batches;
        s.outputBytes = run.largestBatchBytes;
        for (const auto& [slot, handle] : run.outputs) {
            if (std::find(pass.streamedOutputs.begin(), pass.streamedOutputs.end(), slot) != pass.streamedOutputs.end())
                continue;
            if (!handle->data)
                throw std::logic_error("pass '" + pass.node.instance + "' did not produce its output '" + slot + "'");
            s.outputBytes += handle->bytes ? handle->bytes() : 0;
        }
        run.ctx.reset();
        run.instance.reset();

        // Free every input this pass was the last reader of.
        std::lock_guard lock(bufferMutex);
        for (const SlotSpec& in : pass.registration->spec.inputs) {
            const std::string buffer = slotBuffer(pass.node.inputBindings, in.name);
            if (--readers[buffer] == 0 && !results.count(buffer)) buffers[buffer].data.reset();
        }
        // Outputs nobody reads (side outputs of a needed pass) go at once.
        for (const SlotSpec& out : pass.registration->spec.outputs) {
            const std::string buffer = slotBuffer(pass.node.outputBindings, out.name);
            if (readers[buffer] == 0 && !results.count(buffer)) buffers[buffer].data.reset();
        }
    };

    jobs::TaskGraph graph;
    std::vector<int> taskOf(n, -1);
    for (std::size_t i = 0; i < n; ++i) {
        const PlannedPass& p = passes[i];
        if (p.culled || p.streamHost >= 0) continue;
        taskOf[i] = graph.addTask([&, i] {
            const PlannedPass& pass = passes[i];
            for (std::size_t reader : hosted[i]) prepare(reader);
            prepare(i);
            consumeStored(i);
            PassRun& run = runs[i];
            if (!pass.streamedOutputs.empty()) {
                run.ctx->setBatchSink(pass.streamedOutputs, [&, i](const std::string& slot, std::shared_ptr<void> batch,
                                                                   std::size_t bytes) {
                    PassRun& producer = runs[i];
                    const std::string buffer = slotBuffer(passes[i].node.outputBindings, slot);
                    const std::int64_t wall0 = jobs::wallNanos();
                    for (std::size_t j : hosted[i]) {
                        const PlannedPass& reader = passes[j];
                        for (const SlotSpec& in : reader.registration->spec.inputs) {
                            if (slotBuffer(reader.node.inputBindings, in.name) != buffer) continue;
                            BufferHandle& standIn = runs[j].streamedInputs.at(in.name);
                            standIn.data = batch;
                            timed(runs[j], reader.node.instance, [&] { runs[j].instance->consumeBatch(*runs[j].ctx, in.name); });
                            standIn.data.reset();
                        }
                    }
                    producer.batchWallNs += jobs::wallNanos() - wall0;
                    producer.largestBatchBytes = std::max(producer.largestBatchBytes, bytes);
                    ++producer.batches;
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
    result.wallSeconds = 1e-9 * static_cast<double>(jobs::wallNanos() - runStart);
    for (int i : plan.topologicalOrder())
        if (!passes[static_cast<std::size_t>(i)].culled) result.stats.push_back(stats[static_cast<std::size_t>(i)]);
    for (const std::string& r : results) result.results[r] = buffers.at(r);
    return result;
}

}  // namespace fg
